import numpy as np
import pytest

from aril_ros.envs import POSITION, VELOCITY, EnvLayoutError, MujocoSim, layout_of

# (obs_dim, act_dim, qpos_offset, n_position, n_velocity, first names)
EXPECTED = {
    "HalfCheetah-v5": (17, 6, 1, 8, 9, ["rootz:pos", "rooty:pos", "bthigh:pos"]),
    "Ant-v5": (105, 8, 2, 13, 14, ["root[2]:pos", "root[3]:pos"]),
    "Swimmer-v5": (8, 2, 2, 3, 5, ["free_body_rot:pos", "motor1_rot:pos", "motor2_rot:pos"]),
}


@pytest.mark.parametrize("env_id", sorted(EXPECTED))
def test_layout_and_zero_order_mask(env_id):
    obs_dim, act_dim, offset, n_pos, n_vel, first = EXPECTED[env_id]
    lay = layout_of(env_id)
    assert (lay.obs_dim, lay.act_dim, lay.qpos_offset, lay.n_position, lay.n_velocity) == (
        obs_dim, act_dim, offset, n_pos, n_vel)
    assert list(lay.names[: len(first)]) == first
    assert len(lay.names) == obs_dim
    mask = lay.zero_order_mask
    assert mask.sum() == n_pos and mask[:n_pos].all() and not mask[n_pos:].any()
    assert lay.kinds[lay.position.start] == POSITION and lay.kinds[lay.velocity.start] == VELOCITY
    assert all(name.endswith(":vel") for name in lay.names[lay.velocity])
    assert lay.other.stop - lay.other.start == obs_dim - n_pos - n_vel


def test_zero_order_entries_are_qpos_and_velocities_are_qvel():
    sim = MujocoSim("Ant-v5")
    obs = sim.reset(seed=3)
    lay = sim.layout
    np.testing.assert_array_equal(obs[lay.position], sim.data.qpos[lay.qpos_offset:])
    np.testing.assert_array_equal(obs[lay.velocity], sim.data.qvel)
    sim.close()


def test_other_mujoco_ids_are_inferred():
    lay = layout_of("Hopper-v5")
    assert (lay.qpos_offset, lay.n_position, lay.n_velocity, lay.obs_dim) == (1, 5, 6, 11)


@pytest.mark.parametrize("env_id, message", [
    ("CartPole-v1", "not a gymnasium MuJoCo environment"),
    ("NoSuchEnv-v0", "unknown gymnasium env id"),
    ("Reacher-v5", "does not start with qpos"),
])
def test_clear_errors_for_unsupported_ids(env_id, message):
    with pytest.raises(EnvLayoutError, match=message):
        layout_of(env_id)


@pytest.mark.parametrize("env_id", ["HalfCheetah-v5", "Ant-v5", "Swimmer-v5"])
def test_full_state_round_trip_replays_exactly(env_id):
    sim = MujocoSim(env_id)
    sim.reset(seed=1)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (40, sim.layout.act_dim))
    for a in actions[:20]:
        sim.step(a)
    state = sim.get_state()
    first = [sim.step(a)[0] for a in actions[20:]]
    sim.set_state(state)
    again = [sim.step(a)[0] for a in actions[20:]]
    np.testing.assert_array_equal(np.array(first), np.array(again))
    sim.close()


def test_set_state_rejects_bad_input():
    sim = MujocoSim("Swimmer-v5")
    sim.reset(seed=0)
    good = sim.get_state()
    with pytest.raises(ValueError, match="entries"):
        sim.set_state(good[:-1])
    bad = good.copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        sim.set_state(bad)
    np.testing.assert_array_equal(sim.get_state(), good)  # a rejected state changes nothing
    sim.close()


def test_reset_is_seeded_not_global():
    a, b = MujocoSim("HalfCheetah-v5"), MujocoSim("HalfCheetah-v5")
    np.random.seed(123)  # global state must not matter
    oa = a.reset(seed=7)
    np.random.seed(999)
    ob = b.reset(seed=7)
    np.testing.assert_array_equal(oa, ob)
    assert not np.array_equal(oa, a.reset(seed=8))


def test_physical_perturbation_moves_exactly_the_observed_qpos_entries():
    import mujoco

    from aril_ros.step import physical_state

    a, b, c = MujocoSim("Ant-v5"), MujocoSim("Ant-v5"), MujocoSim("Ant-v5")
    for sim in (a, b, c):
        sim.reset(seed=2)
    delta = np.zeros(a.layout.obs_dim)
    delta[a.layout.position] = np.random.default_rng(0).uniform(-0.1, 0.1, a.layout.n_position)
    obs_a = a.perturb(delta)
    # the rule, written out by hand on MuJoCo's own arrays: qpos[k:] += delta[position], nothing else
    b.data.qpos[b.layout.qpos_offset:] += delta[b.layout.position]
    mujoco.mj_forward(b.model, b.data)
    np.testing.assert_array_equal(obs_a, b.observe())
    # the graph's way (the attacker sends the whole moved state to the simulator) lands on the same state
    c.set_state(physical_state(c.layout, c.get_state(), delta))
    np.testing.assert_array_equal(obs_a, c.observe())
    np.testing.assert_array_equal(a.get_state(), c.get_state())
    assert len(a.state_names) == a.state_size and a.state_names[0] == "time"
    assert a.state_names[1] == "root[0]:pos"

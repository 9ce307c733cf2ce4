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


# --- the batched step against gymnasium's own, bit for bit ---

BATCHED_ENVS = ["HalfCheetah-v5", "Ant-v5", "Swimmer-v5", "Hopper-v5", "Walker2d-v5"]


def random_states(env_id, n, rng):
    """Integration states of ``n`` gymnasium resets moved by random noise, some far enough that Hopper,
    Walker2d and Ant start unhealthy (the terminated branch)."""
    import mujoco

    from aril_ros.envs import make_gym_env

    env = make_gym_env(env_id)
    sim = env.unwrapped
    states = []
    for i in range(n):
        env.reset(seed=i)
        scale = 0.5 if i % 3 == 2 else 0.05
        sim.data.qpos[:] += rng.uniform(-scale, scale, sim.model.nq)
        sim.data.qvel[:] += rng.normal(0.0, 20 * scale, sim.model.nv)
        mujoco.mj_forward(sim.model, sim.data)
        state = np.empty(mujoco.mj_stateSize(sim.model, mujoco.mjtState.mjSTATE_INTEGRATION))
        mujoco.mj_getState(sim.model, sim.data, state, mujoco.mjtState.mjSTATE_INTEGRATION)
        states.append(state)
    env.close()
    return np.array(states)


def gymnasium_steps(env_id, state, actions, horizon):
    """gymnasium's ``env.step`` (every wrapper of ``gym.make``) from ``state``: per step the observation,
    reward, terminated, truncated and the integration state after it."""
    import warnings

    import mujoco

    from aril_ros.envs import make_gym_env

    env = make_gym_env(env_id, horizon)
    env.reset(seed=0)
    model, data = env.unwrapped.model, env.unwrapped.data
    mujoco.mj_setState(model, data, state, mujoco.mjtState.mjSTATE_INTEGRATION)
    mujoco.mj_forward(model, data)
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the checker's warnings on actions outside the box
        for a in actions:
            obs, reward, terminated, truncated, _ = env.step(a)
            after = np.empty_like(state)
            mujoco.mj_getState(model, data, after, mujoco.mjtState.mjSTATE_INTEGRATION)
            out.append((obs, reward, terminated, truncated, after))
    env.close()
    return out


@pytest.mark.parametrize("env_id", BATCHED_ENVS)
def test_batched_step_is_gymnasiums_bit_for_bit(env_id):
    from aril_ros.rollout import SimBatch

    n, steps, horizon = 5, 12, 8  # past the horizon: truncated both ways
    rng = np.random.default_rng(1)
    states = random_states(env_id, n, rng)
    act_dim = layout_of(env_id).act_dim
    # float32 like gymnasium's action space, float64 like a policy's; beyond the box too (MuJoCo clamps ctrl)
    actions = rng.uniform(-1.5, 1.5, (steps, n, act_dim))
    actions = [a.astype(np.float32) if t % 2 else a for t, a in enumerate(actions)]
    batch = SimBatch(env_id, n, horizon, threads=3)  # uneven groups of rows
    assert batch.sims[0].rules is not None, batch.sims[0].batched
    for sim, state in zip(batch.sims, states):
        sim.set_state(state)
        sim.elapsed = 0
    expected = [gymnasium_steps(env_id, states[i], [a[i] for a in actions], horizon) for i in range(n)]
    terminated_seen = set()
    for t, a in enumerate(actions):
        obs, reward, terminated, truncated = batch.step(a, range(n))
        for i, sim in enumerate(batch.sims):
            want_obs, want_reward, want_terminated, want_truncated, want_state = expected[i][t]
            where = f"{env_id} row {i} step {t}"
            assert obs[i].tobytes() == want_obs.tobytes(), where
            assert obs[i].dtype == want_obs.dtype and np.float64(reward[i]).tobytes() == np.float64(want_reward).tobytes(), where
            assert (terminated[i], truncated[i]) == (want_terminated, want_truncated), where
            assert sim.get_state().tobytes() == want_state.tobytes(), where
            terminated_seen.add(bool(terminated[i]))
    if env_id in ("Hopper-v5", "Walker2d-v5", "Ant-v5"):
        assert terminated_seen == {True, False}
    batch.close()


@pytest.mark.parametrize("env_id", BATCHED_ENVS)
def test_batched_step_and_perturbation_do_not_depend_on_the_batch(env_id):
    """32 simulators on the pool step, perturb and observe each row as one simulator alone does (the batch is given
    its observations, which spare reading them again where no mj_forward is needed; one simulator alone reads them)."""
    from aril_ros.rollout import SimBatch

    n, lay = 32, layout_of(env_id)
    rng = np.random.default_rng(2)
    actions = rng.uniform(-1, 1, (6, n, lay.act_dim))
    delta = np.zeros((6, n, lay.obs_dim))
    delta[..., lay.position] = rng.uniform(-0.05, 0.05, (6, n, lay.n_position))
    batch, alone = SimBatch(env_id, n, threads=2), MujocoSim(env_id)
    batch_obs = batch.reset(list(range(n)))
    runs = []
    for t in range(6):
        seen = batch.seen("physical", batch_obs, delta[t], range(n))
        runs.append((seen, *batch.step(actions[t], range(n))))
        batch_obs = runs[-1][1]
    for i in range(n):
        obs = alone.reset(i)
        for t in range(6):
            seen = alone.perturb(delta[t, i])
            assert seen.tobytes() == alone.gym_env._get_obs().tobytes()  # gymnasium's observation of the moved state
            obs, reward, terminated, truncated = alone.step(actions[t, i])
            got = runs[t]
            assert got[0][i].tobytes() == seen.tobytes() and got[1][i].tobytes() == obs.tobytes()
            assert (got[2][i], got[3][i], got[4][i]) == (reward, terminated, truncated)
        assert batch.sims[i].get_state().tobytes() == alone.get_state().tobytes()
    batch.close()


@pytest.mark.parametrize("env_id", BATCHED_ENVS)
def test_the_engines_physical_attack_steps_as_the_graphs_set_state_does(env_id):
    """The engine moves the state and calls ``mj_forward`` only where the rules read derived quantities; the
    graph's simulator replaces the whole state and always calls it. Every step after is the same bit for bit."""
    from aril_ros.step import physical_state

    lay, rng = layout_of(env_id), np.random.default_rng(3)
    engine, graph = MujocoSim(env_id), MujocoSim(env_id)
    engine.reset(seed=4), graph.reset(seed=4)
    for t in range(8):
        delta = np.zeros(lay.obs_dim)
        delta[lay.position] = rng.uniform(-0.05, 0.05, lay.n_position)
        graph.set_state(physical_state(lay, graph.get_state(), delta))
        assert engine.perturb(delta).tobytes() == graph.observe().tobytes(), f"{env_id} step {t}"
        action = rng.uniform(-1, 1, lay.act_dim)
        (obs, *outcome), (want_obs, *want_outcome) = engine.step(action), graph.step(action)
        assert obs.tobytes() == want_obs.tobytes() and outcome == want_outcome, f"{env_id} step {t}"
        assert engine.get_state().tobytes() == graph.get_state().tobytes(), f"{env_id} step {t}"


def test_an_env_without_batched_rules_is_stepped_by_gymnasium():
    sim = MujocoSim("InvertedPendulum-v5")
    assert sim.rules is None and "InvertedPendulumEnv has no batched rules" in sim.batched
    sim.reset(seed=0)
    obs, reward, terminated, truncated = sim.step(np.array([0.1]))
    assert obs.shape == (sim.layout.obs_dim,) and reward == 1.0 and not terminated and not truncated

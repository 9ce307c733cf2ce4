import numpy as np
import pytest

from aril_ros.attacks import Attack, NoAttack, RandomAttack, make_attack
from aril_ros.envs import MujocoSim, layout_of
from aril_ros.rollout import RolloutEngine

H = 60  # short episodes keep the suite fast; the engine is the same at 1000


def engine(env_id, make_policy, mode="sensory", attack="random", eps=0.1, n_envs=3, horizon=H):
    policy, expert = make_policy(env_id, seed=1), make_policy(env_id, seed=2)
    return RolloutEngine(
        env_id, policy, expert, make_attack(attack, layout_of(env_id), eps, victim=policy, expert=expert), mode,
        n_envs=n_envs, horizon=horizon,
    )


FIELDS = ("true_obs", "obs", "delta", "action", "expert_action", "reward", "length")


@pytest.mark.parametrize("mode", ["clean", "sensory", "physical"])
def test_same_seed_gives_identical_arrays(mode, make_policy):
    attack = "none" if mode == "clean" else "random"
    a = engine("HalfCheetah-v5", make_policy, mode, attack).rollout(4, seed=5)
    b = engine("HalfCheetah-v5", make_policy, mode, attack).rollout(4, seed=5)
    c = engine("HalfCheetah-v5", make_policy, mode, attack).rollout(4, seed=6)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert not np.array_equal(a.true_obs, c.true_obs)


@pytest.mark.slow
@pytest.mark.parametrize("attack", ["random", "fgsm_k"])
@pytest.mark.parametrize("mode", ["sensory", "physical"])
def test_results_do_not_depend_on_how_many_envs_run_side_by_side(mode, attack, make_policy):
    one = engine("Swimmer-v5", make_policy, mode, attack, n_envs=1).rollout(5, seed=0)
    many = engine("Swimmer-v5", make_policy, mode, attack, n_envs=4).rollout(5, seed=0)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(one, name), getattr(many, name), err_msg=name)


@pytest.mark.parametrize("attack", ["random", "fgsm", "fgsm_k"])
@pytest.mark.parametrize("mode", ["sensory", "physical"])
@pytest.mark.parametrize("env_id", ["HalfCheetah-v5", "Ant-v5", "Swimmer-v5"])
def test_perturbation_bounds(env_id, mode, attack, make_policy):
    eps = 0.07
    traj = engine(env_id, make_policy, mode, attack, eps=eps, horizon=30).rollout(2, seed=0)
    mask = layout_of(env_id).zero_order_mask
    steps = traj.step_mask
    delta = traj.delta[steps]
    assert np.all(np.abs(delta[:, mask]) <= eps)
    assert np.all(delta[:, ~mask] == 0)
    assert np.abs(delta[:, mask]).max() > 0.9 * eps  # the budget is used, not just respected
    seen_minus_true = (traj.obs - traj.true_obs)[steps]
    np.testing.assert_allclose(seen_minus_true[:, mask], delta[:, mask], atol=1e-12)
    if mode == "sensory":
        assert np.all(seen_minus_true[:, ~mask] == 0)


def test_projection_clips_any_proposal():
    class Wild(Attack):
        name = "wild"

        def propose(self, true_obs, rngs):
            return np.full_like(true_obs, 5.0)

    lay = layout_of("Ant-v5")
    delta = Wild(lay, 0.2).perturb(np.zeros((2, lay.obs_dim)), [None, None])
    assert np.all(delta[:, lay.zero_order_mask] == 0.2) and np.all(delta[:, ~lay.zero_order_mask] == 0)


def replay(env_id, traj, episode, physical):
    """Step a fresh simulator with the recorded actions, moving its state by delta only if physical."""
    sim = MujocoSim(env_id, horizon=H)
    true = [sim.reset(traj.seed + episode)]
    for t in range(traj.length[episode] - 1):
        if physical:
            sim.perturb(traj.delta[episode, t])
        true.append(sim.step(traj.action[episode, t])[0])
    sim.close()
    return np.array(true)


def test_sensory_attack_leaves_the_true_state_untouched(make_policy):
    traj = engine("HalfCheetah-v5", make_policy, "sensory").rollout(2, seed=3)
    for e in range(2):
        np.testing.assert_array_equal(replay("HalfCheetah-v5", traj, e, physical=False), traj.true_obs[e, :H])
    # ... while the policy saw something else
    assert np.abs(traj.obs - traj.true_obs).max() > 0


def test_physical_attack_moves_the_state_the_dynamics_continue_from(make_policy):
    traj = engine("HalfCheetah-v5", make_policy, "physical").rollout(2, seed=3)
    for e in range(2):
        np.testing.assert_array_equal(replay("HalfCheetah-v5", traj, e, physical=True), traj.true_obs[e, :H])
        unperturbed = replay("HalfCheetah-v5", traj, e, physical=False)
        assert not np.allclose(unperturbed[1:], traj.true_obs[e, 1:H])


def test_expert_labels_the_true_state(make_policy):
    eng = engine("Swimmer-v5", make_policy, "sensory")
    traj = eng.rollout(2, seed=0)
    for e in range(2):
        np.testing.assert_array_equal(traj.expert_action[e], eng.expert.act(traj.true_obs[e]))
        np.testing.assert_array_equal(traj.action[e], eng.policy.act(traj.obs[e]))


def test_episodes_that_terminate_stop_early(make_policy):
    # A physical attack that pushes Ant's torso down makes it unhealthy (z < 0.2) at once.
    class Sink(Attack):
        name = "sink"

        def propose(self, true_obs, rngs):
            delta = np.zeros_like(true_obs)
            delta[:, 0] = -self.eps
            return delta

    lay = layout_of("Ant-v5")
    eng = RolloutEngine("Ant-v5", make_policy("Ant-v5"), make_policy("Ant-v5"), Sink(lay, 0.5), "physical",
                        n_envs=2, horizon=H)
    traj = eng.rollout(2, seed=0)
    assert np.all(traj.length < H)
    assert np.all(traj.reward[~traj.step_mask] == 0)


def test_clean_mode_refuses_an_attack_and_mismatched_policies(make_policy):
    lay = layout_of("Swimmer-v5")
    with pytest.raises(ValueError, match="clean runs no attack"):
        RolloutEngine("Swimmer-v5", make_policy("Swimmer-v5"), make_policy("Swimmer-v5"),
                      RandomAttack(lay, 0.1), "clean")
    with pytest.raises(ValueError, match="expert: policy is for HalfCheetah-v5"):
        RolloutEngine("Swimmer-v5", make_policy("Swimmer-v5"), make_policy("HalfCheetah-v5"), NoAttack(lay, 0))
    with pytest.raises(ValueError, match="unknown mode"):
        RolloutEngine("Swimmer-v5", make_policy("Swimmer-v5"), make_policy("Swimmer-v5"), mode="sideways")
    with pytest.raises(ValueError, match="unknown attack"):
        make_attack("fgsm-ish", lay, 0.1)
    with pytest.raises(ValueError, match="eps must be"):
        make_attack("random", lay, -1)

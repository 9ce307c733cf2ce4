"""Timing attacks on the engine (aril_ros.timing): budgets held, what the policy saw and what the simulator applied
traceable to their steps, and an episode's timing its own."""
import numpy as np
import pytest

from aril_ros.attacks import make_attack
from aril_ros.envs import layout_of
from aril_ros.rollout import RolloutEngine
from aril_ros.step import DEFAULT_ACTION, episode_rng, may_drop, timing_rng
from aril_ros.timing import TimingAttack, TimingBudget

H = 80
ENV = "Swimmer-v5"


def steps_of(make_policy, budget, chooser, mode="clean", n_envs=3, episodes=3, seed=7):
    """Every step of ``episodes`` episodes under the timing attack, per episode: its StepBatch rows in order."""
    policy, expert = make_policy(ENV, seed=1), make_policy(ENV, seed=2)
    attack = make_attack("none" if mode == "clean" else "random", layout_of(ENV), 0.1)
    engine = RolloutEngine(ENV, policy, expert, attack, mode, n_envs=n_envs, horizon=H,
                           timing=TimingAttack(budget, chooser))
    per_episode = {e: [] for e in range(episodes)}
    for step in engine.iter_steps(episodes, seed):
        for row, e in enumerate(step.episodes):
            per_episode[e].append({name: (value[row] if isinstance(value, np.ndarray) else value)
                                   for name, value in vars(step).items() if name not in ("episodes",)})
    engine.close()
    return per_episode


@pytest.mark.parametrize("chooser", ["fixed", "random"])
def test_the_policy_sees_an_observation_of_its_episode_no_older_than_the_delay(make_policy, chooser):
    for steps in steps_of(make_policy, TimingBudget(delay=3), chooser).values():
        ages = [s["obs_age"] for s in steps]
        assert max(ages) <= 3 and all(age <= s["t"] for age, s in zip(ages, steps))
        for s in steps:  # clean: the observation of step t - age is that step's true one
            np.testing.assert_array_equal(s["obs"], steps[s["t"] - s["obs_age"]]["true_obs"])
        if chooser == "fixed":
            assert ages == [min(3, s["t"]) for s in steps]
        else:
            assert set(ages[3:]) == {0, 1, 2, 3}


@pytest.mark.parametrize("chooser", ["fixed", "random"])
def test_drops_show_the_last_observation_again_and_never_exceed_their_share_of_any_prefix(make_policy, chooser):
    for steps in steps_of(make_policy, TimingBudget(drop=0.2), chooser, mode="sensory").values():
        dropped = [s["obs_age"] > 0 for s in steps]
        assert any(dropped)
        for t in range(len(steps)):
            assert sum(dropped[:t + 1]) <= 0.2 * (t + 1) + 1e-9
            if dropped[t]:  # the observation seen at t - 1 again: the value attack's at its own step
                np.testing.assert_array_equal(steps[t]["obs"], steps[t - 1]["obs"])
            else:
                np.testing.assert_array_equal(steps[t]["obs"], steps[t]["true_obs"] + steps[t]["delta"])
        if chooser == "fixed":  # every drop as soon as the share allows it: steps 4, 9, 14, ...
            assert [t for t, d in enumerate(dropped) if d] == list(range(4, len(steps), 5))


def test_may_drop_counts_every_prefix():
    drops, share = np.array([0, 0, 1, 1]), 0.25
    assert may_drop(drops, 3, share).tolist() == [True, True, False, False]  # 1 of 4, 2 of 4
    assert may_drop(np.array([0]), 2, share).tolist() == [False]  # 1 of 3 is over a quarter


@pytest.mark.parametrize("chooser", ["fixed", "random"])
def test_the_simulator_applies_an_action_no_older_than_the_action_delay_and_rest_before_the_first(make_policy,
                                                                                                  chooser):
    for steps in steps_of(make_policy, TimingBudget(action_delay=2), chooser).values():
        for s in steps:
            assert 0 <= s["action_age"] <= 2
            step = s["t"] - s["action_age"]
            expected = steps[step]["action"] if step >= 0 else np.full_like(s["action"], DEFAULT_ACTION)
            np.testing.assert_array_equal(s["applied_action"], expected)
            np.testing.assert_array_equal(s["obs"], s["true_obs"])  # observations on time
        if chooser == "fixed":
            assert [s["action_age"] for s in steps] == [2] * len(steps)


def test_an_episodes_timing_is_its_own_whatever_runs_beside_it(make_policy):
    budget = TimingBudget(delay=2, drop=0.2, action_delay=1)
    one = steps_of(make_policy, budget, "random", mode="sensory", n_envs=1)
    many = steps_of(make_policy, budget, "random", mode="sensory", n_envs=3)
    for e in one:
        for a, b in zip(one[e], many[e], strict=True):
            for name in ("obs", "applied_action", "obs_age", "action_age", "delta", "reward"):
                np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def test_a_timing_attack_keeps_the_value_attacks_noise(make_policy):
    """The timing stream is apart from the value attack's: random noise (state-independent) is the same draw for
    draw with the timing attack as without."""
    timed = steps_of(make_policy, TimingBudget(delay=2), "random", mode="sensory", episodes=2)
    untimed = steps_of(make_policy, TimingBudget(), "fixed", mode="sensory", episodes=2)
    for e in timed:
        n = min(len(timed[e]), len(untimed[e]))
        np.testing.assert_array_equal(np.stack([s["delta"] for s in timed[e][:n]]),
                                      np.stack([s["delta"] for s in untimed[e][:n]]))
    assert untimed[0][0]["obs_age"] is None  # no budget: no timing attack at all
    assert timing_rng(7, 0).random(4).tolist() != episode_rng(7, 0).random(4).tolist()  # nor the same draws


def test_budgets_are_checked():
    with pytest.raises(ValueError, match="delay:= and action_delay:= are steps"):
        TimingBudget(delay=-1)
    with pytest.raises(ValueError, match="drop:= is a share"):
        TimingBudget(drop=1.0)
    with pytest.raises(ValueError, match="unknown timing chooser 'late'; choose one of fixed, random"):
        TimingAttack(TimingBudget(delay=1), "late")

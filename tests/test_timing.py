"""Timing attacks on the engine (aril_ros.timing): budgets held, what the policy saw and what the simulator applied
traceable to their steps, and an episode's timing its own, whoever picks it (fixed, random, a learned timing
adversary)."""
from pathlib import Path

import numpy as np
import pytest

from aril_ros.adversary import AdversaryConfig, train_adversary
from aril_ros.attacks import make_attack
from aril_ros.envs import layout_of
from aril_ros.policy import save_policy
from aril_ros.rollout import RolloutEngine
from aril_ros.step import DEFAULT_ACTION, episode_rng, may_drop, timing_rng
from aril_ros.timing import TimingAttack, TimingBudget
from tests.conftest import random_policy

H = 80
ENV = "Swimmer-v5"
CHOOSERS = ["fixed", "random", "learned"]
TRAINED: dict[tuple, Path] = {}


def timing_adversary(budget: TimingBudget, folder: Path, env_id: str = ENV, victim: Path | None = None,
                     expert: Path | None = None, seed: int = 0) -> Path:
    """A timing adversary of ``budget`` briefly trained (2048 steps) against ``victim`` (default: the random policy
    of seed 1 that :func:`steps_of` attacks), labelled by ``expert`` (seed 2's); trained once per session."""
    if victim is None:
        victim, expert = (save_policy(random_policy(env_id, seed=s), folder / f"{env_id}-{s}.pt") for s in (1, 2))
    key = (budget, env_id, str(victim), seed)
    if key not in TRAINED:
        TRAINED[key] = train_adversary(AdversaryConfig(
            env=env_id, mode="clean", delay=budget.delay, drop=budget.drop, action_delay=budget.action_delay,
            victim=str(victim), expert=str(expert), steps=2048, n_envs=4, rollout=128, minibatch=128, warmup=5,
            seed=seed, out=str(folder / f"timing-{env_id}-{budget.delay}-{budget.drop}-{budget.action_delay}-{seed}.pt")),
            log=lambda *a, **k: None)
    return TRAINED[key]


@pytest.fixture(scope="module")
def trained_here(tmp_path_factory):
    return tmp_path_factory.mktemp("timing-adversaries")


def steps_of(make_policy, budget, chooser, mode="clean", n_envs=3, episodes=3, seed=7, folder=None):
    """Every step of ``episodes`` episodes under the timing attack, per episode: its StepBatch rows in order
    (``learned``: a timing adversary of the budget, trained into ``folder``)."""
    policy, expert = make_policy(ENV, seed=1), make_policy(ENV, seed=2)
    attack = make_attack("none" if mode == "clean" else "random", layout_of(ENV), 0.1)
    file = str(timing_adversary(budget, folder)) if chooser == "learned" else ""
    engine = RolloutEngine(ENV, policy, expert, attack, mode, n_envs=n_envs, horizon=H,
                           timing=TimingAttack(budget, chooser, file))
    per_episode = {e: [] for e in range(episodes)}
    for step in engine.iter_steps(episodes, seed):
        for row, e in enumerate(step.episodes):
            row_of = {name: (value[row] if isinstance(value, np.ndarray) else value)
                      for name, value in vars(step).items() if name not in ("episodes",)}
            if step.timing is not None:
                row_of["obs_age"], row_of["dropped"], row_of["action_age"] = step.timing[row].astype(int)
            else:
                row_of["obs_age"] = None
            per_episode[e].append(row_of)
    engine.close()
    return per_episode


@pytest.mark.parametrize("chooser", CHOOSERS)
def test_the_policy_sees_an_observation_of_its_episode_no_older_than_the_delay(make_policy, chooser, trained_here):
    for steps in steps_of(make_policy, TimingBudget(delay=3), chooser, folder=trained_here).values():
        ages = [s["obs_age"] for s in steps]
        assert max(ages) <= 3 and all(age <= s["t"] for age, s in zip(ages, steps))
        for s in steps:  # clean: the observation of step t - age is that step's true one
            np.testing.assert_array_equal(s["obs"], steps[s["t"] - s["obs_age"]]["true_obs"])
        if chooser == "fixed":
            assert ages == [min(3, s["t"]) for s in steps]
        elif chooser == "random":
            assert set(ages[3:]) == {0, 1, 2, 3}


@pytest.mark.parametrize("chooser", CHOOSERS)
def test_drops_show_the_last_observation_again_and_never_exceed_their_share_of_any_prefix(make_policy, chooser,
                                                                                          trained_here):
    for steps in steps_of(make_policy, TimingBudget(drop=0.2), chooser, mode="sensory", folder=trained_here).values():
        dropped = [bool(s["dropped"]) for s in steps]
        assert all(s["obs_age"] > 0 for s, d in zip(steps, dropped) if d)
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


@pytest.mark.parametrize("chooser", CHOOSERS)
def test_the_simulator_applies_an_action_no_older_than_the_action_delay_and_rest_before_the_first(make_policy,
                                                                                                  chooser, trained_here):
    for steps in steps_of(make_policy, TimingBudget(action_delay=2), chooser, folder=trained_here).values():
        for s in steps:
            assert 0 <= s["action_age"] <= 2
            step = s["t"] - s["action_age"]
            expected = steps[step]["action"] if step >= 0 else np.full_like(s["action"], DEFAULT_ACTION)
            np.testing.assert_array_equal(s["applied_action"], expected)
            np.testing.assert_array_equal(s["obs"], s["true_obs"])  # observations on time
        if chooser == "fixed":
            assert [s["action_age"] for s in steps] == [2] * len(steps)


@pytest.mark.parametrize("chooser", ["random", "learned"])
def test_an_episodes_timing_is_its_own_whatever_runs_beside_it(make_policy, chooser, trained_here):
    budget = TimingBudget(delay=2, drop=0.2, action_delay=1)
    one = steps_of(make_policy, budget, chooser, mode="sensory", n_envs=1, folder=trained_here)
    many = steps_of(make_policy, budget, chooser, mode="sensory", n_envs=3, folder=trained_here)
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


# ------------------------------------------------------------------------------- through the graph
@pytest.mark.slow
@pytest.mark.parametrize("mode, env_id, timing", [
    ("sensory", "HalfCheetah-v5", ("delay:=2", "drop:=0.2", "timing:=random")),
    ("clean", "Swimmer-v5", ("delay:=1",)),
    ("sensory", "Swimmer-v5", ("drop:=0.3",)),
    ("physical", "HalfCheetah-v5", ("action_delay:=2", "timing:=random")),
    ("clean", "Swimmer-v5", ("delay:=1", "action_delay:=1")),
    ("clean", "HalfCheetah-v5", ("delay:=2", "drop:=0.2", "action_delay:=1", "timing:=learned"))])
def test_a_timing_attack_through_the_graph_is_the_engines(mode, env_id, timing, tmp_path):
    """The attacker node delivers what the engine shows the policy, and the simulator node applies the action the
    engine applies, bit for bit; the log says per step how old the observation was, whether it was dropped and how
    old the applied action was; its reader checks that the observation is the one of the step it names."""
    from aril_ros.policy import load_policy
    from aril_ros.runlog import read_run
    from tests.conftest import assert_same_steps, policy_files, run_graph, summary_of

    policy, expert = policy_files(tmp_path, env_id)
    attack = "none" if mode == "clean" else "random"
    log = tmp_path / "run.mcap"
    settings = dict(arg.split(":=") for arg in timing)
    budget = TimingBudget(int(settings.get("delay", 0)), float(settings.get("drop", 0)),
                          int(settings.get("action_delay", 0)))
    chooser = settings.get("timing", "fixed")
    file = str(timing_adversary(budget, tmp_path, env_id, policy, expert)) if chooser == "learned" else ""
    summary = summary_of(run_graph(f"mode:={mode}", f"env:={env_id}", f"policy:={policy}", f"expert:={expert}",
                                   f"attack:={attack}", "eps:=0.1", "episodes:=2", "horizon:=80", "seed:=4",
                                   f"record:={log}", *timing, *([f"timing_file:={file}"] if file else [])))
    victim = load_policy(policy)
    engine = RolloutEngine(env_id, victim, load_policy(expert), make_attack(attack, layout_of(env_id), 0.1), mode,
                           n_envs=2, horizon=80, timing=TimingAttack(budget, chooser, file))
    traj = engine.rollout(2, seed=4)
    run = read_run(log)
    assert_same_steps(run, traj)
    for e in range(2):
        np.testing.assert_array_equal(run.timing[run.episodes == e], traj.timing[e, : traj.length[e]])
    assert run.timing[:, [0, 2]].max() >= 1  # something came late
    assert summary["mean_return"] == pytest.approx(traj.returns.mean(), abs=1e-3)
    assert summary["mean_expert_loss"] == pytest.approx(traj.mean_expert_loss, abs=1e-6)  # the applied action's
    assert summary["timing"] == {"delay": budget.delay, "drop": budget.drop, "action_delay": budget.action_delay,
                                 "chooser": chooser, **({"file": file} if file else {})}
    assert run.metadata["timing"] == summary["timing"]


@pytest.mark.slow
def test_a_timed_logs_reader_refuses_what_the_attacker_did_not_deliver(tmp_path):
    """Every rule of a timed step, broken in one step of a real timed log: an age that does not name the step shown,
    one beyond the delay, a drop beyond the share, a timing message missing; and a stray one in an untimed log."""
    from aril_ros import protocol as P
    from aril_ros.runlog import RunLogError, read_run
    from tests.conftest import policy_files, run_graph, summary_of
    from tests.test_log_faults import edited, steps_of, values, write_log

    policy, expert = policy_files(tmp_path, ENV)
    log = tmp_path / "timed.mcap"
    summary_of(run_graph("mode:=sensory", f"env:={ENV}", f"policy:={policy}", f"expert:={expert}", "attack:=random",
                         "eps:=0.1", "episodes:=1", "horizon:=30", "delay:=1", "drop:=0.2", f"record:={log}"))
    meta, steps = steps_of(log)
    assert read_run(write_log(tmp_path / "same.mcap", meta, steps)).tags == read_run(log).tags  # a faithful rewrite

    def with_timing(row, timing):
        stamp, messages = steps[row]
        return [*steps[:row], (stamp, {**messages, P.TIMING: edited(messages[P.TIMING], position=timing)}),
                *steps[row + 1:]]

    # fixed: a step late every step, and step 4 dropped (step 3 showed step 2's, shown again, 2 steps old)
    assert values(steps[4][1][P.TIMING]).tolist() == [2.0, 1.0, 0.0]
    assert values(steps[5][1][P.TIMING]).tolist() == [1.0, 0.0, 0.0]
    untimed = {k: v for k, v in meta.items() if k != "timing"}
    faults = {
        "on time, says it": (meta, with_timing(5, [0.0, 0.0, 0.0]),
                             r"step 0/5 observation: not step 5's sim/state \+ attack/perturbation"),
        "beyond the delay": (meta, with_timing(5, [2.0, 0.0, 0.0]), r"step 0/5 attack/timing: observation age 2, "
                                                                    r"beyond the delay 1"),
        "a drop too many": (meta, with_timing(3, [1.0, 1.0, 0.0]), r"step 0/3 attack/timing: drop 1 of 4 steps, "
                                                                  r"beyond the share 0.2"),
        "an action too old": (meta, with_timing(5, [1.0, 0.0, 1.0]), r"step 0/5 attack/timing: action age 1, beyond "
                                                                     r"the action delay 0"),
        "no timing": (meta, [(s, {k: v for k, v in m.items() if k != P.TIMING}) for s, m in steps],
                      r"step 0/0 misses attack/timing"),
        "timing in an untimed run": (untimed, steps, r"step 0/0 has attack/timing, which a run without a timing "
                                                     r"attack has not"),
    }
    for name, (run_meta, broken_steps, message) in faults.items():
        # written as the steps are, whatever the run's record says: a writer's channels follow the record
        writer = write_log(tmp_path / f"{name}.mcap", run_meta, [], close=False)
        if P.TIMING not in writer._channels:
            writer._register(P.TIMING, P.MESSAGE_TYPES[P.TIMING])
        writer.topics = tuple(t for t in P.TIMED_STEP_TOPICS if t in broken_steps[0][1])
        for stamp, messages in broken_steps:
            writer.write_step(stamp, messages)
        writer.close(interrupted=False, episodes=[])
        with pytest.raises(RunLogError, match=message):
            read_run(tmp_path / f"{name}.mcap")


def test_the_graph_refuses_observation_timing_where_the_simulator_publishes_the_observation():
    from aril_ros_nodes.graph_config import GraphConfig, plan_run
    from aril_ros_nodes.launcher import GraphError

    with pytest.raises(GraphError, match="delay:= and drop:= are played by the attacker node .* give mode:=clean or "
                                         "sensory"):
        plan_run(GraphConfig(mode="physical", delay=1))


@pytest.mark.slow
def test_a_timed_cell_gives_the_same_figures_through_the_graph_as_on_the_engine(tmp_path):
    """A cell with a timing attack (an aril eval's settings) reaches the graph whole: as a graph run (what the scorecard
    and a DAgger round through the graph run) it gives the engine's figures."""
    from aril_ros.cell_runner import CellRunner
    from aril_ros.evaluation import EvalConfig
    from tests.conftest import free_domain, policy_files

    policy, expert = policy_files(tmp_path, ENV)
    cell = EvalConfig(env=ENV, policy=str(policy), expert=str(expert), mode="sensory", attack="random", eps=0.1,
                      episodes=2, seed=3, horizon=40, delay=1, drop=0.2, action_delay=1, timing="random")
    quiet = lambda *a, **k: None  # noqa: E731
    on_engine, = CellRunner("engine", 1, "").run([cell], quiet)
    through_graph, = CellRunner("graph", 1, "", domain=str(free_domain())).run([cell], quiet)
    assert through_graph["episodes"] == on_engine["episodes"]
    assert through_graph["mean_expert_loss"] == pytest.approx(on_engine["mean_expert_loss"], abs=1e-6)

"""A zero perturbation is no perturbation: the physical mode under ``attack:=none`` runs exactly as clean, on the
engine and on the graph. Rewriting an unchanged state had MuJoCo derive the bodies' positions anew, which Ant's
reward reads: its episodes drifted from clean by up to 0.75 return (issue 37)."""
from __future__ import annotations

import numpy as np
import pytest

from aril_ros.attacks import NoAttack
from aril_ros.envs import MujocoSim, layout_of
from aril_ros.runlog import read_run
from aril_ros.policy import load_policy
from aril_ros.rollout import RolloutEngine, SimBatch
from aril_ros.step import physical_state
from tests.conftest import assert_same_steps, policy_files, run_graph, summary_of

FIELDS = ("true_obs", "obs", "delta", "action", "expert_action", "reward", "length")
ENVS = ["HalfCheetah-v5", "Ant-v5", "Swimmer-v5", "Hopper-v5"]


def engine_run(env_id, mode, policy, expert, horizon=60, episodes=2, seed=4):
    engine = RolloutEngine(env_id, policy, expert, NoAttack(layout_of(env_id), 0.0), mode, n_envs=2, horizon=horizon)
    try:
        return engine.rollout(episodes, seed)
    finally:
        engine.close()


@pytest.mark.parametrize("env_id", ENVS)
def test_physical_with_no_attack_is_clean_on_the_engine(env_id, make_policy):
    policy, expert = make_policy(env_id, seed=1), make_policy(env_id, seed=2)
    clean = engine_run(env_id, "clean", policy, expert)
    physical = engine_run(env_id, "physical", policy, expert)
    for name in FIELDS:
        assert getattr(physical, name).tobytes() == getattr(clean, name).tobytes(), name


@pytest.mark.parametrize("env_id", ENVS)
def test_a_zero_row_of_a_batch_steps_as_clean_beside_moved_rows(env_id):
    """The rule holds per simulator: rows 0 and 2 get a zero perturbation, rows 1 and 3 a real one."""
    lay, rng = layout_of(env_id), np.random.default_rng(5)
    batch, clean = SimBatch(env_id, 4, threads=2), MujocoSim(env_id)
    obs = batch.reset([7, 8, 7, 8])
    clean.reset(7)
    for t in range(10):
        delta = np.zeros((4, lay.obs_dim))
        delta[1::2, lay.position] = rng.uniform(-0.05, 0.05, (2, lay.n_position))
        action = rng.uniform(-1, 1, lay.act_dim)
        seen = batch.seen("physical", obs, delta, range(4))
        assert seen[0].tobytes() == obs[0].tobytes(), f"step {t}"
        obs, reward, terminated, _ = batch.step(np.repeat(action[None], 4, axis=0), range(4))
        want_obs, want_reward, want_terminated, _ = clean.step(action)
        for row in (0, 2):
            assert (obs[row].tobytes(), reward[row], terminated[row]) == (want_obs.tobytes(), want_reward,
                                                                           want_terminated), f"row {row} step {t}"
        assert not np.array_equal(obs[1], obs[3])  # the moved rows did move, each its own way
    batch.close()
    clean.close()


@pytest.mark.parametrize("env_id", ENVS)
def test_the_simulators_set_state_of_its_own_state_changes_nothing(env_id):
    """The graph's physical attack under attack:=none: the attacker sends the simulator its own state back."""
    lay, rng = layout_of(env_id), np.random.default_rng(6)
    graph, clean = MujocoSim(env_id), MujocoSim(env_id)
    graph.reset(3), clean.reset(3)
    for t in range(10):
        graph.set_state(physical_state(lay, graph.get_state(), np.zeros(lay.obs_dim)))
        action = rng.uniform(-1, 1, lay.act_dim)
        (obs, *outcome), (want_obs, *want_outcome) = graph.step(action), clean.step(action)
        assert obs.tobytes() == want_obs.tobytes() and outcome == want_outcome, f"step {t}"
    graph.close()
    clean.close()


def test_physical_with_no_attack_on_the_graph_is_the_engines_clean_run(tmp_path):
    env_id = "Ant-v5"
    policy, expert = policy_files(tmp_path, env_id)
    log = tmp_path / "run.mcap"
    summary = summary_of(run_graph("mode:=physical", f"env:={env_id}", f"policy:={policy}", f"expert:={expert}",
                                   "attack:=none", "episodes:=2", "horizon:=60", "seed:=4", f"record:={log}"))
    clean = engine_run(env_id, "clean", load_policy(policy), load_policy(expert))
    assert summary["mode"] == "physical" and summary["attack"] == "none"
    assert_same_steps(read_run(log), clean)

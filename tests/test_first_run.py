"""The first run a user makes: ``python run_graph.py mode:=sensory`` attacks the bundled DAgger learner with the
ARIL-A bundled against it, says so on its first line, and ends with the clean return of the same episodes beside
the attacked one (the engine's: the graph is bit-identical to it), in the terminal and in the JSON line."""
from __future__ import annotations

import json

import numpy as np
import pytest

from aril_ros.evaluation import EvalConfig, evaluate
from aril_ros.registry import adversary_path, choose_attack
from aril_ros.runlog import read_run
from tests.conftest import documented_node, episode_stats, free_domain, run_graph, start_node, stop, summary_of

SHORT = dict(episodes=2, horizon=60, seed=0)


@pytest.mark.slow
def test_the_first_run_attacks_with_the_adversary_bundled_against_dagger_beside_the_clean_return(tmp_path):
    out = run_graph("mode:=sensory", *(f"{k}:={v}" for k, v in SHORT.items()), f"record:={tmp_path / 'run.mcap'}",
                    process=True)  # the README's first command, as a user runs it
    summary = summary_of(out)
    first = out.stderr.splitlines()[0]
    assert summary["attack"] == "aril_a" and "ARIL-A trained against DAgger" in first, first
    # the figures the engine gives for the same episodes, clean and under the same adversary
    clean = evaluate(EvalConfig(policy="dagger", mode="clean", **SHORT))
    attacked = evaluate(EvalConfig(policy="dagger", mode="sensory", attack="aril_a",
                                   attack_file=str(adversary_path("HalfCheetah-v5", "sensory")), **SHORT))
    assert summary["returns"] == attacked["returns"]
    assert summary["clean"]["returns"] == clean["returns"] and summary["clean"]["source"] == "engine"
    assert summary["clean"]["mean_expert_loss"] == clean["mean_expert_loss"]
    assert summary["drop_pct"] == round(-100 * (clean["mean_return"] - attacked["mean_return"])
                                        / abs(clean["mean_return"]), 2)
    printed = out.stdout.splitlines()
    assert printed[-1] == json.dumps(summary)
    assert any(line.startswith("  clean") and f"{clean['mean_return']:.1f}" in line for line in printed)
    assert any(line.startswith("  attacked") and f"drop {summary['drop_pct']:+.1f}%" in line for line in printed)
    assert any(line.startswith("  log") and str(tmp_path / "run.mcap") in line for line in printed)


@pytest.mark.parametrize("policy, attack", [("aril", "aril_a"), ("expert", "random")])
def test_the_default_attack_is_the_adversary_bundled_against_the_policy_or_random_noise(policy, attack):
    choice = choose_attack("Swimmer-v5", "physical", policy)
    assert choice.name == attack
    assert choice.file == (str(adversary_path("Swimmer-v5", "physical", "aril")) if policy == "aril" else "")
    assert ("no adversary is bundled against expert" in choice.why) == (policy == "expert")
    assert choose_attack("Swimmer-v5", "physical", policy, "spsa").name == "spsa"  # a named one is kept
    assert choose_attack("Swimmer-v5", "clean", policy).name == "none"


@pytest.mark.slow
def test_an_external_nodes_clean_baseline_is_a_clean_run_of_the_graph(tmp_path):
    """The engine cannot run a node it does not have: the clean episodes go through the graph too, logged beside."""
    domain = free_domain()
    node = start_node(documented_node(), domain, tmp_path, "-p", "act_dim:=6")
    try:
        out = run_graph("mode:=sensory", "policy:=external", "attack:=random", "episodes:=2", "horizon:=30",
                        f"record:={tmp_path / 'run.mcap'}", domain=domain, besides=(node.pid,))
    finally:
        stop(node)
    summary = summary_of(out)
    assert summary["clean"]["source"] == "graph"
    run = read_run(tmp_path / "run-clean.mcap")
    assert not run.delta.any()
    returns = [e.reward for e in episode_stats(run)]
    np.testing.assert_allclose(summary["clean"]["returns"], returns, atol=5e-4)  # the summary rounds to 3 places
    assert any("a clean run of the graph with the external node" in line for line in out.stdout.splitlines())

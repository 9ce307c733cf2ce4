"""aril scorecard: paired cells, the drop and its interval from the episodes, the page, the black-box pipeline's
record and reuse of its files."""
import dataclasses
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from aril_ros.cell_runner import engine_cell
from aril_ros.evaluation import EvalConfig, evaluate
from aril_ros.adversary_net import load_adversary
from aril_ros.policy import load_policy
from aril_ros.registry import SCORECARD_ATTACKS, directed_adversary_path
from aril_ros.report.stats import t95
from aril_ros.scorecard import PIPELINE_ATTACKS, SCORED_ATTACKS, ScorecardConfig, scorecard
from aril_ros.verdict import ZOO_FOLDERS, relative, victim_digest, zoo_members


SMALL = dict(env="Swimmer-v5", modes="sensory", episodes=3, adversary_steps=4096, horizon=25, scales="2,1",
             attacks=",".join(SCORED_ATTACKS))  # every row, not the quick budget's few


@pytest.fixture(scope="module")
def small_card(tmp_path_factory):
    out = tmp_path_factory.mktemp("card")
    lines = []
    cfg = ScorecardConfig(policy="dagger", out=str(out), **SMALL)
    page = scorecard(cfg, log=lambda line, **_: lines.append(line))
    return cfg, out, page, lines


@pytest.mark.slow
def test_every_cell_runs_the_same_episodes_and_the_clean_one_is_aril_evals(small_card):
    cfg, out, _, _ = small_card
    card = json.loads((out / "scorecard.json").read_text())
    sensory = card["modes"]["sensory"]
    seeds_of = lambda cell: [e["env_seed"] for e in cell["episodes"]]  # noqa: E731
    assert seeds_of(sensory["clean"]) == [cfg.seed, cfg.seed + 1, cfg.seed + 2]
    assert set(sensory["attacks"]) == set(SCORED_ATTACKS)
    for sweep in sensory["attacks"].values():
        assert [float(s) for s in sweep] == [1.0, 2.0]
        for scale, cell in sweep.items():
            assert seeds_of(cell) == seeds_of(sensory["clean"])
            assert cell["eps"] == pytest.approx(float(scale) * sensory["eps"])
            assert max(e["max_abs_delta"] for e in cell["episodes"]) <= cell["eps"] + 1e-12
    clean = evaluate(EvalConfig(env=cfg.env, policy="dagger", episodes=3, seed=cfg.seed, horizon=25))
    assert [round(e["return"], 3) for e in sensory["clean"]["episodes"]] == clean["returns"]


@pytest.mark.slow
def test_the_worst_case_and_its_paired_interval_come_from_the_episodes(small_card):
    _, out, page, _ = small_card
    sensory = json.loads((out / "scorecard.json").read_text())["modes"]["sensory"]
    at_eps = {a: sweep["1.0"] for a, sweep in sensory["attacks"].items()}
    worst = min(at_eps, key=lambda a: at_eps[a]["mean_return"])
    clean = np.array([e["return"] for e in sensory["clean"]["episodes"]])
    diff = clean - np.array([e["return"] for e in at_eps[worst]["episodes"]])
    half = t95(2) * diff.std(ddof=1) / math.sqrt(3)
    base = abs(clean.mean())
    assert sensory["worst"]["attack"] == worst
    assert sensory["worst"]["drop_pct"] == pytest.approx(-100 * diff.mean() / base)
    assert sensory["worst"]["ci95_pct"] == pytest.approx([-100 * (diff.mean() + half) / base,
                                                          -100 * (diff.mean() - half) / base])
    text = page.read_text()
    assert f"{sensory['worst']['drop_pct']:+.1f}%" in text and "![return against eps, sensory](sweep-sensory.png)" in text
    png = (out / "sweep-sensory.png").read_bytes()
    # a PNG of the figure's size: 6 x 3.6 in at 110 dpi
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and np.frombuffer(png[16:24], ">u4").tolist() == [660, 396]


@pytest.mark.slow
def test_a_rerun_reuses_the_surrogate_and_the_adversary_trained_against_it(small_card, tmp_path):
    cfg, out, _, lines = small_card
    made = ("[surrogate]", "[sweep] adversary trainings")  # what fitting the surrogate and training ARIL-A log
    assert all(any(line.startswith(start) for line in lines) for start in made)
    again, rerun = [], shutil.copytree(out, tmp_path / "card")  # the other tests read the first run's folder
    scorecard(dataclasses.replace(cfg, attacks="aril_a,aril_a_directed", scales="1", out=str(rerun)),
              log=lambda line, **_: again.append(line))
    assert not any(line.startswith(made) for line in again)
    for name in ("surrogate-sensory.pt", "adversary-sensory.pt", "directed-sensory.pt"):
        assert (rerun / name).read_bytes() == (out / name).read_bytes()
    first, second = (json.loads((folder / "scorecard.json").read_text())["modes"]["sensory"] for folder in (out, rerun))
    assert second["clean"] == first["clean"]
    assert second["attacks"] == {row: {"1.0": first["attacks"][row]["1.0"]} for row in ("aril_a", "aril_a_directed")}
    # the cells ran as sweeps, whose progress is the scorecard's: the clean cell, the quick budget's timing row (the
    # policy a step late), then both ARIL-As at eps alone
    assert [line.split(",")[0] for line in again if line.startswith("[sweep] scorecard")] == [
        "[sweep] scorecard clean cell: 1/1 done", "[sweep] scorecard timing cells: 1/1 done",
        "[sweep] scorecard cells: 2/2 done"]


def test_the_page_quotes_each_attacks_paired_drop_and_questions_per_step_at_eps(small_card):
    """The page's rows are report.stats.paired_drop of the cells in scorecard.json (its one producer), and the
    questions each attack put to the policy per step, as scorecard.json counted them (a white-box one: gradients)."""
    from aril_ros.registry import WHITE_BOX
    from aril_ros.report.stats import paired_drop

    _, out, page, _ = small_card
    sensory = json.loads((out / "scorecard.json").read_text())["modes"]["sensory"]
    rows = {line.split(" | ")[0].lstrip("| "): line for line in page.read_text().splitlines() if line.startswith("| ")}
    assert rows["attack"].split(" | ")[4] == "questions per step"
    for attack, sweep in sensory["attacks"].items():
        drop = paired_drop(sensory["clean"], sweep["1.0"])
        row = rows[SCORECARD_ATTACKS[attack]]
        assert f"| {drop['drop_pct']:+.1f}% [{drop['ci95_pct'][0]:+.1f}, {drop['ci95_pct'][1]:+.1f}] |" in row
        asked = "gradients" if attack in WHITE_BOX else f"{sweep['1.0']['queries_per_step']:g}"
        assert row.split(" | ")[4] == asked
    per_step = {attack: sweep["1.0"]["queries_per_step"] for attack, sweep in sensory["attacks"].items()}
    assert per_step["spsa"] == 1 + 1 * (2 * 2 + 1) and per_step["random"] == per_step["transfer"] == 0
    assert per_step["aril_a_search"] == per_step["aril_a"] + 9 and sensory["clean"]["queries"] == 0
    assert per_step["fd_fgsm"] == 2 * 3  # the quick budget's one iteration: 2 questions per Swimmer position entry


def test_each_budget_runs_fd_fgsm_and_spsa_at_its_own_iterations_and_the_others_at_theirs():
    """fd_fgsm's cells iterate as the budget says (one probe batch a step in both: on screening episodes one iteration
    took at least as much as FGSM^k's 10 in 6 of 8 cells), SPSA^k's at the budget's directions (5 x 8 at the full
    budget), the other attacks at their own settings (white-box FGSM^k's k is not fd_fgsm's)."""
    from aril_ros.scorecard import BUDGETS, cell
    cfg = ScorecardConfig(policy="dagger", env="HalfCheetah-v5")
    full = {attack: cell(cfg, BUDGETS["full"], "sensory", attack, 0.04) for attack in ("fd_fgsm", "spsa", "fgsm_k")}
    assert (full["fd_fgsm"].k, full["spsa"].k, full["spsa"].samples, full["fgsm_k"].k) == (1, 5, 8, 0)
    quick = {attack: cell(cfg, BUDGETS["quick"], "sensory", attack, 0.04) for attack in ("fd_fgsm", "spsa")}
    assert (quick["fd_fgsm"].k, quick["spsa"].k, quick["spsa"].samples) == (1, 1, 2)


def test_the_full_budget_scores_the_rows_chosen_on_screening_episodes_unless_named():
    """The full budget scores the rows chosen on screening episodes for an external node's hour
    (scorecard.FULL_ROWS), the quick budget's among them: in sensory mode fd_fgsm and the directed ARIL-A, so that
    its pipeline fits no surrogate; a file's white-box rows stand beside them; attacks:= names any row back."""
    from aril_ros.scorecard import BUDGETS, rows_of
    full = BUDGETS["full"]
    file = ScorecardConfig(policy="dagger", env="HalfCheetah-v5", budget="full")
    every = list(SCORED_ATTACKS)
    assert rows_of(file, full, every, "sensory", None) == ["fd_fgsm", "aril_a_directed", "fgsm", "fgsm_k"]
    assert rows_of(file, full, every, "physical", None) == ["zoo", "aril_a", "fgsm", "fgsm_k"]
    assert set(BUDGETS["quick"].black_box["physical"]) <= set(full.black_box["physical"])
    assert set(BUDGETS["quick"].black_box["sensory"]) <= set(full.black_box["sensory"])
    named = dataclasses.replace(file, attacks="spsa,fd_fgsm,random")
    assert rows_of(named, full, ["spsa", "fd_fgsm", "random"], "physical", None) == ["spsa", "fd_fgsm", "random"]
    assert "86 queries per step (where attacks:= names it)" in full.describe()


def test_the_page_and_scorecard_json_say_how_the_black_box_pipeline_used_the_policy(small_card):
    """The rows of the pipeline's attacks, run on its files, and its line on the page: the surrogate's questions and
    held-out fidelity (its file's own record), the zoo's choice (the strongest of those screened, which are every
    bundled adversary but the scored DAgger's own), ARIL-A's training against the policy from it, with its questions
    (its file's own record)."""
    cfg, out, page, _ = small_card
    sensory = json.loads((out / "scorecard.json").read_text())["modes"]["sensory"]
    text = page.read_text()
    rows = {line.split(" | ")[0].lstrip("| ") for line in text.splitlines() if line.startswith("| ")}
    assert {SCORECARD_ATTACKS[attack] for attack in PIPELINE_ATTACKS} <= rows
    made = load_policy(out / "surrogate-sensory.pt").meta.provenance
    assert (sensory["surrogate_fidelity"], sensory["surrogate_queries"]) == (made["fidelity"], made["queries"])
    screened = sensory["zoo_screened"]
    assert sensory["zoo"] == screened[0][1] and screened == sorted(screened)
    others = zoo_members(cfg.env, "sensory", victim_digest("dagger", cfg.env, "sensory"), ZOO_FOLDERS)
    assert sorted(member for _, member in screened) == sorted(relative(member) for member in others)
    fidelity = made["fidelity"]
    assert (f"Surrogate `{sensory['surrogate']}`: {made['queries']:,} questions to the policy, held-out error "
            f"{fidelity['mse']:.4f} (R^2 {fidelity['r2']:.4f}, inside the ±eps box {fidelity['local_r2']:.4f}); zoo: "
            f"`{sensory['zoo']}`, the strongest of "
            f"{len(screened)} against the surrogate") in text
    trained = load_adversary(out / "adversary-sensory.pt").meta["provenance"]  # against the policy, from the zoo's
    assert (trained["victim"], trained["settings"]["init"]) == ("dagger", sensory["zoo"])
    assert (sensory["adversary_steps"], sensory["adversary_queries"]) == (trained["steps"], trained["queries"])
    # one PPO update: no state before its end, which the rows used
    assert (sensory["adversary_kept_steps"], len(sensory["adversary_states_screened"])) == (trained["steps"], 1)
    assert (f"ARIL-A: `{sensory['adversary']}`, the state after {trained['steps']:,} of {trained['steps']:,} steps "
            f"trained against the policy ({trained['queries']:,} questions), the strongest of 1 state against the "
            f"policy on these episodes ({sensory['adversary_states_queries']:,} questions).") in text
    directed = load_adversary(out / "directed-sensory.pt")  # against the policy, from fresh weights
    trained = directed.meta["provenance"]
    assert (directed.meta["policy"], trained["victim"], trained["settings"]["init"]) == ("directed", "dagger", "")
    assert (sensory["directed"], sensory["directed_steps"], sensory["directed_queries"]) == (
        relative(out / "directed-sensory.pt"), trained["steps"], trained["queries"])
    assert sensory["directed_zoo"] is None and sensory["directed_zoo_screened"] == []  # DAgger's own left out
    assert (f"Directed ARIL-A: `{sensory['directed']}`, the state after {trained['steps']:,} of {trained['steps']:,} "
            f"steps trained against the policy ({trained['queries']:,} questions), the strongest of 1 state against "
            f"the policy on these episodes ({sensory['directed_states_queries']:,} questions), from fresh "
            "weights") in text
    for attack, file in (("transfer", sensory["surrogate"]), ("aril_a", sensory["zoo"])):  # the zoo's row
        alone = evaluate(EvalConfig(env=cfg.env, policy="dagger", mode="sensory", attack=attack, eps=sensory["eps"],
                                    attack_file=file, rescale=attack == "aril_a", episodes=3, seed=cfg.seed,
                                    horizon=25))
        row = sensory["attacks"]["zoo" if attack == "aril_a" else attack]["1.0"]
        assert [round(e["return"], 3) for e in row["episodes"]] == alone["returns"]


@pytest.mark.parametrize("changes, message", [
    ({"budget": "huge"}, "unknown budget 'huge'; choose one of quick, full"),
    ({"scales": "0.5,2"}, "scales:=0.5,2: positive multiples of eps, 1 among them"),
    ({"modes": "clean"}, "unknown mode 'clean'"),
    ({"policy": "external"}, r"policy:=external needs domain:=<the ROS_DOMAIN_ID your node runs in>"),
    ({"policy": "external", "domain": "42", "via": "engine"}, "policy:=external is scored through the graph only"),
    ({"via": "ros"}, "unknown via 'ros'; choose one of engine, graph"),
    ({"policy": "external", "domain": "181"}, r"domain:=181 is not an allowed ROS domain id: auto, 0-101 or 215-232"),
    ({"policy": "external", "domain": "42", "attacks": "fgsm"}, "unknown attack 'fgsm'; choose one of random, spsa, fd_fgsm, "
                                                                  "transfer, zoo, aril_a, aril_a_search, "
                                                                  "aril_a_directed$"),
    ({"env": "Hopper-v5", "policy": "dagger"}, "no dagger for Hopper-v5"),
])
def test_bad_arguments_are_refused_before_anything_runs(tmp_path, changes, message):
    with pytest.raises(ValueError, match=message):
        scorecard(ScorecardConfig(out=str(tmp_path / "card"), **changes), log=lambda *a, **k: None)
    assert not (tmp_path / "card").exists()


def test_a_name_trained_per_mode_is_scored_in_each_mode_against_the_clean_cell_of_its_own_file(tmp_path):
    """dr is another file in each mode: each mode's clean cell is that file's (aril eval of it), so that its drops
    pair the same policy clean and attacked, and the page's clean row and drops are that mode's."""
    from aril_ros.registry import bundled_file
    from aril_ros.report.stats import paired_drop

    cfg = ScorecardConfig(policy="dr", env="Swimmer-v5", episodes=2, horizon=25, scales="1", attacks="random",
                          workers=1, out=str(tmp_path))
    page = scorecard(cfg, log=lambda *a, **k: None).read_text()
    modes = json.loads((tmp_path / "scorecard.json").read_text())["modes"]
    for mode, r in modes.items():
        own = bundled_file("dr", cfg.env, mode)
        assert Path(r["policy"]).resolve() == own
        clean = evaluate(EvalConfig(env=cfg.env, policy=str(own), episodes=2, seed=cfg.seed, horizon=25))
        assert [round(e["return"], 3) for e in r["clean"]["episodes"]] == clean["returns"]
        section = page.split(f"## {mode},")[1].split("## ")[0]
        drop = paired_drop(r["clean"], r["attacks"]["random"]["1.0"])
        assert f"| clean | {r['clean']['mean_return']:.1f} |" in section and f"`{r['policy']}`" in section
        assert f"| {drop['drop_pct']:+.1f}% [{drop['ci95_pct'][0]:+.1f}, {drop['ci95_pct'][1]:+.1f}] |" in section
    assert modes["sensory"]["clean"]["mean_return"] != modes["physical"]["clean"]["mean_return"]  # two policies


def fails_as_a_user_error(job: dict):
    """A cell (a sweep task) failing on a user's error: its policy a name trained per mode, asked in mode clean."""
    return engine_cell({**job, "policy": "dr", "mode": "clean"})


@pytest.mark.parametrize("workers", [1, pytest.param(2, marks=[pytest.mark.slow, pytest.mark.xdist_group("ray")])])
def test_an_error_inside_a_cell_reaches_the_user_as_one_line(workers, monkeypatch, capsys, tmp_path):
    """In this process or as a Ray task: the CLI's one line naming the culprit, not the task's traceback."""
    from contextlib import nullcontext

    from aril_ros.cli import main
    from tests.conftest import local_ray

    monkeypatch.setattr("aril_ros.cell_runner.engine_cell", fails_as_a_user_error)
    with local_ray() if workers > 1 else nullcontext():
        code = main(["scorecard", "env:=Swimmer-v5", "policy:=dagger", "attacks:=random", "episodes:=1",
                     "horizon:=5", f"workers:={workers}", f"out:={tmp_path}"])
    [line] = capsys.readouterr().err.splitlines()
    assert code == 2 and line.startswith("aril scorecard: error: the bundled dr policies are trained per attack "
                                         "mode: it takes mode sensory or physical (got clean)")


def test_the_adversary_is_told_the_policy_as_typed_or_the_file_of_a_per_mode_name(monkeypatch, tmp_path):
    from aril_ros.registry import bundled_file
    from aril_ros.scorecard import victim_of

    assert victim_of("dagger", "Swimmer-v5", "sensory") == "dagger"
    assert victim_of("runs/mine.pt", "Swimmer-v5", "sensory") == "runs/mine.pt"
    package = bundled_file("aril", "Swimmer-v5", "physical")
    monkeypatch.chdir(package.parents[3])  # where the package is: the recorded path is relative to here
    assert victim_of("aril", "Swimmer-v5", "physical") == "aril_ros/data/aril/Swimmer-v5-physical.pt"
    monkeypatch.chdir(tmp_path)
    assert victim_of("aril", "Swimmer-v5", "physical") == str(package)


@pytest.mark.slow
def test_an_external_node_is_scored_through_the_graph_as_the_engine_scores_its_file(small_card, tmp_path):
    """The bundled DAgger learner run as the user's own node: every cell through the graph, the surrogate fitted to
    the node's answers, ARIL-A and the directed ARIL-A trained against it; the graph is bit-exact to the engine, so
    the node answers as the file does, the surrogate is the file's and the figures are the engine's (random runs
    through the graph in tests/test_graph.py)."""
    import os
    import signal
    import subprocess
    import sys

    node = subprocess.Popen([sys.executable, "-m", "aril_ros_nodes.policy_node", "--ros-args", "-p", "env:=Swimmer-v5",
                             "-p", "policy:=dagger", "-r", "__node:=my_policy"], env=dict(os.environ))
    try:
        lines = []
        scorecard(ScorecardConfig(policy="external", domain=os.environ["ROS_DOMAIN_ID"], out=str(tmp_path / "node"),
                                  **{**SMALL, "attacks": "aril_a,aril_a_directed"}),
                  log=lambda line, **_: lines.append(line))
    finally:
        node.send_signal(signal.SIGINT)
        node.wait(timeout=20)
    by_node, by_file = (json.loads((folder / "scorecard.json").read_text())["modes"]["sensory"]
                        for folder in (tmp_path / "node", small_card[1]))
    assert by_node["clean"]["episodes"] == by_file["clean"]["episodes"]
    # the same surrogate, fitted to the node's answers, and the same adversary trained against it, at its eps and
    # (rescale:=true through the graph) at 2x
    assert load_policy(tmp_path / "node" / "surrogate-sensory.pt").meta.provenance["victim"] == "ros"
    for key in ("surrogate_fidelity", "surrogate_queries"):
        assert by_node[key] == by_file[key]
    # a node has no file whose digest could set adversaries aside: its zoo is the file's and DAgger's own
    screened_for_file = {tuple(member) for member in by_file["zoo_screened"]}
    assert screened_for_file < {tuple(member) for member in by_node["zoo_screened"]}
    assert by_node["attacks"]["aril_a"] == by_file["attacks"]["aril_a"]
    # the directed ARIL-A: trained as many steps against the node, a step's questions as many; the node's zoo keeps
    # DAgger's own directed ARIL-A (screened against the node, its questions counted), the file's sets it aside
    assert (by_node["directed_steps"], by_node["directed_queries"]) == (by_file["directed_steps"],
                                                                        by_file["directed_queries"])
    assert by_file["directed_zoo"] is None and by_node["directed_zoo"] == relative(
        directed_adversary_path(SMALL["env"], "sensory")) and by_node["directed_zoo_queries"] > 0
    assert by_node["attacks"]["aril_a_directed"]["1.0"]["queries_per_step"] == 7  # Swimmer: 1 + 2 x 3 entries
    assert any(line.startswith("[surrogate]") for line in lines)


@pytest.mark.slow
@pytest.mark.xdist_group("ray")  # with the other Ray tests (tests/test_sweep.py)
def test_a_file_scored_through_the_graph_on_two_nodes_is_scored_as_the_engine_scores_it(small_card, tmp_path):
    """via:=graph: every cell a run of the graph with a policy node serving the file, each a sweep task of
    GRAPH_RUN_CPUS. On two nodes of that many CPUs, the first two runs go one to each node at once (each in a ROS
    domain of its own), the file travels to them by content, their logs come back; the graph is bit-exact to the
    engine, so the figures are the engine's."""
    from ray.cluster_utils import Cluster

    from aril_ros.registry import bundled_file
    from aril_ros.cell_runner import GRAPH_RUN_CPUS
    from aril_ros.sweep import ensure_ray

    ensure_ray()
    mine = tmp_path / "mine.pt"
    shutil.copy(bundled_file("dagger", "Swimmer-v5"), mine)
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": GRAPH_RUN_CPUS})
    cluster.add_node(num_cpus=GRAPH_RUN_CPUS)
    try:
        scorecard(ScorecardConfig(policy=str(mine), via="graph", keep_logs=True, address=cluster.address,
                                  out=str(tmp_path / "card"), **{**SMALL, "attacks": "random,fgsm"}),
                  log=lambda *a, **k: None)
    finally:
        cluster.shutdown()
    cards = [json.loads((folder / "scorecard.json").read_text()) for folder in (tmp_path / "card", small_card[1])]
    by_graph, by_engine = (card["modes"]["sensory"] for card in cards)
    assert by_graph["clean"] == by_engine["clean"]
    assert cards[0]["timing"]["policies"][str(mine)]["cells"] == cards[1]["timing"]["policies"]["dagger"]["cells"]
    # every row at eps, and the eps sweep (each cell a run) of the worst one alone; white-box fgsm: the file is the
    # node's victim
    worst = by_graph["worst"]["attack"]
    other = ({"random", "fgsm"} - {worst}).pop()
    assert worst == min(("random", "fgsm"), key=lambda a: by_engine["attacks"][a]["1.0"]["mean_return"])
    assert by_graph["attacks"] == {worst: by_engine["attacks"][worst], other: {"1.0": by_engine["attacks"][other]["1.0"]}}
    assert sorted(p.name for p in (tmp_path / "card" / "logs").iterdir()) == sorted([
        "clean-none-0.mcap", "clean-none-delay1-0.mcap", f"sensory-{worst}-0.3.mcap", f"sensory-{worst}-0.6.mcap", f"sensory-{other}-0.3.mcap"])
    page = (tmp_path / "card" / "scorecard.md").read_text()
    assert "a run of the ROS 2 graph" in page and "worst attack's alone: – marks a cell not run" in page
    row = next(line for line in page.splitlines() if line.startswith(f"| {SCORECARD_ATTACKS[other]} |"))
    assert row.endswith(f"| {by_engine['attacks'][other]['1.0']['mean_return']:.0f}, – |")  # at 1x and 2x eps


def test_an_env_without_bundled_adversaries_is_scored_without_a_zoo(tmp_path, monkeypatch):
    """A new robot has no bundled ARIL-A: the pipeline trains its own from fresh weights and the page has no zoo row
    (the zoo's screening refused to run with no member, failing the whole scorecard)."""
    import aril_ros.verdict

    monkeypatch.setattr(aril_ros.verdict, "ZOO_FOLDERS", (tmp_path / "no-adversaries",))
    cfg = ScorecardConfig(policy="dagger", out=str(tmp_path / "card"), workers=1, **{**SMALL, "attacks": "zoo,aril_a"})
    page = scorecard(cfg, log=lambda *a, **k: None)
    sensory = json.loads((tmp_path / "card" / "scorecard.json").read_text())["modes"]["sensory"]
    assert list(sensory["attacks"]) == ["aril_a"] and sensory["zoo"] is None and sensory["zoo_screened"] == []
    command = load_adversary(tmp_path / "card" / "adversary-sensory.pt").meta["provenance"]["command"]
    # its first round from fresh weights, each later one from where the last ended: never another file
    assert {arg.split(":=", 1)[1] for arg in command.split() if arg.startswith("init:=")} <= {
        str(tmp_path / "card" / "adversary-sensory.pt")}
    assert "no bundled adversary for a zoo" in page.read_text()


@pytest.mark.slow
@pytest.mark.parametrize("attack", ["spsa", "aril_a_search"])
def test_a_cells_questions_are_counted_alike_on_the_engine_and_through_the_graph(attack, tmp_path):
    """A cell's queries on the engine are its attack's count of the rows it asked; through the graph, the probes its
    run's log holds, each answered by the policy node. The same cell gives the same figures both ways, questions
    included: SPSA^k 1 + k (2 samples + 1) a step, ARIL-A with search its input action and the 8 + 1 candidates."""
    from aril_ros.adversary import load_adversary
    from aril_ros.cell_runner import CellRunner
    from aril_ros.registry import DATA_DIR
    from aril_ros.verdict import SEARCH

    adversary = DATA_DIR / "adversary" / "Swimmer-v5-sensory.pt"
    settings = ({"attack": "spsa", "k": 1, "samples": 2} if attack == "spsa" else
                {"attack": "aril_a", "attack_file": str(adversary), "rescale": True, "search": SEARCH})
    cell = EvalConfig(env="Swimmer-v5", policy="dagger", mode="sensory", eps=0.3, episodes=2, seed=4000, horizon=20,
                      **settings)
    [on_engine], [through_graph] = (CellRunner(via, workers=1, address="").run([cell], log=lambda *a, **k: None)
                                    for via in ("engine", "graph"))
    assert through_graph == on_engine
    per_step = 1 + 1 * (2 * 2 + 1) if attack == "spsa" else int(load_adversary(adversary).takes_actions) + SEARCH + 1
    assert on_engine["queries_per_step"] == per_step == (6 if attack == "spsa" else 10)
    assert on_engine["queries"] == per_step * sum(e["steps"] for e in on_engine["episodes"]) == per_step * 40


def test_page_warns_when_the_worst_cases_interval_is_as_wide_as_its_drop():
    """A verdict whose 95% interval is as wide as the drop it reports (too few episodes for the env) says so and how
    to fix it; a tight one says nothing."""
    from aril_ros.report.text import too_few_episodes
    assert too_few_episodes({"drop_pct": -30.0, "ci95_pct": [-40.0, -20.0]}, 10) == []
    warning = too_few_episodes({"drop_pct": -20.0, "ci95_pct": [-45.0, 5.0]}, 10)
    # width 50 against a drop of 20: 1.5 x 10 x (50/20)^2 = 93.75 episodes, up to tens
    assert "10 episodes do not pin this verdict down" in warning[0] and "`episodes:=100`" in warning[0]
    assert too_few_episodes({"drop_pct": -10.0, "ci95_pct": [-15.0, -5.0]}, 10)  # width 10 = |drop|: not narrower
    assert "`episodes:=100`" in too_few_episodes({"drop_pct": 0.0, "ci95_pct": [-3.0, 3.0]}, 10)[0]


def test_timing_rows_score_the_policy_late_on_the_clean_cells_episodes(tmp_path):
    """The full budget's timing rows (timing:=k: every observation k steps late, every action k steps late, k tenths
    of the observations dropped) are aril eval's cells of the same episodes, the policy otherwise clean; the worst is
    the lowest return, with its paired drop; timing:=0 scores none, and the quick budget the delay alone."""
    from aril_ros.report.stats import paired_drop
    from aril_ros.timing_adversary import load_timing_adversary

    cfg = ScorecardConfig(policy="dagger", env="Swimmer-v5", modes="sensory", budget="full", episodes=2, horizon=25,
                          scales="1", attacks="random", timing=2, timing_steps=4096, workers=1,
                          out=str(tmp_path / "full"))
    page = scorecard(cfg, log=lambda *a, **k: None).read_text()
    card = json.loads((tmp_path / "full" / "scorecard.json").read_text())
    assert card["timing"]["k"] == 2 and list(card["timing"]["policies"]) == ["dagger"]
    timed = card["timing"]["policies"]["dagger"]
    assert list(timed["cells"]) == ["delay", "action_delay", "drop", "drop_learned"]
    learned = tmp_path / "full" / "timing-adversary-dagger.pt"  # trained against the policy, black-box
    assert load_timing_adversary(learned).meta["provenance"]["steps"] == 4096
    for row, settings in {"delay": {"delay": 2}, "action_delay": {"action_delay": 2}, "drop": {"drop": 0.2},
                          "drop_learned": {"drop": 0.2, "timing": "learned", "timing_file": str(learned)}}.items():
        alone = evaluate(EvalConfig(env="Swimmer-v5", policy="dagger", episodes=2, seed=cfg.seed, horizon=25,
                                    **settings))
        assert [round(e["return"], 3) for e in timed["cells"][row]["episodes"]] == alone["returns"]
    worst = min(timed["cells"], key=lambda row: timed["cells"][row]["mean_return"])
    drop = paired_drop(card["modes"]["sensory"]["clean"], timed["cells"][worst])
    assert timed["worst"]["attack"] == worst and timed["worst"]["drop_pct"] == drop["drop_pct"]
    section = page.split("## Timing, 2 step(s)")[1]
    assert "| every observation 2 step(s) late |" in section and "| 20% of the observations dropped |" in section
    assert "| 20% of the observations dropped when a timing adversary trained against it picks |" in section
    assert f"{drop['drop_pct']:+.1f}% [{drop['ci95_pct'][0]:+.1f}, {drop['ci95_pct'][1]:+.1f}]**" in section

    quick = dataclasses.replace(cfg, budget="quick", timing=1, out=str(tmp_path / "quick"))
    scorecard(quick, log=lambda *a, **k: None)
    assert list(json.loads((tmp_path / "quick" / "scorecard.json").read_text())["timing"]["policies"]["dagger"]
                ["cells"]) == ["delay"]
    none = dataclasses.replace(cfg, timing=0, out=str(tmp_path / "none"))
    assert "## Timing" not in scorecard(none, log=lambda *a, **k: None).read_text()
    assert "timing" not in json.loads((tmp_path / "none" / "scorecard.json").read_text())

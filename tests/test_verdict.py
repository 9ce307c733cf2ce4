"""The black-box pipeline (aril_ros.verdict, aril_ros.surrogate): it asks the scored policy for actions alone and
counts every question, its surrogate holds none of the policy's parameters, transfer never asks the policy, the zoo
leaves out every adversary trained against the policy, the directed ARIL-A is trained from fresh weights against the
policy's answers, and a rerun reuses what it made. Short Swimmer episodes."""
from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil
from contextlib import contextmanager
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from aril_ros import adversary, verdict
from aril_ros.adversary import load_adversary
from aril_ros.attacks import make_attack
from aril_ros.envs import layout_of
from aril_ros.evaluation import EvalConfig, evaluate
from aril_ros.policy import load_policy, load_weights, policy_file, resolve_policy
from aril_ros.registry import (DATA_DIR, DEFAULT_POLICY, DEFENSES, DIRECTED_ROW, PAPER_ENVS, calibrated_eps,
                               directed_adversary_path)
from aril_ros.rollout import RolloutEngine
from aril_ros.surrogate import SurrogateConfig, fit_surrogate
from aril_ros.verdict import SEARCH, victim_digest, zoo_members
from tests.conftest import AnswersOnly, local_ray

ENV, MODE, EPS = "Swimmer-v5", "sensory", 0.3
HORIZON = 50
STEPS = 4096
"""ARIL-A's training against the policy: one PPO update."""
SCORED_ON = (4000, 3)
"""The scored episodes a pipeline training's states are judged on: the first one's env seed, their count."""
N_POSITION = layout_of(ENV).n_position


def quiet(*args, **kwargs):
    pass


def one_pipeline(*args, **kwargs):
    """One mode's black-box pipeline (:func:`aril_ros.verdict.pipeline`), its trainings in this process."""
    return verdict.run_pipelines([verdict.pipeline(*args, **kwargs)], quiet)[0]


def run_pipeline(folder, eps: float = EPS):
    """The pipeline on the bundled DAgger, its five steps (the directed one beside the others, as the scorecard runs
    them), the policy seen through :class:`AnswersOnly` (its act alone, its questions counted) by the surrogate's
    questions and by both trainings (which may read what the file is, its provenance, and nothing more): what it
    made, and the black boxes it asked."""
    boxes = []

    def answers_only(policy):
        boxes.append(AnswersOnly(policy))
        return boxes[-1]

    def trained_against(path, env_id=None):
        policy = load_policy(path, env_id)
        box = answers_only(policy)
        box.meta = SimpleNamespace(provenance=policy.meta.provenance)
        return box

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(verdict, "Answers", answers_only)
        patch.setattr(adversary, "load_policy", trained_against)
        made, directed = verdict.run_pipelines(
            [verdict.pipeline("dagger", ENV, MODE, eps, "expert", STEPS, folder, SCORED_ON, log=quiet, horizon=HORIZON),
             verdict.directed_pipeline("dagger", ENV, MODE, eps, "expert", STEPS, folder, SCORED_ON, log=quiet)],
            quiet)
    return dataclasses.replace(made, directed=directed), boxes


@contextmanager
def answers_counted():
    """The pipeline's black boxes, each seen through :class:`AnswersOnly` (its act alone, its questions counted): the
    list of them, as they are made."""
    box = []

    def answers_only(policy):
        box.append(AnswersOnly(policy))
        return box[-1]

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(verdict, "Answers", answers_only)
        yield box


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory):
    folder = tmp_path_factory.mktemp("pipeline")
    made, boxes = run_pipeline(folder)
    return folder, made, boxes


def sha256(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.slow
def test_the_pipeline_asks_the_policy_for_actions_alone_and_counts_every_question(pipeline):
    folder, made, boxes = pipeline
    # the policy asked for the surrogate's questions, then by the two trainings and the screenings of their states,
    # and by nothing else: the zoo is screened against the surrogate
    copy, training, directing, keeping, keeping_directed = boxes
    surrogate = load_policy(made.surrogate).meta.provenance
    assert copy.asked == surrogate["queries"] > 0
    assert (surrogate["victim"], surrogate["mode"], surrogate["eps"], surrogate["horizon"]) == ("dagger", MODE, EPS,
                                                                                               HORIZON)
    # ARIL-A was trained against the policy's answers, counted in its file, from the zoo's strongest (the one at the
    # head of the screening)
    trained = load_adversary(made.adversary.end).meta["provenance"]
    assert trained["victim_sha256"] == sha256(policy_file("dagger", ENV)) and trained["steps"] >= STEPS
    assert trained["queries"] == training.asked >= 2 * STEPS
    assert trained["settings"]["init"] == made.screened[0][1] == str(made.zoo)
    assert made.screened == sorted(made.screened)
    assert made.surrogate == folder / f"surrogate-{MODE}.pt" and made.adversary.end == folder / f"adversary-{MODE}.pt"
    # one PPO update, no state before the end: the screening of its states ran the end alone, its questions counted
    assert made.adversary.kept == folder / f"adversary-{MODE}.pt" and len(made.adversary.screened) == 1
    assert made.adversary.queries == keeping.asked > 0 and made.directed.trained.queries == keeping_directed.asked > 0
    # the directed ARIL-A from fresh weights against the policy's answers: a training step asks for its action on the
    # true state, on the two points per perturbed entry the actor's slopes need, and on the perturbed state
    directed = load_adversary(made.directed.trained.end)
    trained = directed.meta["provenance"]
    assert made.directed.trained.kept == folder / f"directed-{MODE}.pt" and directed.meta["policy"] == "directed"
    assert trained["victim_sha256"] == sha256(policy_file("dagger", ENV)) and trained["settings"]["init"] == ""
    assert trained["queries"] == directing.asked >= (2 + 2 * N_POSITION) * STEPS


@pytest.mark.slow
@pytest.mark.parametrize("attack", ["transfer", "zoo", "aril_a", "aril_a_search", DIRECTED_ROW])
def test_each_black_box_attack_runs_against_a_policy_that_only_answers(pipeline, attack):
    """As the scorecard runs them (aril_ros.scorecard.cell): the attack's victim answers act and nothing else, and
    every row it was asked is one the attack counted; transfer asks it nothing."""
    _, made, _ = pipeline
    policy, expert = resolve_policy("dagger", ENV), resolve_policy("expert", ENV)
    victim = AnswersOnly(policy)
    files = {"transfer": made.surrogate, "zoo": made.zoo, DIRECTED_ROW: made.directed.trained.kept}
    file = files.get(attack, made.adversary.kept)
    chosen = make_attack("transfer" if attack == "transfer" else "aril_a", layout_of(ENV), EPS, victim=victim,
                         expert=expert, adversary=str(file), mode=MODE, rescale=True,
                         search=SEARCH if attack == "aril_a_search" else 0)
    engine = RolloutEngine(ENV, policy, expert, chosen, MODE, n_envs=2, horizon=HORIZON)
    traj = engine.rollout(2, seed=1)
    engine.close()
    steps = int(traj.length.sum())
    assert np.abs(traj.delta).max() > 0 and np.abs(traj.delta).max() <= EPS
    if attack == "transfer":
        assert victim.asked == 0
    else:  # the adversary takes the policy's action (1 row a step), the search asks about SEARCH + 1 candidates, the
        # directed actor about 2 points per perturbed entry
        more = {"aril_a_search": SEARCH + 1, DIRECTED_ROW: 2 * N_POSITION}.get(attack, 0)
        assert victim.asked == chosen.queries == steps * (1 + more)


@pytest.mark.slow
def test_the_surrogate_is_fitted_to_answers_alone_and_records_its_fidelity(tmp_path):
    """The policy behind answers only (its parameters out of reach), a surrogate of its own width: weights of its
    own, every question counted, and a held-out R^2 that says it copies the policy."""
    policy = resolve_policy("dagger", ENV)
    box = AnswersOnly(policy)
    path = fit_surrogate(box, ENV, MODE, EPS, tmp_path / "surrogate.pt",
                         SurrogateConfig(episodes=4, epochs=100, hidden=policy.meta.hidden[0]), "dagger", log=quiet,
                         horizon=100)
    surrogate = load_policy(path, ENV)
    made = surrogate.meta.provenance
    assert made["algorithm"] == "surrogate" and made["queries"] == box.asked
    assert made["fidelity"]["r2"] > 0.9 and made["fidelity"]["held_out"] == made["queries"] // 10
    assert made["fidelity"]["local_r2"] > 0.5  # the variation inside the box, which attacks follow, is copied too
    theirs, ours = policy.state_dict(), surrogate.state_dict()
    weights = [name for name in theirs if name.endswith("weight")]
    assert weights and all(theirs[name].shape == ours[name].shape for name in weights)
    assert not any(np.allclose(theirs[name].numpy(), ours[name].numpy(), atol=1e-3) for name in weights)


def test_fitting_the_variation_inside_the_box_copies_it_better(tmp_path):
    """The same answers fitted with and without the loss on each probe's answer minus its visited observation's: with
    it the copy explains more of that variation on held-out observations (what FGSM^k on the copy follows)."""
    policy = resolve_policy("dagger", ENV)
    local_r2 = {}
    for local in (0.0, SurrogateConfig().local):
        path = fit_surrogate(AnswersOnly(policy), ENV, MODE, EPS, tmp_path / f"surrogate-{local}.pt",
                             SurrogateConfig(episodes=4, epochs=100, hidden=policy.meta.hidden[0], local=local),
                             "dagger", log=quiet, horizon=100)
        local_r2[local] = load_policy(path, ENV).meta.provenance["fidelity"]["local_r2"]
    assert local_r2[SurrogateConfig().local] > local_r2[0.0] + 0.2, local_r2


class Mute:
    """A victim that must not be asked: any use of it fails the test."""

    def __getattr__(self, name):
        raise AssertionError(f"transfer reached for the victim's {name!r}")


@pytest.mark.slow
def test_transfer_is_fgsm_k_on_the_surrogate_and_never_asks_the_victim(pipeline):
    _, made, _ = pipeline
    layout, expert = layout_of(ENV), resolve_policy("expert", ENV)
    engine = RolloutEngine(ENV, resolve_policy("dagger", ENV), expert, None, MODE, n_envs=2, horizon=HORIZON)
    states = engine.rollout(2, seed=2).true_obs.reshape(-1, layout.obs_dim)
    engine.close()
    rngs = [None] * len(states)
    delta = make_attack("transfer", layout, EPS, victim=Mute(), expert=expert, adversary=str(made.surrogate),
                        steps=4).perturb(states, rngs)
    assert np.abs(delta).max() == pytest.approx(EPS) and np.all(delta[:, ~layout.zero_order_mask] == 0)
    on_the_surrogate = make_attack("fgsm_k", layout, EPS, victim=load_policy(made.surrogate, ENV), expert=expert,
                                   steps=4).perturb(states, rngs)
    np.testing.assert_array_equal(delta, on_the_surrogate)


def members_against(env_id: str, mode: str, learner: str) -> set[str]:
    """The bundled adversaries trained against the bundled ``learner`` (three seeds), by their file names."""
    if learner == DEFAULT_POLICY:
        folder, stem = DATA_DIR / "adversary", f"{env_id}-{mode}"
    else:
        folder, stem = DATA_DIR / "defense-adversary", f"{env_id}-{mode}-{learner}"
    return {str(folder / f"{stem}{seed}.pt") for seed in ("", "-seed1", "-seed2")}


@pytest.mark.parametrize("mode", ["sensory", "physical"])
@pytest.mark.parametrize("env_id", PAPER_ENVS)
@pytest.mark.parametrize("learner", list(DEFENSES))
def test_the_zoo_leaves_out_every_adversary_trained_against_the_scored_policy(learner, env_id, mode, tmp_path):
    """Leave-one-out, by the scored file's digest: the bundled adversaries trained against that learner (each of
    its three seeds, the older files by the provenance they recorded of it) are set aside, every other kept; a copy
    of the file elsewhere is the same policy; an external node (no file) keeps them all."""
    every = {str(p) for p in zoo_members(env_id, mode, None, verdict.ZOO_FOLDERS)}
    assert every == {str(p) for folder in verdict.ZOO_FOLDERS for p in folder.glob(f"{env_id}-{mode}*.pt")}
    own = members_against(env_id, mode, learner)
    assert own < every
    kept = {str(p) for p in zoo_members(env_id, mode, victim_digest(learner, env_id, mode), verdict.ZOO_FOLDERS)}
    assert kept == every - own
    if learner == "bc":  # DAgger's adversaries stay in BC's zoo
        assert members_against(env_id, mode, DEFAULT_POLICY) <= kept
    copy = tmp_path / "mine.pt"
    shutil.copy(policy_file(learner, env_id, mode), copy)
    assert {str(p) for p in zoo_members(env_id, mode, victim_digest(str(copy), env_id, mode), verdict.ZOO_FOLDERS)} == kept
    assert victim_digest("ros", env_id, mode) is None


@pytest.mark.parametrize("mode", ["sensory", "physical"])
@pytest.mark.parametrize("env_id", ["HalfCheetah-v5", "Ant-v5"])
@pytest.mark.parametrize("learner", ["dagger", "bc", "dr", "aril"])
def test_the_directed_zoo_leaves_out_the_directed_aril_a_trained_against_the_scored_policy(learner, env_id, mode):
    """The directed step's warm starts: every bundled directed ARIL-A of the env and mode but the one trained against
    the scored learner's file (by its digest)."""
    every = set(zoo_members(env_id, mode, None, verdict.DIRECTED_ZOO))
    assert len(every) == 4
    kept = set(zoo_members(env_id, mode, victim_digest(learner, env_id, mode), verdict.DIRECTED_ZOO))
    assert every - kept == {directed_adversary_path(env_id, mode, learner)}


@pytest.mark.slow
def test_the_directed_step_starts_from_the_directed_aril_a_that_takes_the_most_from_the_policy(tmp_path):
    """Scoring BC, the directed zoo's members (DAgger's directed ARIL-A, BC's own left out) are screened against the
    policy's answers, counted, and the training starts from the strongest; a rerun makes nothing."""
    with answers_counted() as box:
        made = verdict.run_pipelines([verdict.directed_pipeline("bc", ENV, MODE, EPS, "expert", STEPS, tmp_path,
                                                                SCORED_ON, log=quiet, horizon=HORIZON)], quiet)[0]
    members = zoo_members(ENV, MODE, victim_digest("bc", ENV, MODE), verdict.DIRECTED_ZOO)
    assert [member for _, member in made.screened] == [verdict.relative(m) for m in members]  # DAgger's
    assert str(made.zoo) == verdict.relative(members[0]) and made.queries == box[0].asked > 0
    trained = load_adversary(made.trained.end).meta["provenance"]
    assert trained["settings"]["init"] == str(made.zoo) and trained["victim"] == "bc"
    again = verdict.run_pipelines([verdict.directed_pipeline("bc", ENV, MODE, EPS, "expert", STEPS, tmp_path,
                                                             SCORED_ON, log=quiet, horizon=HORIZON)], quiet)[0]
    assert again == made


@pytest.mark.slow
def test_a_rerun_reuses_the_surrogate_and_the_adversary_and_another_eps_makes_new_ones(pipeline, tmp_path):
    folder, first, _ = pipeline
    rerun = shutil.copytree(folder, tmp_path / "rerun")  # copy2: the files keep their times
    files = [rerun / first.surrogate.name, rerun / first.adversary.end.name, rerun / first.directed.trained.end.name]
    before = [(p.stat().st_mtime_ns, p.read_bytes()) for p in files]
    again, boxes = run_pipeline(rerun)
    assert boxes == [] and [(p.stat().st_mtime_ns, p.read_bytes()) for p in files] == before
    assert (again.zoo, again.screened) == (first.zoo, first.screened)
    other, boxes = run_pipeline(rerun, eps=0.2)
    # the policy asked again: a copy, two trainings, the screenings of their states
    assert len(boxes) == 5 and all(box.asked > 0 for box in boxes)
    assert load_policy(other.surrogate).meta.provenance["eps"] == 0.2
    assert load_adversary(other.adversary.end).eps == load_adversary(other.directed.trained.end).eps == 0.2
    assert all(path.read_bytes() != old for path, (_, old) in zip(
        (other.surrogate, other.adversary.end, other.directed.trained.end), before))


@pytest.mark.slow
def test_pipelines_side_by_side_make_the_files_each_makes_alone(pipeline, tmp_path):
    """Two modes' pipelines run together (their trainings at once, as Ray tasks) make byte for byte the files the
    pipeline makes alone in this process: the scorecard runs its modes so, two trainings in the time of one."""
    folder, alone, _ = pipeline
    with local_ray():
        both = verdict.run_pipelines([verdict.pipeline("dagger", ENV, mode, eps, "expert", STEPS, tmp_path,
                                                       SCORED_ON, log=quiet, horizon=HORIZON)
                                      for mode, eps in ((MODE, EPS), ("physical", 0.005))], quiet, workers=2)
    assert [made.adversary.end.name for made in both] == [f"adversary-{MODE}.pt", "adversary-physical.pt"]
    # the same weights (their provenance has the times they were made)
    for name, kind in ((alone.surrogate.name, "policy"), (alone.adversary.end.name, "adversary")):
        ours, theirs = (load_weights(path, kind)[1] for path in (tmp_path / name, folder / name))
        assert ours.keys() == theirs.keys() and all(torch.equal(ours[k], theirs[k]) for k in ours), name
    assert both[0].screened == alone.screened
    assert load_adversary(both[1].adversary.end).meta["provenance"]["settings"]["mode"] == "physical"


def test_aril_fit_surrogate_writes_the_file_attack_transfer_runs_on(tmp_path, capsys):
    """``aril fit-surrogate`` (the command the errors of attack transfer name) makes the surrogate; ``aril eval
    attack:=transfer`` runs FGSM^k on it; a clean mode is refused in one line."""
    from aril_ros.cli import main

    out = tmp_path / "s.pt"
    assert main(["fit-surrogate", "victim:=bc", "env:=Swimmer-v5", "horizon:=30", f"out:={out}"]) == 0
    made = load_policy(out).meta.provenance
    assert (made["algorithm"], made["victim"], made["mode"], made["horizon"]) == ("surrogate", "bc", "sensory", 30)
    assert made["eps"] == calibrated_eps("Swimmer-v5", "sensory")
    result = evaluate(EvalConfig(env="Swimmer-v5", policy="bc", mode="sensory", attack="transfer",
                                 attack_file=str(out), episodes=2, horizon=30))
    assert result["attack"] == "transfer" and result["max_abs_delta"] == pytest.approx(made["eps"])
    assert main(["fit-surrogate", "mode:=clean"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        "aril fit-surrogate: error: unknown mode 'clean'; choose one of sensory, physical")


def test_an_external_node_keeps_the_whole_zoo_unless_told_the_file_it_serves(tmp_path):
    """An external node has no file to compare: every bundled adversary stays in its zoo, unless ``leave_out`` names
    the file it serves; then it leaves out the same ones as that file scored itself."""
    own = victim_digest("dagger", ENV, MODE)
    assert verdict.victim_digest("ros", ENV, MODE) is None
    everyone, kept = (zoo_members(ENV, MODE, digest, verdict.ZOO_FOLDERS) for digest in (None, own))
    assert len(everyone) == len(kept) + 3
    folder = tmp_path / "as-node"
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(verdict, "answering", lambda name, env, mode, domain: NodeStandIn())
        patch.setattr(adversary.plugins, "load", lambda group, name: lambda env_id: NodeStandIn())
        made = one_pipeline("ros", ENV, MODE, EPS, "expert", STEPS, folder, SCORED_ON, log=quiet, horizon=HORIZON,
                            leave_out="dagger")
    screened = {member for _, member in made.screened}
    assert screened == {verdict.relative(m) for m in zoo_members(ENV, MODE, own, verdict.ZOO_FOLDERS)}
    assert load_adversary(made.adversary.end).meta["provenance"]["victim"] == "ros"


class NodeStandIn(AnswersOnly):
    """The bundled DAgger learner's answers standing in for a node: ``answering``'s context for victim ros, and the
    live victim ARIL-A's training connects to (what it is, its answers, close)."""

    def __init__(self):
        super().__init__(resolve_policy("dagger", ENV))
        self.meta = SimpleNamespace(provenance={"victim": "a stand-in for a node"})

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def close(self):
        pass


def bench_cell(drops: dict, budget: str = "quick", mode: str = "physical", episodes: int | None = None,
               reference: float = -50.0, cpu: str = "Intel(R) Xeon(R) Processor (AVX512)",
               policy: str = "dagger", pipeline: int | None = verdict.PIPELINE,
               directed: int | None = verdict.DIRECTED, fd_iterations: int | None = None) -> dict:
    """A verdict benchmark cell's figures as ``cell.json`` keeps them: every black-box row's drop, the reference and
    the CPU they were scored on, the pipeline that made its files (None: a cell of before pipeline 4, which recorded
    none), the directed step's version (None: its first, which cells did not record) and fd_fgsm's iterations (None:
    the budget's of today)."""
    from aril_ros.benchmarks.verdict import BLACK_BOX_ROWS
    from aril_ros.scorecard import BUDGETS
    drop = {row: drops.get(row, -1.0) for row in BLACK_BOX_ROWS}
    figures = {"env": "HalfCheetah-v5", "policy": policy, "mode": mode, "budget": budget, "minutes": 1.0,
               "clean": 5000.0, "drops": {row: {"drop_pct": d, "ci95_pct": [d - 1, d + 1]} for row, d in drop.items()},
               "reference": {"attack": "fgsm_k", "drop_pct": reference,
                             "drops": {name: {"drop_pct": reference / 2 if name != "fgsm_k" else reference}
                                       for name in ("fgsm_k", "bundled_aril_a", "bundled_directed")}}, "cpu": cpu,
               **({"pipeline": pipeline} if pipeline else {}), **({"directed": directed} if directed else {}),
               "fd_iterations": fd_iterations or BUDGETS[budget].fd_iterations}
    return figures if episodes is None else {**figures, "episodes": episodes}


def test_benchmark_judges_a_cell_by_the_budget_rows_of_today():
    """The budget's verdict is the worst of the rows it scores, read again from every row's drop: a row the quick
    budget does not score (random here) is never its verdict however strong, but stays the worst of every row."""
    from aril_ros.benchmarks.verdict import judged
    from aril_ros.scorecard import BUDGETS
    quick_rows = BUDGETS["quick"].black_box["physical"]
    strongest_scored = quick_rows[-1]
    cell = judged(bench_cell({"random": -90.0, strongest_scored: -60.0}))
    assert cell["budget_rows"] == list(quick_rows)
    assert (cell["black_box_worst"], cell["black_box_drop_pct"]) == (strongest_scored, -60.0)
    assert cell["black_box_ci95_pct"] == [-61.0, -59.0] and cell["ratio"] == pytest.approx(60.0 / 50.0)
    assert (cell["worst_of_every_row"], cell["worst_of_every_row_drop_pct"]) == ("random", -90.0)
    full_rows = BUDGETS["full"].black_box["physical"]
    full = judged(bench_cell({"random": -90.0, full_rows[0]: -70.0, strongest_scored: -60.0}, budget="full"))
    assert full["black_box_worst"] == full_rows[0]  # the full budget scores more rows, but not random either


def test_benchmark_refuses_a_cell_of_other_episodes(tmp_path):
    """A resumed cell scored on other episodes than the run asks for is refused by name, not mixed into the table."""
    import json
    from aril_ros.benchmarks.verdict import VerdictBenchConfig, score_cell
    folder = tmp_path / "cells" / "HalfCheetah-v5-dagger-physical-quick"
    folder.mkdir(parents=True)
    (folder / "cell.json").write_text(json.dumps(bench_cell({"aril_a": -50.0}, episodes=20)))
    cfg = VerdictBenchConfig(out=str(tmp_path))
    assert score_cell(cfg, "HalfCheetah-v5", "dagger", "physical", "quick")["episodes"] == 20
    with pytest.raises(ValueError, match="cell.json was scored on 20 episodes, not 30"):
        score_cell(VerdictBenchConfig(out=str(tmp_path), episodes=30), "HalfCheetah-v5", "dagger", "physical", "quick")


def test_benchmark_scores_a_cell_again_on_more_episodes_where_its_interval_is_as_wide_as_its_drop(tmp_path, monkeypatch):
    """A cell whose verdict's interval is as wide as its drop is scored again on as many episodes as the scorecard's
    page would ask a user for (at most WIDEN_AT_MOST times as many): the table keeps the wider scoring, how many
    episodes it took and both scorings' minutes, and the first verdict beside it; a resumed run reads it as
    scored; widen:=false keeps the first; near no drop at all, the count stops at the cap."""
    import json
    from aril_ros.benchmarks import verdict
    from aril_ros.report.stats import episodes_to_pin

    asked = []

    def scoring(cfg, env, policy, mode, budget, episodes):  # the interval narrows as 1/sqrt(episodes)
        asked.append(episodes)
        half = 20.0 * (20 / episodes) ** 0.5
        figures = bench_cell({"aril_a": -drop}, mode=mode, episodes=episodes)
        figures["drops"]["aril_a"]["ci95_pct"] = [-drop - half, -drop + half]
        return figures

    monkeypatch.setattr(verdict, "scorecard_figures", scoring)
    cfg, cell = verdict.VerdictBenchConfig(out=str(tmp_path), episodes=20), ("HalfCheetah-v5", "dagger", "physical", "quick")
    drop = 30.0  # width 40 at 20 episodes: 1.5 x 20 x (40/30)^2 = 53.3, up to 60
    widened = verdict.score_cell(cfg, *cell)
    assert asked == [20, 60] and widened["episodes"] == 60
    assert widened["minutes"] == 2.0 and widened["widened_from"]["episodes"] == 20
    assert widened["widened_from"]["black_box_ci95_pct"] == [-50.0, -10.0]
    assert episodes_to_pin(verdict.verdict_drop(widened), 60) is None
    assert verdict.score_cell(cfg, *cell) == widened and asked == [20, 60]  # resumed: read, not scored again
    assert "(aril_a; 60 episodes) |" in verdict.table(verdict.scored_rows(cfg, [cell[:3]], ["quick"]), ["quick"])

    drop, asked[:] = 1.0, []  # near no drop: the cap, and the table says the interval is still too wide
    near = verdict.score_cell(verdict.VerdictBenchConfig(out=str(tmp_path / "near"), episodes=20), *cell)
    assert asked == [20, 20 * verdict.WIDEN_AT_MOST]
    assert "(aril_a; 80 episodes; the interval still as wide as the drop) |" in verdict.table([{"quick": near}], ["quick"])

    asked[:] = []
    kept = verdict.score_cell(verdict.VerdictBenchConfig(out=str(tmp_path / "kept"), episodes=20, widen=False), *cell)
    assert asked == [20] and "widened_from" not in kept
    resumed = verdict.score_cell(verdict.VerdictBenchConfig(out=str(tmp_path / "kept"), episodes=20), *cell)
    assert asked == [20, 80] and resumed["widened_from"]["episodes"] == 20  # a wide cell of an earlier run too
    json.loads((tmp_path / "kept" / "cells" / "HalfCheetah-v5-dagger-physical-quick" / "cell.json").read_text())


def test_benchmark_table_holds_every_cell_scored_so_far_and_marks_a_budget_still_to_score(tmp_path):
    """A run resumed or stopped midway writes the table of every cell of its grid already scored, by it or an earlier
    run: a cell's budget still to score shows a dash, a cell no budget scored is left out. A budget scored on another
    CPU model is judged against the reference scored with it, which its ratio names; a cell an older pipeline made
    says so."""
    import json
    from aril_ros.benchmarks.verdict import VerdictBenchConfig, cell_folder, needed, scored_rows, table
    cfg = VerdictBenchConfig(out=str(tmp_path), episodes=20)
    env = "HalfCheetah-v5"
    scored_cells = {("dagger", "sensory", "quick"): {"fd_fgsm": -45.0},
                    ("dagger", "sensory", "full"): {"fd_fgsm": -55.0}, ("dagger", "physical", "quick"): {"aril_a": -90.0},
                    ("bc", "physical", "quick"): {"aril_a": -70.0}, ("bc", "physical", "full"): {"aril_a": -66.0}}
    elsewhere = {"reference": -60.0, "cpu": "AMD EPYC (AVX2)", "pipeline": None, "directed": None}
    for (policy, mode, budget), drops in scored_cells.items():
        folder = cell_folder(cfg, env, policy, mode, budget)
        folder.mkdir(parents=True)
        figures = bench_cell(drops, budget=budget, mode=mode, episodes=20, policy=policy,
                             **(elsewhere if (policy, budget) == ("bc", "full") else {}))
        (folder / "cell.json").write_text(json.dumps(figures))
    grid = [(env, "dagger", mode) for mode in ("sensory", "physical")] + [("Ant-v5", "bc", "sensory"),
                                                                          (env, "bc", "physical")]
    rows = scored_rows(cfg, grid, ["quick", "full"])
    assert [sorted(row) for row in rows] == [["full", "quick"], ["quick"], ["full", "quick"]]  # Ant BC: no row
    lines = table(rows, ["quick", "full"]).splitlines()
    assert "| -45.0% [-46.0, -44.0] (fd_fgsm) | 0.90 | 1.0 | -55.0% [-56.0, -54.0] (fd_fgsm) | 1.10 | 1.0 |" in lines[2]
    assert lines[3].endswith("| -90.0% [-91.0, -89.0] (aril_a) | 1.80 | 1.0 | – | – | – | -50.0% (fgsm_k) |")
    assert lines[4].startswith("| HalfCheetah-v5 | bc | physical |")
    assert lines[4].endswith("| -70.0% [-71.0, -69.0] (aril_a) | 1.40 | 1.0 | -66.0% [-67.0, -65.0] (aril_a; ARIL-A "
                             "trained against the surrogate; directed step 1) | 1.10 (of -60.0%, AMD EPYC (AVX2)) | 1.0 "
                             "| -50.0% (fgsm_k) |")
    full_alone = scored_rows(cfg, [(env, "bc", "physical")], ["full"])
    assert table(full_alone, ["full"]).splitlines()[2].endswith("| 1.10 | 1.0 | -60.0% (fgsm_k) |")
    assert "Rows needed in sensory" in needed(rows, ["quick", "full"])


def test_benchmark_run_of_a_few_cells_writes_the_table_of_every_cell_in_its_folder(tmp_path, capsys):
    """A run of Ant BC's quick cell rewrites the table with HalfCheetah's cells and the full budget scored earlier in
    the same folder, in the order of the benchmark's defaults; a cell of other screening seeds stays out of it. An
    unknown budget is refused by name before anything is scored."""
    from aril_ros import seeds
    from aril_ros.benchmarks import verdict as bench
    cfg = bench.VerdictBenchConfig(out=str(tmp_path), episodes=20)
    earlier = {("HalfCheetah-v5", "dagger", "physical", "quick", seeds.SCORECARD): -90.0,
               ("HalfCheetah-v5", "dagger", "physical", "full", seeds.SCORECARD): -95.0,
               ("Ant-v5", "bc", "sensory", "quick", seeds.SCORECARD): -40.0,
               ("HalfCheetah-v5", "bc", "sensory", "quick", 6600): -30.0}
    for (env, policy, mode, budget, seed), drop in earlier.items():
        folder = bench.cell_folder(bench.VerdictBenchConfig(out=str(tmp_path), seed=seed), env, policy, mode, budget)
        folder.mkdir(parents=True)
        figures = {**bench_cell({"aril_a": drop, "fd_fgsm": drop}, budget=budget, mode=mode, episodes=20,
                                policy=policy), "env": env}
        (folder / "cell.json").write_text(json.dumps(figures))
    bench.main([f"out:={tmp_path}", "episodes:=20", "envs:=Ant-v5", "policies:=bc", "modes:=sensory",
                "budgets:=quick", "add_rows:=false"])
    printed = capsys.readouterr().out
    assert "HalfCheetah" not in printed.split("\n", 1)[1]  # it prints the cells it was asked for
    lines = (tmp_path / "verdict.md").read_text().splitlines()
    assert "| quick ratio |" in lines[0] and "| full ratio |" in lines[0]
    assert lines[2].startswith("| HalfCheetah-v5 | dagger | physical |") and "-95.0%" in lines[2]
    assert lines[3].startswith("| Ant-v5 | bc | sensory |") and lines[4] == ""
    assert len(json.loads((tmp_path / "verdict.json").read_text())["cells"]) == 2
    assert bench.table_cells(cfg, [], ["full"]) == ([("HalfCheetah-v5", "dagger", "physical"),
                                                   ("Ant-v5", "bc", "sensory")], ["quick", "full"])
    with pytest.raises(ValueError, match="unknown budget 'fast'"):
        bench.main([f"out:={tmp_path / 'other'}", "budgets:=quick,fast"])
    assert not (tmp_path / "other").exists()


def test_benchmark_finds_the_fewest_rows_that_find_the_drop_of_every_row():
    """fewest_rows: the smallest set of rows whose worst finds WITHIN of every row's drop in each cell of the mode (of
    the reference's where every row finds more), the rows that ask least among as few; cells of the other mode do
    not count."""
    from aril_ros.benchmarks.verdict import fewest_rows, judged
    cells = [judged(bench_cell({"transfer": -40.0, "aril_a": -50.0})),
             judged(bench_cell({"zoo": -30.0, "aril_a": -29.0})),
             judged(bench_cell({"spsa": -90.0}, mode="sensory"))]
    assert fewest_rows(cells, "physical") == ("aril_a",)  # -29 finds 0.97 of -30
    assert fewest_rows(cells, "physical", within=1.0) == ("zoo", "aril_a")
    assert fewest_rows(cells, "sensory") == ("spsa",)
    # beyond the strongest known attack (the reference, -50%) a row adds nothing: the search's -100% is not needed
    assert fewest_rows([judged(bench_cell({"aril_a": -60.0, "aril_a_search": -100.0}))], "physical") == ("aril_a",)
    # two rows as good alone: the one that asks the policy least
    assert fewest_rows([judged(bench_cell({"transfer": -50.0, "aril_a_search": -50.0}))], "physical") == ("transfer",)
    # a cell that not even every row all cells scored reaches (its strongest row, fd_fgsm, is one another cell lacks)
    # does not decide the rows, and the table's last lines name it
    from aril_ros.benchmarks.verdict import needed
    older = bench_cell({"transfer": -40.0, "aril_a": -50.0})
    older = judged({**older, "drops": {row: d for row, d in older["drops"].items() if row != "fd_fgsm"}})
    out_of_reach = judged(bench_cell({"transfer": -20.0, "aril_a": -10.0, "fd_fgsm": -40.0}))
    assert fewest_rows([older, out_of_reach], "physical") == ("aril_a",)
    lines = needed([{"quick": older}, {"quick": out_of_reach}], ["quick"])
    assert lines.strip().endswith(": aril_a; no set of the rows every cell scored finds it in "
                                  f"{out_of_reach['env']} {out_of_reach['policy']}")


def test_benchmark_adds_a_row_a_cell_was_scored_without_on_its_own_episodes(tmp_path, monkeypatch):
    """A cell scored before fd_fgsm existed gets it on its own episodes (only rows that need no pipeline file), its
    drop paired with the clean episodes scored again with it, and keeps it: the budget's verdict and fewest_rows can
    count it. Refused on another CPU model, and where the clean episodes do not come out the same."""
    import json
    from aril_ros.benchmarks import verdict
    from aril_ros.provenance import cpu

    asked = []

    def scoring(cfg, env, policy, mode, budget, episodes, attacks, folder):  # clean 5000 per episode, fd takes 40%
        asked.append((episodes, attacks))
        episode = lambda r: {"episodes": [{"return": r + i} for i in range(episodes)]}  # noqa: E731
        return {"clean": {"mean_return": 5000.0 + (episodes - 1) / 2, **episode(5000.0)},
                "attacks": {"fd_fgsm": {"1.0": episode(3000.0)}}}, 0.5

    monkeypatch.setattr(verdict, "scorecard_result", scoring)
    cfg, cell = verdict.VerdictBenchConfig(out=str(tmp_path), episodes=4), ("HalfCheetah-v5", "dagger", "sensory", "quick")
    folder = verdict.cell_folder(cfg, *cell)
    folder.mkdir(parents=True)
    old = bench_cell({"aril_a_search": -30.0}, mode="sensory", episodes=4, cpu=cpu())
    del old["drops"]["fd_fgsm"]
    old["clean"] = 5001.5
    (folder / "cell.json").write_text(json.dumps(old))
    verdict.add_missing_rows(cfg, *cell)
    judged = verdict.score_cell(cfg, *cell)
    assert asked == [(4, ["fd_fgsm"])]
    assert judged["drops"]["fd_fgsm"]["drop_pct"] == pytest.approx(-2000.0 / 5001.5 * 100)
    assert judged["drops"]["aril_a_search"]["drop_pct"] == -30.0  # the others as they were
    kept = json.loads((folder / "cell.json").read_text())
    assert kept["rows_added"] == {"fd_fgsm": {"minutes": 0.5}} and kept["minutes"] == 1.5  # the scoring's minutes too
    verdict.add_missing_rows(cfg, *cell)
    assert len(asked) == 1  # kept: not scored again

    for changed, message in (({"cpu": "Another CPU (AVX2)"}, "was scored on Another CPU"),
                             ({"clean": 4000.0}, "its clean episodes came out at 5001.500 here, not 4000.000")):
        (folder / "cell.json").write_text(json.dumps({**old, **changed}))
        with pytest.raises(ValueError, match=message):
            verdict.add_missing_rows(cfg, *cell)


def test_benchmark_adds_a_reference_candidate_bundled_since_and_judges_the_cell_against_the_strongest(tmp_path,
                                                                                                       monkeypatch):
    """A cell scored before the directed ARIL-A against its learner was bundled gets it in its reference: run on the
    cell's own episodes, paired with its clean episodes scored again (no scorecard: every row is there), and the
    reference becomes the strongest candidate, which the ratio is then taken to."""
    import json
    from aril_ros.benchmarks import verdict as bench
    from aril_ros.provenance import cpu
    from aril_ros.registry import directed_adversary_path

    episodes = 4
    runs = []

    def evaluated(cfg):  # clean 5000 per episode; the directed ARIL-A takes 60%
        runs.append((cfg.mode, cfg.attack, cfg.attack_file, cfg.episodes, cfg.seed))
        per = 5000.0 if cfg.mode == "clean" else 2000.0
        return {"mean_return": per + (episodes - 1) / 2, "episodes": [{"return": per + i} for i in range(episodes)]}

    monkeypatch.setattr(bench, "episode_cell", evaluated)
    monkeypatch.setattr(bench, "scorecard_result", lambda *a, **k: pytest.fail("no row is missing: no scorecard"))
    cfg, cell = bench.VerdictBenchConfig(out=str(tmp_path), episodes=episodes), ("HalfCheetah-v5", "dagger",
                                                                                 "sensory", "quick")
    folder = bench.cell_folder(cfg, *cell)
    folder.mkdir(parents=True)
    old = bench_cell({DIRECTED_ROW: -30.0}, mode="sensory", episodes=episodes, cpu=cpu(), reference=-40.0)
    del old["reference"]["drops"]["bundled_directed"]
    old["clean"] = 5001.5
    (folder / "cell.json").write_text(json.dumps(old))
    bench.add_missing_rows(cfg, *cell)
    directed = directed_adversary_path("HalfCheetah-v5", "sensory")
    assert runs == [("clean", "none", "", episodes, cfg.seed),
                    ("sensory", "aril_a", str(directed), episodes, cfg.seed)]
    judged = bench.score_cell(cfg, *cell)
    ref = judged["reference"]
    assert ref["attack"] == "bundled_directed" and ref["added"] == ["bundled_directed"]
    assert ref["drop_pct"] == pytest.approx(-3000.0 / 5001.5 * 100) and ref["drops"]["fgsm_k"]["drop_pct"] == -40.0
    assert ref["files"]["bundled_directed"].endswith("directed-adversary/HalfCheetah-v5-sensory.pt")
    assert judged["ratio"] == pytest.approx(-30.0 / ref["drop_pct"])
    bench.add_missing_rows(cfg, *cell)
    assert len(runs) == 2  # kept: not run again


def test_benchmark_keeps_every_episode_and_gives_the_ratio_its_interval(tmp_path, monkeypatch):
    """A scored cell keeps each episode's return (clean, every row, every reference candidate), and its ratio gets a
    paired bootstrap interval over the episodes: it holds the ratio and narrows as the episodes grow; rows that take
    what the reference takes, episode by episode, give [1, 1]; each resample takes the strongest of a training row's
    states again (the row was the strongest of them on these episodes); a cell scored before returns were kept shows
    its ratio alone."""
    from aril_ros.benchmarks import verdict

    def cell_of(returns):
        return {"mean_return": float(np.mean(returns)), "episodes": [{"return": float(r)} for r in returns]}

    def scored(episodes: int, aril_a_loss=None, other_state: bool = False) -> dict:
        rng = np.random.default_rng(episodes)
        clean = 5000 + 500 * rng.standard_normal(episodes)
        reference_loss = 2000 * (1 + 0.5 * rng.standard_normal(episodes))
        losses = {row: 100 * (1 + 0.5 * rng.standard_normal(episodes)) for row in (*verdict.BLACK_BOX_ROWS, "fgsm_k")}
        losses["aril_a"] = (reference_loss if aril_a_loss is None
                            else aril_a_loss * (1 + 0.5 * rng.standard_normal(episodes)))
        # ARIL-A's training's other state: as strong on average, the row's the stronger on these episodes
        other = aril_a_loss * (1 + 0.5 * rng.standard_normal(episodes)) if other_state else None
        if other is not None:
            other += losses["aril_a"].mean() - other.mean() - 1
        states = {"adversary-physical.pt": list(clean - losses["aril_a"]),
                  **({"adversary-physical-at-250000.pt": list(clean - other)} if other_state else {})}
        monkeypatch.setattr(verdict, "scorecard_result", lambda *args: ({
            "clean": cell_of(clean), "attacks": {row: {"1.0": cell_of(clean - loss)} for row, loss in losses.items()},
            "adversary_states_returns": states, "directed_states_returns": {}}, 1.0))
        monkeypatch.setattr(verdict, "bundled_references", lambda *args: {"bundled_aril_a": tmp_path / "bundled.pt"})
        monkeypatch.setattr(verdict, "episode_cell", lambda cfg: cell_of(clean - reference_loss))
        cfg = verdict.VerdictBenchConfig(out=str(tmp_path / str(episodes)), episodes=episodes)
        figures = verdict.scorecard_figures(cfg, "HalfCheetah-v5", "dagger", "physical", "quick", episodes)
        json.dumps(figures)  # as cell.json keeps it
        assert figures["clean_returns"] == pytest.approx(clean)
        assert figures["drops"]["aril_a"]["returns"] == pytest.approx(clean - losses["aril_a"])
        assert figures["reference"]["drops"]["bundled_aril_a"]["returns"] == pytest.approx(clean - reference_loss)
        return verdict.judged(figures)

    few, many = scored(20, aril_a_loss=1800), scored(500, aril_a_loss=1800)
    for cell in (few, many):
        low, high = cell["ratio_ci95"]
        assert cell["black_box_worst"] == "aril_a" and low < cell["ratio"] < high
    assert many["ratio_ci95"][1] - many["ratio_ci95"][0] < (few["ratio_ci95"][1] - few["ratio_ci95"][0]) / 3
    assert 0.8 < many["ratio_ci95"][0] and many["ratio_ci95"][1] < 1.0  # around 1800 / 2000
    low, high = many["ratio_ci95"]
    assert f"| {many['ratio']:.2f} [{low:.2f}, {high:.2f}] |" in verdict.table([{"quick": many}], ["quick"])
    assert scored(20)["ratio_ci95"] == pytest.approx([1.0, 1.0])
    both = scored(20, aril_a_loss=1800, other_state=True)
    assert both["drops"]["aril_a"]["states_returns"]["adversary-physical-at-250000.pt"] is not None
    assert both["ratio"] == pytest.approx(few["ratio"])  # the same row's figure: the stronger state on these episodes
    assert both["ratio_ci95"][0] > few["ratio_ci95"][0] and both["ratio_ci95"][1] > few["ratio_ci95"][1]
    old = verdict.judged(bench_cell({"aril_a": -40.0}))
    assert old["ratio_ci95"] is None and "| 0.80 |" in verdict.table([{"quick": old}], ["quick"])


def test_benchmark_judges_a_cell_without_a_row_it_could_not_score_and_says_so():
    """A cell scored before a budget row and a reference candidate existed, not given them (add_rows:=false, or on a
    CPU model that cannot add them here), is judged by what it has, and the table names what it lacks."""
    from aril_ros.benchmarks.verdict import judged, table
    cell = bench_cell({"fd_fgsm": -70.0}, budget="full", mode="sensory")
    del cell["drops"][DIRECTED_ROW], cell["reference"]["drops"]["bundled_directed"]
    got = judged(cell)
    assert DIRECTED_ROW not in got["budget_rows"] and got["rows_lacking"] == [DIRECTED_ROW]
    assert got["black_box_worst"] == "fd_fgsm"
    page = table([{"full": got}], ["full"])
    assert f"(fd_fgsm; without {DIRECTED_ROW})" in page and "-50.0% (fgsm_k; without bundled_directed) |" in page


def test_benchmark_judges_a_cell_without_fd_fgsm_scored_as_the_budget_no_longer_does_and_scores_it_again(
        tmp_path, monkeypatch):
    """A cell whose fd_fgsm was scored at other iterations than its budget's of today (the full budget's were 10
    until 2026-12-07) is judged without it, the table saying so, however much it took; add_rows scores it again at
    today's iterations on the cell's own episodes (on its CPU model: on another it names the row as today's budget
    scores it), and the cell records them."""
    import json
    from aril_ros.benchmarks import verdict as bench
    from aril_ros.provenance import cpu
    from aril_ros.scorecard import BUDGETS

    today = BUDGETS["full"].fd_iterations
    old = bench_cell({"fd_fgsm": -70.0, DIRECTED_ROW: -40.0}, budget="full", mode="sensory", episodes=4, cpu=cpu(),
                     fd_iterations=today + 9)
    old["clean"] = 5001.5
    got = bench.judged(old)
    assert (got["black_box_worst"], got["rows_lacking"]) == (DIRECTED_ROW, ["fd_fgsm"])
    assert got["worst_of_every_row"] == "fd_fgsm"  # measured, kept beside the verdict
    assert f"({DIRECTED_ROW}; without fd_fgsm at {today} iteration" in bench.table([{"full": got}], ["full"])

    asked = []

    def scoring(cfg, env, policy, mode, budget, episodes, attacks, folder):  # fd at today's iterations takes 60%
        asked.append(attacks)
        episode = lambda r: {"episodes": [{"return": r + i} for i in range(episodes)]}  # noqa: E731
        return {"clean": {"mean_return": 5001.5, **episode(5000.0)}, "attacks": {"fd_fgsm": {"1.0": episode(2000.0)}}}, 0.5

    monkeypatch.setattr(bench, "scorecard_result", scoring)
    cfg, cell = bench.VerdictBenchConfig(out=str(tmp_path), episodes=4), ("HalfCheetah-v5", "dagger", "sensory", "full")
    folder = bench.cell_folder(cfg, *cell)
    folder.mkdir(parents=True)
    (folder / "cell.json").write_text(json.dumps({**old, "cpu": "Another CPU (AVX2)"}))
    with pytest.raises(ValueError, match=f"lacks fd_fgsm at {today} iteration.*was scored on Another CPU"):
        bench.add_missing_rows(cfg, *cell)
    (folder / "cell.json").write_text(json.dumps(old))
    bench.add_missing_rows(cfg, *cell)
    assert asked == [["fd_fgsm"]]
    again = bench.score_cell(dataclasses.replace(cfg, widen=False), *cell)
    assert again["fd_iterations"] == today and again["rows_lacking"] == []
    assert (again["black_box_worst"], again["black_box_drop_pct"]) == ("fd_fgsm", pytest.approx(-3000.0 / 5001.5 * 100))
    bench.add_missing_rows(cfg, *cell)
    assert len(asked) == 1  # scored as today: not again


@pytest.mark.slow
def test_a_pipeline_training_keeps_its_state_that_takes_the_most_from_the_policy_on_the_scored_episodes(tmp_path):
    """The states a training kept (its snapshots and its end) run against the policy's answers on the scored episodes,
    every question counted: the row gets the one with the lowest mean return, whose returns are the row's cell's
    episode by episode (so the row is the strongest state on the very episodes it reports); every state's returns are
    kept, and a rerun's record names the same state, or on other scored episodes judges the states again."""
    end = adversary.train_adversary(adversary.AdversaryConfig(
        env=ENV, mode=MODE, eps=EPS, victim="dagger", steps=3 * STEPS, snapshot_every=STEPS,
        out=str(tmp_path / "a.pt")), log=quiet)
    states = [*adversary.snapshots_of(end), end]
    assert [path.name for path in states] == [f"a-at-{STEPS}.pt", f"a-at-{2 * STEPS}.pt", "a.pt"]
    seed, episodes = SCORED_ON
    with answers_counted() as box:
        trained = verdict.keep_strongest(end, "dagger", ENV, MODE, EPS, "expert", "", HORIZON, SCORED_ON, quiet)
    cells = [evaluate(EvalConfig(env=ENV, policy="dagger", mode=MODE, attack="aril_a", eps=EPS, attack_file=str(state),
                                 rescale=True, episodes=episodes, seed=seed, horizon=HORIZON)) for state in states]
    assert trained.returns == {state.name: cell["returns"] for state, cell in zip(states, cells)}
    means = [round(float(np.mean(cell["returns"])), 3) for cell in cells]
    assert trained.screened == sorted(zip(means, map(verdict.relative, states)))
    assert trained.end == end and trained.kept == states[int(np.argmin(means))] and trained.scored_on == SCORED_ON
    assert trained.queries == box[0].asked >= 3 * episodes  # a question a step at least
    record = tmp_path / "record.json"
    made = json.loads(json.dumps(verdict.kept_record(trained)))
    assert verdict.kept_before(end, made) == trained
    assert verdict.kept_on(end, made, record, "dagger", ENV, MODE, EPS, "expert", "", HORIZON, SCORED_ON) == trained
    assert not record.exists()  # judged on these episodes already: nothing run, nothing written
    other = (seed + 100, episodes + 1)
    again = verdict.kept_on(end, {**made, "zoo": None}, record, "dagger", ENV, MODE, EPS, "expert", "", HORIZON, other,
                            quiet)
    assert again.scored_on == other and all(len(r) == other[1] for r in again.returns.values())
    assert json.loads(record.read_text()) == {"zoo": None, **json.loads(json.dumps(verdict.kept_record(again)))}

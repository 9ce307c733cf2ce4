"""How much of the strongest known damage the scorecard's black-box verdict finds, and in how many minutes.

    python -m aril_ros.benchmarks.verdict envs:=HalfCheetah-v5,Ant-v5 policies:=dagger,bc,dr,aril budgets:=quick,full

For each env, bundled learner and attacked mode (a cell), ``aril scorecard`` scores the learner's file as a black
box at each budget (every black-box row: random, SPSA^k, FGSM by finite differences, transfer, zoo, ARIL-A, ARIL-A +
search, directed ARIL-A; the zoo leaves out every adversary trained against this very file), on the scorecard's
episodes at eps
(scale 1; a cell whose verdict's interval comes out as wide as its drop, as Ant's can, is scored again on about as
many episodes as narrow it, the count the scorecard's page names to a user, reusing what the first scoring trained);
the budget's verdict is the worst of the rows the budget scores by default (the quick budget's few; the
full budget's more, :data:`~aril_ros.scorecard.FULL_ROWS`), the worst of every row is kept beside it. The reference
is the strongest of white-box FGSM^k on the file, the bundled ARIL-A trained against that very learner (1M steps;
2M for HalfCheetah DAgger) and the bundled directed ARIL-A trained against it (1M steps), on the same episodes.
Per cell it prints the black-box worst drop per budget, the reference drop, their ratio (with its 95% interval over the
cell's episodes: :func:`ratio_interval`) and the minutes the budget took, and writes every figure (each episode's
return among them) to ``<out>/verdict.json`` and the table to ``<out>/verdict.md``, both of every cell scored in
``<out>`` so far (a run of a few cells leaves the others in the table). Each cell's scorecard folder is kept under
``<out>/cells/``: a rerun resumes from the cells already scored (a cell's figures are in its
``cell.json``, with the CPU they were scored on, its progress with the seconds in its ``scorecard.log``). A
budget's ratio is to the reference scored with it: a run resumed on another CPU model, whose episodes differ from
the same files, is judged against its own. Below the table, per mode, the fewest rows that find nearly every row's
drop (or the reference's) in each cell (:func:`fewest_rows`): run on screening episodes (``seed:=6600
out:=results/verdict-screening``), it is how the quick budget's rows are chosen, never on the scorecard's own
episodes.
"""
from __future__ import annotations

import itertools
import json
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .. import seeds
from ..args import arg, comma_list, module_config
from ..evaluation import EvalConfig, evaluate
from ..provenance import cpu, portable
from ..registry import ATTACKED_MODES, DIRECTED_ROW, adversary_path, check_name, directed_adversary_path
from ..report.stats import episodes_to_pin, paired_drop, returns_of
from ..scorecard import BUDGETS, SURROGATE_ATTACKS, ScorecardConfig, policy_in, scorecard
from ..verdict import DIRECTED, PIPELINE

BLACK_BOX_ROWS = ("random", "spsa", "fd_fgsm", "transfer", "zoo", "aril_a", "aril_a_search", DIRECTED_ROW)
WITHIN = 0.95
"""A budget's rows must find this share of the drop every row finds in each cell, or of the reference's where every
row finds more (:func:`fewest_rows`)."""
DEFAULT_EPISODES = 20
EPISODES = {"Ant-v5": 50}
"""Episodes per cell where 20 leave the verdict's interval wider than its drop: Ant's clean episodes range from a
dozen steps to the full horizon (issue 38: at 10 episodes its drops swung by 20-70 points)."""
TRAINED_ROWS = {"aril_a": "adversary", DIRECTED_ROW: "directed"}
"""The rows that run the strongest of a pipeline training's states on the scored episodes, and the training's name in
a scorecard's record (:func:`aril_ros.scorecard.training_record`)."""
RATIO_RESAMPLES = 10_000
"""Bootstrap resamples of a cell's episodes behind its ratio's interval (:func:`ratio_interval`)."""
WIDEN_AT_MOST = 4
"""A cell whose verdict's interval is as wide as its drop is scored again on at most this many times its episodes:
near no drop at all, no count of episodes narrows the interval below it."""


@dataclass
class VerdictBenchConfig:
    """Arguments of ``python -m aril_ros.benchmarks.verdict``."""

    envs: str = arg("HalfCheetah-v5,Ant-v5", "comma-separated env ids")
    policies: str = arg("dagger,bc,dr,aril", "comma-separated bundled learners (each has bundled ARIL-As against it)")
    modes: str = arg(",".join(ATTACKED_MODES), "comma-separated attacked modes")
    budgets: str = arg("quick,full", f"comma-separated scorecard budgets ({', '.join(BUDGETS)})")
    episodes: int = arg(0, "episodes per cell (paired: the same env seeds in every row); 0: the env's of "
                           f"EPISODES ({', '.join(f'{e} {n}' for e, n in EPISODES.items())}; else {DEFAULT_EPISODES})",
                        low=0, high=100_000)
    seed: int = arg(seeds.SCORECARD, "env seed of every cell's first episode: the scorecard's (the verdict), or a "
                                     f"screening one ({seeds.SCREENING}..) to choose the quick budget's rows on",
                    low=0, high=2**31 - 1)
    widen: bool = arg(True, "where a cell's verdict has an interval as wide as its drop, score it again on about as "
                            f"many episodes as narrow it (at most {WIDEN_AT_MOST} times as many)")
    add_rows: bool = arg(True, "score the rows and reference candidates a cell scored before they existed lacks, on its "
                               "own episodes (on the CPU model it was scored on); false: judge it by what it has, the "
                               "table naming the rows it lacks")
    workers: int = arg(2, "CPUs of the local Ray each scorecard's cells run on", low=1, high=1024)
    out: str = arg("runs/verdict", "the folder of the cells and the table")


def episodes_of(cfg: VerdictBenchConfig, env: str) -> int:
    """Episodes per cell of ``env``: ``episodes:=``, else the env's own count."""
    return cfg.episodes or EPISODES.get(env, DEFAULT_EPISODES)


def reference(env: str, policy: str, mode: str, episodes: int, seed: int, result: dict) -> dict:
    """The reference of a cell: the strongest of white-box FGSM^k (from the scorecard's ``mode`` results) and the
    bundled adversaries trained against this learner (:func:`bundled_references`), each with its paired drop from the
    scorecard's clean cell."""
    drops, files = bundled_drops(env, policy, mode, episodes, seed, result["clean"],
                                 bundled_references(env, policy, mode))
    return strongest_reference({"fgsm_k": paired(result["clean"], result["attacks"]["fgsm_k"]["1.0"]), **drops},
                               files)


def bundled_references(env: str, policy: str, mode: str) -> dict[str, Path]:
    """The bundled adversaries trained against the bundled learner ``policy`` that a cell's reference runs, by name:
    its ARIL-A, and its directed ARIL-A where one is bundled."""
    files = {"bundled_aril_a": adversary_path(env, mode, policy),
             "bundled_directed": directed_adversary_path(env, mode, policy)}
    return {name: path for name, path in files.items() if path.exists()}


def bundled_drops(env: str, policy: str, mode: str, episodes: int, seed: int, clean: dict,
                  adversaries: dict[str, Path]) -> tuple[dict, dict]:
    """Each named bundled adversary's paired drop from ``clean`` (the cell's clean episodes), ``policy`` in ``mode``
    under it on the cell's episodes, and the files they ran, by the same names."""
    drops = {name: paired(clean, episode_cell(EvalConfig(env=env, policy=policy, mode=mode, attack="aril_a",
                                                         attack_file=str(path), episodes=episodes, seed=seed)))
             for name, path in adversaries.items()}
    return drops, {name: portable(str(path)) for name, path in adversaries.items()}


def episode_cell(cfg: EvalConfig) -> dict:
    """``cfg``'s evaluation as a scorecard's cell holds it: the mean return and each episode's."""
    evaluated = evaluate(cfg)
    return {"mean_return": evaluated["mean_return"], "episodes": [{"return": r} for r in evaluated["returns"]]}


def paired(clean: dict, attacked: dict) -> dict:
    """The paired drop of ``attacked`` from ``clean`` (two cells of the same episodes), with the attacked episodes'
    returns, which :func:`ratio_interval` resamples."""
    return paired_drop(clean, attacked) | {"returns": returns_of(attacked)}


def strongest_reference(drops: dict, files: dict) -> dict:
    """A reference from its candidates' paired ``drops`` and the adversary ``files`` they ran: the strongest."""
    strongest = min(drops, key=lambda name: drops[name]["drop_pct"])  # a drop is negative: the lowest is strongest
    return {"attack": strongest, "files": files, "drops": drops, "drop_pct": drops[strongest]["drop_pct"]}


def cell_folder(cfg: VerdictBenchConfig, env: str, policy: str, mode: str, budget: str) -> Path:
    """Where a cell's scorecard and figures (``cell.json``) are kept."""
    seeded = "" if cfg.seed == seeds.SCORECARD else f"-seed{cfg.seed}"
    return Path(cfg.out) / "cells" / f"{env}-{policy}-{mode}-{budget}{seeded}"


def scored(cfg: VerdictBenchConfig, env: str, policy: str, mode: str, budget: str) -> dict | None:
    """A cell's figures, judged, when it was scored already (on the episodes the run asks for, or widened from
    them: :func:`score_cell`); else None."""
    done = cell_folder(cfg, env, policy, mode, budget) / "cell.json"
    if not done.exists():
        return None
    figures, episodes = json.loads(done.read_text()), episodes_of(cfg, env)
    first = figures.get("widened_from", figures).get("episodes", DEFAULT_EPISODES)
    if first != episodes:
        raise ValueError(f"{done} was scored on {first} episodes, not {episodes}: give another out:= (a table's "
                         "cells share their episodes)")
    return judged(figures)


def score_cell(cfg: VerdictBenchConfig, env: str, policy: str, mode: str, budget: str) -> dict:
    """One scorecard of ``policy`` in ``mode`` at ``budget`` (its figures, worst black-box drop and minutes); with
    ``widen``, where its verdict's interval is as wide as the drop, scored again on about as many episodes as
    narrow it (at most :data:`WIDEN_AT_MOST` times as many), the scorecard reusing what it trained the first time:
    what the scorecard's page tells a user to do."""
    done = cell_folder(cfg, env, policy, mode, budget) / "cell.json"
    figures = scored(cfg, env, policy, mode, budget)
    if figures is None:
        done.parent.mkdir(parents=True, exist_ok=True)
        measured = scorecard_figures(cfg, env, policy, mode, budget, episodes_of(cfg, env))
        done.write_text(json.dumps(measured, indent=1) + "\n")
        figures = judged(measured)
    wanted = episodes_to_pin(verdict_drop(figures), figures["episodes"])
    if not cfg.widen or "widened_from" in figures or wanted is None:
        return figures
    first = {k: figures[k] for k in ("episodes", "minutes", "black_box_worst", "black_box_drop_pct",
                                     "black_box_ci95_pct")}
    wider = scorecard_figures(cfg, env, policy, mode, budget, min(wanted, WIDEN_AT_MOST * first["episodes"]))
    # the minutes of both scorings: what the benchmark spent (a user scoring this many episodes at once trains once)
    wider |= {"minutes": round(first["minutes"] + wider["minutes"], 2), "widened_from": first}
    done.write_text(json.dumps(wider, indent=1) + "\n")
    return judged(wider)


def add_missing_rows(cfg: VerdictBenchConfig, env: str, policy: str, mode: str, budget: str) -> None:
    """A cell scored before a black-box row existed holds no figure for it, so neither its verdict nor
    :func:`fewest_rows` can count the row: the missing rows that need no file of the pipeline's first four steps
    (``fd_fgsm`` came after the first cells, the directed ARIL-A after pipeline 4), and those it scored as the budget
    no longer does (:func:`scored_as_today`), are scored on the cell's own episodes and put in its ``cell.json``, with
    the minutes they took; so are the reference's missing candidates (a
    directed ARIL-A bundled since). Only on the CPU model the cell was scored on, whose clean episodes they must give
    again (its other rows are paired with those)."""
    done = cell_folder(cfg, env, policy, mode, budget) / "cell.json"
    figures = json.loads(done.read_text())
    as_today = scored_as_today(figures)
    missing = [row for row in BLACK_BOX_ROWS if row not in as_today and row not in SURROGATE_ATTACKS]
    references = {name: path for name, path in bundled_references(env, policy, mode).items()
                  if name not in figures["reference"]["drops"]}
    if not missing and not references:
        return
    if figures.get("cpu", cpu()) != cpu():  # a cell that did not record it: its clean episodes tell (below)
        raise ValueError(f"{done} lacks {', '.join([lacking_row(figures, row) for row in missing] or references)}, "
                         f"and was scored on {figures['cpu']}: score "
                         f"them on that CPU model (this is {cpu()}), or the cell again (remove its folder)")
    if missing:
        result, minutes = scorecard_result(cfg, env, policy, mode, budget, figures["episodes"], missing,
                                           done.parent / "added")
    else:  # only the reference lacks a candidate: the clean episodes alone, which pair its returns
        result, minutes = {"clean": episode_cell(EvalConfig(env=env, policy=policy_in(policy, env, mode),
                                                            mode="clean", attack="none", episodes=figures["episodes"],
                                                            seed=cfg.seed))}, 0.0
    if abs(result["clean"]["mean_return"] - figures["clean"]) > 1e-3:
        raise ValueError(f"{done}: its clean episodes came out at {result['clean']['mean_return']:.3f} here, not "
                         f"{figures['clean']:.3f}: the rows {', '.join(missing or references)} would not pair with "
                         "its others")
    figures["drops"] |= {row: paired(result["clean"], result["attacks"][row]["1.0"]) for row in missing}
    figures.setdefault("clean_returns", returns_of(result["clean"]))
    figures["rows_added"] = figures.get("rows_added", {}) | {row: {"minutes": round(minutes, 2)} for row in missing}
    figures["fd_iterations"] = BUDGETS[budget].fd_iterations
    if DIRECTED_ROW in missing:
        figures["directed"] = DIRECTED
    figures["minutes"] = round(figures["minutes"] + minutes, 2)
    if references:
        ref = figures["reference"]
        drops, files = bundled_drops(env, policy, mode, figures["episodes"], cfg.seed, result["clean"], references)
        figures["reference"] = strongest_reference(ref["drops"] | drops, ref.get("files", {"bundled_aril_a": ref.get(
            "file")}) | files) | {"added": sorted(references)}
    done.write_text(json.dumps(figures, indent=1) + "\n")


def scorecard_result(cfg: VerdictBenchConfig, env: str, policy: str, mode: str, budget: str, episodes: int,
                     attacks: list[str], folder: Path) -> tuple[dict, float]:
    """``mode``'s results of one scorecard of ``policy`` at ``budget`` on ``episodes`` with ``attacks`` at eps
    (scale 1), in ``folder`` (reusing the surrogate and adversary a scoring there trained before), and the minutes
    it took; its progress in ``scorecard.log`` with the seconds since it began: where a cell's minutes went."""
    folder.mkdir(parents=True, exist_ok=True)
    started = time.time()
    with (folder / "scorecard.log").open("a") as log_file:
        def log(*parts, **_):
            print(f"[{time.time() - started:7.1f} s]", *parts, file=log_file, flush=True)

        # no timing rows: the benchmark times the value verdict, as its cells scored before them did
        scorecard(ScorecardConfig(policy=policy, env=env, modes=mode, budget=budget, episodes=episodes,
                                  seed=cfg.seed, scales="1", attacks=",".join(attacks), timing=0,
                                  workers=cfg.workers, out=str(folder)), log=log)
    return json.loads((folder / "scorecard.json").read_text())["modes"][mode], (time.time() - started) / 60


def scorecard_figures(cfg: VerdictBenchConfig, env: str, policy: str, mode: str, budget: str, episodes: int) -> dict:
    """Score ``policy`` in ``mode`` at ``budget`` on ``episodes`` into the cell's folder (reusing the surrogate and
    adversary a scoring there trained before): the measured figures alone, the budget's verdict is judged from them
    on every read."""
    result, minutes = scorecard_result(cfg, env, policy, mode, budget, episodes, [*BLACK_BOX_ROWS, "fgsm_k"],
                                       cell_folder(cfg, env, policy, mode, budget))
    drops = {row: paired(result["clean"], result["attacks"][row]["1.0"]) for row in BLACK_BOX_ROWS}
    for row, training in TRAINED_ROWS.items():  # the states its row was the strongest of, on these episodes
        drops[row]["states_returns"] = result[f"{training}_states_returns"]
    return {"env": env, "policy": policy, "mode": mode, "budget": budget, "minutes": round(minutes, 2),
            "clean": result["clean"]["mean_return"], "clean_returns": returns_of(result["clean"]), "drops": drops,
            "episodes": episodes, "seed": cfg.seed,
            "reference": reference(env, policy, mode, episodes, cfg.seed, result), "cpu": cpu(), "pipeline": PIPELINE,
            "directed": DIRECTED, "fd_iterations": BUDGETS[budget].fd_iterations}


def verdict_drop(cell: dict) -> dict:
    """The judged cell's verdict as a drop: its percentage and 95% interval."""
    return {"drop_pct": cell["black_box_drop_pct"], "ci95_pct": cell["black_box_ci95_pct"]}


def judged(figures: dict) -> dict:
    """A cell's figures with its budget's verdict: the worst of the rows the budget scores by default (every row is
    run, and kept, to show which), judged again on every read, so a cell scored before the budget's rows changed
    gives the verdict of today's rows, and its ratio to the reference scored with it; and the worst of every row
    beside it."""
    drops, budget = figures["drops"], BUDGETS[figures["budget"]]
    wanted = budget.black_box[figures["mode"]] if budget.black_box else BLACK_BOX_ROWS
    # a cell scored before a row existed (or as the budget no longer scores it), on a CPU model that cannot score it
    # here, is judged without it (and says so)
    as_today = scored_as_today(figures)
    rows = [row for row in wanted if row in as_today]
    worst = min(rows, key=lambda row: drops[row]["drop_pct"])
    worst_of_all = min(drops, key=lambda row: drops[row]["drop_pct"])
    return {**figures, "budget_rows": rows, "rows_lacking": [row for row in wanted if row not in rows],
            "black_box_worst": worst,
            "black_box_drop_pct": drops[worst]["drop_pct"], "black_box_ci95_pct": drops[worst]["ci95_pct"],
            "ratio": drops[worst]["drop_pct"] / figures["reference"]["drop_pct"],
            "ratio_ci95": ratio_interval(figures, rows),
            "worst_of_every_row": worst_of_all, "worst_of_every_row_drop_pct": drops[worst_of_all]["drop_pct"]}


def ratio_interval(figures: dict, rows: list[str]) -> list[float] | None:
    """The 95% interval of a cell's ratio, its budget's verdict over its reference: a paired bootstrap over the
    cell's episodes (percentiles of :data:`RATIO_RESAMPLES` resamples, seeded), each resample taking again the worst
    of the budget's ``rows`` (of a training's row, the strongest of its states: :data:`TRAINED_ROWS`) and the
    strongest reference candidate, as the cell's own figures were taken. Where it holds the target ratio, the episodes
    cannot tell the verdict from it. None for a cell with a row or reference candidate scored before cells kept their
    episodes' returns (2026-12-07)."""
    candidates = figures["reference"]["drops"].values()
    if "clean_returns" not in figures or any("returns" not in figures["drops"][row] for row in rows) or any(
            "returns" not in candidate for candidate in candidates):
        return None
    clean = np.asarray(figures["clean_returns"])
    picks = np.random.default_rng(0).integers(0, len(clean), size=(RATIO_RESAMPLES, len(clean)))

    def strongest(returns: list[list[float]]) -> np.ndarray:  # per resample, the largest mean loss of return
        return np.max([(clean - np.asarray(r))[picks].mean(axis=1) for r in returns], axis=0)

    ratios = (strongest([returns for row in rows for returns in
                         [figures["drops"][row]["returns"], *figures["drops"][row].get("states_returns", {}).values()]])
              / strongest([candidate["returns"] for candidate in candidates]))
    return [float(q) for q in np.percentile(ratios, [2.5, 97.5])]


def scored_as_today(figures: dict) -> list[str]:
    """The rows of a cell scored as its budget scores them today: every one but an ``fd_fgsm`` scored at other
    iterations (the full budget's were FGSM^k's 10 until 2026-12-07, which cells record as ``fd_iterations``)."""
    fd_as_today = figures["fd_iterations"] == BUDGETS[figures["budget"]].fd_iterations
    return [row for row in figures["drops"] if row != "fd_fgsm" or fd_as_today]


def row_target(cell: dict, within: float = WITHIN) -> float:
    """The drop a set of rows must find in ``cell``: ``within`` of every row's drop, or of the reference's where
    every row finds more (drops are negative: the max is the weaker)."""
    return within * max(cell["worst_of_every_row_drop_pct"], cell["reference"]["drop_pct"])


def fewest_rows(cells: list[dict], mode: str, within: float = WITHIN) -> tuple[str, ...]:
    """The fewest black-box rows that find ``within`` of each ``mode`` cell's target: the drop of every row, or the
    reference's where every row finds more (beyond the strongest known attack a row adds nothing the benchmark
    judges). Among as few, the ones earliest in :data:`BLACK_BOX_ROWS`, which ask the policy least; a cell that not
    even all of them reach (the strongest row being one some cell lacks) does not count. Run on screening episodes,
    it is how the quick budget's rows are chosen."""
    targets = [(cell["drops"], row_target(cell, within)) for cell in cells if cell["mode"] == mode]
    # a cell scored before a row existed holds no figure for it: only the rows every cell scored can be chosen
    in_every = [row for row in BLACK_BOX_ROWS if all(row in drops for drops, _ in targets)]
    targets = [(drops, target) for drops, target in targets if min(drops[row]["drop_pct"] for row in in_every) <= target]
    subsets = sorted((rows for size in range(1, len(in_every) + 1) for rows in itertools.combinations(in_every, size)),
                     key=lambda rows: (len(rows), [BLACK_BOX_ROWS.index(row) for row in rows][::-1]))
    for rows in subsets:
        if all(min(drops[row]["drop_pct"] for row in rows) <= target for drops, target in targets):
            return rows
    return tuple(in_every)


def table(rows: list[dict], budgets: list[str]) -> str:
    """The benchmark's table: per cell the black-box drop and ratio per budget (– where that budget is still to
    score), the reference and the minutes. A budget's ratio is to the reference scored with it, on its machine (the
    same files give other episodes on another CPU model): where that is not the first budget's, the ratio names its
    reference and CPU."""
    head = "| env | policy | mode | clean | " + " | ".join(
        f"{b} black-box drop [95%] | {b} ratio | {b} min" for b in budgets) + " | reference drop |"
    lines = [head, "|" + "---|" * (5 + 3 * len(budgets))]
    for cell in rows:
        first = next(iter(cell.values()))
        ref = first["reference"]
        parts = [f"{c['black_box_drop_pct']:+.1f}% [{c['black_box_ci95_pct'][0]:+.1f}, {c['black_box_ci95_pct'][1]:+.1f}] "
                 f"({c['black_box_worst']}{episodes_note(c)}{pipeline_note(c)}{lacking_note(c)}) | "
                 f"{ratio(c, first)} | {c['minutes']:.1f}" if c else "– | – | –"
                 for c in (cell.get(b) for b in budgets)]
        lines.append(f"| {first['env']} | {first['policy']} | {first['mode']} | {first['clean']:.0f} | "
                     + " | ".join(parts) + f" | {ref['drop_pct']:+.1f}% ({ref['attack']}{reference_note(first)}) |")
    return "\n".join(lines) + "\n"


def episodes_note(cell: dict) -> str:
    """For a cell scored again on more episodes (its first interval was as wide as its drop), how many; and if
    even they leave it so, that too."""
    if "widened_from" not in cell:
        return ""
    still = episodes_to_pin(verdict_drop(cell), cell["episodes"]) is not None
    return f"; {cell['episodes']} episodes" + ("; the interval still as wide as the drop" if still else "")


def reference_note(cell: dict) -> str:
    """For a cell whose reference lacks a candidate bundled since it was scored, which."""
    lacking = [name for name in bundled_references(cell["env"], cell["policy"], cell["mode"])
               if name not in cell["reference"].get("drops", {})]
    return f"; without {', '.join(lacking)}" if lacking else ""


def lacking_note(cell: dict) -> str:
    """For a cell judged without some of its budget's rows (scored before they existed, or as the budget no longer
    scores them), which."""
    lacking = [lacking_row(cell, row) for row in cell.get("rows_lacking", [])]
    return f"; without {', '.join(lacking)}" if lacking else ""


def lacking_row(cell: dict, row: str) -> str:
    """A row a cell lacks, named as its budget scores it where the cell scored it otherwise (fd_fgsm's iterations)."""
    if row != "fd_fgsm" or row not in cell["drops"]:
        return row
    iterations = BUDGETS[cell["budget"]].fd_iterations
    return f"fd_fgsm at {iterations} iteration{'s' if iterations != 1 else ''}"


def pipeline_note(cell: dict) -> str:
    """For a cell whose pipeline rows (:data:`aril_ros.scorecard.SURROGATE_ATTACKS`) an older pipeline made, which
    one: cells record it since pipeline 4; those that record none had ARIL-A trained against the surrogate. Likewise
    for its directed row, whose step cells record since its version 2 (:data:`aril_ros.verdict.DIRECTED`)."""
    made = cell.get("pipeline")
    note = ("; ARIL-A trained against the surrogate" if made is None else
            "" if made == PIPELINE else f"; pipeline {made}")
    directed = cell.get("directed", 1)
    return note + (f"; directed step {directed}" if DIRECTED_ROW in cell["drops"] and directed != DIRECTED else "")


def ratio(cell: dict, first: dict) -> str:
    """A budget's black-box drop over the reference scored with it, and its 95% interval where the cell kept its
    episodes' returns; its reference and CPU named where they are not those of the row's first budget (whose
    reference the table's last column shows)."""
    ref = cell["reference"]["drop_pct"]
    text = f"{cell['ratio']:.2f}"
    if cell.get("ratio_ci95"):
        text += f" [{cell['ratio_ci95'][0]:.2f}, {cell['ratio_ci95'][1]:.2f}]"
    if (ref, cell.get("cpu")) != (first["reference"]["drop_pct"], first.get("cpu")):
        text += f" (of {ref:+.1f}%, {cell.get('cpu', 'CPU not recorded')})"
    return text


def main(argv=None) -> None:
    cfg = module_config(VerdictBenchConfig, "python -m aril_ros.benchmarks.verdict", __doc__, argv)
    if cfg is None:
        return
    if cfg.episodes == 1:
        raise ValueError("episodes:=1: a paired interval needs at least 2 episodes per cell")
    budgets, out = [check_name("budget", b, tuple(BUDGETS)) for b in comma_list(cfg.budgets)], Path(cfg.out)
    grid = [(env, policy, mode) for env in comma_list(cfg.envs) for policy in comma_list(cfg.policies)
            for mode in comma_list(cfg.modes)]
    # first every cell scored before a row existed gets it: the table after each cell judges them all by today's rows
    for (env, policy, mode), budget in itertools.product(grid, budgets):
        if cfg.add_rows and (cell_folder(cfg, env, policy, mode, budget) / "cell.json").exists():
            add_missing_rows(cfg, env, policy, mode, budget)
    for env, policy, mode in grid:
        cell = {budget: score_cell(cfg, env, policy, mode, budget) for budget in budgets}
        print(f"{env} {policy} {mode}: " + "; ".join(
            f"{b} {c['black_box_drop_pct']:+.1f}% ({c['black_box_worst']}) against the reference's "
            f"{c['reference']['drop_pct']:+.1f}% ({c['reference']['attack']}): ratio {c['ratio']:.2f}, "
            f"{c['minutes']:.1f} min"
            for b, c in cell.items()), flush=True)
        # the table after every cell, of every cell scored so far in out:= (by this run or an earlier one): a run
        # stopped midway leaves the whole of what was measured, and a run of a few cells the table of them all
        table_grid, table_budgets = table_cells(cfg, grid, budgets)
        rows = scored_rows(cfg, table_grid, table_budgets)
        (out / "verdict.json").write_text(json.dumps({"settings": asdict(cfg), "cells": rows}, indent=1) + "\n")
        (out / "verdict.md").write_text(table(rows, table_budgets) + needed(rows, table_budgets))
    rows = scored_rows(cfg, grid, budgets)
    print(table(rows, budgets) + needed(rows, budgets))


def table_cells(cfg: VerdictBenchConfig, grid: list[tuple[str, str, str]],
                budgets: list[str]) -> tuple[list[tuple[str, str, str]], list[str]]:
    """The table's grid and budgets: the run's, and those of every cell already scored in ``out:=`` on its
    ``seed:=`` (a run of Ant's cells keeps HalfCheetah's in the table), in the order of the benchmark's defaults."""
    found = []
    for done in sorted(Path(cfg.out).glob("cells/*/cell.json")):
        figures = json.loads(done.read_text())
        if cell_folder(cfg, *(figures[key] for key in ("env", "policy", "mode", "budget"))) == done.parent:
            found.append(figures)  # a cell of another seed:= keeps its seed in its folder's name
    defaults = VerdictBenchConfig()
    orders = [comma_list(defaults.envs), comma_list(defaults.policies), comma_list(defaults.modes)]

    def rank(cell: tuple[str, str, str]) -> tuple[int, ...]:  # one not in the defaults after those, as first seen
        return tuple(order.index(value) if value in order else len(order) for order, value in zip(orders, cell))

    cells = dict.fromkeys([*grid, *((f["env"], f["policy"], f["mode"]) for f in found)])
    scored_budgets = dict.fromkeys([*budgets, *(f["budget"] for f in found)])  # a cell's budget is one of BUDGETS
    return sorted(cells, key=rank), sorted(scored_budgets, key=list(BUDGETS).index)


def scored_rows(cfg: VerdictBenchConfig, grid: list[tuple[str, str, str]], budgets: list[str]) -> list[dict]:
    """The table's rows: per cell of the grid (env, policy, mode) that any budget scored, each budget's figures."""
    rows = []
    for env, policy, mode in grid:
        row = {budget: figures for budget in budgets if (figures := scored(cfg, env, policy, mode, budget))}
        if row:
            rows.append(row)
    return rows


def needed(rows: list[dict], budgets: list[str]) -> str:
    """The table's last lines: per mode the fewest rows that find :data:`WITHIN` of every row's drop in each cell (of
    the reference's where every row finds more), and the cells no set of the rows every cell scored reaches."""
    cells = [cell[budgets[0]] for cell in rows if budgets[0] in cell]
    lines = []
    for mode in dict.fromkeys(cell["mode"] for cell in cells):
        chosen = fewest_rows(cells, mode)
        short = [f"{cell['env']} {cell['policy']}" for cell in cells if cell["mode"] == mode
                 and min(cell["drops"][row]["drop_pct"] for row in chosen) > row_target(cell)]
        lines.append(f"Rows needed in {mode} (at least {WITHIN:g} of every row's drop in each of these cells, or of the "
                     "reference's where every row finds more): " + ", ".join(chosen)
                     + (f"; no set of the rows every cell scored finds it in {', '.join(short)}" if short else ""))
    return "\n" + "\n".join(lines) + "\n"

if __name__ == "__main__":
    main(sys.argv[1:])

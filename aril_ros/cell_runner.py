"""A scorecard's cells, run: each cell an ``aril eval`` (its :class:`~aril_ros.evaluation.EvalConfig`) on the
engine, or the same episodes as a run of the ROS 2 graph, as a sweep task (:mod:`aril_ros.sweep`, whose progress
lines give the ETA); every episode's figures come back.

    CellRunner("engine", workers=2, address="").run(cells, log)   # [{"eps", "mean_return", "mean_expert_loss",
                                                                   #   "queries", "queries_per_step",
                                                                   #   "episodes": [...]}, ...] in the cells' order

A cell's ``queries`` are the questions its attack put to the policy (observations asked about only to read the
answer; each step's own action is not one): on the engine the attack's count of the rows it asked, through the graph
the probes its run log holds, each a message the policy node answered.

On the engine a cell is a task of one CPU; through the graph a task of :data:`GRAPH_RUN_CPUS`, its run in a ROS
domain of its own on the task's node, or in the domain given (an external node's, whose cells run one after the
other in this process). A graph cell's log is ``<logs>/<mode>-<attack>[-<its file's stem>][-search<K>]-<eps>.mcap``
when ``logs`` is given, else a scratch file.
"""
from __future__ import annotations

import dataclasses
import tempfile
from dataclasses import dataclass
from pathlib import Path

from . import plugins
from .collectors import RoundSpec
from .evaluation import EvalConfig, evaluate, shipped_job
from .registry import ATTACKS
from .runlog import read_run
from .step import EpisodeStats, summarise_episodes
from .sweep import Produced, run_tasks
from .timing import TimingAttack

GRAPH_RUN_CPUS = 2
"""What a graph run (a cell through the graph) declares as a sweep task: its five processes work in lockstep, about
4.5 ms of CPU per step at 420 steps/s here, i.e. two cores busy (issue 16's profile)."""
GRAPH_RUN_FIELDS = tuple(f.name for f in dataclasses.fields(RoundSpec))


@dataclass(frozen=True)
class CellRunner:
    """Where cells run: ``via`` engine or graph, as sweep tasks of ``workers`` local CPUs or on the Ray cluster at
    ``address`` (one worker and no address: one after the other in this process); a graph run in ``domain`` (auto: a
    free one of its task's node), its log kept under ``logs`` when given."""

    via: str
    workers: int
    address: str
    domain: str = "auto"
    logs: Path | None = None

    def run(self, cells: list[EvalConfig], log, label: str = "scorecard cells") -> list[dict]:
        """Every cell's figures, in the order of ``cells``, each logged as it comes back."""
        if self.via == "graph":
            tasks = run_tasks(graph_cell, [(self.graph_spec(cell),) for cell in cells], self.workers, self.address,
                              cpus=GRAPH_RUN_CPUS, label=label, log=log)
        else:
            tasks = run_tasks(engine_cell, [(shipped_job(dataclasses.asdict(cell)),) for cell in cells], self.workers,
                              self.address, label=label, log=log)
        results: list[dict] = [{}] * len(cells)
        for index, (episodes, queries) in tasks:
            cell = cells[index]
            results[index] = figures(cell, episodes, queries)
            log(f"[scorecard] {cell.mode} {described(cell)} eps {cell.eps:g}: return "
                f"{results[index]['mean_return']:.1f}", flush=True)
        return results

    def graph_spec(self, cell: EvalConfig) -> dict:
        """``cell``'s graph run (:class:`RoundSpec`'s fields), its files marked to travel with its task; its log a
        file the task makes when logs are kept, else none (the task reads it back on its node)."""
        log_file = self.logs / f"{cell.mode}-{named(cell)}-{cell.eps:g}.mcap" if self.logs else None
        run = {k: v for k, v in dataclasses.asdict(cell).items() if k in GRAPH_RUN_FIELDS}
        return shipped_job({**run, "domain": self.domain, "record": Produced(log_file) if log_file else None})


def described(cell: EvalConfig) -> str:
    """A cell's attack as its progress line names it: with its file and its search, which tell cells of one attack
    apart (a scorecard runs aril_a with three adversaries or searches)."""
    return (ATTACKS[cell.attack] + (f" ({Path(cell.attack_file).stem})" if cell.attack_file else "")
            + (f" + search {cell.search}" if cell.search else "")
            + (f", {TimingAttack.of(cell).budget.described()}" if timing_of(cell) else "")
            + (f" ({chooser(cell)})" if timing_of(cell) and cell.timing != "fixed" else ""))


def named(cell: EvalConfig) -> str:
    """A cell's attack in its log's file name: its name, its file's stem and its search."""
    return (cell.attack + (f"-{Path(cell.attack_file).stem}" if cell.attack_file else "")
            + (f"-search{cell.search}" if cell.search else "")
            + "".join(f"-{name}{value:g}" for name, value in timing_of(cell).items())
            + (f"-{chooser(cell).replace(' ', '-')}" if timing_of(cell) and cell.timing != "fixed" else ""))


def chooser(cell: EvalConfig) -> str:
    """Who picks a timed cell's timing: a learned one by its file's stem."""
    return cell.timing + (f" {Path(cell.timing_file).stem}" if cell.timing_file else "")


def timing_of(cell: EvalConfig) -> dict:
    """A cell's timing attack, the settings it sets (none: no timing attack)."""
    return {name: value for name in ("delay", "drop", "action_delay") if (value := getattr(cell, name))}


def figures(cell: EvalConfig, episodes: list[EpisodeStats], queries: int) -> dict:
    """A cell's figures: every episode's (in episode order), their summary, and the attack's ``queries`` in all and
    per step (every step is attacked)."""
    episodes = sorted(episodes, key=lambda e: e.episode)
    summary = summarise_episodes(episodes)
    return {"eps": cell.eps, "mean_return": summary["mean_return"], "mean_expert_loss": summary["mean_expert_loss"],
            "queries": queries, "queries_per_step": round(queries / max(summary["steps"], 1), 2),
            "episodes": [{"episode": e.episode, "env_seed": cell.seed + e.episode, "return": e.reward,
                          "expert_loss": round(e.expert_loss, 6), "steps": e.steps,
                          "max_abs_delta": round(e.max_delta, 6)} for e in episodes]}


def engine_cell(job: dict) -> tuple[list[EpisodeStats], int]:
    """A cell on the engine (a sweep task): ``aril eval`` of ``job``, every episode's figures and the attack's
    questions to the policy."""
    episodes = []
    summary = evaluate(EvalConfig(**job), progress=episodes.append)
    return episodes, summary.get("queries", 0)  # an attack that asks nothing has no count


def graph_cell(spec: dict) -> tuple[list[EpisodeStats], int]:
    """A cell as a run of the graph (a sweep task), every episode's figures and the probes the policy node answered,
    read back from the run's log."""
    spec = {k: str(v) if isinstance(v, Path) else v for k, v in spec.items()}  # a file's copy on the task's node
    with tempfile.TemporaryDirectory(prefix="aril_scorecard-") as scratch:
        record = Path(spec["record"] or Path(scratch) / "cell.mcap")
        record.parent.mkdir(parents=True, exist_ok=True)
        record.unlink(missing_ok=True)  # a rerun's: the writer takes new files only
        logged = read_run(plugins.load("aril_ros.collectors", "graph")(RoundSpec(**{**spec, "record": record})))
    # the recorder's figures, taken once as the run went; a probe is in the log once asked and answered
    return logged.episode_stats, len(logged.probe_row)

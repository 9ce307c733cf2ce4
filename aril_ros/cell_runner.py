"""The scorecard's cells, run: each one ``aril eval``'s episodes on the engine, or a run of the ROS 2 graph, as a
sweep task (:mod:`aril_ros.sweep`, whose progress lines give the ETA), every episode's figures coming back.

    run_cells(cells, cfg, budget, "engine", out, log)   # [{"eps", "mean_return", "mean_expert_loss", "episodes"}]

On the engine a cell is a task of one CPU; through the graph a task of :data:`GRAPH_RUN_CPUS`, its run in a ROS
domain of its own on the task's node (an external node's cells one after the other in this process, in the node's
domain). A graph cell's log is ``<out>/logs/<mode>-<attack>-<eps>.mcap`` with ``keep_logs``, else a scratch file.
"""
from __future__ import annotations

import dataclasses
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from . import plugins
from .dagger import RoundSpec
from .evaluation import EvalConfig, evaluate, shipped_job
from .mcap_log import read_run
from .registry import ATTACKS
from .step import EpisodeStats, episode_stats, summarise_episodes
from .sweep import Produced, run_tasks

if TYPE_CHECKING:
    from .scorecard import Budget, ScorecardConfig

GRAPH_RUN_CPUS = 2
"""What a graph run (a cell through the graph) declares as a sweep task: its five processes work in lockstep, about
4.5 ms of CPU per step at 420 steps/s here, i.e. two cores busy (issue 16's profile)."""


@dataclass(frozen=True)
class Cell:
    """One cell of a scorecard's plan: the policy in ``mode`` under ``attack`` at ``eps``; for ARIL-A, its
    ``adversary`` file, run at the cell's eps (scaled to it: its perturbation times eps / its own eps)."""

    mode: str
    attack: str
    eps: float
    adversary: str = ""

    def describe(self) -> str:
        return f"{self.mode} {ATTACKS[self.attack]} eps {self.eps:g}"


def run_cells(cells: list[Cell], cfg: ScorecardConfig, budget: Budget, via: str, out: Path, log,
              label: str = "scorecard cells") -> list[dict]:
    """Every cell's figures, in the order of ``cells``: run on ``via`` (engine or graph) as sweep tasks of
    ``cfg.workers`` local CPUs or on the cluster at ``cfg.address`` (an external node's one after the other here)."""
    if via == "graph":
        external = cfg.policy == "external"
        calls = [(graph_spec(cell, cfg, budget, out),) for cell in cells]
        tasks = run_tasks(graph_cell, calls, 1 if external else cfg.workers, "" if external else cfg.address,
                          cpus=GRAPH_RUN_CPUS, label=label, log=log)
    else:
        calls = [(shipped_job(dataclasses.asdict(engine_job(cell, cfg, budget))),) for cell in cells]
        tasks = run_tasks(engine_episodes, calls, cfg.workers, cfg.address, label=label, log=log)
    results: list[dict] = [{}] * len(cells)
    for index, episodes in tasks:
        results[index] = cell_of(cells[index].eps, cfg.seed, episodes)
        log(f"[scorecard] {cells[index].describe()}: return {results[index]['mean_return']:.1f}", flush=True)
    return results


def cell_of(eps: float, seed: int, episodes: list[EpisodeStats]) -> dict:
    """A cell's figures: every episode's (in episode order, the first of env seed ``seed``) and their summary."""
    episodes = sorted(episodes, key=lambda e: e.episode)
    summary = summarise_episodes(episodes)
    return {"eps": eps, "mean_return": summary["mean_return"], "mean_expert_loss": summary["mean_expert_loss"],
            "episodes": [{"episode": e.episode, "env_seed": seed + e.episode, "return": e.reward,
                          "expert_loss": round(e.expert_loss, 6), "steps": e.steps,
                          "max_abs_delta": round(e.max_delta, 6)} for e in episodes]}


def spsa_settings(attack: str, budget: Budget) -> dict:
    """SPSA^k's iterations and directions from the budget (the other attacks keep their own: fgsm_k's k is not
    SPSA's)."""
    return {"k": budget.spsa_iterations, "samples": budget.spsa_samples} if attack == "spsa" else {}


def engine_job(cell: Cell, cfg: ScorecardConfig, budget: Budget) -> EvalConfig:
    """A cell on the engine: the ``aril eval`` it is."""
    return EvalConfig(env=cfg.env, policy=cfg.policy, expert=cfg.expert, mode=cell.mode, attack=cell.attack,
                      eps=cell.eps, attack_file=cell.adversary, rescale=bool(cell.adversary), episodes=budget.episodes,
                      seed=cfg.seed, horizon=cfg.horizon, **spsa_settings(cell.attack, budget))


def engine_episodes(job: dict) -> list[EpisodeStats]:
    """A cell on the engine (a sweep task): ``aril eval`` of ``job``, every episode's figures."""
    episodes = []
    evaluate(EvalConfig(**job), progress=episodes.append)
    return episodes


def graph_spec(cell: Cell, cfg: ScorecardConfig, budget: Budget, out: Path) -> dict:
    """A cell's graph run (:class:`RoundSpec`'s fields), its files marked to travel with its task: an external node's
    in the node's domain, a file's in a free one of the task's node. The log is a file the task makes with
    ``keep_logs``, else none (the task reads it back on its node)."""
    log_file = out / "logs" / f"{cell.mode}-{cell.attack}-{cell.eps:g}.mcap"
    return shipped_job({
        "env": cfg.env, "mode": cell.mode, "attack": cell.attack, "eps": cell.eps, "policy": cfg.policy,
        "expert": cfg.expert, "attack_file": cell.adversary, "episodes": budget.episodes, "seed": cfg.seed,
        "horizon": cfg.horizon, "domain": cfg.domain if cfg.policy == "external" else "auto",
        "rescale": bool(cell.adversary), "record": Produced(log_file) if cfg.keep_logs else None,
        **spsa_settings(cell.attack, budget)})


def graph_cell(spec: dict) -> list[EpisodeStats]:
    """A cell as a run of the graph (a sweep task), every episode's figures read back from the run's log."""
    spec = {k: str(v) if isinstance(v, Path) else v for k, v in spec.items()}  # a file's copy on the task's node
    with tempfile.TemporaryDirectory(prefix="aril_scorecard-") as scratch:
        record = Path(spec["record"] or Path(scratch) / "cell.mcap")
        record.parent.mkdir(parents=True, exist_ok=True)
        record.unlink(missing_ok=True)  # a rerun's: the writer takes new files only
        logged = read_run(plugins.load("aril_ros.collectors", "graph")(RoundSpec(**{**spec, "record": record})))
    return episode_stats(logged.episodes, logged.reward, logged.action, logged.expert_action, logged.delta)

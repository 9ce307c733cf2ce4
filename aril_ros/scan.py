"""``aril scan-adversary``: a hyperparameter scan of the learned adversary, every training and evaluation a task.

    aril scan-adversary env:=HalfCheetah-v5 mode:=sensory victim:=dagger grid:="lr=0.001,0.0003 ent_coef=0,0.01"
    aril scan-adversary ... address:=auto          # the same scan on a Ray cluster (docs/scaling.md)

The grid names fields of ``aril train-adversary`` (``<field>=<value>,<value>`` groups, separated by spaces); the
scan trains one ARIL-A per point of their product against the victim (one task each, on a local Ray of
``workers`` CPUs or the cluster at ``address``), then attacks the victim with each on the same episodes (a task
each) beside its clean return, and ranks the points from the strongest attack (the lowest return). An adversary
already in the output folder is kept (delete it to train that point again), so an interrupted scan resumes.

Written to ``out`` (default ``runs/scan-<env>-<mode>-<victim name>``)::

    adversary-<k>.pt     point k's adversary (its provenance: the command and settings that trained it)
    scan.json            the settings, and per point its grid values, file, training time, attacked returns
    scan.md              the points ranked, the strongest first
"""
from __future__ import annotations

import itertools
import json
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from . import seeds
from .adversary import AdversaryConfig, train_adversary
from .adversary_net import load_adversary
from .args import ArgumentError, arg, parse_args
from .evaluation import EvalConfig, evaluate_all
from .policy import resolve_policy
from .provenance import stamp
from .registry import (
    ATTACKED_MODES,
    DEFAULT_ENV,
    DEFAULT_POLICY,
    MAX_EPS,
    calibrated_eps,
    check_name,
    for_task,
)
from .report.stats import summarise
from .sweep import Produced, run_tasks, session, shipped

FIXED = ("env", "mode", "eps", "victim", "expert", "steps", "out", "threads", "init")
"""The fields of train-adversary the scan sets itself: the grid scans any other."""


@dataclass
class ScanConfig:
    """Arguments of ``aril scan-adversary``."""

    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    mode: str = arg("sensory", "sensory or physical")
    victim: str = arg(DEFAULT_POLICY, "the attacked policy: a bundled name or a policy file")
    expert: str = arg("expert", "the expert")
    eps: float = arg(0.0, "the budget (0: the calibrated one for env and mode)", low=0.0, high=MAX_EPS)
    grid: str = arg("lr=0.001,0.0003", "the points: <field>=<v>,<v> groups of train-adversary fields, separated by "
                                       "spaces; the scan trains every combination (a group of one value sets that "
                                       "field for every point, e.g. n_envs=64)")
    steps: int = arg(1_000_000, "training steps of each adversary", low=1, high=10**9)
    episodes: int = arg(10, "episodes each adversary attacks the victim on (the same for all, and clean)",
                        low=1, high=100_000)
    seed: int = arg(seeds.SCAN, "env seed of the first evaluation episode", low=0, high=2**31 - 1)
    horizon: int = arg(1000, "steps per evaluation episode", low=1, high=1_000_000)
    workers: int = arg(2, "CPUs of the local Ray the tasks run on (1: one after the other in this process)",
                       low=1, high=1024)
    address: str = arg("", "run the tasks on this Ray cluster instead (<head ip>:6379, or auto)")
    out: str = arg("", "the folder to write (default runs/scan-<env>-<mode>-<victim name>)")


def grid_points(grid: str) -> list[dict[str, str]]:
    """The product of the grid's values, as ``{field: value text}`` per point; names a bad field or group."""
    known = [f.name for f in fields(AdversaryConfig) if f.name not in FIXED]
    axes = {}
    for group in grid.split():
        name, sep, values = group.partition("=")
        if not sep or not values:
            raise ArgumentError(f"grid:= takes <field>=<value>,<value> groups separated by spaces, got {group!r}")
        if name in FIXED:
            raise ArgumentError(f"grid:= cannot scan {name!r}: the scan sets it (scan-adversary's own {name}:=)")
        if name not in known:
            raise ArgumentError(f"grid:= names {name!r}, not a field of train-adversary; scannable: {', '.join(known)}")
        axes[name] = values.split(",")
    if not axes:
        raise ArgumentError("grid:= names no field to scan")
    return [dict(zip(axes, combo)) for combo in itertools.product(*axes.values())]


def train_point(argv: list[str], victim, expert, out: Path) -> Path:
    """One point's training (a task): ``aril train-adversary`` with ``argv``, against ``victim`` with ``expert``'s
    labels, into ``out``."""
    cfg = parse_args(AdversaryConfig, [*argv, f"victim:={victim}", f"expert:={expert}", f"out:={out}"])
    return train_adversary(cfg, log=lambda *args, **kwargs: None)


def scan_adversary(cfg: ScanConfig, log=print) -> dict:
    """Train, evaluate and rank every point; write the folder; return the JSON written."""
    check_name("mode", cfg.mode, ATTACKED_MODES)
    points = grid_points(cfg.grid)
    resolve_policy(cfg.victim, cfg.env, cfg.mode)  # a missing or mismatched victim is reported first
    eps = cfg.eps or calibrated_eps(cfg.env, cfg.mode)
    out = Path(cfg.out or f"runs/scan-{cfg.env}-{cfg.mode}-{Path(cfg.victim).stem}")
    out.mkdir(parents=True, exist_ok=True)
    common = [f"env:={cfg.env}", f"mode:={cfg.mode}", f"eps:={eps}", f"steps:={cfg.steps}"]
    argvs = [[*common, *(f"{k}:={v}" for k, v in point.items())] for point in points]
    for argv in argvs:
        parse_args(AdversaryConfig, argv)  # every point's values checked before anything trains
    files = [out / f"adversary-{k}.pt" for k in range(len(points))]
    victim, expert = shipped(for_task(cfg.victim, cfg.env, cfg.mode)), shipped(for_task(cfg.expert, cfg.env))

    with session(cfg.workers, cfg.address):
        # 1. the adversaries not trained yet, one task each
        todo = [k for k, file in enumerate(files) if not file.exists()]
        log(f"[scan] {len(points)} points, {len(todo)} to train ({cfg.steps:,} steps each), eps {eps:g}", flush=True)
        for _ in run_tasks(train_point, [(argvs[k], victim, expert, Produced(files[k])) for k in todo], cfg.workers,
                           cfg.address, label="trainings", log=log):
            pass

        # 2. each adversary against the victim on the same episodes, beside the clean ones
        base = dict(env=cfg.env, policy=cfg.victim, expert=cfg.expert, episodes=cfg.episodes, seed=cfg.seed,
                    horizon=cfg.horizon)
        jobs = [asdict(EvalConfig(mode="clean", attack="none", **base))]
        jobs += [asdict(EvalConfig(mode=cfg.mode, attack="aril_a", attack_file=str(file), **base)) for file in files]
        clean, *attacked = evaluate_all(jobs, cfg.workers, cfg.address, log)
    clean_mean = float(np.mean(clean["returns"]))
    rows = []
    for k, (point, file, result) in enumerate(zip(points, files, attacked)):
        cell = summarise([result["returns"]])
        made = load_adversary(file).meta["provenance"]
        rows.append({"point": k, "grid": point, "file": file.name, "mean": cell["mean"], "ci95": cell["ci95"],
                     "drop_pct": -100 * (1 - cell["mean"] / clean_mean) if clean_mean else math.nan,
                     "mean_expert_loss": result["mean_expert_loss"], "returns": result["returns"],
                     "train_seconds": made.get("train_seconds"), "final_episode_loss": made.get("final_episode_loss")})
    rows.sort(key=lambda row: row["mean"])
    payload = {**stamp("aril scan-adversary", cfg), "eps": eps, "clean": {"mean": clean_mean,
                                                                         "returns": clean["returns"]},
               "episode_seeds": f"{cfg.seed}..{cfg.seed + cfg.episodes - 1}", "points": rows}
    (out / "scan.json").write_text(json.dumps(payload, indent=1) + "\n")
    (out / "scan.md").write_text(markdown(payload, cfg))
    best = rows[0]
    log(f"[scan] {out / 'scan.md'}: strongest point {best['grid']} ({best['file']}): return {best['mean']:.1f}, "
        f"{best['drop_pct']:+.1f}% of clean {clean_mean:.1f}", flush=True)
    return payload


def markdown(payload: dict, cfg: ScanConfig) -> str:
    keys = list(payload["points"][0]["grid"])
    lines = [f"# ARIL-A scan: {cfg.env} {cfg.mode}, victim {cfg.victim}, eps {payload['eps']:g}", "",
             f"`{payload['command']}`", "",
             f"Each point: an ARIL-A trained {cfg.steps:,} steps against the victim, then attacking it on the env seeds "
             f"{payload['episode_seeds']} (clean: {payload['clean']['mean']:.1f}). Mean return ± the half-width of a "
             "95% Student-t interval over the episodes; the strongest attack first.", "",
             "| rank | " + " | ".join(keys) + " | return under attack | drop | training s | file |",
             "|---|" + "---|" * len(keys) + "---|---|---|---|"]
    for rank, row in enumerate(payload["points"], 1):
        lines.append(f"| {rank} | " + " | ".join(row["grid"][k] for k in keys)
                     + f" | {row['mean']:.1f} ± {row['ci95']:.1f} | {row['drop_pct']:+.1f}% | "
                     f"{row['train_seconds'] or 0:.0f} | {row['file']} |")
    return "\n".join(lines) + "\n"

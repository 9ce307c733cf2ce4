"""What the report evaluates and how: the evaluation plan, its evaluations as tasks (:mod:`aril_ros.sweep`: Ray,
local or a cluster), and the cache of evaluations keyed by their arguments and the digests of the files they read."""
from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import seeds
from ..evaluation import evaluation_task, shipped_job
from ..files import write_atomically
from ..policy import PolicyFileError
from ..provenance import cpu, portable
from ..registry import DIRECTED_ROW, SEARCH_ROW, TABLE_SEARCH, THREATS, row_attack
from ..sweep import run_tasks
from .paper import BLACK_BOX_ROWS

FAILURES = (PolicyFileError, ValueError, RuntimeError, OSError)
"""Recorded as a missing file or a failed benchmark, not raised."""


def digest(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:12]


@dataclass(frozen=True)
class Key:
    """Which table cell or sweep point an evaluation belongs to (``mode``: the table's, also for the clean run)."""

    env: str
    mode: str
    defense: str
    attack: str
    scale: float
    seed: int


def evaluation_plan(policies: dict, adversaries: dict, surrogates: dict, directed: dict, eps: dict, episodes: int,
                    sweep_episodes: int, sweep_attacks: list[str], scales: list[float], horizon: int
                    ) -> list[tuple[Key, dict]]:
    """Every evaluation of every policy, with the arguments of :class:`aril_ros.evaluation.EvalConfig`:
    clean and under each threat at the calibrated eps (the tables), DAgger under the black-box rows too, the sweep
    attacks at ``scales`` times it (the sweeps); ARIL-A only where an adversary was had, the transfer attack where a
    surrogate was, the directed row where a directed adversary was. Episodes start at the defense table's seeds."""
    plan = []
    for (defense, env, mode, seed), policy in policies.items():
        if policy is None:
            continue
        adversary = adversaries[(defense, env, mode, seed)]
        surrogate = surrogates.get((defense, env, mode, seed))
        points = [("none", 0.0, episodes)] + [(t, 1.0, episodes) for t in THREATS]
        points += [(a, 1.0, episodes) for a in BLACK_BOX_ROWS if defense == "dagger"]
        points += [(a, s, sweep_episodes) for a in sweep_attacks for s in scales]
        files = {"aril_a": adversary, SEARCH_ROW: adversary, DIRECTED_ROW: directed.get((defense, env, mode, seed)),
                 "transfer": surrogate}  # the file each row's attack reads
        for row, scale, n in points:
            attack = row_attack(row)
            attack_file = files.get(row, "")
            if attack_file is None:
                continue
            job = {"env": env, "policy": str(policy), "mode": "clean" if attack == "none" else mode,
                   "attack": attack, "eps": round(scale * eps[env, mode], 6), "attack_file": str(attack_file),
                   "rescale": attack == "aril_a", "episodes": n, "seed": seeds.DEFENSE_TABLE, "horizon": horizon}
            if row == SEARCH_ROW:  # only here: the other jobs' cache keys stay as they were
                job["search"] = TABLE_SEARCH
            plan.append((Key(env, mode, defense, row, scale, seed), job))
    return plan


def _evaluate_job(job: dict) -> dict:
    """The evaluation's per-episode returns, how long it took its CPU, and which CPU (on a cluster, the node's:
    another CPU model gives other returns from the same files)."""
    started = time.time()
    return {"returns": evaluation_task(job)["returns"], "seconds": round(time.time() - started, 2), "cpu": cpu()}


def job_key(job: dict, machine: str) -> str:
    """The cache key: the evaluation's arguments, its policy and adversary files by content (digest), not by
    path, and the CPU model it ran on (``machine``: :func:`aril_ros.provenance.cpu`). The same files give the same
    evaluation in any checkout on that CPU model, so a committed cache serves a fresh clone there; another model
    evaluates again, since its kernels give other returns from the same files and a table mixing the two would
    compare figures across machines."""
    files = {k: digest(Path(job[k])) for k in ("policy", "attack_file") if job.get(k)}
    arguments = {k: v for k, v in job.items() if k not in files}
    return hashlib.sha256(json.dumps([arguments, files, machine], sort_keys=True).encode()).hexdigest()[:20]


def run_jobs(jobs: list[dict], cache: Path, workers: int, address: str, fresh: bool, log
             ) -> tuple[list[list[float]], dict, list[dict]]:
    """Per-episode returns of each evaluation, from ``cache`` (the evaluations made on this CPU model) or computed
    as tasks (``workers`` CPUs of a local Ray, or the cluster at ``address``); how many distinct evaluations were
    run and read from the cache; and how each distinct one ran, as its task recorded it: ``seconds`` it took its CPU
    and ``cpu``. Each result is cached as it comes back, under the CPU model its task ran on (on a cluster of other
    models, the node's), so a killed report resumes. Equal jobs (a mode-independent policy's clean run, asked for
    by both modes) run once."""
    cache.mkdir(parents=True, exist_ok=True)
    machine = cpu()
    keys = [job_key(job, machine) for job in jobs]
    done: dict[str, dict] = {}
    todo: dict[str, dict] = {}
    for key, job in zip(keys, jobs):
        hit = cache / f"{key}.json"
        if hit.exists() and not fresh:
            done[key] = json.loads(hit.read_text())
        else:
            todo[key] = job
    counts = {"run": len(todo), "cached": len(done)}
    log(f"[report] {len(jobs)} evaluations: {len(done)} cached on this CPU model ({machine}), {len(todo)} to run",
        flush=True)
    started = time.time()
    todo_keys = list(todo)
    calls = [(shipped_job(todo[k]),) for k in todo_keys]
    for n, (index, result) in enumerate(run_tasks(_evaluate_job, calls, workers, address, label="evaluations",
                                                  log=log), 1):
        key = todo_keys[index]
        # the job as committed caches keep it: files inside the checkout by their relative path, as anywhere
        job, done[key] = todo[key], {"job": {k: portable(v) for k, v in todo[key].items()}, **result}
        kept = key if result["cpu"] == machine else job_key(job, result["cpu"])
        # whole or not at all: a cache committed while a report runs (benchmarks/scripts/full-protocol.sh) is read
        write_atomically(cache / f"{kept}.json", lambda partial: partial.write_text(json.dumps(done[key])))
        log(f"[report] {n}/{len(todo)} {time.time() - started:6.0f}s  {job['env']} {job['mode']} "
            f"{Path(job['policy']).name} {job['attack']} eps {job['eps']:g}: {np.mean(result['returns']):.1f}",
            flush=True)
    runs = [{k: v for k, v in result.items() if k not in ("job", "returns")} for result in done.values()]
    return [done[key]["returns"] for key in keys], counts, runs


def evaluated_on(runs: list[dict]) -> dict[str, int]:
    """How many distinct evaluations ran on each CPU model (a report resumed on other machines, or a cluster's
    nodes, can mix them); those cached before the CPU was kept count as ``CPU not recorded``."""
    return dict(Counter(run.get("cpu", "CPU not recorded") for run in runs).most_common())


def by_cell(plan: list[tuple[Key, dict]], returns: list[list[float]]) -> dict[tuple, list[list[float]]]:
    """Each (env, mode, defense, attack, scale)'s per-episode returns, one list per training seed."""
    evals: dict[tuple, list[list[float]]] = {}
    for (key, _), r in zip(plan, returns):
        evals.setdefault((key.env, key.mode, key.defense, key.attack, key.scale), []).append(r)
    return evals


def seed_means(plan: list[tuple[Key, dict]], returns: list[list[float]]) -> dict[tuple, dict[tuple, float]]:
    """Per (env, mode), each (defense, attack, training seed)'s mean return at the calibrated eps: what a paired
    comparison over seeds takes (:func:`.tables.top_two`)."""
    means: dict[tuple, dict[tuple, float]] = {}
    for (key, _), r in zip(plan, returns):
        if key.scale == 1.0:
            means.setdefault((key.env, key.mode), {})[(key.defense, key.attack, key.seed)] = float(np.mean(r))
    return means


def evaluations_json(plan: list[tuple[Key, dict]], returns: list[list[float]], relative) -> list[dict]:
    """Each evaluation as the report's JSON records it (file names through ``relative``)."""
    return [{"key": dataclasses.asdict(key),
             "job": {**job, "policy": relative(job["policy"]),
                     "attack_file": job["attack_file"] and relative(job["attack_file"])},
             "mean": float(np.mean(r)), "returns": r} for (key, job), r in zip(plan, returns)]

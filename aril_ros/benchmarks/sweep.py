"""Sweep speed-up: one evaluation sweep run in this process, then as Ray tasks, its wall time each and the ratio.

    python -m aril_ros.benchmarks.sweep env:=Swimmer-v5 workers:=2
    python -m aril_ros.benchmarks.sweep address:=auto     # the same sweep on the cluster this machine has joined

The sweep is the report's kind of work: the bundled DAgger learner evaluated clean and under random, FGSM and
its bundled ARIL-A in both attacked modes, ``repeats`` times over different episodes (``jobs`` evaluations of
``episodes`` episodes each). It runs once with one worker in this process (no Ray) and once on Ray (an embedded
local Ray with ``workers`` CPUs, its start-up counted, or the cluster at ``address``), each from an empty cache;
the results must be bit for bit the same. The last line is the figures as JSON.
"""
import json
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from ..args import arg, module_config
from ..registry import ATTACKED_MODES, adversary_path, bundled_file, calibrated_eps
from ..report.jobs import run_jobs
from ..seeds import DEFENSE_TABLE


@dataclass
class SweepBenchConfig:
    """Arguments of ``python -m aril_ros.benchmarks.sweep``."""

    env: str = arg("Swimmer-v5", "gymnasium MuJoCo env id (one with a bundled DAgger learner and its ARIL-A)")
    repeats: int = arg(2, "how many times the 8 evaluations (4 attacks x 2 modes) run, on other episodes each time",
                       low=1, high=100)
    episodes: int = arg(4, "episodes per evaluation", low=1, high=100_000)
    horizon: int = arg(1000, "steps per episode", low=1, high=1_000_000)
    workers: int = arg(2, "CPUs of the embedded local Ray", low=1, high=1024)
    address: str = arg("", "a Ray cluster to run the sweep on instead (<head ip>:6379, or auto: the one this machine has joined)")


def sweep_jobs(cfg: SweepBenchConfig) -> list[dict]:
    policy = str(bundled_file("dagger", cfg.env))
    jobs = []
    for repeat in range(cfg.repeats):
        for mode in ATTACKED_MODES:
            adversary = str(adversary_path(cfg.env, mode, "dagger"))
            for attack in ("none", "random", "fgsm", "aril_a"):
                jobs.append({"env": cfg.env, "policy": policy, "mode": "clean" if attack == "none" else mode,
                             "attack": attack, "eps": calibrated_eps(cfg.env, mode),
                             "attack_file": adversary if attack == "aril_a" else "", "rescale": attack == "aril_a",
                             "episodes": cfg.episodes, "seed": DEFENSE_TABLE + repeat * cfg.episodes,
                             "horizon": cfg.horizon})
    return jobs


def timed(jobs: list[dict], workers: int, address: str) -> tuple[float, list]:
    with tempfile.TemporaryDirectory() as cache:
        started = time.perf_counter()
        returns, _, _ = run_jobs(jobs, Path(cache), workers, address, False, lambda *a, **k: None)
        return time.perf_counter() - started, returns


def main(argv):
    cfg = module_config(SweepBenchConfig, "python -m aril_ros.benchmarks.sweep", __doc__, argv)
    if cfg is None:
        return
    jobs = sweep_jobs(cfg)
    serial, serial_returns = timed(jobs, 1, "")
    on_ray, ray_returns = timed(jobs, cfg.workers, cfg.address)
    where = cfg.address or f"an embedded local Ray of {cfg.workers} CPUs (its start-up counted)"
    print(f"{cfg.env}: {len(jobs)} evaluations of {cfg.episodes} x {cfg.horizon} steps")
    print(f"{'in this process':<28}{serial:>8.1f} s")
    print(f"{'on Ray':<28}{on_ray:>8.1f} s   {where}")
    print(f"{'speed-up':<28}{serial / on_ray:>8.2f}x   results bit for bit the same: {serial_returns == ray_returns}")
    print(json.dumps({"env": cfg.env, "evaluations": len(jobs), "serial_s": round(serial, 2), "ray_s": round(on_ray, 2),
                      "workers": cfg.workers, "address": cfg.address, "speedup": round(serial / on_ray, 3),
                      "identical": serial_returns == ray_returns}))
    if serial_returns != ray_returns:
        sys.exit("the sweep on Ray gave other results than in this process")


if __name__ == "__main__":
    main(sys.argv[1:])

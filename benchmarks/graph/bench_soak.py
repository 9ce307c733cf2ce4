"""Soak: several long ``run_graph.py`` runs at once; the memory (RSS) of every process at the start and
the end, steps/s over time, the shutdown time, and every log validated with ``read_run``.

    .venv/bin/python -m benchmarks.graph.bench_soak                                   # 3 runs x 50 episodes x 1000 steps
    .venv/bin/python -m benchmarks.graph.bench_soak episodes:=10 horizon:=500         # the quick version, a few minutes

Each run is a ``run_graph.py`` process in a ROS domain of its own (``domain:=auto``) with its four nodes,
recording to a temporary MCAP file. Every ``sample`` seconds the RSS of each process is read from
``/proc``; "start" is the first reading after the run's first episode (every import done, every buffer
warm), "end" the last before it stopped. Steps/s over time: per tenth of the run's episodes, from the
times its episode lines appear. Shutdown: from its last episode line to its exit (the nodes stopped, the
log closed, the summary printed). A run that fails, or whose log ``read_run`` refuses or that differs from
its summary, is reported as such. The last line is the figures as JSON (the ``aril_ros.benchmarks`` entry
point ``soak``).
"""
from __future__ import annotations

import itertools
import json
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from aril_ros.args import arg, module_config
from aril_ros.registry import DEFAULT_ENV, MODES
from aril_ros.runlog import RunLogError, read_run

ROLES = ("orchestrator", "simulator", "attacker", "policy", "expert")
PAGE_MB = 4096 / 2**20


@dataclass
class SoakConfig:
    """Arguments of ``python -m benchmarks.graph.bench_soak``."""

    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    mode: str = arg("sensory", f"one of {', '.join(MODES)}")
    episodes: int = arg(50, "episodes per run", low=1, high=100_000)
    horizon: int = arg(1000, "steps per episode", low=1, high=1_000_000)
    runs: int = arg(3, "runs at once", low=1, high=20)
    sample: float = arg(1.0, "seconds between memory readings", low=0.1, high=3600.0)


@dataclass
class Run:
    """One ``run_graph.py`` process, its episode times and its processes' memory readings."""

    index: int
    record: Path
    proc: subprocess.Popen
    reader: threading.Thread | None = None
    episode_times: list[float] = field(default_factory=list)
    stderr: list[str] = field(default_factory=list)
    rss_start: dict[str, float] = field(default_factory=dict)
    rss_end: dict[str, float] = field(default_factory=dict)
    ended: float = 0.0
    """when its stderr closed: when it exited (its nodes write to log files of their own)"""

    def read_stderr(self) -> None:
        for line in self.proc.stderr:
            if line.startswith("episode"):
                self.episode_times.append(time.monotonic())
            self.stderr.append(line)
        self.ended = time.monotonic()

    def processes(self) -> dict[str, int]:
        """``{role: pid}`` of the orchestrator and its nodes still running."""
        found = {"orchestrator": self.proc.pid}
        for child in _children(self.proc.pid):
            role = next((r for r in ROLES[1:] if f"aril_ros_nodes.{r}_node" in _cmdline(child)), None)
            if role:
                found[role] = child
        return found

    def read_memory(self) -> None:
        rss = {role: _rss_mb(pid) for role, pid in self.processes().items()}
        rss = {role: mb for role, mb in rss.items() if mb is not None}
        if not self.episode_times:
            return  # still starting: imports and DDS discovery are not the soak
        if not self.rss_start and len(rss) == len(ROLES):
            self.rss_start = rss
        if self.rss_start:
            self.rss_end = {**self.rss_end, **rss}


def _children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace")
    except OSError:
        return ""


def _rss_mb(pid: int) -> float | None:
    """The RSS of a running process; ``None`` once it has gone (a zombie reads as 0 pages)."""
    try:
        pages = int(Path(f"/proc/{pid}/statm").read_text().split()[1])
    except (OSError, IndexError):
        return None
    return pages * PAGE_MB or None


def start_run(cfg: SoakConfig, index: int, folder: Path) -> Run:
    record = folder / f"soak-{index}.mcap"
    proc = subprocess.Popen([sys.executable, "-m", "aril_ros_nodes.run_graph", f"env:={cfg.env}",
                             f"mode:={cfg.mode}", f"episodes:={cfg.episodes}", f"horizon:={cfg.horizon}",
                             f"seed:={index}", f"record:={record}"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    run = Run(index, record, proc)
    run.reader = threading.Thread(target=run.read_stderr, daemon=True)
    run.reader.start()
    return run


def steps_per_s_over_time(run: Run, horizon: int, parts: int = 10) -> list[float]:
    """Steps/s in each of ``parts`` equal spans of the run's episodes (the first from its first episode line)."""
    times = run.episode_times
    bounds = sorted({round(i * (len(times) - 1) / parts) for i in range(parts + 1)})
    return [round((b - a) * horizon / (times[b] - times[a]), 1) for a, b in itertools.pairwise(bounds)]


def check_log(run: Run, summary: dict, cfg: SoakConfig) -> str:
    """``ok``, or why the run's log is not the complete, exact record of its summary."""
    try:
        log = read_run(run.record)
    except RunLogError as err:
        return str(err)
    if log.end.get("episodes_completed") != cfg.episodes or len(log.tags) != summary["steps"]:
        return (f"the log has {len(log.tags)} steps and {log.end.get('episodes_completed')} episodes, the run "
                f"{summary['steps']} and {cfg.episodes}")
    return "ok"


def main(argv):
    cfg = module_config(SoakConfig, "python -m benchmarks.graph.bench_soak", __doc__, argv)
    if cfg is None:
        return 0
    with tempfile.TemporaryDirectory(prefix="aril_soak-") as folder:  # the logs, ~1.4 MB per 1000 steps each
        runs = [start_run(cfg, i, Path(folder)) for i in range(cfg.runs)]
        try:
            while any(run.proc.poll() is None for run in runs):
                for run in runs:
                    if run.proc.poll() is None:
                        run.read_memory()
                time.sleep(cfg.sample)
        finally:
            for run in runs:
                run.proc.kill()  # a no-op for a run that has ended; nothing outlives the benchmark
                run.proc.wait()
                run.reader.join()
        figures = [report_run(run, cfg) for run in runs]
    print_table(figures, cfg)
    print(json.dumps({"env": cfg.env, "mode": cfg.mode, "episodes": cfg.episodes, "horizon": cfg.horizon,
                      "runs": figures}))
    return 0 if all(f["log"] == "ok" for f in figures) else 1


def report_run(run: Run, cfg: SoakConfig) -> dict:
    stdout = run.proc.stdout.read()
    if run.proc.returncode != 0 or not stdout.strip():
        return {"run": run.index, "exit_code": run.proc.returncode, "log": "the run failed: "
                + "".join(run.stderr[-3:]).strip()}
    summary = json.loads(stdout.strip().splitlines()[-1])
    steps_k = summary["steps"] / 1000
    return {
        "run": run.index, "exit_code": 0, "steps": summary["steps"], "steps_per_s": summary["steps_per_s"],
        "steps_per_s_over_time": steps_per_s_over_time(run, cfg.horizon),
        "shutdown_s": round(run.ended - run.episode_times[-1], 2),
        "rss_start_mb": {k: round(v, 1) for k, v in run.rss_start.items()},
        "rss_end_mb": {k: round(v, 1) for k, v in run.rss_end.items()},
        "rss_growth_mb_per_1000_steps": {k: round((run.rss_end[k] - v) / steps_k, 3)
                                         for k, v in run.rss_start.items() if k in run.rss_end},
        "log": check_log(run, summary, cfg),
    }


def print_table(figures: list[dict], cfg: SoakConfig) -> None:
    print(f"{cfg.env} {cfg.mode}: {len(figures)} runs at once, {cfg.episodes} episodes x {cfg.horizon} steps each")
    print("RSS in MB at the start / the end (after the first episode / before the run stopped), growth per 1000 steps")
    print(f"{'run':<5}" + "".join(f"{role:>26}" for role in ROLES))
    for f in figures:
        if f["exit_code"] != 0:
            print(f"{f['run']:<5}{f['log']}")
            continue
        cells = [f"{f['rss_start_mb'].get(r, float('nan')):.0f} / {f['rss_end_mb'].get(r, float('nan')):.0f} "
                 f"({f['rss_growth_mb_per_1000_steps'].get(r, float('nan')):+.2f})" for r in ROLES]
        print(f"{f['run']:<5}" + "".join(f"{c:>26}" for c in cells))
    print(f"{'run':<5}{'steps':>8}{'steps/s':>9}{'shutdown s':>12}  steps/s per tenth of the episodes; log")
    for f in figures:
        if f["exit_code"] == 0:
            print(f"{f['run']:<5}{f['steps']:>8}{f['steps_per_s']:>9.1f}{f['shutdown_s']:>12.2f}  "
                  f"{' '.join(f'{v:.0f}' for v in f['steps_per_s_over_time'])}; {f['log']}")


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

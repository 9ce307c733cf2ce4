"""Where a step's CPU goes: milliseconds of CPU per step of each process, for the graph in each mode and for the
bare rclpy chain it is measured against (:mod:`benchmarks.graph.bare_chain`).

    .venv/bin/python -m benchmarks.graph.profile_graph env:=HalfCheetah-v5 steps:=2000

On a machine with fewer cores than processes every process's CPU is on the critical path, so the totals bound
the steps/s: the graph can reach at most (bare total) / (graph total) of the bare chain's rate. Each figure is the
CPU a process used over a window of ``steps`` steps of steady stepping, once every process has started and
matched: the bare chain's measured steps after its warm-up, the graph's second episode (its first is the warm-up).
Start-up (imports, discovery), which varies from run to run by more than a step costs, stays out of it. The CPU
of a process is read from ``/proc/<pid>/stat`` (Linux), every 0.1 s while the run goes on, so that a process is
known before the window opens, and again at each end of the window. The graph runs record (the default run).
"""
import os
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from aril_ros.args import arg, module_config
from aril_ros.registry import DEFAULT_ENV, MAX_EPS, MODES, attack_for_mode
from aril_ros_nodes.orchestrator import GraphConfig, Orchestrator
from benchmarks.graph.bench_graph import bare_chain_steps_per_s

TICKS = os.sysconf("SC_CLK_TCK")


@dataclass
class ProfileConfig:
    """Arguments of ``python -m benchmarks.graph.profile_graph``."""

    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id (the bare chain steps HalfCheetah-v5 whatever it is)")
    steps: int = arg(2000, "steps of the window each figure is measured over", low=100, high=10**9)
    eps: float = arg(0.05, "attack budget", low=0.0, high=MAX_EPS)


def process_name(pid: int, cmdline: str) -> str | None:
    """Which part of a run a process is: this one, a graph node by its module, a bare-chain role; None if neither."""
    if pid == os.getpid():
        return "this process (orchestrator and recorder / bare simulator)"
    if "benchmarks.graph.bare_chain" in cmdline:
        return "bare " + cmdline.split("role:=")[1].split()[0]
    for node in ("simulator", "attacker", "policy", "expert"):
        if f"aril_ros_nodes.{node}_node" in cmdline:
            return node
    return None


class CpuSampler:
    """The CPU seconds each process of a run has used so far, by :func:`process_name`, sampled in a thread."""

    def __init__(self):
        self.seconds: dict[int, tuple[str, float]] = {}
        self.done = threading.Event()
        self.thread = threading.Thread(target=self._sample, daemon=True)

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.done.set()
        self.thread.join()

    def _sample(self) -> None:
        while not self.done.is_set():
            self.read_all()
            time.sleep(0.1)

    def read_all(self) -> None:
        for entry in os.listdir("/proc"):
            if entry.isdigit():
                self._read(int(entry))

    def now(self) -> dict[str, float]:
        """:meth:`by_name` as of this moment (read now, not at the last sample)."""
        self.read_all()
        return self.by_name()

    def _read(self, pid: int) -> None:
        # this run's processes are this one and its children; a pid is not remembered as someone else's, since a
        # busy machine reuses pids within a run
        try:
            stat = Path(f"/proc/{pid}/stat").read_text()
            fields = stat[stat.rindex(")") + 2:].split()  # from field 3 of stat(5) on: state, ppid, ...
            if os.getpid() not in (pid, int(fields[1])):
                return
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:  # ended between the listing and the read
            return
        name = process_name(pid, cmdline)
        if name is not None:
            self.seconds[pid] = (name, (int(fields[11]) + int(fields[12])) / TICKS)  # utime + stime

    def by_name(self) -> dict[str, float]:
        totals: dict[str, float] = {}
        for name, seconds in self.seconds.values():
            totals[name] = totals.get(name, 0.0) + seconds
        return totals


def per_step(run, steps: int) -> dict[str, float]:
    """ms of CPU per step of each process over the window of ``steps`` steps that ``run(steps, mark)`` opens and
    closes by calling ``mark()``."""
    marks: list[dict[str, float]] = []
    with CpuSampler() as sampler:
        run(steps, lambda: marks.append(sampler.now()))
    if len(marks) != 2:
        raise RuntimeError(f"the run marked its window {len(marks)} times, not twice")
    opened, closed = marks
    return {name: 1000 * (closed[name] - opened.get(name, 0.0)) / steps for name in closed}


def graph_run(cfg: ProfileConfig, mode: str):
    """``run(steps, mark)`` of the graph: two episodes of ``steps`` steps, the window the second."""
    def run(steps: int, mark) -> None:
        def log(line="", *args, **kwargs) -> None:
            if line.startswith("episode "):  # the orchestrator's line at the end of each episode
                mark()

        with tempfile.TemporaryDirectory(prefix="aril_profile-") as folder:
            Orchestrator(GraphConfig(mode=mode, env=cfg.env, attack=attack_for_mode(mode), eps=cfg.eps, episodes=2,
                                     horizon=steps, record=str(Path(folder) / "run.mcap")), log=log).run()
    return run


def main(argv):
    cfg = module_config(ProfileConfig, "python -m benchmarks.graph.profile_graph", __doc__, argv)
    if cfg is None:
        return
    import torch

    torch.set_num_threads(1)
    columns = {"bare chain": per_step(bare_chain_steps_per_s, cfg.steps),
               **{f"graph {mode}": per_step(graph_run(cfg, mode), cfg.steps) for mode in MODES}}
    names = sorted({name for column in columns.values() for name in column})
    print(f"{cfg.env}: ms of CPU per step by process, over {cfg.steps} steps of steady stepping")
    print(f"{'process':<58}" + "".join(f"{c:>16}" for c in columns))
    for name in names:
        print(f"{name:<58}" + "".join(f"{col[name]:>16.3f}" if name in col else f"{'':>16}" for col in columns.values()))
    totals = {c: sum(col.values()) for c, col in columns.items()}
    print(f"{'total':<58}" + "".join(f"{t:>16.3f}" for t in totals.values()))
    print(f"{'bound on graph / bare (bare total / total)':<58}"
          + "".join(f"{totals['bare chain'] / t:>16.2f}" for t in totals.values()))


if __name__ == "__main__":
    main(sys.argv[1:])

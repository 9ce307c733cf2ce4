"""Where a step's CPU goes: milliseconds of CPU per step of each process, for the graph in each mode and for the
bare rclpy chain it is measured against (:mod:`aril_ros_nodes.bare_chain`).

    .venv/bin/python -m aril_ros_nodes.profile_graph env:=HalfCheetah-v5 steps:=2000

On a machine with fewer cores than processes every process's CPU is on the critical path, so the totals bound
the steps/s: the graph can reach at most (bare total) / (graph total) of the bare chain's rate. Each run is made
at two lengths, ``steps`` and ``3 * steps``, and the per-step figure is the difference of the CPU they took over
the difference of their steps, so start-up (imports, discovery) drops out. The CPU of a process is read from
``/proc/<pid>/stat`` every 0.1 s while the run goes on (Linux). The graph runs record (the default run).
"""
import os
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from aril_ros.args import arg, module_config
from aril_ros.registry import DEFAULT_ENV, MODES, attack_for_mode
from aril_ros_nodes.bench_graph import bare_chain_steps_per_s
from aril_ros_nodes.orchestrator import GraphConfig, Orchestrator

TICKS = os.sysconf("SC_CLK_TCK")


@dataclass
class ProfileConfig:
    """Arguments of ``python -m aril_ros_nodes.profile_graph``."""

    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id (the bare chain steps HalfCheetah-v5 whatever it is)")
    steps: int = arg(2000, "steps of the shorter run of each pair (the longer: three times as many)", low=100)
    eps: float = arg(0.05, "attack budget")


def process_name(pid: int, cmdline: str) -> str | None:
    """Which part of a run a process is: this one, a graph node by its module, a bare-chain role; None if neither."""
    if pid == os.getpid():
        return "this process (orchestrator and recorder / bare simulator)"
    if "aril_ros_nodes.bare_chain" in cmdline:
        return "bare " + cmdline.split("role:=")[1].split()[0]
    for node in ("simulator", "attacker", "policy", "expert"):
        if f"aril_ros_nodes.{node}_node" in cmdline:
            return node
    return None


class CpuSampler:
    """The CPU seconds each process of a run has used so far, by :func:`process_name`, sampled in a thread."""

    def __init__(self):
        self.seconds: dict[int, tuple[str, float]] = {}
        self.others: set[int] = set()  # pids seen not to be the run's: never read again (the sampler's own cost)
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
            for entry in os.listdir("/proc"):
                if entry.isdigit() and int(entry) not in self.others:
                    self._read(int(entry))
            time.sleep(0.1)

    def _read(self, pid: int) -> None:
        try:
            stat = Path(f"/proc/{pid}/stat").read_text()
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:  # ended between the listing and the read
            return
        fields = stat[stat.rindex(")") + 2:].split()  # from field 3 of stat(5) on: state, ppid, ...
        name = process_name(pid, cmdline)
        if name is not None and os.getpid() in (pid, int(fields[1])):  # this run's: this process and its children
            self.seconds[pid] = (name, (int(fields[11]) + int(fields[12])) / TICKS)  # utime + stime
        elif "python" not in cmdline:  # a python process may still become a node (rclpy's wheels re-exec it)
            self.others.add(pid)

    def by_name(self) -> dict[str, float]:
        totals: dict[str, float] = {}
        for name, seconds in self.seconds.values():
            totals[name] = totals.get(name, 0.0) + seconds
        return totals


def cpu_of(run) -> dict[str, float]:
    with CpuSampler() as sampler:
        run()
    return sampler.by_name()


def per_step(run, steps: int) -> dict[str, float]:
    """ms of CPU per step of each process: ``run(n)`` at ``steps`` and ``3 * steps``, the difference."""
    short, long = cpu_of(lambda: run(steps)), cpu_of(lambda: run(3 * steps))
    return {name: 1000 * (long[name] - short.get(name, 0.0)) / (2 * steps) for name in long}


def graph_run(cfg: ProfileConfig, mode: str):
    def run(steps: int) -> None:
        with tempfile.TemporaryDirectory(prefix="aril_profile-") as folder:
            Orchestrator(GraphConfig(mode=mode, env=cfg.env, attack=attack_for_mode(mode), eps=cfg.eps, episodes=1,
                                     horizon=steps, record=str(Path(folder) / "run.mcap")),
                         log=lambda *a, **k: None).run()
    return run


def main(argv):
    cfg = module_config(ProfileConfig, "python -m aril_ros_nodes.profile_graph", __doc__, argv)
    if cfg is None:
        return
    import torch

    torch.set_num_threads(1)
    columns = {"bare chain": per_step(bare_chain_steps_per_s, cfg.steps),
               **{f"graph {mode}": per_step(graph_run(cfg, mode), cfg.steps) for mode in MODES}}
    names = sorted({name for column in columns.values() for name in column})
    print(f"{cfg.env}: ms of CPU per step by process ({cfg.steps} and {3 * cfg.steps} steps, the difference)")
    print(f"{'process':<58}" + "".join(f"{c:>16}" for c in columns))
    for name in names:
        print(f"{name:<58}" + "".join(f"{col[name]:>16.3f}" if name in col else f"{'':>16}" for col in columns.values()))
    totals = {c: sum(col.values()) for c, col in columns.items()}
    print(f"{'total':<58}" + "".join(f"{t:>16.3f}" for t in totals.values()))
    print(f"{'bound on graph / bare (bare total / total)':<58}"
          + "".join(f"{totals['bare chain'] / t:>16.2f}" for t in totals.values()))


if __name__ == "__main__":
    main(sys.argv[1:])

"""Threads that run many simulators' physics side by side.

MuJoCo's bindings release the GIL inside ``mj_step``, so simulators stepped on threads run in parallel. A
:class:`PhysicsPool` belongs to whoever steps its simulators (a :class:`~aril_ros.rollout.SimBatch`, a
:class:`~aril_ros.envs.sim.MujocoSim`), which closes it with them: there is no shared pool.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor


class PhysicsPool:
    """Runs ``work(i)`` for every row ``i`` of ``range(n)`` on ``threads`` threads, the calling one
    included: each takes the next row not yet taken until none is left. The rows' MuJoCo calls run in
    parallel (the bindings release the GIL inside them); the Python between them takes turns. Rows are
    taken, not dealt in fixed groups, so a pool thread the OS runs late (a busy machine) costs at most
    the row it holds: the caller takes the rest, and a helper that has not started is cancelled.
    With one thread it starts none: the caller runs every row."""

    def __init__(self, threads: int):
        self.threads = max(1, int(threads))
        self._executor = (ThreadPoolExecutor(self.threads - 1, thread_name_prefix="aril-physics")
                          if self.threads > 1 else None)

    def run(self, work, n: int) -> None:
        rows = iter(range(n))  # shared: next() on it is atomic under the GIL

        def take_rows() -> None:
            for i in rows:
                work(i)

        helpers = [self._executor.submit(take_rows) for _ in range(min(self.threads, n) - 1)]
        take_rows()
        for helper in helpers:
            if not helper.cancel():
                helper.result()

    def close(self) -> None:
        if self._executor is not None:
            self._executor.shutdown()


def physics_threads() -> int:
    """The default size of a :class:`PhysicsPool`: the cores this process may run on, or fewer where
    ``OMP_NUM_THREADS`` caps a process's threads (a Ray task's: its CPUs, so two tasks on two cores do not run
    four physics threads)."""
    cores = len(os.sched_getaffinity(0))
    cap = os.environ.get("OMP_NUM_THREADS", "")
    return min(cores, int(cap)) if cap.isdigit() and int(cap) > 0 else cores

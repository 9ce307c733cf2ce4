"""Sweeps on Ray: the jobs of a sweep (the report's trainings and evaluations) as Ray tasks.

    run_tasks(fn, calls, workers=2)                         # an embedded local Ray with ``workers`` CPUs
    run_tasks(fn, calls, address="10.0.0.5:6379")           # a running cluster (or "auto": the one this node joined)
    run_tasks(fn, calls, workers=1)                         # in this process, one after the other, no Ray

Each call is one task declaring one CPU (``cpus``). Nothing is shared through a filesystem: a file a task reads
is marked :class:`Shipped` in its call and travels by content (put once per digest in Ray's object store, written
on the worker's node under its digest, so a node holds each file once), and a file a task makes is marked
:class:`Produced`: the task writes it on its node and its bytes travel back to the driver, which writes them where
the call said. A file inside the checkout is shown to its task by its checkout-relative path, so that what the task
records of it (a trained file's provenance) reads as one process records it. A folder a task keeps its progress
in across interruptions (a training's run directory) is marked :class:`Kept`: the driver's own folder when the
task runs on the driver's machine. Results come back to the driver as they finish; the caller keeps them (the
report's cache), so killing the driver and running the same command again reruns only what had not finished.
Ray is an extra (``pip install -e .[cluster]``, ``ray==2.60``): the sweeps install it on first use, the quick
start never does.
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
import shutil
import socket
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from .extras import RAY, ensure
from .files import write_atomically
from .provenance import portable



@dataclass(frozen=True)
class Shipped:
    """A file a task reads (in a call: replaced by the path of its copy on the task's node)."""

    path: Path


@dataclass(frozen=True)
class Produced:
    """A file a task writes (in a call: replaced by a path on the task's node; the driver gets the bytes). A task on
    the driver's own Ray node writes a file named by an absolute path at that very path, so that what it records of
    itself (a trained file's provenance) names it as the driver does."""

    path: Path
    node: str | None = None  # the driver's Ray node, set as the call is shipped


@dataclass(frozen=True)
class Kept:
    """A folder a task keeps its progress in, so that the same call run again resumes (a training's run
    directory). On the driver's machine it is the driver's folder itself; on another node, a folder of that
    node's named after it that outlives the task: a retry there resumes, and its contents never travel (only the
    task's :class:`Produced` files do). Made on the driver, it records where that is."""

    path: Path  # as the call gives it; relative: to the driver's working folder
    host: str = dataclasses.field(default_factory=socket.gethostname)
    home: str = dataclasses.field(default_factory=os.getcwd)


def kept_folder(kept: Kept) -> Path:
    """Where a task keeps ``kept`` on this node."""
    if kept.host == socket.gethostname():
        return Path(kept.home) / kept.path
    name = hashlib.sha256(f"{kept.host}:{Path(kept.home) / kept.path}".encode()).hexdigest()[:16]
    return Path(tempfile.gettempdir()) / "aril_ros-kept" / name


@dataclass(frozen=True)
class _Content:
    path: Path  # as the call gave it
    digest: str
    ref: object  # the bytes, as an ObjectRef in Ray's store
    node: str  # the driver's Ray node, where the file is at ``path`` itself when that is absolute


def digest_of(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def node_copy(digest: str, suffix: str, fetch) -> Path:
    """The file of these bytes (``fetch()`` gives them) on this node: under its digest in a node-local store,
    fetched and written once, atomically."""
    store = Path(tempfile.gettempdir()) / "aril_ros-files"
    path = store / f"{digest}{suffix}"
    if not path.exists():
        store.mkdir(parents=True, exist_ok=True)
        write_atomically(path, lambda partial: partial.write_bytes(fetch()))
    return path


MARKED = (Shipped, Produced, Kept, _Content)


def _map(value, leaf, is_leaf=lambda value: isinstance(value, MARKED)):
    """``value`` with every part ``is_leaf`` accepts (by default the marked files) inside tuples, lists and dicts
    replaced by ``leaf(it)``."""
    if is_leaf(value):
        return leaf(value)
    if isinstance(value, (tuple, list)):
        return type(value)(_map(v, leaf, is_leaf) for v in value)
    if isinstance(value, dict):
        return {k: _map(v, leaf, is_leaf) for k, v in value.items()}
    return value


def shipped(value):
    """``value`` marked to travel with its task when it names a file (a path with a suffix); else as it is (a
    bundled name resolves in each node's own installation)."""
    is_file = isinstance(value, (str, Path)) and bool(Path(value).suffix) and Path(value).is_file()
    return Shipped(Path(value)) if is_file else value


def _in_place(call):
    """A call for this process: each marked file is its own path."""
    return _map(call, lambda marked: marked.path)


def _task(fn, call):
    """What runs on a worker: the call in a scratch folder of its own, where each shipped file and each file to
    make given by a relative path sits at that same relative path, so that what the task records (a trained file's
    provenance names its inputs and itself) reads as it would on the driver; the result and the produced files'
    bytes go back."""
    import ray

    scratch = Path(tempfile.mkdtemp(prefix="aril_ros-task-"))
    made, here = {}, ray.get_runtime_context().get_node_id()

    def leaf(marked):
        path = Path(marked.path)
        if isinstance(marked, _Content):
            if path.is_absolute() and marked.node == here and path.is_file() and digest_of(
                    path.read_bytes()) == marked.digest:
                return path  # on the driver's node the driver's file itself, so the task records its path
            stored = node_copy(marked.digest, path.suffix, lambda: ray.get(marked.ref))
            if path.is_absolute():
                return stored
            (scratch / path).parent.mkdir(parents=True, exist_ok=True)
            (scratch / path).symlink_to(stored)
            return path
        if isinstance(marked, Kept):  # reached through the call's own path, like a shipped file
            folder = kept_folder(marked)
            folder.mkdir(parents=True, exist_ok=True)
            if path.is_absolute():
                return folder
            (scratch / path).parent.mkdir(parents=True, exist_ok=True)
            (scratch / path).symlink_to(folder, target_is_directory=True)
            return path
        if path.is_absolute() and marked.node == here:
            path.parent.mkdir(parents=True, exist_ok=True)
            made[str(path)] = path
            return path
        made[str(path)] = scratch / (path if not path.is_absolute() else path.name)
        made[str(path)].parent.mkdir(parents=True, exist_ok=True)
        return path if not path.is_absolute() else made[str(path)]

    where = os.getcwd()
    try:
        os.chdir(scratch)
        result = fn(*_map(call, leaf))
        produced = {original: local.read_bytes() for original, local in made.items()}
    finally:
        os.chdir(where)
        shutil.rmtree(scratch, ignore_errors=True)
    # a result naming a file made at an absolute path names the driver's copy of it
    renamed = {str(local): Path(original) for original, local in made.items()}
    return _map(result, lambda v: renamed[str(v)] if isinstance(v, Path) else str(renamed[str(v)]),
                lambda v: isinstance(v, (str, Path)) and str(v) in renamed), produced


def ensure_ray():
    """``ray``, installed into this Python first if it is missing (the ``cluster`` extra, on first use)."""
    return ensure("ray", RAY, "the cluster extra, for sweeps on Ray")


def connect(address: str, workers: int):
    """Ray, connected: to the cluster at ``address``, or an embedded local one with ``workers`` CPUs. Returns
    ``(ray, started)``: ``started`` when this call started it (then the caller shuts it down)."""
    ray = ensure_ray()
    if ray.is_initialized():
        return ray, False
    if address:
        ray.init(address=address, logging_level="ERROR", log_to_driver=False)
    else:
        # address "local": a new Ray of its own, even where this machine runs a cluster (which ray.init would join)
        ray.init(address="local", num_cpus=workers, include_dashboard=False, logging_level="ERROR",
                 log_to_driver=False)
    return ray, True


@contextmanager
def session(workers: int, address: str):
    """One Ray for every sweep of a command (each would otherwise start and stop its own): connected on entry
    when tasks will leave this process (``workers`` above 1, or an ``address``), shut down on exit if started here."""
    if workers == 1 and not address:
        yield
        return
    ray, started = connect(address, workers)
    try:
        yield
    finally:
        if started:
            ray.shutdown()


class Progress:
    """``[sweep] label: done/total, running, failed, ETA`` lines, at most every ``every`` seconds and at the end."""

    def __init__(self, label: str, total: int, parallel: int, log, every: float = 10.0):
        self.label, self.total, self.parallel, self.log, self.every = label, total, max(parallel, 1), log, every
        self.done = self.failed = 0
        self.started = self.last = time.monotonic()

    def line(self) -> str:
        elapsed = time.monotonic() - self.started
        left = self.total - self.done - self.failed
        eta = elapsed / (self.done + self.failed) * left if self.done + self.failed else float("nan")
        running = min(left, self.parallel)
        return (f"[sweep] {self.label}: {self.done}/{self.total} done, {running} running, {self.failed} failed, "
                f"{elapsed:.0f}s elapsed, ETA {eta:.0f}s")

    def finished(self, ok: bool) -> None:
        self.done += ok
        self.failed += not ok
        now = time.monotonic()
        if now - self.last >= self.every or self.done + self.failed == self.total:
            self.last = now
            self.log(self.line(), flush=True)


def run_tasks(fn, calls: list[tuple], workers: int = 2, address: str = "", cpus: float = 1, failures=(),
              label: str = "tasks", log=print) -> Iterator[tuple[int, object]]:
    """``fn(*call)`` for each call, as Ray tasks of ``cpus`` CPUs each (in this process, in order, when ``workers``
    is 1 and no ``address`` is given); yields ``(index, result)`` as each finishes, the result being the exception
    when ``fn`` raised one of ``failures`` (any other is raised: the task's own exception on Ray too, with Ray's
    traceback of it as its cause). Produced files are at their paths when yielded."""
    progress = Progress(label, len(calls), workers, log)
    if not calls:
        return
    if workers == 1 and not address:
        for index, call in enumerate(calls):
            try:
                result = fn(*_in_place(call))
            except failures as err:
                result = err
            progress.finished(not isinstance(result, Exception))
            yield index, result
        return
    ray, started = connect(address, workers)
    try:
        progress.parallel = int(ray.cluster_resources().get("CPU", workers) // cpus)
        contents: dict[Path, _Content] = {}
        driver = ray.get_runtime_context().get_node_id()

        def ship(marked, destinations):
            # a file inside the checkout is shown to the task by its checkout-relative path (and sits at that path
            # in its scratch folder), so what the task records of it reads as it would on the driver, where
            # provenance.stamp makes such paths relative; ``destinations`` maps it back to the driver's path. Any
            # other absolute path is the driver's file itself to a task on the driver's node
            if isinstance(marked, Kept):
                return marked
            shown = Path(portable(str(marked.path)))
            if shown != Path(marked.path):
                destinations[str(shown)] = Path(marked.path)
            if isinstance(marked, Produced):
                return Produced(shown, driver)
            if marked.path not in contents:
                data = Path(marked.path).read_bytes()
                contents[marked.path] = _Content(shown, digest_of(data), ray.put(data), driver)
            return contents[marked.path]

        remote = ray.remote(num_cpus=cpus, max_retries=0)(_task)
        pending, destinations = {}, [{} for _ in calls]
        for index, call in enumerate(calls):
            pending[remote.remote(fn, _map(call, lambda marked: ship(marked, destinations[index])))] = index
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            index = pending.pop(ready[0])
            try:
                result, produced = ray.get(ready[0])
            except ray.exceptions.RayTaskError as err:
                # the task's own exception, as the call in this process would raise it: a user's error keeps its one
                # line (Ray's wrapper reads as the task's traceback), a bug shows that traceback as its cause
                cause = err.cause
                if not isinstance(cause, failures):
                    raise cause from err
                progress.finished(False)
                yield index, cause
                continue
            back = destinations[index]
            for shown, data in produced.items():
                original = back.get(shown, Path(shown))
                original.parent.mkdir(parents=True, exist_ok=True)
                write_atomically(original, lambda partial: partial.write_bytes(data))
            progress.finished(True)
            yield index, _map(result, lambda v: type(v)(back[str(v)]), lambda v: isinstance(v, (str, Path))
                              and str(v) in back)
    finally:
        if started:
            ray.shutdown()

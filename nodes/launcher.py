"""What stands in for ``ros2 launch``: a ROS domain of the run's own, the node processes started in it and watched,
the stop signals caught, and every node stopped at the end however the run ends.

Each node is its own process (``python -m aril_ros_nodes.<name>_node --ros-args ...``, from the installed package),
in a session of its own and killed with its parent; its output goes to ``<log dir>/<name>.log``, whose last error
line names why it died.
"""
from __future__ import annotations

import ctypes
import fcntl
import os
import re
import signal
import stat
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from aril_ros.protocol import SAFE_DOMAINS, checked_domain

NODE_MODULES = {name: f"aril_ros_nodes.{name}_node" for name in ("simulator", "attacker", "policy", "expert")}
"""The module each node runs as (``python -m``, from the installed package: no checkout on the path)."""

NODE_POLL = 0.05
"""Seconds between two looks at whether a node process has died."""

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""The signals that stop a run in order (nodes stopped, log closed as interrupted)."""


class GraphError(RuntimeError):
    """The run cannot go on: a node died, did not connect, or stopped answering."""


class RunInterrupted(KeyboardInterrupt):
    """A signal (Ctrl-C, SIGTERM, SIGHUP) stopped the run. A KeyboardInterrupt, so a caller that stops
    on Ctrl-C stops on it; ``exit_code`` is the shell's for a process ended by that signal."""

    def __init__(self, signum: int):
        self.signal_name = signal.Signals(signum).name
        self.exit_code = 128 + signum
        super().__init__(f"interrupted by {self.signal_name}")


# ------------------------------------------------------------------------------------------ domains
def domain_candidates(requested: str) -> list[int]:
    """The ids ``domain:=requested`` may take: that one, or for ``auto`` every safe one but 0 (every ROS
    tool's default), starting at one chosen by the process id so that runs starting together rarely contend."""
    if requested == "auto":
        ids = SAFE_DOMAINS[1:]
        return [ids[(os.getpid() + i) % len(ids)] for i in range(len(ids))]
    return [checked_domain(requested)]


def allocate_domain(requested: str):
    """A ROS domain id no other aril_ros run on this machine holds, and the open lock file holding it."""
    candidates = domain_candidates(requested)
    lock_dir = _domain_lock_dir()
    for domain in candidates:
        try:
            handle = _open_lock(lock_dir / f"{domain}.lock")
        except PermissionError:  # a lock file another user made unreadable: take that domain as theirs
            continue
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return domain, handle
        except OSError:
            handle.close()
    raise GraphError(f"ROS domain {requested} is held by another aril_ros run" if requested != "auto"
                     else "no free ROS domain id (1-101, 215-232)")


def _domain_lock_dir() -> Path:
    """The directory of the domain lock files, shared by every user of the machine (mode 1777, like /tmp): the
    runs of two users must not take the same domain either."""
    lock_dir = Path(tempfile.gettempdir()) / "aril_ros-domains"
    try:
        lock_dir.mkdir(exist_ok=True)
        info = lock_dir.stat()
        if info.st_uid == os.getuid() and stat.S_IMODE(info.st_mode) != 0o1777:
            lock_dir.chmod(0o1777)  # mkdir's mode is cut by the umask, and an older aril_ros made it 755
    except OSError as err:
        raise GraphError(f"the ROS domain lock directory {lock_dir} cannot be made: {err.strerror or err}") from None
    if not os.access(lock_dir, os.W_OK | os.X_OK):
        raise GraphError(f"the ROS domain lock directory {lock_dir} (mode {stat.S_IMODE(info.st_mode):o}) is not "
                         f"writable by this user; its owner (uid {info.st_uid}) can share it: chmod 1777 {lock_dir}")
    return lock_dir


def _open_lock(path: Path):
    """The lock file ``path`` opened for flock, made readable by every user if new. Read-only, as flock needs no
    more, and another user's lock file is read-only to us (and O_CREAT on it may be refused: fs.protected_regular)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        try:
            fd = os.open(path, os.O_RDONLY | os.O_CREAT | os.O_EXCL, 0o644)
            os.fchmod(fd, 0o644)  # whatever the umask
        except FileExistsError:  # another run made it just now
            fd = os.open(path, os.O_RDONLY)
    return open(fd, "rb")


# ------------------------------------------------------------------------------------------- signals
class StopSignals:
    """While entered, a stop signal only sets a flag, which :meth:`check` raises as :class:`RunInterrupted`: a
    KeyboardInterrupt raised inside an rclpy callback can be swallowed by the executor, and the run would go on.
    The handlers stay until exit, so a second Ctrl-C cannot cut the shutdown short."""

    def __init__(self):
        self.signum: int | None = None
        self._previous = {}

    def __enter__(self) -> "StopSignals":
        self._previous = {sig: signal.signal(sig, self._request_stop) for sig in STOP_SIGNALS}
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def _request_stop(self, signum, frame) -> None:
        self.signum = self.signum or signum

    def check(self) -> None:
        if self.signum is not None:
            raise RunInterrupted(self.signum)


# --------------------------------------------------------------------------------------------- nodes
def _detach_but_die_with_parent() -> None:
    # Own session: a terminal's Ctrl-C reaches only the orchestrator, which then stops the nodes itself.
    # Parent-death signal: if the orchestrator is killed outright, no node is left running.
    os.setsid()
    ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


class NodeProcess:
    """One node as a child process with its output in a log file."""

    def __init__(self, name: str, params: dict, log_dir: Path, env: dict):
        self.name = name
        self.log_path = log_dir / f"{name}.log"
        cmd = [sys.executable, "-m", NODE_MODULES[name], "--ros-args"]
        for key, value in params.items():
            cmd += ["-p", f"{key}:={value}"]
        self._log = open(self.log_path, "w")
        self.proc = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.STDOUT, env=env,
                                     preexec_fn=_detach_but_die_with_parent)

    def exited(self) -> int | None:
        return self.proc.poll()

    def death(self) -> str:
        """How the node ended and the last error its log shows (the node has exited)."""
        code = self.proc.returncode
        how = f"was killed by {signal.Signals(-code).name}" if code < 0 else f"exited with code {code}"
        error = last_error_line(self.log_path)
        if error is None:
            return f"node '{self.name}' {how}; its log has no error line (full log: {self.log_path})"
        return f"node '{self.name}' {how}: {error} (full log: {self.log_path})"

    def interrupt(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)

    def reap(self, deadline: float) -> None:
        """Wait for the interrupted node until ``deadline`` (monotonic), then kill it."""
        try:
            self.proc.wait(max(deadline - time.monotonic(), 0.0))
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._log.close()


class Nodes:
    """The run's node processes: started together, watched for a death, stopped together."""

    def __init__(self, log_dir: Path):
        self.log_dir = log_dir
        self.processes: list[NodeProcess] = []
        self.next_look = 0.0  # when check() next looks at the processes

    def start(self, params: dict[str, dict], envs: dict[str, dict]) -> None:
        """Start a node per entry of ``params`` (its parameters), in its environment of ``envs``."""
        self.processes = [NodeProcess(name, node_params, self.log_dir, envs[name])
                          for name, node_params in params.items()]

    @property
    def names(self) -> set[str]:
        return {node.name for node in self.processes}

    def check(self) -> None:
        """Raise a GraphError naming a node that has died (looked at every :data:`NODE_POLL` seconds: every wait
        loop calls this, after each message)."""
        if time.monotonic() < self.next_look:
            return
        self.next_look = time.monotonic() + NODE_POLL
        for node in self.processes:
            if node.exited() is not None:
                raise GraphError(node.death())

    def stop(self, grace: float = 3.0) -> None:
        """Stop every node at once: SIGINT to all, then one shared deadline, SIGKILL for any still running."""
        for node in self.processes:
            node.interrupt()
        deadline = time.monotonic() + grace
        for node in self.processes:
            node.reap(deadline)


# rclpy's "[ERROR] [<time>] [<node>]: ..." and "[FATAL]", our nodes' "[<node>] FATAL: ...", a traceback's
# closing "SomeError: ..." line; and rclpy's "[WARN]" or a Python warning ("...: SomeWarning: ...")
ERROR_LINE = re.compile(r"^\[(ERROR|FATAL)\]|\] FATAL: |^[\w.]+(Error|Exception|Interrupt)\b")
WARNING_LINE = re.compile(r"^\[WARN\]|\b\w+Warning: ")


def last_error_line(log_path: Path) -> str | None:
    """A node log's last error line (a FATAL or ERROR, an exception), else its last warning; ``None`` if it
    has neither: a start-up INFO line says nothing about why a node ended."""
    lines = [ln.strip() for ln in log_path.read_text(errors="replace").splitlines()]
    for pattern in (ERROR_LINE, WARNING_LINE):
        found = [ln for ln in lines if pattern.search(ln)]
        if found:
            return found[-1]
    return None

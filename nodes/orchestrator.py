"""The orchestrator behind ``run_graph.py``: starts the nodes, drives episodes, records, shuts down.

It stands in for ``ros2 launch`` and ``ros2 bag record``: each node is its own process
(``python -m aril_ros_nodes.<name>_node --ros-args ...``, from the installed package) in a ROS domain
of its own; the orchestrator's node resets the simulator at each episode start (env seed
:func:`aril_ros.step.episode_seed`), records every step topic (raw CDR, see :mod:`aril_ros.mcap_log`)
once the step is complete (:func:`aril_ros.step.missing_topics`) and its probes answered, prints
per-episode figures and one JSON summary line (:class:`aril_ros.step.EpisodeStats`; ``queries_per_step``:
probes answered per step), and stops every node, all at once, on success, on Ctrl-C, SIGTERM or
SIGHUP (:class:`RunInterrupted`), when a node dies (naming how, and its last error line) and when a step
makes no progress for ``step_timeout`` seconds. Every end but success closes the log as interrupted, with
the reason.
"""
from __future__ import annotations

import ctypes
import datetime
import fcntl
import hashlib
import os
import re
import secrets
import signal
import stat
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from aril_ros import __version__
from aril_ros import protocol as P
from aril_ros.adversary_net import load_adversary
from aril_ros.args import ArgumentError, arg, check_ranges
from aril_ros.attacks import queries_victim
from aril_ros.envs import HORIZON, layout_of
from aril_ros.mcap_log import RunLogError, RunLogWriter, cdr_header, cdr_joint_values, cdr_stamp
from aril_ros.policy import resolve_policy
from aril_ros.protocol import SAFE_DOMAINS, ProbeTag, StepTag, checked_domain, ros_domain
from aril_ros.provenance import git_revision
from aril_ros.registry import (ATTACKS, BUNDLED_NAMES, BUNDLED_POLICIES, DEFAULT_ENV, DEFAULT_POLICY, DEFENSES, MAX_EPS,
                               MODES, PER_MODE_POLICIES, WHITE_BOX, adversary_path, attack_budget, choose_attack)
from aril_ros.render import frame_size
from aril_ros.step import EpisodeStats, episode_seed, missing_topics, summarise_episodes

NODE_MODULES = {name: f"aril_ros_nodes.{name}_node" for name in ("simulator", "attacker", "policy", "expert")}
"""The module each node runs as (``python -m``, from the installed package: no checkout on the path)."""


@dataclass
class GraphConfig:
    """Arguments of ``run_graph.py``."""

    mode: str = arg("sensory", f"one of {', '.join(MODES)}")
    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    attack: str = arg("", f"one of {', '.join(ATTACKS)} (default: none when clean; attacked, the strongest bundled "
                          "for the policy: the ARIL-A trained against it, random where none is bundled)")
    eps: float = arg(0.0, f"L-infinity bound of the perturbation on the zero-order entries, at most {MAX_EPS} "
                          "(0: the calibrated one for env and mode, bundled with aril_ros; aril_a: its adversary's)")
    k: int = arg(0, "iterations of fgsm_k and spsa (0: the attack's default)", low=0, high=1000)
    samples: int = arg(0, "spsa: random directions per iteration, each asked at +- (0: the attack's default)",
                       low=0, high=1000)
    attack_file: str = arg("", "aril_a: the adversary file (from aril train-adversary)")
    search: int = arg(0, "aril_a: query-time search over this many candidates drawn from the adversary, the policy "
                         "node asked about all (probes), the most damaging applied (0: no search)", low=0, high=1000)
    baseline: bool = arg(True, "run_graph.py, an attacked mode: the clean return of the same episodes beside the "
                               "attacked one (the engine's; an external node's through a clean run of the graph)")
    rescale: bool = arg(False, "aril_a at an eps:= other than its adversary's: scale its perturbation by eps / its eps "
                               "(an eps sweep with one adversary)")
    episodes: int = arg(2, "episodes to run (env seeds seed, seed+1, ...)", low=1, high=100_000)
    # seeds are non-negative (numpy, gymnasium), and seed + episodes stays within 32 bits
    seed: int = arg(0, "seed of the first episode and of the attack noise", low=0, high=2**31 - 1)
    policy: str = arg("bundled", f"bundled (the default bundled policy: the {DEFENSES[DEFAULT_POLICY]} learner), "
                                 f"{', '.join(BUNDLED_POLICIES)} ({' and '.join(PER_MODE_POLICIES)}: the one trained "
                                 "against mode:=), a policy file, or external (start none, wait for one)")
    expert: str = arg("expert", "the labelling expert: a bundled name or a policy file")
    horizon: int = arg(HORIZON, "steps per episode", low=1, high=1_000_000)
    record: str = arg("", "MCAP file to record to, created anew (default: runs/<time>-<env>-<mode>-<random>.mcap; "
                          "off: no file)")
    domain: str = arg("auto", "ROS_DOMAIN_ID for this run: 0-101 or 215-232 (auto: a free one of those, held "
                              "by a lock file)")
    # below a second a loaded machine's DDS discovery or a slow step would stop a healthy run; an hour is a typo
    connect_timeout: float = arg(30.0, "seconds to wait for every node (and an external policy) to connect",
                                 low=1.0, high=3600.0)
    step_timeout: float = arg(10.0, "seconds without progress before the run is stopped as stuck", low=1.0,
                              high=3600.0)
    render: bool = arg(False, "record camera frames: the simulator renders offscreen (MuJoCo on the CPU, MUJOCO_GL=egl "
                              "unless set) and publishes sim/camera/image/compressed (JPEG), the log keeps them")
    render_every: int = arg(5, "render:=true: a frame every this many steps", low=1)
    render_size: str = arg("320x240", "render:=true: frame width x height in pixels")


class GraphError(RuntimeError):
    """The run cannot go on: a node died, did not connect, or stopped answering."""


class StepFault(GraphError):
    """A step message the recorder refuses (a second, different copy; a malformed frame_id); the GraphClient adds
    who published it."""


class RunInterrupted(KeyboardInterrupt):
    """A signal (Ctrl-C, SIGTERM, SIGHUP) stopped the run. A KeyboardInterrupt, so a caller that stops
    on Ctrl-C stops on it; ``exit_code`` is the shell's for a process ended by that signal."""

    def __init__(self, signum: int):
        self.signal_name = signal.Signals(signum).name
        self.exit_code = 128 + signum
        super().__init__(f"interrupted by {self.signal_name}")


NODE_POLL = 0.05
"""Seconds between two looks at whether a node process has died."""

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""The signals that stop a run in order (nodes stopped, log closed as interrupted)."""

EXTERNAL_HINT_EVERY = 5.0
"""Seconds between two reminders, while an external policy node is awaited, of what is missing and how to join."""

ONE_ATTACKS_ARGUMENTS = {"attack_file": "aril_a", "search": "aril_a", "rescale": "aril_a", "samples": "spsa"}
"""Arguments that one attack alone reads, and that attack."""


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


def stop_nodes(nodes: list[NodeProcess], grace: float = 3.0) -> None:
    """Stop every node at once: SIGINT to all, then one shared deadline, SIGKILL for any still running."""
    for node in nodes:
        node.interrupt()
    deadline = time.monotonic() + grace
    for node in nodes:
        node.reap(deadline)


class Orchestrator:
    def __init__(self, cfg: GraphConfig, log=print):
        self.cfg, self.log = check_ranges(cfg), log
        domain_candidates(cfg.domain)  # a bad id is refused here, before any file is loaded
        # a bad mode or attack: a ValueError naming both; none named: the strongest bundled for the policy
        self.choice = choose_attack(cfg.env, cfg.mode, cfg.policy, cfg.attack, cfg.attack_file)
        self.attack = self.choice.name
        for name, user in ONE_ATTACKS_ARGUMENTS.items():  # elsewhere it would be silently ignored
            if getattr(cfg, name) and self.attack != user:
                raise ArgumentError(f"{name}:={getattr(cfg, name)} is used by attack:={user} only, got "
                                    f"attack:={self.attack}")
        if cfg.render:
            frame_size(cfg.render_size)
        if self.attack in WHITE_BOX and cfg.policy == "external":
            raise GraphError(f"attack:={self.attack} is white-box and needs the victim's weights; an external "
                             "policy can be attacked with a black-box one: "
                             + ", ".join(a for a in ATTACKS if a not in (*WHITE_BOX, "none")))
        self.layout = layout_of(cfg.env)
        self.eps = attack_budget(cfg.env, cfg.mode, self.attack, cfg.eps)
        adversary = None
        if self.attack == "aril_a":  # its file's eps; a missing or mismatched file is reported before anything starts
            adversary = load_adversary(self.choice.file or adversary_path(cfg.env, cfg.mode), cfg.env, cfg.mode)
            if cfg.eps and abs(cfg.eps - adversary.eps) > 1e-12 and not cfg.rescale:
                raise ValueError(f"the adversary was trained with eps={adversary.eps}, not eps:={cfg.eps} "
                                 "(rescale:=true scales its perturbation)")
            self.eps = cfg.eps if cfg.rescale and cfg.eps else adversary.eps
        # who listens on action: the simulator, the recorder and, when the attack queries, the attacker's
        # probe client; the policy node waits for all of them, or step 0's action may reach only some
        self.probes = queries_victim(self.attack, adversary, cfg.search)
        self.action_listeners = 2 + self.probes
        # load both now: a bad file is reported before any process starts
        self.expert_meta = resolve_policy(cfg.expert, cfg.env).meta
        self.policy_meta = None if cfg.policy == "external" else resolve_policy(cfg.policy, cfg.env, cfg.mode).meta
        stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        # runs started in the same second get names of their own (the writer refuses a file that exists)
        default_record = f"runs/{stamp}-{cfg.env}-{cfg.mode}-{secrets.token_hex(3)}.mcap"
        self.record = None if cfg.record == "off" else Path(cfg.record or default_record)
        self.log_dir = Path(tempfile.mkdtemp(prefix=f"aril_ros-{stamp}-"))
        self.nodes: list[NodeProcess] = []
        self.stop_signal: int | None = None
        self.next_node_look = 0.0  # when check_nodes() next looks at the node processes

    def _request_stop(self, signum, frame) -> None:
        self.stop_signal = self.stop_signal or signum

    # ----------------------------------------------------------------------------------- set-up
    def start_nodes(self, env: dict) -> None:
        cfg = self.cfg
        common = {"env": cfg.env, "mode": cfg.mode}
        policy, expert = (_node_path(name) for name in (cfg.policy, cfg.expert))
        specs = {
            "simulator": {**common, "horizon": cfg.horizon,
                          **({"render_every": cfg.render_every, "render_size": cfg.render_size} if cfg.render else {})},
            "attacker": {**common, "attack": self.attack, "eps": float(self.eps), "seed": cfg.seed,
                         "k": cfg.k, "samples": cfg.samples, "search": cfg.search, "expert": expert,
                         "rescale": cfg.rescale,
                         **({"victim": policy} if self.attack in WHITE_BOX else {}),
                         **({"attack_file": str(Path(self.choice.file).resolve())} if self.choice.file else {})},
            "expert": {"env": cfg.env, "expert": expert},
        }
        if cfg.policy != "external":
            specs["policy"] = {**common, "policy": policy, "listeners": self.action_listeners}
        node_env = {name: env for name in specs}
        if cfg.render:  # mujoco picks its GL backend on import: the simulator's process needs it set
            node_env["simulator"] = {**env, "MUJOCO_GL": env.get("MUJOCO_GL", "egl")}
        self.nodes = [NodeProcess(name, params, self.log_dir, node_env[name]) for name, params in specs.items()]

    def check_nodes(self) -> None:
        """Raise if the user interrupted the run or a node died (looked at every ``NODE_POLL`` seconds: every wait
        loop calls this, after each message)."""
        if self.stop_signal is not None:
            raise RunInterrupted(self.stop_signal)
        if time.monotonic() < self.next_node_look:
            return
        self.next_node_look = time.monotonic() + NODE_POLL
        for node in self.nodes:
            if node.exited() is not None:
                raise GraphError(node.death())

    def wait_connected(self, ros) -> None:
        """Until every started node has announced that its endpoints are matched (graph/ready), the
        recorder hears every step topic, and the reset service answers. While an external policy node is
        awaited, says every :data:`EXTERNAL_HINT_EVERY` seconds what of it is missing and how to join the run."""
        deadline = time.monotonic() + self.cfg.connect_timeout
        next_hint = time.monotonic() + EXTERNAL_HINT_EVERY
        expected = {node.name for node in self.nodes}
        external = self.cfg.policy == "external"
        while True:
            self.check_nodes()
            missing = [f"node '{name}' not ready" for name in sorted(expected - ros.ready)]
            missing += [f"publisher on {ros.node.resolve_topic_name(t)}" for t in ros.unfed_topics()]
            if self.probes and not ros.hears_probes():
                missing.append(f"the recorder matched with {P.PROBE_CLIENT} on "
                               f"{ros.node.resolve_topic_name(P.OBSERVATION)}")
            if not ros.reset_client.service_is_ready():
                missing.append(f"service {ros.node.resolve_topic_name(P.RESET_SERVICE)}")
            if not missing:
                ros.admit(self.own_nodes(), external_policy=external)
                return
            now = time.monotonic()
            if now > deadline:
                endpoints = self.external_endpoints(ros) if external else {}
                absent = [what for what, nodes in endpoints.items() if not nodes]
                if absent:
                    raise GraphError(f"an external policy node did not connect within {self.cfg.connect_timeout:.0f} "
                                     f"s: no node but the run's own has {' or '.join(absent)} in ROS domain "
                                     f"{os.environ['ROS_DOMAIN_ID']}; {self.external_advice(ros, endpoints)}; also "
                                     f"missing: " + ", ".join(missing) + f" (node logs: {self.log_dir})")
                best_effort = self.best_effort_policy(ros) if external else None
                raise GraphError(f"the graph did not connect within {self.cfg.connect_timeout:.0f} s; missing: "
                                 + ", ".join(missing) + (f"; {best_effort}" if best_effort else "")
                                 + f" (node logs: {self.log_dir})")
            if external and now >= next_hint:
                next_hint = now + EXTERNAL_HINT_EVERY
                endpoints = self.external_endpoints(ros)
                absent = [what for what, nodes in endpoints.items() if not nodes]
                if absent:
                    self.log(f"[run_graph] waiting for the external policy node ({deadline - now:.0f} s left): "
                             f"{' and '.join(absent)}; {self.external_advice(ros, endpoints)}", file=sys.stderr,
                             flush=True)
            ros.spin(0.05)

    def external_endpoints(self, ros) -> dict[str, list[str]]:
        """The nodes this run did not start that show a subscription on observation, and a publisher on action."""
        own, node = self.own_nodes(), ros.node
        observation, action = (node.resolve_topic_name(t) for t in (P.OBSERVATION, P.ACTION))
        return {f"a subscriber on {observation}": [info.node_name for info in
                                                   node.get_subscriptions_info_by_topic(observation)
                                                   if info.node_name not in own],
                f"a publisher on {action}": [info.node_name for info in node.get_publishers_info_by_topic(action)
                                             if info.node_name not in own]}

    def external_advice(self, ros, endpoints: dict[str, list[str]]) -> str:
        """What to do about an external policy node that shows only part of its endpoints (``endpoints``)."""
        _, publishers = endpoints.values()
        if not publishers:  # no node of the user's, or one that does not publish: how to start one in this run
            return f"start it with {self.join_text()}" + ("; to start it before the run, pin the run's domain: "
                                                          "domain:=N" if self.cfg.domain == "auto" else "")
        return self.best_effort_policy(ros) or (
            f"node '{publishers[0]}' publishes on {ros.node.resolve_topic_name(P.ACTION)} but has not subscribed to "
            f"{ros.node.resolve_topic_name(P.OBSERVATION)}: a node that waits for subscribers on action first must "
            f"wait for {self.action_listeners}, not more")

    def best_effort_policy(self, ros) -> str | None:
        """Why a node's publisher on action is in the graph but matched by none of the run's subscriptions: it is
        best effort, which no reliable subscription matches."""
        from rclpy.qos import ReliabilityPolicy

        action = ros.node.resolve_topic_name(P.ACTION)
        best_effort = [info.node_name for info in ros.node.get_publishers_info_by_topic(action)
                       if info.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT]
        return (f"node '{best_effort[0]}' publishes on {action} best effort, which no reliable subscription matches: "
                "step topics are reliable" if best_effort else None)

    def join_text(self) -> str:
        """The environment a node needs to join this run (run() has set both variables in this process)."""
        return (f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} "
                f"ROS_AUTOMATIC_DISCOVERY_RANGE={os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']} <your node's command>, "
                f"answering once action has {self.action_listeners} subscribers")

    def own_nodes(self) -> set[str]:
        """The names of the nodes this run started, its own and (with a query attack) the attacker's probe client."""
        return {node.name for node in self.nodes} | {GraphClient.NAME} | ({P.PROBE_CLIENT} if self.probes else set())

    def run_metadata(self) -> dict:
        cfg = self.cfg
        return {
            "env": cfg.env, "mode": cfg.mode, "attack": self.attack, "attack_file": self.choice.file, "eps": self.eps,
            "seed": cfg.seed, "episodes": cfg.episodes, "horizon": cfg.horizon, "policy": cfg.policy, "expert": cfg.expert,
            "policy_provenance": self.policy_meta.provenance if self.policy_meta else "external",
            "expert_provenance": self.expert_meta.provenance, "obs_names": list(self.layout.names),
            "zero_order": self.layout.zero_order_mask.tolist(),
            "action_names": list(self.layout.action_names), "aril_ros": __version__,
            "git_revision": git_revision(), "created": datetime.datetime.now().isoformat(timespec="seconds"),
        }

    # -------------------------------------------------------------------------------------- run
    def run(self) -> dict:
        domain, domain_lock = allocate_domain(self.cfg.domain)
        try:
            with ros_domain(domain):  # this process's client and the nodes it starts; an in-process caller's come back
                return self._run(domain, {**os.environ, "PYTHONUNBUFFERED": "1"})
        finally:
            domain_lock.close()

    def _run(self, domain: int, env: dict) -> dict:
        self.log(f"[run_graph] {self.cfg.env} mode={self.cfg.mode} attack={self.attack} eps={self.eps} "
                 + (f"({self.choice.why}) " if self.choice.why else "") + f"domain={domain} logs={self.log_dir}"
                 + (f" (the external policy node: answer once action has {self.action_listeners} subscribers)"
                    if self.cfg.policy == "external" else ""), file=sys.stderr)
        writer = None
        ros = None
        interrupted, reason = False, ""
        # A stop signal only sets a flag, checked between spins: a KeyboardInterrupt raised inside an
        # rclpy callback can be swallowed by the executor, and the run would go on. The handler stays
        # until the log is closed, so a second Ctrl-C cannot cut the shutdown short.
        previous = {sig: signal.signal(sig, self._request_stop) for sig in STOP_SIGNALS}
        try:
            # first: a record path that exists or cannot be written stops the run before any node starts
            writer = RunLogWriter(self.record, self.run_metadata(), camera=self.cfg.render) if self.record else None
            recorder = StepRecorder(writer)
            self.start_nodes(env)
            ros = GraphClient(recorder, camera=self.cfg.render)
            self.wait_connected(ros)
            started = time.monotonic()
            for episode in range(self.cfg.episodes):
                self.run_episode(ros, recorder, episode)
            seconds = time.monotonic() - started
        except BaseException as err:  # any abnormal end: a signal, a dead or stuck node, a bug of ours
            interrupted, reason = True, end_reason(err)
            raise
        finally:
            stop_nodes(self.nodes)
            if ros is not None:
                ros.close()
            if writer is not None:
                writer.close(interrupted=interrupted, reason=reason,
                             episodes_completed=len(recorder.episode_stats))
                self.log(f"[run_graph] recorded {writer.steps} complete steps to {self.record}", file=sys.stderr)
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        return self.summary(recorder, seconds, domain)

    def run_episode(self, ros, recorder: "StepRecorder", episode: int) -> None:
        recorder.start_episode(episode)
        ros.reset(seed=episode_seed(self.cfg.seed, episode), episode=episode, check=self.check_nodes,
                  timeout=self.cfg.step_timeout)
        last_progress, progress = time.monotonic(), recorder.steps_written
        while not recorder.episode_done:
            ros.spin(0.05)
            self.check_nodes()
            if recorder.steps_written != progress:
                last_progress, progress = time.monotonic(), recorder.steps_written
            elif time.monotonic() - last_progress > self.cfg.step_timeout:
                cause = recorder.stray_text()
                raise GraphError(f"step {recorder.waiting_for()} made no progress for {self.cfg.step_timeout:.0f} s: "
                                 f"{recorder.missing_text()}" + (f"; {cause}" if cause else
                                                                 " (is the external policy still running?)"
                                                                 if self.cfg.policy == "external" else ""))
        self.log(recorder.episode_stats[-1].line(), file=sys.stderr, flush=True)

    def summary(self, recorder: "StepRecorder", seconds: float, domain: int) -> dict:
        figures = summarise_episodes(recorder.episode_stats)
        return {
            "mode": self.cfg.mode, "env": self.cfg.env, "attack": self.attack, "eps": self.eps,
            "episodes": figures.pop("episodes"), "seed": self.cfg.seed, "policy": self.cfg.policy, **figures,
            "queries_per_step": round(recorder.probes_answered / max(figures["steps"], 1), 2),
            "duplicates": recorder.duplicates,
            "steps_per_s": round(figures["steps"] / seconds, 1),
            "record": str(self.record) if self.record else None, "domain": domain,
            **({"camera_frames": recorder.frames_written} if self.cfg.render else {}),
        }


def end_reason(err: BaseException) -> str:
    """The ``reason`` an abnormal end leaves in the log's end record."""
    if isinstance(err, (GraphError, RunInterrupted)):
        return str(err)
    if isinstance(err, KeyboardInterrupt):  # an in-process caller's own Ctrl-C
        return "interrupted by KeyboardInterrupt"
    return f"the orchestrator failed: {type(err).__name__}: {err}"


def _node_path(name: str) -> str:
    """What a node is given for a policy: a bundled name as it is (the node resolves it, the per-mode
    ones with its ``mode``), a file as an absolute path (a node need not share the caller's folder)."""
    return name if name in (*BUNDLED_NAMES, "external") else str(Path(name).resolve())


PRODUCERS = {P.CLOCK: "simulator", P.STATE: "simulator", P.PHYSICS: "simulator", P.REWARD: "simulator",
             P.PERTURBATION: "attacker", P.OBSERVATION: "attacker, or simulator when physical", P.ACTION: "policy",
             P.EXPERT_ACTION: "expert"}


class StepRecorder:
    """Collects each step's raw messages by step tag, and the probes asked during it by probe tag; writes a
    step with its probes once it is complete, in order.

    Exactly one message per topic per step: a second copy of a step message, whether the step is still open or
    already written, is counted as a harmless duplicate (``duplicates``) when it is byte for byte the first, and
    is a :class:`StepFault` otherwise (the step keeps the first, which is what the simulator applied). A written
    step is never reopened. Copies are compared by digest, kept for the steps of this episode and the last.
    """

    def __init__(self, writer: RunLogWriter | None):
        self.writer = writer
        self.pending: dict[StepTag, dict[str, bytes]] = {}
        self.clock: dict[int, bytes] = {}
        self.stamp: dict[StepTag, int] = {}
        self.episode_stats: list[EpisodeStats] = []  # the finished episodes
        self.steps_written = 0
        self.episode = -1
        self.frames: dict[StepTag, tuple[int, bytes]] = {}  # camera frames whose step is not written yet
        self.last_written: StepTag | None = None
        self.frames_written = 0
        self.probes: dict[StepTag, dict[ProbeTag, dict[str, bytes]]] = {}  # of the steps not written yet
        self.probes_answered = 0
        self.written: dict[StepTag, dict[str, bytes]] = {}  # digests of the written steps' messages, by tag
        self.last_stamp = -1  # the sim time of the last written step (its /clock)
        self.duplicates = 0  # harmless byte-identical copies of step messages

    def start_episode(self, episode: int) -> None:
        self.episode, self.episode_done = episode, False
        self.current = EpisodeStats(episode)
        self.written = {tag: digests for tag, digests in self.written.items() if tag.episode >= episode - 1}

    def on_frame(self, raw: bytes) -> None:
        """A camera frame goes into the log right after its step (log times stay in sim-time order)."""
        stamp, frame_id = cdr_header(raw)
        tag = step_tag_of(P.CAMERA, frame_id)
        if self.last_written is not None and tag <= self.last_written:
            self._write_frame(stamp, raw)
        else:
            self.frames[tag] = (stamp, raw)

    def _write_frame(self, stamp: int, raw: bytes) -> None:
        if self.writer is not None:
            self.writer.write_frame(stamp, raw)
        self.frames_written += 1

    def on_message(self, topic: str, raw: bytes) -> None:
        if topic == P.CLOCK:
            stamp = cdr_stamp(raw)
            if stamp <= self.last_stamp or stamp in self.clock:
                self.duplicates += 1  # a Clock is its stamp alone: a second one for a stamp is the same bytes
                return
            self.clock[stamp] = raw
        else:
            stamp, frame_id = cdr_header(raw)
            if P.is_probe(frame_id):  # a query-based attack's question to the policy, or the answer
                probe = ProbeTag.parse(frame_id)
                if self.last_written is None or probe.step > self.last_written:  # else a late repeat of a probe
                    self.probes.setdefault(probe.step, {}).setdefault(probe, {})[topic] = raw
            else:
                tag = step_tag_of(topic, frame_id)
                if self.last_written is not None and tag <= self.last_written:
                    self.repeated(tag, topic, raw, self.written.get(tag, {}).get(topic), "was written already")
                    return
                if topic in self.pending.get(tag, {}):
                    self.repeated(tag, topic, raw, digest(self.pending[tag][topic]), "has one already")
                    return
                self.pending.setdefault(tag, {})[topic] = raw
                if topic == P.STATE:
                    self.stamp[tag] = stamp
        self.flush()

    def repeated(self, tag: StepTag, topic: str, raw: bytes, first: bytes | None, step_has: str) -> None:
        """A second message on ``topic`` for step ``tag``, whose first has digest ``first`` (None: forgotten)."""
        if first == digest(raw):
            self.duplicates += 1
            return
        raise StepFault(f"step {tag}: a second message on {topic}, different from the first (the step {step_has}; "
                        "one message per topic per step)" if first is not None else
                        f"step {tag}: a message on {topic} for a step written more than an episode ago")

    def arrived(self, tag: StepTag) -> set[str]:
        """The step topics of ``tag`` heard so far (its ``/clock`` joins it by the state's stamp)."""
        return {*self.pending[tag], *([P.CLOCK] if self.stamp.get(tag) in self.clock else [])}

    def half_heard(self, tag: StepTag) -> int:
        """Probes of ``tag`` heard on one of observation and action only. The policy answers a step's probes
        before it acts, on one publisher, so once the step's action is in so is every probe's answer; but a
        probe's observation comes from another publisher (the attacker's probe client) and may still be on its way."""
        return sum(len(probe) < len(P.PROBE_CHANNELS) for probe in self.probes.get(tag, {}).values())

    def complete(self, tag: StepTag) -> bool:
        return not missing_topics(self.arrived(tag)) and not self.half_heard(tag)

    def flush(self) -> None:
        # the step to write is the waiting one, not the first heard: a stray action's tag (a policy that does not
        # copy the observation's header) must not hold up the steps after it
        while (tag := self.waiting_for()) in self.pending and self.complete(tag):
            msgs = self.pending.pop(tag)
            stamp = self.stamp.pop(tag)
            msgs[P.CLOCK] = self.clock.pop(stamp)
            asked = self.probes.pop(tag, {})
            probes = [asked[probe] for probe in sorted(asked)]
            if self.writer is not None:
                self.writer.write_step(stamp, msgs, probes)
            self.written[tag] = {topic: digest(raw) for topic, raw in msgs.items()}
            self.last_stamp = stamp
            self.probes_answered += len(probes)
            self.last_written = tag
            if tag in self.frames:
                self._write_frame(*self.frames.pop(tag))
            reward, terminated, truncated = cdr_joint_values(msgs[P.REWARD], "position")
            action = cdr_joint_values(msgs[P.ACTION], "effort")
            expert = cdr_joint_values(msgs[P.EXPERT_ACTION], "effort")
            delta = cdr_joint_values(msgs[P.PERTURBATION], "position")
            self.count_step(reward, action, expert, delta, done=bool(terminated or truncated))

    def count_step(self, reward: float, action, expert_action, delta, done: bool) -> None:
        """A written step's figures into the episode's; the episode ends with its last step."""
        self.current.add(reward, action, expert_action, delta, done=done)
        self.steps_written += 1
        if self.current.done:
            self.episode_stats.append(self.current)
            self.episode_done = True

    def waiting_for(self) -> StepTag:
        """The step to be written next: steps are written in order, from 0 in each episode."""
        return StepTag(self.episode, self.current.steps)

    def missing_text(self) -> str:
        tag = self.waiting_for()
        if tag not in self.pending:
            return f"no {P.STATE} from the simulator"
        missing = [f"{t} ({PRODUCERS[t]})" for t in missing_topics(self.arrived(tag))]
        half_heard = self.half_heard(tag)
        if half_heard:
            missing.append(f"{half_heard} probes' observation or answer (attacker, policy)")
        return "waiting for " + ", ".join(missing)

    def stray_text(self) -> str:
        """Why the waiting step's action never came, if actions for other steps did; else ``""``."""
        tag, strays = self.waiting_for(), self.stray_actions()
        if not strays or P.ACTION in self.pending.get(tag, {}):
            return ""
        shown = ", ".join(map(str, strays[:3])) + (f" and {len(strays) - 3} more" if len(strays) > 3 else "")
        return (f"actions arrived tagged {shown} while step {tag} was waiting: the policy must answer with the "
                "observation's header (its frame_id, the step tag, is what the simulator steps on)")

    def stray_actions(self) -> list[StepTag]:
        """Tags of the actions heard for a step other than the one waiting, which no step can use: in lockstep the
        simulator publishes no step before its predecessor's action, so these come from a policy that tags its
        answers with something else than the observation's frame_id."""
        waiting = self.waiting_for()
        return sorted(tag for tag, msgs in self.pending.items() if tag != waiting and P.ACTION in msgs)


def step_tag_of(topic: str, frame_id: str) -> StepTag:
    try:
        return StepTag.parse(frame_id)
    except ValueError as err:
        raise StepFault(f"a message on {topic} with a malformed frame_id: {err}"
                        + (" (a policy must answer with the observation's header)" if topic == P.ACTION else "")
                        ) from None


def digest(raw: bytes) -> bytes:
    return hashlib.blake2b(raw, digest_size=16).digest()


class GraphClient:
    """The orchestrator's own ROS node: raw subscriptions for the recorder and the reset client, and the guards of
    every step topic and service (:class:`aril_ros_nodes.common.PublisherGuard`): once :meth:`admit` has checked
    who is connected, a publisher or service client that joins later stops the run, named."""

    NAME = "orchestrator"

    def __init__(self, recorder: StepRecorder, camera: bool = False):
        import rclpy
        from rcl_interfaces.srv import SetParametersAtomically
        from rclpy.experimental import EventsExecutor
        from rclpy.signals import SignalHandlerOptions
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_msgs.msg import String

        from aril_ros_nodes.common import READY_QOS, STEP_QOS, PublisherGuard, guarded_subscription

        self._rclpy = rclpy
        # no rclpy signal handlers: Ctrl-C must reach the orchestrator's own handler
        rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(self.NAME)
        classes = {"sensor_msgs/msg/JointState": JointState, "rosgraph_msgs/msg/Clock": Clock}
        self.guards = {
            topic: guarded_subscription(self.node, classes[msg_type], topic,
                                        lambda raw, topic=topic: self.receive(topic, recorder.on_message, topic, raw),
                                        STEP_QOS, raw=True)
            for topic, msg_type in P.MESSAGE_TYPES.items()}
        if camera:
            from sensor_msgs.msg import CompressedImage

            self.guards[P.CAMERA] = guarded_subscription(self.node, CompressedImage, P.CAMERA,
                                                         lambda raw: self.receive(P.CAMERA, recorder.on_frame, raw),
                                                         STEP_QOS, raw=True)
        self.service_guards = [PublisherGuard(self.node, name, service=True)
                               for name in (P.RESET_SERVICE, P.SET_STATE_SERVICE)]
        # what stops the run, raised by spin(): raised inside a callback it would also be logged by the executor
        self.fault: GraphError | RunLogError | None = None
        self.ready: set[str] = set()
        self.node.create_subscription(String, P.READY, lambda msg: self.ready.add(msg.data), READY_QOS)
        self.reset_client = self.node.create_client(SetParametersAtomically, P.RESET_SERVICE)
        self._request_type = SetParametersAtomically.Request
        self.executor = EventsExecutor()
        self.executor.add_node(self.node)
        self.next_look = 0.0  # when spin() next checks every guard

    def spin(self, timeout: float) -> None:
        """Handle one event (a message, a matched event, an answer), or wait ``timeout`` seconds for one; every
        :data:`~aril_ros_nodes.common.GRAPH_POLL` seconds, look for an intruder that has not sent yet (a message is
        checked as it arrives: looking after each of the 8 of a step would double the orchestrator's work)."""
        from aril_ros_nodes.common import GRAPH_POLL, IntruderError

        self.executor.spin_once(timeout_sec=timeout)
        if time.monotonic() >= self.next_look:
            self.next_look = time.monotonic() + GRAPH_POLL
            try:
                for guard in [*self.guards.values(), *self.service_guards]:
                    guard.check()
            except IntruderError as err:
                self.fault = self.fault or GraphError(str(err))
        if self.fault is not None:
            raise self.fault

    def receive(self, topic: str, handler, *args) -> None:
        """A message on ``topic`` to ``handler``, once its publisher is known to be admitted; a fault in it names
        the admitted publisher(s), the only ones it can have come from. After a fault nothing more is taken."""
        from aril_ros_nodes.common import IntruderError

        if self.fault is not None:
            return
        guard = self.guards[topic]
        try:
            guard.check()
            handler(*args)
        except IntruderError as err:
            self.fault = GraphError(str(err))
        except StepFault as err:
            self.fault = StepFault(f"{err}, from {guard.describe()}")
        except RunLogError as err:  # the log could not be written (a full disk): raised from spin, not in rclpy's callback
            self.fault = err

    def admit(self, own_nodes: set[str], external_policy: bool) -> None:
        """Admit the publishers and service peers connected now, if each is one of ``own_nodes`` (the names of
        the nodes this run started: unique in the domain, so no other node can pass for one) or, with an
        external policy, the one node publishing on action that this run did not start."""
        from aril_ros_nodes.common import endpoint_text

        guards = [*self.guards.values(), *self.service_guards]
        admitted = {guard: guard.admit() for guard in guards}  # this waits until the graph knows their node names
        names = [name for name, _ in self.node.get_node_names_and_namespaces()]
        impostors = sorted({name for name in names if name in own_nodes and names.count(name) > 1})
        if impostors:
            endpoints = [f"{endpoint_text(info)} on {guard.what}" for guard, infos in admitted.items()
                         for info in infos if info.node_name in impostors]
            raise GraphError(f"more than one node named {', '.join(impostors)} in the run's domain: another process "
                             "passes for one of this run's nodes (" + ("; ".join(endpoints) or "no step endpoints")
                             + ")")
        for guard, infos in admitted.items():
            strangers = [info for info in infos if info.node_name not in own_nodes]
            if external_policy and guard is self.guards[P.ACTION] and len(strangers) == 1:
                continue  # the external policy node the user started
            if strangers:
                raise GraphError(f"intruder on {guard.what}: " + ", ".join(endpoint_text(i) for i in strangers)
                                 + ", not one of this run's nodes" + (" (an external policy publishes on action "
                                                                      "alone)" if external_policy else ""))

    def hears_probes(self) -> bool:
        """Whether the recorder knows the attacker's probe client as a publisher on observation. The attacker's
        readiness says only that the client matched the recorder (each side discovers the other on its own), and
        a publisher the recorder meets after admission is an intruder."""
        return any(info.node_name == P.PROBE_CLIENT for info in self.guards[P.OBSERVATION].publishers())

    def unfed_topics(self) -> list[str]:
        """Step topics whose publisher is not yet matched with the recorder."""
        return [topic for topic, guard in self.guards.items() if guard.subscription.get_publisher_count() < 1]

    def reset(self, seed: int, episode: int, check, timeout: float) -> None:
        from aril_ros_nodes.common import param_msg

        request = self._request_type()
        request.parameters = [param_msg("seed", seed), param_msg("episode", episode)]
        future = self.reset_client.call_async(request)
        deadline = time.monotonic() + timeout
        while not future.done():
            self.spin(0.05)
            check()
            if time.monotonic() > deadline:
                raise GraphError(f"the simulator did not answer {P.RESET_SERVICE} within {timeout:.0f} s")
        result = future.result().result
        if not result.successful:
            raise GraphError(f"the simulator refused to reset: {result.reason}")

    def close(self) -> None:
        from rclpy.utilities import get_default_context

        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.try_shutdown()
        get_default_context().destroy()  # the DDS participant leaves now, not at the process's teardown

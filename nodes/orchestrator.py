"""The orchestrator behind ``run_graph.py``: checks the run, starts the nodes, drives episodes, records, shuts down.

It stands in for ``ros2 launch`` and ``ros2 bag record``, as an outline over its rooms: :mod:`.graph_config` (the
arguments and the run they make, every acting file loaded once), :mod:`.launcher` (a ROS domain of the run's own,
the node processes, the stop signals), :mod:`.graph_client` (its own ROS node) and the rclpy-free
:class:`aril_ros.runlog.StepRecorder`. Each node is its own process in the run's domain; the orchestrator's node
resets the simulator at each episode start (env seed :func:`aril_ros.step.episode_seed`), the recorder writes every
step (raw CDR, see :mod:`aril_ros.runlog`) once it is complete (:func:`aril_ros.step.missing_topics`) and its
probes answered, and takes each episode's figures once (:class:`aril_ros.step.EpisodeStats`, into the log's end
record); the run prints them per episode and one JSON summary line (``queries_per_step``: probes answered per
step; ``attack_settings`` and ``files``: what acted in the run, as the log records them), and stops every node, all
at once, on success, on Ctrl-C, SIGTERM or SIGHUP (:class:`RunInterrupted`), when a node dies (naming how, and its
last error line) and when a step makes no progress for ``step_timeout`` seconds. Every end but success closes the
log as interrupted, with the reason.
"""
from __future__ import annotations

import datetime
import os
import secrets
import sys
import tempfile
import time
from pathlib import Path

from aril_ros import protocol as P
from aril_ros.protocol import ros_domain
from aril_ros.runlog import RunLogWriter, StepRecorder
from aril_ros.runlog.live import LiveView
from aril_ros.step import episode_seed, summarise_episodes
from aril_ros_nodes.graph_client import GraphClient
from aril_ros_nodes.graph_config import GraphConfig, plan_run
from aril_ros_nodes.launcher import GraphError, Nodes, RunInterrupted, StopSignals, allocate_domain

__all__ = ["GraphConfig", "GraphError", "Orchestrator", "RunInterrupted", "allocate_domain"]  # run_graph's, collect's

HINT_EVERY = 5.0
"""Seconds between two reminders of what a run waits for: of an external policy node, what is missing and how to
join; a live viewer (``live:=wait``)."""


class Orchestrator:
    def __init__(self, cfg: GraphConfig, log=print):
        self.cfg, self.log = cfg, log
        self.plan = plan_run(cfg)  # a bad argument or file is refused here, before any process starts
        stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        # runs started in the same second get names of their own (the writer refuses a file that exists)
        default_record = f"runs/{stamp}-{cfg.env}-{cfg.mode}-{secrets.token_hex(3)}.mcap"
        self.record = None if cfg.record == "off" else Path(cfg.record or default_record)
        self.log_dir = Path(tempfile.mkdtemp(prefix=f"aril_ros-{stamp}-"))
        self.nodes = Nodes(self.log_dir)
        self.signals = StopSignals()

    # -------------------------------------------------------------------------------------- run
    def run(self) -> dict:
        domain, domain_lock = allocate_domain(self.cfg.domain)
        try:
            with ros_domain(domain):  # this process's client and the nodes it starts; an in-process caller's come back
                return self._run(domain, {**os.environ, "PYTHONUNBUFFERED": "1"})
        finally:
            domain_lock.close()

    def _run(self, domain: int, env: dict) -> dict:
        plan = self.plan
        self.log(f"[run_graph] {self.cfg.env} mode={self.cfg.mode} attack={plan.attack} eps={plan.eps} "
                 + (f"({plan.why}) " if plan.why else "") + f"domain={domain} logs={self.log_dir}"
                 + (f" (the external policy node: answer once action has {plan.action_listeners} subscribers)"
                    if self.cfg.policy == "external" else ""), file=sys.stderr)
        recorder = ros = live = None
        interrupted, reason = False, ""
        with self.signals:  # until the log is closed
            try:
                # first: a record path that exists or cannot be written stops the run before any node starts
                writer = RunLogWriter(self.record, plan.metadata(), camera=self.cfg.render) if self.record else None
                topics = P.step_topics(plan.timing is not None)
                live = self.start_live(topics)
                recorder = StepRecorder(writer, topics, live)
                self.start_nodes(env)
                ros = GraphClient(recorder, camera=self.cfg.render)
                self.wait_connected(ros)
                if self.cfg.live == "wait":
                    self.wait_watched(ros, live)
                started = time.monotonic()
                for episode in range(self.cfg.episodes):
                    self.run_episode(ros, recorder, episode)
                seconds = time.monotonic() - started
            except BaseException as err:  # any abnormal end: a signal, a dead or stuck node, a bug of ours
                interrupted, reason = True, end_reason(err)
                raise
            finally:
                self.nodes.stop()
                if ros is not None:
                    ros.close()
                if recorder is not None and recorder.writer is not None:
                    recorder.close(interrupted=interrupted, reason=reason)
                    self.log(f"[run_graph] recorded {recorder.writer.steps} complete steps to {self.record}",
                             file=sys.stderr)
                if live is not None:
                    live.close()
        return self.summary(recorder, seconds, domain)

    def start_live(self, topics: tuple[str, ...]) -> LiveView | None:
        """The live view (``live:=on|wait``), serving before any node starts, its address said; else None."""
        if self.cfg.live == "off":
            return None
        live = LiveView(self.cfg.live_host, self.cfg.live_port, topics, camera=self.cfg.render)
        self.log(f"[run_graph] live view at {live.url}: in Foxglove, Open connection > Foxglove WebSocket > {live.url}"
                 " (layout: docs/foxglove/aril-layout.json)", file=sys.stderr, flush=True)
        return live

    def wait_watched(self, ros: GraphClient, live: LiveView) -> None:
        """Until a viewer subscribes to the live view (``live:=wait``), saying every :data:`HINT_EVERY`
        seconds what the run waits for; as long as it takes (Ctrl-C stops the run)."""
        next_hint = time.monotonic() + HINT_EVERY
        while not live.watched():
            self.check_nodes()
            if time.monotonic() >= next_hint:
                next_hint = time.monotonic() + HINT_EVERY
                self.log(f"[run_graph] live:=wait: waiting for a viewer to subscribe at {live.url}", file=sys.stderr,
                         flush=True)
            ros.spin(0.05)

    def start_nodes(self, env: dict) -> None:
        params = self.plan.node_params()
        envs = {name: env for name in params}
        if self.cfg.render:  # mujoco picks its GL backend on import: the simulator's process needs it set
            envs["simulator"] = {**env, "MUJOCO_GL": env.get("MUJOCO_GL", "egl")}
        self.nodes.start(params, envs)

    def check_nodes(self) -> None:
        """Raise if the user interrupted the run or a node died (every wait loop calls this, after each message)."""
        self.signals.check()
        self.nodes.check()

    def run_episode(self, ros: GraphClient, recorder: StepRecorder, episode: int) -> None:
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

    def summary(self, recorder: StepRecorder, seconds: float, domain: int) -> dict:
        figures = summarise_episodes(recorder.episode_stats)
        return {
            "mode": self.cfg.mode, "env": self.cfg.env, "attack": self.plan.attack, "eps": self.plan.eps,
            "episodes": figures.pop("episodes"), "seed": self.cfg.seed, "policy": self.cfg.policy, **figures,
            "queries_per_step": round(recorder.probes_answered / max(figures["steps"], 1), 2),
            "duplicates": recorder.duplicates,
            "steps_per_s": round(figures["steps"] / seconds, 1),
            "record": str(self.record) if self.record else None, "domain": domain,
            **({"camera_frames": recorder.frames_written} if self.cfg.render else {}),
            "attack_settings": self.plan.attack_settings(), "files": self.plan.files,
            **({"timing": self.plan.timing.record()} if self.plan.timing else {}),
        }

    # ------------------------------------------------------------------------------- connecting
    def wait_connected(self, ros: GraphClient) -> None:
        """Until every started node has announced that its endpoints are matched (graph/ready), the
        recorder hears every step topic, and the reset service answers. While an external policy node is
        awaited, says every :data:`HINT_EVERY` seconds what of it is missing and how to join the run."""
        deadline = time.monotonic() + self.cfg.connect_timeout
        next_hint = time.monotonic() + HINT_EVERY
        external = self.cfg.policy == "external"
        while True:
            self.check_nodes()
            missing = self.missing_connections(ros)
            if not missing:
                ros.admit(self.own_nodes(), external_policy=external)
                return
            now = time.monotonic()
            if now > deadline:
                raise GraphError(self.not_connected_text(ros, missing))
            if external and now >= next_hint:
                next_hint = now + HINT_EVERY
                endpoints = ros.external_endpoints(self.own_nodes())
                absent = [what for what, nodes in endpoints.items() if not nodes]
                if absent:
                    self.log(f"[run_graph] waiting for the external policy node ({deadline - now:.0f} s left): "
                             f"{' and '.join(absent)}; {self.external_advice(ros, endpoints)}", file=sys.stderr,
                             flush=True)
            ros.spin(0.05)

    def missing_connections(self, ros: GraphClient) -> list[str]:
        missing = [f"node '{name}' not ready" for name in sorted(self.nodes.names - ros.ready)]
        missing += [f"publisher on {ros.node.resolve_topic_name(t)}" for t in ros.unfed_topics()]
        if self.plan.probes and not ros.hears_probes():
            missing.append(f"the recorder matched with {P.PROBE_CLIENT} on "
                           f"{ros.node.resolve_topic_name(P.OBSERVATION)}")
        if not ros.reset_client.service_is_ready():
            missing.append(f"service {ros.node.resolve_topic_name(P.RESET_SERVICE)}")
        return missing

    def not_connected_text(self, ros: GraphClient, missing: list[str]) -> str:
        """Why the graph did not connect in time, and for an external policy node what to do about it."""
        external = self.cfg.policy == "external"
        endpoints = ros.external_endpoints(self.own_nodes()) if external else {}
        absent = [what for what, nodes in endpoints.items() if not nodes]
        if absent:
            return (f"an external policy node did not connect within {self.cfg.connect_timeout:.0f} s: no node but "
                    f"the run's own has {' or '.join(absent)} in ROS domain {os.environ['ROS_DOMAIN_ID']}; "
                    f"{self.external_advice(ros, endpoints)}; also missing: " + ", ".join(missing)
                    + f" (node logs: {self.log_dir})")
        best_effort = ros.best_effort_policy() if external else None
        return (f"the graph did not connect within {self.cfg.connect_timeout:.0f} s; missing: " + ", ".join(missing)
                + (f"; {best_effort}" if best_effort else "") + f" (node logs: {self.log_dir})")

    def external_advice(self, ros: GraphClient, endpoints: dict[str, list[str]]) -> str:
        """What to do about an external policy node that shows only part of its endpoints (``endpoints``)."""
        _, publishers = endpoints.values()
        if not publishers:  # no node of the user's, or one that does not publish: how to start one in this run
            return f"start it with {self.join_text()}" + ("; to start it before the run, pin the run's domain: "
                                                          "domain:=N" if self.cfg.domain == "auto" else "")
        return ros.best_effort_policy() or (
            f"node '{publishers[0]}' publishes on {ros.node.resolve_topic_name(P.ACTION)} but has not subscribed to "
            f"{ros.node.resolve_topic_name(P.OBSERVATION)}: a node that waits for subscribers on action first must "
            f"wait for {self.plan.action_listeners}, not more")

    def join_text(self) -> str:
        """The environment a node needs to join this run (run() has set both variables in this process)."""
        return (f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} "
                f"ROS_AUTOMATIC_DISCOVERY_RANGE={os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']} <your node's command>, "
                f"answering once action has {self.plan.action_listeners} subscribers")

    def own_nodes(self) -> set[str]:
        """The names of the nodes this run started, its own and (with a query attack) the attacker's probe client."""
        return self.nodes.names | {GraphClient.NAME} | ({P.PROBE_CLIENT} if self.plan.probes else set())


def end_reason(err: BaseException) -> str:
    """The ``reason`` an abnormal end leaves in the log's end record."""
    if isinstance(err, (GraphError, RunInterrupted)):
        return str(err)
    if isinstance(err, KeyboardInterrupt):  # an in-process caller's own Ctrl-C
        return "interrupted by KeyboardInterrupt"
    return f"the orchestrator failed: {type(err).__name__}: {err}"

"""A policy reached over ROS: any node that answers ``observation`` with ``action`` (the documented
policy contract), asked for actions as a black box. It is the ``aril_ros.victims`` entry point ``ros``
(``aril train-adversary victim:=ros``) and the victim of the attacker node's query-based attacks.

``RemotePolicy.act(batch)`` publishes every row at once as a probe (``observation`` tagged
:class:`aril_ros.protocol.ProbeTag` ``"<episode>/<step>/probe/<k>"``, numbered within the step
:meth:`RemotePolicy.begin_step` names; step 0/0 unless one is named) and waits for every tagged
``action``: the simulator never steps on a probe's answer. It spins a context, node and executor of
its own inside the call, so an attacker node can wait for answers within its own callback.
"""
from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import rclpy
from rclpy.experimental import EventsExecutor
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState

from aril_ros import protocol as P
from aril_ros.envs import layout_of
from aril_ros.protocol import ProbeTag, StepTag
from aril_ros_nodes.common import STEP_QOS, joint_state, publishers, step_header, subscribers


RESEND_AFTER = 1.0
"""Seconds after which an unanswered probe is asked again: a probe sent just after the client matched the
policy's publisher may go out before that publisher has matched the client (each side matches on its own),
and its answer is then lost. A policy without hidden state answers a repeated probe the same way."""


class RemotePolicyError(ConnectionError):
    """No policy node answers, or it stopped answering."""


class RemotePolicy:
    """``connect_timeout``: seconds to wait in the constructor for a policy node; ``None`` returns at
    once, and whoever builds it waits for :meth:`checks` (the attacker node's ReadyAnnouncer does)."""

    def __init__(self, env_id: str, timeout: float = 10.0, connect_timeout: float | None = 30.0,
                 name: str = "adversary_trainer"):
        self.layout = layout_of(env_id)
        self.timeout = timeout
        self.meta = SimpleNamespace(provenance={"victim": "a policy node reached over ROS (black box)"})
        self.context = rclpy.Context()
        rclpy.init(args=[], context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(name, context=self.context)
        self.pub = self.node.create_publisher(JointState, P.OBSERVATION, STEP_QOS)
        self.waiting: set[str] = set()  # the probe tags asked and not yet answered
        self.replies: dict[str, np.ndarray] = {}
        self.sub = self.node.create_subscription(JointState, P.ACTION, self.on_action, STEP_QOS)
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.begin_step(StepTag(0, 0), 0)
        if connect_timeout is not None:
            self.wait_connected(connect_timeout)

    def checks(self, listeners: int = 1) -> dict:
        """What must be matched before the first probe: ``listeners`` subscribers on the probes (the policy;
        in a graph the recorder too) and a publisher of the answers."""
        return {f"{listeners} subscribers on observation (probes)": subscribers(self.pub, listeners),
                "a publisher on action (probe answers)": publishers(self.sub)}

    def wait_connected(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not all(ok() for ok in self.checks().values()):
            if time.monotonic() > deadline:
                # a node that publishes actions but has not subscribed yet is most likely msgs_doc's, which subscribes
                # once `listeners` subscribers hear its actions (2 in a run): alone, this trainer is one
                waiting = self.sub.get_publisher_count() and not self.pub.get_subscription_count()
                self.close()
                raise RemotePolicyError(
                    f"a node publishes {P.ACTION} but none subscribes to {P.OBSERVATION} within {timeout:.0f} s: a "
                    "node written from msgs_doc subscribes once its 'listeners' parameter's count of subscribers hear "
                    "its actions, and an adversary's training alone is one; start it with --ros-args -p listeners:=1"
                    if waiting else
                    f"no policy node subscribes to {P.OBSERVATION} and publishes {P.ACTION} within {timeout:.0f} s "
                    "(ROS_DOMAIN_ID and the node running?)")
            self.executor.spin_once(timeout_sec=0.05)

    def begin_step(self, step: StepTag, stamp_ns: int) -> None:
        """The probes from now on are asked during ``step`` (tagged as its, stamped with its sim time), from 0."""
        self.step, self.stamp_ns, self.asked = step, stamp_ns, 0

    def on_action(self, msg: JointState) -> None:
        if msg.header.frame_id in self.waiting:  # step actions and others' answers are not ours to keep
            self.waiting.discard(msg.header.frame_id)
            self.replies[msg.header.frame_id] = np.asarray(msg.effort, dtype=np.float64)

    def act(self, obs: np.ndarray) -> np.ndarray:
        rows = np.atleast_2d(obs)
        tags = [ProbeTag(self.step, self.asked + i) for i in range(len(rows))]
        self.asked += len(rows)
        self.waiting.update(map(str, tags))
        self.publish(zip(tags, rows))
        deadline, resend = time.monotonic() + self.timeout, time.monotonic() + RESEND_AFTER
        while self.waiting:
            if time.monotonic() > resend:
                self.publish((tag, row) for tag, row in zip(tags, rows) if str(tag) in self.waiting)
                resend = time.monotonic() + RESEND_AFTER
            if time.monotonic() > deadline:
                missing = len(self.waiting)
                self.waiting.clear()
                raise RemotePolicyError(f"the policy node did not answer {missing} of {len(tags)} probes "
                                        f"of step {self.step} within {self.timeout:.0f} s")
            self.executor.spin_once(timeout_sec=0.05)
        actions = [self.replies.pop(str(tag)) for tag in tags]
        sizes = {a.size for a in actions}
        if sizes != {self.layout.act_dim}:
            raise RemotePolicyError(f"the policy node answered {'/'.join(map(str, sorted(sizes)))} action values, "
                                    f"{self.layout.env_id} takes {self.layout.act_dim}")
        return actions[0] if np.ndim(obs) == 1 else np.stack(actions)

    def publish(self, probes) -> None:
        for tag, row in probes:
            self.pub.publish(joint_state(step_header(tag, self.stamp_ns), self.layout.names, row))

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

"""A policy reached over ROS: any node that answers ``observation`` with ``action`` (the documented
policy contract), asked for actions as a black box. It is the ``aril_ros.victims`` entry point ``ros``
(``aril train-adversary victim:=ros``) and the victim of the attacker node's query-based attacks.

``RemotePolicy.act(batch)`` publishes every row at once as a probe (``observation`` tagged
:class:`aril_ros.protocol.ProbeTag` ``"<episode>/<step>/probe/<k>"``, numbered within the step
:meth:`RemotePolicy.begin_step` names; unless one is named, step 0 of an episode numbered by the process id) and
waits for every tagged ``action``: the simulator never steps on a probe's answer. Where the policy node declares the
parameter ``probe_batches`` true (``aril_ros_nodes.policy_node`` does), the rows go as probe batches instead, up to
:data:`BATCH_ROWS` a message (tagged ``"<episode>/<step>/probe/<k>..<m>"``), each answered by one message: a
message and its callbacks, not the policy's arithmetic, are what a probe costs. It spins a context, node and executor of
its own inside the call, so an attacker node can wait for answers within its own callback.
"""
from __future__ import annotations

import os
import time
from types import SimpleNamespace

import numpy as np
import rclpy
from rcl_interfaces.msg import ParameterType
from rclpy.experimental import EventsExecutor
from rclpy.parameter_client import AsyncParameterClient
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState

from aril_ros import protocol as P
from aril_ros.envs import layout_of
from aril_ros.protocol import ProbeTag, StepTag
from aril_ros_nodes.common import STEP_QOS, joint_state, publishers, step_header, subscribers


RESEND_AFTER = 1.0
"""Seconds after which an unanswered probe is asked again, until the policy's first answer arrives: a probe sent
just after the client matched the policy's publisher may go out before that publisher has matched the client (each
side matches on its own), and its answer is then lost. Once an answer has arrived nothing more is lost (the step QoS
keeps every message), so a slow node is not asked twice. A policy without hidden state answers a repeated probe the
same way."""


BATCH_ROWS = 256
"""Probes in one probe batch at most: a step's (SPSA^k's 17 an iteration, FGSM by finite differences' 27 on Ant) go
in one; a surrogate's thousands of questions in messages of about 0.1 MB."""
CAPABILITY_TIMEOUT = 2.0
"""Seconds to wait for a policy node's parameter services when asking whether it takes probe batches; a node
without them is asked one probe a message."""
UNKNOWN_NODE = "_NODE_NAMESPACE_UNKNOWN_/_NODE_NAME_UNKNOWN_"
"""What an endpoint's node is called until its name has been discovered."""


class RemotePolicyError(ConnectionError):
    """No policy node answers, or it stopped answering."""


class RemotePolicy:
    """``connect_timeout``: seconds to wait in the constructor for a policy node; ``None`` returns at
    once, and whoever builds it waits for :meth:`checks` (the attacker node's ReadyAnnouncer does)."""

    def __init__(self, env_id: str, timeout: float = 10.0, connect_timeout: float | None = 30.0,
                 name: str = "adversary_trainer", batches: bool = True):
        self.layout = layout_of(env_id)
        self.timeout = timeout
        self.batches = None if batches else False  # None: ask the policy node before the first probe
        self.meta = SimpleNamespace(provenance={"victim": "a policy node reached over ROS (black box)"})
        self.context = rclpy.Context()
        rclpy.init(args=[], context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(name, context=self.context)
        self.pub = self.node.create_publisher(JointState, P.OBSERVATION, STEP_QOS)
        self.waiting: set[str] = set()  # the probe tags asked and not yet answered
        self.replies: dict[str, np.ndarray] = {}
        self.answered = False  # whether any answer of ours has arrived: the policy's publisher has matched us
        self.sub = self.node.create_subscription(JointState, P.ACTION, self.on_action, STEP_QOS)
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        # outside a run's steps the probes are tagged as steps of an episode numbered by this process: every client
        # hears every answer, and two asking one node at once (the two modes' adversary trainings) must not take
        # each other's
        self.begin_step(StepTag(os.getpid(), 0), 0)
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
            self.answered = True
            self.replies[msg.header.frame_id] = np.asarray(msg.effort, dtype=np.float64)

    def answers_in_batches(self) -> tuple[bool, str]:
        """Whether the probes go in batches (every node publishing on ``action`` declares the parameter
        ``probe_batches`` true) or one a message (the first node that does not), and why, for the log."""
        deadline = time.monotonic() + CAPABILITY_TIMEOUT
        # an endpoint can be discovered before the name of its node (which DDS learns apart): wait for the names
        while UNKNOWN_NODE in (nodes := self.policy_nodes()) and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)
        for name in nodes:
            client = AsyncParameterClient(self.node, name)
            if not client.wait_for_services(timeout_sec=CAPABILITY_TIMEOUT):
                return False, f"one a message: {name} offers no parameter services within {CAPABILITY_TIMEOUT:g} s"
            future = client.get_parameters([P.PROBE_BATCHES])
            deadline = time.monotonic() + self.timeout
            while not future.done() and time.monotonic() < deadline:
                self.executor.spin_once(timeout_sec=0.05)
            values = future.result().values if future.done() else []  # none for a parameter it never declared
            if not values or values[0].type != ParameterType.PARAMETER_BOOL or not values[0].bool_value:
                return False, f"one a message: {name} does not declare {P.PROBE_BATCHES} true"
        if not nodes:
            return False, f"one a message: no node publishes on {P.ACTION}"
        return True, f"in batches: {', '.join(nodes)} declare{'s' if len(nodes) == 1 else ''} {P.PROBE_BATCHES} true"

    def policy_nodes(self) -> list[str]:
        """The full names of the nodes publishing on ``action``."""
        return [f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in self.node.get_publishers_info_by_topic(P.ACTION)]

    def act(self, obs: np.ndarray) -> np.ndarray:
        if self.batches is None:
            self.batches, why = self.answers_in_batches()
            self.node.get_logger().info(f"probes to the policy: {why}")
        rows = np.atleast_2d(obs)
        size = BATCH_ROWS if self.batches else 1
        chunks = [rows[i:i + size] for i in range(0, len(rows), size)]
        tags = [ProbeTag(self.step, self.asked + i * size, len(chunk)) for i, chunk in enumerate(chunks)]
        self.asked += len(rows)
        self.waiting.update(map(str, tags))
        self.publish(zip(tags, chunks))
        deadline, resend = time.monotonic() + self.timeout, time.monotonic() + RESEND_AFTER
        while self.waiting:
            if not self.answered and time.monotonic() > resend:
                self.publish((tag, chunk) for tag, chunk in zip(tags, chunks) if str(tag) in self.waiting)
                resend = time.monotonic() + RESEND_AFTER
            if time.monotonic() > deadline:
                missing = sum(tag.rows for tag in tags if str(tag) in self.waiting)
                self.waiting.clear()
                raise RemotePolicyError(f"the policy node did not answer {missing} of {len(rows)} probes "
                                        f"of step {self.step} within {self.timeout:.0f} s")
            self.executor.spin_once(timeout_sec=0.05)
        answers = [self.replies.pop(str(tag)) for tag in tags]
        for answer, tag in zip(answers, tags):
            if answer.size != tag.rows * self.layout.act_dim:
                batch = f" to probe batch {tag} ({tag.rows} probes)" if tag.rows > 1 else ""
                raise RemotePolicyError(f"the policy node answered {answer.size} action values{batch}, "
                                        f"{self.layout.env_id} takes {self.layout.act_dim}" + (" a probe" if batch else ""))
        actions = np.concatenate(answers).reshape(len(rows), self.layout.act_dim)
        return actions[0] if np.ndim(obs) == 1 else actions

    def publish(self, probes) -> None:
        """Each probe (a tag and its rows) as one message, the rows' values one after the other."""
        for tag, chunk in probes:
            self.pub.publish(joint_state(step_header(tag, self.stamp_ns), self.layout.names, chunk.ravel()))

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

"""rclpy plumbing shared by the nodes: QoS, JointState messages, the spin loop, fatal errors."""
from __future__ import annotations

import array
import os
import sys
import time
import traceback
import typing

import numpy as np
import rclpy
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import get_default_context
from sensor_msgs.msg import JointState

from aril_ros import protocol as P
from aril_ros.protocol import ProbeTag, StepTag

STEP_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_ALL,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
    depth=1,
)


# Latched, so the orchestrator hears a node's announcement however late it subscribes.
READY_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    depth=10,
)


class ReadyAnnouncer:
    """Publishes the node's name on ``graph/ready`` once every one of its endpoints is matched.

    DDS shows an endpoint in the graph well before (sometimes over a second before) it is matched
    with its peers, and a step message sent before that is lost for good. Each node therefore checks
    its own publishers' subscriber counts and subscriptions' publisher counts; the orchestrator
    starts the first episode only when every node has announced itself.
    """

    def __init__(self, node: Node, checks: dict):
        from std_msgs.msg import String

        self.node, self.checks = node, checks
        self.pub = node.create_publisher(String, P.READY, READY_QOS)
        self.message = String(data=node.get_name())
        self.started = node.get_clock().now()
        self.last_report = 0.0
        self.timer = node.create_timer(0.02, self.check)

    def check(self) -> None:
        waiting = [what for what, ok in self.checks.items() if not ok()]
        if not waiting:
            self.pub.publish(self.message)
            self.timer.cancel()
            return
        waited = (self.node.get_clock().now() - self.started).nanoseconds / 1e9
        if waited - self.last_report > 2.0:
            self.last_report = waited
            self.node.get_logger().info("waiting for " + ", ".join(waiting))


def subscribers(publisher, n: int):
    return lambda: publisher.get_subscription_count() >= n


def publishers(subscription, n: int = 1):
    return lambda: subscription.get_publisher_count() >= n


class FatalNodeError(RuntimeError):
    """Raised inside a callback to stop the node with a clear last error (exit code 1)."""


class IntruderError(FatalNodeError):
    """A publisher or service client that is not one of the run's own nodes took part in a step."""


UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"  # what the graph calls an endpoint whose node has not announced itself yet


def endpoint_text(info) -> str:
    """``node '/name' (GID 01.0f...)`` of a ``TopicEndpointInfo``: what an error names an endpoint by."""
    name = "(not announced)" if info.node_name == UNKNOWN_NODE else info.node_name
    return f"node '{info.node_namespace.rstrip('/')}/{name}' (GID {bytes(info.endpoint_gid).hex('.')})"


GRAPH_POLL = 0.05
"""Seconds between two looks at a service's endpoints in the graph by its guard: listing them costs a graph query
per call, too much for every request of a step. In between, the service's client and server counts stand in (a
new client or server raises them)."""


class PublisherGuard:
    """Who may publish on one topic, or call (or serve) one service, of a run.

    rclpy hands a subscription callback no publisher GID, so a receiver cannot tell who sent a message. What it
    can know is which publishers are matched: once :meth:`admit` has admitted those of the moment, any publisher
    matched later is an intruder. Its matched event is queued before any message of it (DDS matches a writer
    before it accepts its data) and marks the topic as intruded for good, even if the intruder leaves at once;
    :meth:`check`, called before a message or a request is used, raises :class:`IntruderError` once the topic is
    intruded or more publishers are matched than were admitted (for a service: once it has more clients or servers
    than were admitted, or, looked at every :data:`GRAPH_POLL` seconds, the graph shows one that was not). The error
    names the intruder's node and GID.

    For a service the publishers are the DDS writers of its request topic (its clients) and of its reply topic
    (its servers): ``rq<service>Request`` and ``rr<service>Reply``, the mangling of every DDS rmw.
    """

    def __init__(self, node: Node, name: str, service: bool = False):
        self.node = node
        self.service = None  # a service's resolved name
        if service:
            resolved = node.resolve_service_name(name)
            self.what = f"service {resolved}"
            self.service = resolved
            self.graph_names = ((f"rq{resolved}Request", True), (f"rr{resolved}Reply", True))
        else:
            resolved = node.resolve_topic_name(name)
            self.what = f"topic {resolved}"
            self.graph_names = ((resolved, False),)
        self.subscription = None  # a guarded subscription's matched count stands in for the graph
        self.next_graph_look = 0.0  # a service's: when check() next lists its endpoints
        self.admitted: set[bytes] | None = None  # GIDs, once admitted
        # publishers ever matched (DDS's total count): before admit() (a publisher may have come and gone, like a
        # probe client the attacker closes), then those admitted; more later is an intruder, even one gone again
        self.matched_total = 0
        self.intruded = False

    def publishers(self, wait: float = 0.0, until=lambda infos: True) -> list:
        """The publishers the graph shows now; with ``wait``, once it knows every one's node name (a node
        announces its name apart from its endpoints, so for a moment the graph has a GID alone) and ``until(them)``
        holds, or after ``wait`` seconds with what it knows."""
        deadline = time.monotonic() + wait
        while True:
            infos = [info for name, no_mangle in self.graph_names
                     for info in self.node.get_publishers_info_by_topic(name, no_mangle=no_mangle)]
            if (all(info.node_name != UNKNOWN_NODE for info in infos) and until(infos)) or time.monotonic() >= deadline:
                return infos
            time.sleep(0.05)

    def admit(self, wait: float = 5.0) -> list:
        """Admit the publishers connected now; returns them. A guarded subscription's matched count must agree
        with the graph (matching and the graph are both updated on discovery, not at the same instant), or a
        publisher admitted by count but not by GID would later pass for an intruder; ``wait`` bounds the wait."""
        infos = self.publishers(wait=wait, until=lambda infos: self.matched_count() == len(infos))
        self.admitted = {bytes(info.endpoint_gid) for info in infos}
        self.matched_total = max(self.matched_total, len(self.admitted))
        return infos

    def matched_count(self) -> int:
        """What stands in for the graph between two looks at it: the publishers matched with the guarded
        subscription, or a service's clients and servers (one request writer, one reply writer each)."""
        if self.service is None:
            return self.subscription.get_publisher_count()
        return self.node.count_clients(self.service) + self.node.count_services(self.service)

    def on_matched(self, info) -> None:
        # marked, not raised: an exception in an event callback is also logged by the executor, with its trace
        if self.admitted is None:
            self.matched_total = info.total_count
        else:
            self.intruded |= info.total_count > self.matched_total

    def check(self) -> None:
        """Before a message or a request is used: refuse it if a publisher not admitted is (or was) matched."""
        if self.admitted is None:
            return
        self.intruded |= self.matched_count() > len(self.admitted)
        if self.service is not None and time.monotonic() >= self.next_graph_look:  # one that replaced an admitted one
            self.next_graph_look = time.monotonic() + GRAPH_POLL
            self.intruded |= any(bytes(info.endpoint_gid) not in self.admitted for info in self.publishers())
        if self.intruded:
            self.refuse()

    def refuse(self, wait: float = 1.0):
        # the count that gave the intruder away may come before the graph lists its endpoint (a service client's
        # reply reader can be discovered before its request writer): look again for up to ``wait`` seconds
        def stranger(info) -> bool:
            return bytes(info.endpoint_gid) not in self.admitted

        strangers = [info for info in self.publishers(wait=wait, until=lambda infos: any(map(stranger, infos)))
                     if stranger(info)]
        who = (", ".join(endpoint_text(info) for info in strangers) if strangers
               else "a publisher that left before it could be named")
        raise IntruderError(f"intruder on {self.what}: {who}, not one of this run's nodes; the run stops rather "
                            "than go on with data it may have injected")

    def describe(self) -> str:
        """The admitted publishers, for an error about one of their messages."""
        infos = [info for info in self.publishers(wait=1.0)
                 if self.admitted is None or bytes(info.endpoint_gid) in self.admitted]
        return " or ".join(endpoint_text(info) for info in infos) or "a publisher that has left"


def guarded_subscription(node: Node, msg_type, topic: str, callback, qos, raw: bool = False) -> PublisherGuard:
    """A subscription (``.subscription`` of the result) whose publishers a :class:`PublisherGuard` watches."""
    guard = PublisherGuard(node, topic)
    guard.subscription = node.create_subscription(msg_type, topic, callback, qos, raw=raw,
                                                  event_callbacks=SubscriptionEventCallbacks(matched=guard.on_matched))
    return guard


def float64_array(values) -> array.array:
    """Values for a float64 sequence field of a message: an ``array('d')`` is taken as it is and serialised as one
    block, where a list is checked and converted value by value (twice the cost of a whole JointState's publish)."""
    return array.array("d", np.ascontiguousarray(values, dtype=np.float64).tobytes())


def joint_state(header, names, position=None, effort=None) -> JointState:
    msg = JointState()
    msg.header = header
    msg.name = list(names)
    if position is not None:
        msg.position = float64_array(position)
    if effort is not None:
        msg.effort = float64_array(effort)
    return msg


def step_header(tag: StepTag | ProbeTag, stamp_ns: int):
    from std_msgs.msg import Header

    header = Header()
    header.stamp.sec, header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    header.frame_id = str(tag)
    return header


def request_params(request) -> dict:
    """``{name: python value}`` of a SetParametersAtomically request."""
    return {p.name: parameter_value_to_python(p.value) for p in request.parameters}


def param_msg(name: str, value) -> ParameterMsg:
    """A ``rcl_interfaces/Parameter`` for an int, a string or a float sequence."""
    v = ParameterValue()
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        v.type, v.integer_value = ParameterType.PARAMETER_INTEGER, int(value)
    elif isinstance(value, str):
        v.type, v.string_value = ParameterType.PARAMETER_STRING, value
    else:
        v.type = ParameterType.PARAMETER_DOUBLE_ARRAY
        v.double_array_value = float64_array(value)
    return ParameterMsg(name=name, value=v)


def declared(node: Node, name: str, default):
    return node.declare_parameter(name, default).value


def spin(node: Node) -> int:
    """Spin until shutdown; a :class:`FatalNodeError` (or any crash) is logged and gives exit code 1.

    Uses ``EventsExecutor`` driven by ``spin_once``: about twice the rate of the default executor.
    """
    executor = EventsExecutor()
    executor.add_node(node)
    code = 0
    try:
        while rclpy.ok():
            executor.spin_once(timeout_sec=0.2)
    except (KeyboardInterrupt, ExternalShutdownException):  # Ctrl-C, or SIGINT through rclpy's handler: a stop
        pass
    except FatalNodeError as err:
        print(f"[{node.get_name()}] FATAL: {err}", file=sys.stderr, flush=True)
        code = 1
    except Exception as err:  # a crash in a callback: report it the same way, with the trace
        traceback.print_exc()
        print(f"[{node.get_name()}] FATAL: {type(err).__name__}: {err}", file=sys.stderr, flush=True)
        code = 1
    finally:
        executor.shutdown()
        node.destroy_node()
        if rclpy.ok():
            rclpy.try_shutdown()
    return code


def main_for(node_class, args=None) -> typing.NoReturn:
    """Run ``node_class`` as this process, then end the process: exit code 0 on shutdown, 1 on a fatal error.

    Once the node is destroyed and its ROS context too (its DDS participant leaves the graph, its shared
    memory is released), the process ends at once (``os._exit``): Python's own teardown of torch and the
    DDS libraries would take another 0.5-1.5 s per node on a loaded machine, with nothing left to clean.
    """
    rclpy.init(args=args)
    try:
        node = node_class()
    except Exception as err:  # bad parameters, missing policy file, unknown env: say so and stop
        print(f"[{node_class.__name__}] FATAL: {err}", file=sys.stderr, flush=True)
        rclpy.try_shutdown()
        code = 1
    else:
        code = spin(node)
    get_default_context().destroy()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)

"""rclpy plumbing shared by the nodes: QoS, JointState messages, the spin loop, fatal errors."""
from __future__ import annotations

import os
import sys
import traceback
import typing

import numpy as np
import rclpy
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
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


def joint_state(header, names, position=None, effort=None) -> JointState:
    msg = JointState()
    msg.header = header
    msg.name = list(names)
    if position is not None:
        msg.position = np.asarray(position, dtype=np.float64).tolist()
    if effort is not None:
        msg.effort = np.asarray(effort, dtype=np.float64).tolist()
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
        v.double_array_value = np.asarray(value, dtype=np.float64).tolist()
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
    except KeyboardInterrupt:
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

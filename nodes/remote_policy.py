"""A policy reached over ROS: any node that answers ``observation`` with ``action`` (the documented
policy contract), used as a black-box victim, e.g. for ``aril train-adversary victim:=ros``: the
``aril_ros.victims`` entry point ``ros`` is :class:`RemotePolicy` itself.

``RemotePolicy.act(batch)`` publishes one ``observation`` per row, tagged ``"<batch>/<row>"``, and
waits for every tagged ``action``; the policy node needs nothing but the contract in msgs_doc/.
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
from aril_ros.protocol import StepTag
from aril_ros_nodes.common import STEP_QOS, joint_state, step_header


class RemotePolicyError(ConnectionError):
    """No policy node answers, or it stopped answering."""


class RemotePolicy:
    def __init__(self, env_id: str, timeout: float = 10.0, connect_timeout: float = 30.0):
        self.layout = layout_of(env_id)
        self.timeout = timeout
        self.meta = SimpleNamespace(provenance={"victim": "a policy node reached over ROS (black box)"})
        self.context = rclpy.Context()
        rclpy.init(args=[], context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("adversary_trainer", context=self.context)
        self.pub = self.node.create_publisher(JointState, P.OBSERVATION, STEP_QOS)
        self.replies: dict[str, np.ndarray] = {}
        self.sub = self.node.create_subscription(JointState, P.ACTION, self.on_action, STEP_QOS)
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.batch = 0
        deadline = time.monotonic() + connect_timeout
        while self.pub.get_subscription_count() < 1 or self.sub.get_publisher_count() < 1:
            if time.monotonic() > deadline:
                self.close()
                raise RemotePolicyError(f"no policy node subscribes to {P.OBSERVATION} and publishes {P.ACTION} "
                                        f"within {connect_timeout:.0f} s (ROS_DOMAIN_ID and the node running?)")
            self.executor.spin_once(timeout_sec=0.05)

    def on_action(self, msg: JointState) -> None:
        self.replies[msg.header.frame_id] = np.asarray(msg.effort, dtype=np.float64)

    def act(self, obs: np.ndarray) -> np.ndarray:
        rows = np.atleast_2d(obs)
        tags = [str(StepTag(self.batch, i)) for i in range(len(rows))]
        for i, row in enumerate(rows):
            self.pub.publish(joint_state(step_header(StepTag(self.batch, i), 0), self.layout.names, row))
        self.batch += 1
        deadline = time.monotonic() + self.timeout
        while any(tag not in self.replies for tag in tags):
            if time.monotonic() > deadline:
                missing = sum(tag not in self.replies for tag in tags)
                raise RemotePolicyError(f"the policy node did not answer {missing} of {len(tags)} observations "
                                        f"within {self.timeout:.0f} s")
            self.executor.spin_once(timeout_sec=0.05)
        actions = np.stack([self.replies.pop(tag) for tag in tags])
        if actions.shape[1] != self.layout.act_dim:
            raise RemotePolicyError(f"the policy node answered {actions.shape[1]} action values, "
                                    f"{self.layout.env_id} takes {self.layout.act_dim}")
        return actions[0] if np.ndim(obs) == 1 else actions

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

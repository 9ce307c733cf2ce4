"""Policy node: answers each ``observation`` with an ``action`` carrying the same header.

Parameters: ``env``, ``policy`` (a bundled name such as ``expert`` or a policy file path) and ``mode``
(sensory | physical: which of the per-mode bundled learners ``dr`` and ``aril`` to load; unused for
other names and files), ``probe_batches`` (default true: it declares that it answers a probe batch, several
observations in one message, with their actions in one message; false makes a query-based attack ask one
probe a message). Any node that does the same on these two topics can replace it
(``run_graph.py policy:=external``).
"""
from __future__ import annotations

import numpy as np
import torch
from rclpy.node import Node
from sensor_msgs.msg import JointState

from aril_ros import protocol as P
from aril_ros.envs import layout_of
from aril_ros.policy import resolve_policy
from aril_ros.registry import DEFAULT_ENV
from aril_ros_nodes.common import STEP_QOS, ReadyAnnouncer, declared, joint_state, main_for, publishers, subscribers


class PolicyNode(Node):
    """Maps ``in_topic`` observations to ``out_topic`` actions with a policy file.

    ``listeners`` (parameter; default ``out_subscribers``): how many subscribers on ``out_topic`` to wait
    for before announcing ready -- the simulator and the recorder, and the attacker's probe client when
    the attack queries the policy. A count that others can fill would let the node answer step 0 before
    the simulator has matched its publisher, and that action would be lost.
    """

    def __init__(self, name="policy", in_topic=P.OBSERVATION, out_topic=P.ACTION, default_policy="expert",
                 out_subscribers=2):
        super().__init__(name)
        torch.set_num_threads(1)  # one observation at a time: more threads only contend for the cores
        env_id = declared(self, "env", DEFAULT_ENV)
        self.policy = resolve_policy(declared(self, name, default_policy), env_id, declared(self, "mode", "") or None)
        self.names = layout_of(env_id).action_names
        self.pub = self.create_publisher(JointState, out_topic, STEP_QOS)
        sub = self.create_subscription(JointState, in_topic, self.on_observation, STEP_QOS)
        declared(self, P.PROBE_BATCHES, True)  # read by the attacker's probe client, which then asks in batches
        listeners = declared(self, "listeners", out_subscribers)
        self.ready = ReadyAnnouncer(self, {f"a publisher on {in_topic}": publishers(sub),
                                           f"{listeners} subscribers on {out_topic}": subscribers(self.pub, listeners)})

    def on_observation(self, msg: JointState) -> None:
        obs = np.asarray(msg.position, dtype=np.float64)
        rows = P.probe_rows(msg.header.frame_id)
        # a batch's rows in one call: the policy acts on each row as it would alone (16-row blocks)
        action = self.policy.act(obs.reshape(rows, -1) if rows > 1 else obs)
        self.pub.publish(joint_state(msg.header, self.names, effort=np.ravel(action)))


def main(args=None):
    main_for(PolicyNode, args)


if __name__ == "__main__":
    main()

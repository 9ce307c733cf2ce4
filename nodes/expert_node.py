"""Expert labelling node: labels every true state (``sim/state``) with the expert's action.

Parameters: ``env``, ``expert`` (a bundled name or a policy file path). Publishes ``expert/action``
with the header of the state it labels.
"""
from __future__ import annotations

from aril_ros import protocol as P
from aril_ros_nodes.common import main_for
from aril_ros_nodes.policy_node import PolicyNode


class ExpertNode(PolicyNode):
    def __init__(self):
        super().__init__("expert", in_topic=P.STATE, out_topic=P.EXPERT_ACTION, default_policy="expert",
                         out_subscribers=1)  # the recorder


def main(args=None):
    main_for(ExpertNode, args)


if __name__ == "__main__":
    main()

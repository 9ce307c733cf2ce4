"""Issue 16: the most any redesign of the recorder can give the graph. Runs, in turn, the bare rclpy chain
(:mod:`benchmarks.graph.bare_chain`), the graph as it is, and the graph whose orchestrator drops every subscription
but ``sim/reward`` once the graph is connected (it still counts steps and returns from the rewards, so the episodes
end as usual), in sensory and physical mode; prints steps/s and each graph's ratio to the bare chain.

Dropping the subscriptions takes off what recording costs anywhere: the recorder's process and the 7 deliveries
per step it needs besides the reward. Recording in the simulator's process instead would still pay the writing and
the deliveries of the other nodes' topics, so the ratio of the graph without a recorder bounds that design from
above. Only this process's orchestrator is changed (patched below); the four nodes run as in every run.

    .venv/bin/python -m benchmarks.scripts.graph_without_recorder 4000 2
"""
from __future__ import annotations

import sys

import numpy as np


def reward_only(client, recorder) -> None:
    """``client`` (a connected :class:`~aril_ros_nodes.orchestrator.GraphClient`) unsubscribes from every step
    topic and hears ``sim/reward`` alone, adding each step's reward to ``recorder``'s episode."""
    from sensor_msgs.msg import JointState

    from aril_ros import protocol as P
    from aril_ros.mcap_log import cdr_joint_values
    from aril_ros_nodes.common import STEP_QOS

    for guard in client.guards.values():
        client.node.destroy_subscription(guard.subscription)
    client.guards = {}  # no guard left to check: spin() looks at none

    def on_reward(raw: bytes) -> None:
        reward, terminated, truncated = cdr_joint_values(raw, "position")
        none = np.zeros(1)  # no action, expert action or perturbation is heard
        recorder.count_step(reward, none, none, none, done=bool(terminated or truncated))

    client.node.create_subscription(JointState, P.REWARD, on_reward, STEP_QOS, raw=True)


def patch_orchestrator() -> None:
    """After admission, every GraphClient of this process hears the reward alone."""
    from aril_ros_nodes import orchestrator

    original_init, original_admit = orchestrator.GraphClient.__init__, orchestrator.GraphClient.admit

    def init(self, recorder, camera=False):
        original_init(self, recorder, camera)
        self.recorder = recorder

    def admit(self, own_nodes, external_policy):
        original_admit(self, own_nodes, external_policy)
        reward_only(self, self.recorder)

    orchestrator.GraphClient.__init__, orchestrator.GraphClient.admit = init, admit


def main(argv):
    import torch

    steps, repeats = (int(argv[0]) if argv else 4000), (int(argv[1]) if len(argv) > 1 else 2)
    torch.set_num_threads(1)
    from aril_ros_nodes import orchestrator
    from benchmarks.graph.bench_graph import GraphBenchConfig, bare_chain_steps_per_s, graph_steps_per_s

    cfg = GraphBenchConfig(steps=steps)
    as_is = (orchestrator.GraphClient.__init__, orchestrator.GraphClient.admit)
    for _ in range(repeats):
        bare = bare_chain_steps_per_s(steps)
        figures = []
        for mode in ("sensory", "physical"):
            orchestrator.GraphClient.__init__, orchestrator.GraphClient.admit = as_is
            graph = graph_steps_per_s(cfg, mode, record=False)
            patch_orchestrator()
            bound = graph_steps_per_s(cfg, mode, record=False)
            figures.append(f"{mode}: graph {graph:.0f} ({graph / bare:.2f}), without a recorder {bound:.0f} "
                           f"({bound / bare:.2f})")
        print(f"bare chain {bare:.0f} steps/s; " + "; ".join(figures), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])

"""Issue 16: what one more subscriber on every step topic costs the bare rclpy chain (the graph's recorder hears all
of a step's messages; the bare chain has no recorder). Runs the bare chain (:mod:`benchmarks.graph.bare_chain`) alone
and with a fifth process subscribing raw to its four topics, in turn, ``repeats`` times; prints steps/s of each.

    .venv/bin/python -m benchmarks.scripts.bare_chain_listener 3000 2
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

LISTENER = """
import rclpy
from rclpy.experimental import EventsExecutor
from sensor_msgs.msg import JointState
from aril_ros_nodes.common import STEP_QOS
from benchmarks.graph.bare_chain import TOPICS
rclpy.init()
node = rclpy.create_node("listener")
for topic in {"state", "action"} | {out for _, out in TOPICS.values()}:
    node.create_subscription(JointState, topic, lambda raw: None, STEP_QOS, raw=True)
executor = EventsExecutor()
executor.add_node(node)
try:
    while rclpy.ok():
        executor.spin_once(timeout_sec=0.2)
except KeyboardInterrupt:
    pass
"""


def measure(steps: int, listener: bool) -> float:
    from aril_ros.protocol import ros_domain
    from aril_ros_nodes.orchestrator import allocate_domain
    from benchmarks.graph import bare_chain

    domain, lock = allocate_domain("auto")
    try:
        with ros_domain(domain):
            extra = subprocess.Popen([sys.executable, "-c", LISTENER]) if listener else None
            try:
                time.sleep(2.0 if listener else 0.0)  # the listener's subscriptions exist before the chain starts
                return bare_chain.steps_per_s(steps, dict(os.environ))
            finally:
                if extra is not None:
                    extra.send_signal(signal.SIGINT)
                    extra.wait()
    finally:
        lock.close()


def main(argv):
    steps, repeats = (int(argv[0]) if argv else 3000), (int(argv[1]) if len(argv) > 1 else 2)
    for _ in range(repeats):
        print(f"bare chain {measure(steps, False):.0f} steps/s, with a listener on its 4 topics "
              f"{measure(steps, True):.0f}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])

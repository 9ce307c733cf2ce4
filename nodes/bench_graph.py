"""Graph throughput: steps/s of the ROS 2 graph per mode, with and without recording, beside the
in-process engine and a bare two-process rclpy ping-pong (the practical limit of one hop).

    .venv/bin/python -m aril_ros_nodes.bench_graph env:=HalfCheetah-v5 steps:=2000

The graph figure is ``steps_per_s`` of the orchestrator behind ``run_graph.py`` (episodes only,
start-up excluded); the engine runs the same policy, expert, attack and episode length with one env
(``n_envs:=1``, like the graph) and with 32. The last line is the figures as JSON (what ``aril report``
reads: this module is the ``aril_ros.benchmarks`` entry point ``graph``).
"""
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from aril_ros.args import arg, parse_args, usage
from aril_ros.attacks import make_attack
from aril_ros.envs import layout_of
from aril_ros.policy import resolve_policy
from aril_ros.registry import DEFAULT_ENV, MODES, attack_for_mode
from aril_ros.rollout import RolloutEngine
from aril_ros_nodes.orchestrator import GraphConfig, GraphError, Orchestrator, allocate_domain

PONG = r"""
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from sensor_msgs.msg import JointState
from aril_ros_nodes.common import STEP_QOS
rclpy.init()
node = rclpy.create_node("pong")
pub = node.create_publisher(JointState, "pong", STEP_QOS)
node.create_subscription(JointState, "ping", pub.publish, STEP_QOS)
executor = EventsExecutor()
executor.add_node(node)
try:
    while rclpy.ok():
        executor.spin_once(timeout_sec=0.2)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
"""


@dataclass
class GraphBenchConfig:
    """Arguments of ``python -m aril_ros_nodes.bench_graph``."""

    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    steps: int = arg(2000, "steps per graph measurement (whole episodes of this length)")
    eps: float = arg(0.05, "attack budget")
    seconds: float = arg(5.0, "length of the ping-pong measurement")


def graph_steps_per_s(cfg, mode: str, record: bool) -> float:
    """The orchestrator's ``steps_per_s`` for two episodes of ``steps / 2`` (the default policy and expert)."""
    log = Path(tempfile.gettempdir()) / "aril_bench_graph.mcap"
    graph = GraphConfig(mode=mode, env=cfg.env, attack=attack_for_mode(mode), eps=cfg.eps, episodes=2,
                        horizon=cfg.steps // 2, record=str(log) if record else "off")
    try:
        return Orchestrator(graph, log=lambda *a, **k: None).run()["steps_per_s"]
    except (ValueError, GraphError) as err:
        raise SystemExit(f"the graph run ({mode}) failed: {err}") from None


def engine_steps_per_s(cfg, mode: str, n_envs: int) -> float:
    expert = resolve_policy("expert", cfg.env)
    attack = make_attack(attack_for_mode(mode), layout_of(cfg.env), cfg.eps)
    engine = RolloutEngine(cfg.env, expert, expert, attack, mode, n_envs=n_envs, horizon=cfg.steps // 2)
    started = time.perf_counter()
    traj = engine.rollout(max(2, n_envs), seed=0)
    return int(traj.length.sum()) / (time.perf_counter() - started)


def ping_pong_per_s(seconds: float) -> float:
    import rclpy
    from rclpy.experimental import EventsExecutor
    from sensor_msgs.msg import JointState

    from aril_ros_nodes.common import STEP_QOS

    domain, lock = allocate_domain("auto")
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    pong = subprocess.Popen([sys.executable, "-c", PONG], env=env)
    rclpy.init(args=[])
    node = rclpy.create_node("ping")
    pub = node.create_publisher(JointState, "ping", STEP_QOS)
    replies = []
    sub = node.create_subscription(JointState, "pong", replies.append, STEP_QOS)
    executor = EventsExecutor()
    executor.add_node(node)
    try:
        while pub.get_subscription_count() < 1 or sub.get_publisher_count() < 1:
            executor.spin_once(timeout_sec=0.05)
        time.sleep(0.5)
        msg = JointState(position=[0.0] * 17)
        count, started = 0, time.perf_counter()
        while time.perf_counter() - started < seconds:
            pub.publish(msg)
            while len(replies) <= count:
                executor.spin_once(timeout_sec=1.0)
            count += 1
        return count / (time.perf_counter() - started)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        pong.terminate()
        pong.wait()
        lock.close()


def main(argv):
    if "--help" in argv or "-h" in argv:
        print(usage(GraphBenchConfig, "python -m aril_ros_nodes.bench_graph", __doc__.strip().splitlines()[0]))
        return
    cfg = parse_args(GraphBenchConfig, argv)
    import torch

    torch.set_num_threads(1)
    rows = {}
    for mode in MODES:
        rows[mode] = {
            "graph": graph_steps_per_s(cfg, mode, record=False),
            "graph+record": graph_steps_per_s(cfg, mode, record=True),
            "engine n_envs=1": engine_steps_per_s(cfg, mode, 1),
            "engine n_envs=32": engine_steps_per_s(cfg, mode, 32),
        }
    ping = ping_pong_per_s(cfg.seconds)
    columns = list(rows["clean"])
    print(f"{cfg.env}: steps/s ({cfg.steps} graph steps per cell); rclpy ping-pong {ping:.0f} round trips/s")
    print(f"{'mode':<10}" + "".join(f"{c:>18}" for c in columns) + f"{'graph/ping-pong':>17}")
    for mode, row in rows.items():
        print(f"{mode:<10}" + "".join(f"{row[c]:>18.0f}" for c in columns) + f"{row['graph'] / ping:>17.2f}")
    print(json.dumps({"env": cfg.env, "ping_pong_round_trips_per_s": round(ping, 1),
                      **{m: {k: round(v, 1) for k, v in r.items()} for m, r in rows.items()}}))


if __name__ == "__main__":
    main(sys.argv[1:])

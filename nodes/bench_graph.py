#!/usr/bin/env python3
"""Graph throughput: steps/s of the ROS 2 graph per mode, with and without recording, beside the
in-process engine and a bare two-process rclpy ping-pong (the practical limit of one hop).

    .venv/bin/python benchmarks/bench_graph.py env:=HalfCheetah-v5 steps:=2000

The graph figure is ``steps_per_s`` of ``run_graph.py`` (episodes only, start-up excluded); the
engine runs the same policy, expert, attack and episode length with one env (``n_envs:=1``, like
the graph) and with 32.
"""
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from aril_ros.args import arg, parse_args, usage  # noqa: E402
from aril_ros.attacks import make_attack  # noqa: E402
from aril_ros.envs import layout_of  # noqa: E402
from aril_ros.experts import resolve_policy  # noqa: E402
from aril_ros.rollout import RolloutEngine  # noqa: E402
from nodes.orchestrator import allocate_domain  # noqa: E402

PONG = r"""
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from sensor_msgs.msg import JointState
from nodes.common import STEP_QOS
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
    env: str = arg("HalfCheetah-v5", "gymnasium MuJoCo env id")
    steps: int = arg(2000, "steps per graph measurement (whole episodes of this length)")
    eps: float = arg(0.05, "attack budget")
    seconds: float = arg(5.0, "length of the ping-pong measurement")


def graph_steps_per_s(cfg, mode: str, record: bool) -> float:
    attack = "none" if mode == "clean" else "random"
    out = subprocess.run(
        [sys.executable, str(ROOT / "run_graph.py"), f"mode:={mode}", f"env:={cfg.env}", f"attack:={attack}",
         f"eps:={cfg.eps}", "episodes:=2", f"horizon:={cfg.steps // 2}",
         f"record:={'/tmp/aril_bench_graph.mcap' if record else 'off'}"],
        capture_output=True, text=True, cwd=ROOT)
    if out.returncode != 0:
        raise SystemExit(f"run_graph failed: {out.stderr}")
    return json.loads(out.stdout.strip().splitlines()[-1])["steps_per_s"]


def engine_steps_per_s(cfg, mode: str, n_envs: int) -> float:
    expert = resolve_policy("expert", cfg.env)
    attack = make_attack("none" if mode == "clean" else "random", layout_of(cfg.env), cfg.eps)
    engine = RolloutEngine(cfg.env, expert, expert, attack, mode, n_envs=n_envs, horizon=cfg.steps // 2)
    started = time.perf_counter()
    traj = engine.rollout(max(2, n_envs), seed=0)
    return int(traj.length.sum()) / (time.perf_counter() - started)


def ping_pong_per_s(seconds: float) -> float:
    import rclpy
    from rclpy.experimental import EventsExecutor
    from sensor_msgs.msg import JointState

    from nodes.common import STEP_QOS

    domain, lock = allocate_domain("auto")
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
           "PYTHONPATH": str(ROOT)}
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
        print(usage(GraphBenchConfig, "benchmarks/bench_graph.py", __doc__.strip().splitlines()[0]))
        return
    cfg = parse_args(GraphBenchConfig, argv)
    import torch

    torch.set_num_threads(1)
    rows = {}
    for mode in ("clean", "sensory", "physical"):
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

"""The bare rclpy chain the graph benchmark measures the graph against: the same four roles with nothing else.

    python -m benchmarks.graph.bare_chain --ros-args -p role:=policy    # or attacker, expert

A gymnasium HalfCheetah step (the simulator: :func:`steps_per_s`, in the benchmark's own process), an attacker
adding noise to the state, a 64x64 MLP policy acting on the noisy observation and a 256x256 MLP expert answering
every state: one plain rclpy node each, ``EventsExecutor`` driven by ``spin_once``, the step topics' QoS
(:data:`aril_ros_nodes.common.STEP_QOS`), ``JointState`` messages carrying the step tag and the values only. No
orchestrator, no recorder, no guards, no readiness protocol, no names in the messages: what the graph costs
beyond the bare chain is what the graph adds.
"""
from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import JointState

from aril_ros_nodes.common import STEP_QOS, main_for

CHECKOUT = Path(__file__).resolve().parents[2]
"""Where ``python -m benchmarks.graph.bare_chain`` finds this module (it is not installed)."""

ENV_ID = "HalfCheetah-v5"
OBS_DIM, ACT_DIM = 17, 6  # HalfCheetah's
HIDDEN = {"policy": 64, "expert": 256}  # the sizes of the bundled policy and expert MLPs
TOPICS = {"attacker": ("state", "observation"), "policy": ("observation", "action"),
          "expert": ("state", "expert_action")}  # role: (in, out)
NOISE = 0.05


def mlp(obs_dim: int, act_dim: int, hidden: int):
    import torch

    return torch.nn.Sequential(torch.nn.Linear(obs_dim, hidden), torch.nn.Tanh(), torch.nn.Linear(hidden, hidden),
                               torch.nn.Tanh(), torch.nn.Linear(hidden, act_dim), torch.nn.Tanh()).eval()


def answer_function(role: str):
    """``values -> values`` of a role: the attacker's noise, or an MLP's action."""
    import torch

    if role == "attacker":
        rng = np.random.default_rng(0)
        return lambda obs: obs + rng.uniform(-NOISE, NOISE, obs.shape)
    torch.set_num_threads(1)
    net = mlp(OBS_DIM, ACT_DIM, HIDDEN[role])

    def act(obs):
        with torch.no_grad():
            return net(torch.as_tensor(obs, dtype=torch.float32)).numpy().astype(np.float64)
    return act


class AnswerNode(Node):
    """One role of the chain (parameter ``role``): answers each message on its input topic on its output topic,
    with the same header."""

    def __init__(self):
        super().__init__("bare_chain")
        role = self.declare_parameter("role", "policy").value
        in_topic, out_topic = TOPICS[role]
        self.answer = answer_function(role)
        self.field = "position" if role == "attacker" else "effort"
        self.pub = self.create_publisher(JointState, out_topic, STEP_QOS)
        self.create_subscription(JointState, in_topic, self.on_message, STEP_QOS)

    def on_message(self, msg: JointState) -> None:
        values = self.answer(np.asarray(msg.position, dtype=np.float64))
        self.pub.publish(JointState(header=msg.header, **{self.field: values.tolist()}))


def steps_per_s(steps: int, env: dict, mark=lambda: None) -> float:
    """The chain's steps/s over ``steps`` steps (after a warm-up), its simulator in this process and the other
    three roles started as processes in ``env`` (which must hold the ROS domain: this process's own too).
    ``mark()`` is called as the measured steps start and once they are done (a profiler's window)."""
    import gymnasium as gym
    import rclpy
    from rclpy.experimental import EventsExecutor

    roles = [subprocess.Popen([sys.executable, "-m", "benchmarks.graph.bare_chain", "--ros-args",
                              "-p", f"role:={role}", "-r", f"__node:=bare_{role}"],
                              env=env, cwd=CHECKOUT) for role in TOPICS]  # this module is the checkout's only
    sim = gym.make(ENV_ID)
    obs, _ = sim.reset(seed=0)
    rclpy.init(args=[])
    node = rclpy.create_node("bare_simulator")
    state_pub = node.create_publisher(JointState, "state", STEP_QOS)
    actions, labelled = [], []
    action_sub = node.create_subscription(JointState, "action", actions.append, STEP_QOS)
    # the expert is off the chain's path and may fall behind: the time counts until it has labelled every state,
    # as the graph's counts until its recorder has every step's expert action
    label_sub = node.create_subscription(JointState, "expert_action", lambda msg: labelled.append(msg.header.frame_id),
                                         STEP_QOS)
    executor = EventsExecutor()
    executor.add_node(node)
    step = 0

    def publish_state():
        msg = JointState(position=obs.tolist())
        msg.header.frame_id = str(step)
        state_pub.publish(msg)

    try:
        while (state_pub.get_subscription_count() < 2 or action_sub.get_publisher_count() < 1
               or label_sub.get_publisher_count() < 1):
            executor.spin_once(timeout_sec=0.05)
            if any(role.poll() is not None for role in roles):
                raise RuntimeError("a process of the bare chain died while starting")
        warm_up, started = 100, None
        publish_state()
        asked = time.monotonic()
        while step < warm_up + steps:
            executor.spin_once(timeout_sec=0.5)
            mine = [a for a in actions if a.header.frame_id == str(step)]
            actions.clear()
            if not mine:  # a state sent before the attacker and the policy had matched each other is lost: again
                if time.monotonic() - asked > 2.0:
                    publish_state()
                    asked = time.monotonic()
                continue
            obs, _, terminated, truncated, _ = sim.step(np.asarray(mine[0].effort))
            if terminated or truncated:
                obs, _ = sim.reset()
            step += 1
            if step == warm_up:
                mark()
                started = time.perf_counter()
            if step < warm_up + steps:  # none after the last: the chain is idle when its processes are stopped
                publish_state()
            asked = time.monotonic()
        deadline = time.monotonic() + 10.0
        while str(step - 1) not in labelled[-1:]:
            executor.spin_once(timeout_sec=0.5)
            if time.monotonic() > deadline:
                raise RuntimeError("the bare chain's expert did not label the last state within 10 s")
        seconds = time.perf_counter() - started
        mark()
        return steps / seconds
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        for role in roles:
            role.send_signal(signal.SIGINT)
        for role in roles:
            role.wait()
        sim.close()


def main(args=None):
    main_for(AnswerNode, args)


if __name__ == "__main__":
    main()

"""Attacker node: perturbs the zero-order state within ±eps, as the mode says.

Parameters: ``env``, ``mode`` (clean | sensory | physical), ``attack`` (none | random | fgsm |
fgsm_k | spsa | aril_a), ``eps``, ``seed``, ``expert`` (the label of fgsm, fgsm_k, spsa and aril_a: the
testbed's own file, loaded here), ``k`` (steps of fgsm_k and spsa; 0: the attack's default), ``samples``
(spsa's directions per step; 0: its default); for the white-box attacks ``victim`` (the attacked policy: a
bundled name or a file); for aril_a ``attack_file``
(an adversary file) and ``search`` (query-time search over this many candidates; 0: none). ``eps`` 0
takes the calibrated one (:func:`aril_ros.registry.attack_budget`). Episode ``e`` draws its noise from
:func:`aril_ros.step.episode_rng`, like the in-process engine, so both give the same perturbations. A timing attack
(:mod:`aril_ros.timing`): ``delay`` (steps) and ``drop`` (a share of the steps), clean and sensory, played here;
``action_delay`` (steps), in every mode, chosen here and applied by the simulator as ``attack/timing`` says; and
``timing`` (``fixed``, ``random`` or ``learned``, drawn from :func:`aril_ros.step.timing_rng` as the engine does;
``learned`` plays the timing adversary file ``timing_file``).

The black-box attacks (spsa; aril_a when its adversary takes actions or searches) ask the policy node
itself, whichever it is: their victim is a :class:`aril_ros_nodes.remote_policy.RemotePolicy` that
publishes probes on ``observation`` and waits for their tagged ``action`` inside this node's step.

- clean / sensory: on ``sim/state`` publish ``attack/perturbation`` and ``observation``
  (:func:`aril_ros.step.sensory_observation`: state + delta); under a timing attack the observation delivered is that
  of an earlier step, or the one delivered last again (:class:`aril_ros.timing.Timeline`), and ``attack/timing``
  says which.
- physical: on ``sim/state`` and ``sim/physics_state`` of the same step, send the perturbed physical
  state (:func:`aril_ros.step.physical_state`) to ``sim/set_state``; the simulator then publishes the
  ``observation`` of the moved state, and this node publishes ``attack/perturbation`` once the service
  has accepted it.
"""
from __future__ import annotations

import numpy as np
import torch
from rcl_interfaces.srv import SetParametersAtomically
from rclpy.node import Node
from rclpy.time import Time
from sensor_msgs.msg import JointState

from aril_ros import protocol as P
from aril_ros.attacks import make_attack
from aril_ros.envs import layout_of
from aril_ros.policy import resolve_policy
from aril_ros.protocol import StepTag
from aril_ros.registry import DEFAULT_ENV, QUERY_ATTACKS, SURROGATE_ATTACKS, WHITE_BOX, attack_budget, attack_for_mode
from aril_ros.step import episode_rng, physical_state, sensory_observation, timing_rng
from aril_ros.timing import TimingAttack, TimingBudget
from aril_ros_nodes.common import (STEP_QOS, FatalNodeError, ReadyAnnouncer, declared, joint_state, main_for,
                                   param_msg, publishers, subscribers)
from aril_ros_nodes.remote_policy import RemotePolicy, RemotePolicyError


class AttackerNode(Node):
    def __init__(self):
        super().__init__("attacker")
        torch.set_num_threads(1)  # white-box attacks run small networks one observation at a time
        self.layout = layout_of(declared(self, "env", DEFAULT_ENV))
        self.mode = declared(self, "mode", "sensory")
        attack = attack_for_mode(self.mode, declared(self, "attack", ""))  # checks the mode and the attack
        victim_name, expert_name = declared(self, "victim", ""), declared(self, "expert", "expert")
        white_box = attack in WHITE_BOX
        if white_box and not victim_name:
            raise ValueError(f"attack {attack} is white-box: set the victim parameter to the attacked policy")
        env_id = self.layout.env_id
        # spsa always asks the policy node; aril_a does when its adversary takes actions or it searches,
        # which its file tells once the attack is made
        self.probes = (RemotePolicy(env_id, connect_timeout=None, name=P.PROBE_CLIENT,
                                    batches=declared(self, P.PROBE_BATCHES, True))
                       if attack in (*QUERY_ATTACKS, "aril_a") else None)
        self.attack = make_attack(
            attack, self.layout, attack_budget(env_id, self.mode, attack, declared(self, "eps", 0.0)),
            victim=resolve_policy(victim_name, env_id, self.mode) if white_box else self.probes,
            expert=(resolve_policy(expert_name, env_id)
                    if white_box or attack in SURROGATE_ATTACKS or self.probes is not None else None),
            steps=declared(self, "k", 0) or None, samples=declared(self, "samples", 0) or None,
            adversary=declared(self, "attack_file", ""), mode=self.mode, search=declared(self, "search", 0),
            rescale=declared(self, "rescale", False))
        if self.probes is not None and not self.attack.asks_victim:  # an adversary of the state alone, no search
            self.probes.close()
            self.probes = None
        self.seed = declared(self, "seed", 0)
        self.rng = None
        timing = TimingAttack(TimingBudget(declared(self, "delay", 0), declared(self, "drop", 0.0),
                                           declared(self, "action_delay", 0)), declared(self, "timing", "fixed"),
                              declared(self, "timing_file", ""))
        self.timing = timing if timing.budget.any else None
        if self.mode == "physical" and (timing.budget.delay or timing.budget.drop):
            raise ValueError("delay and drop are played on the observation this node publishes, which in mode physical "
                             "the simulator publishes")
        self.timeline = None
        self.perturbation_pub = self.create_publisher(JointState, P.PERTURBATION, STEP_QOS)
        state_sub = self.create_subscription(JointState, P.STATE, self.on_state, STEP_QOS)
        ready = {"a subscriber on attack/perturbation": subscribers(self.perturbation_pub, 1),
                 "a publisher on sim/state": publishers(state_sub)}
        if self.mode == "physical":
            self.physics: dict[str, JointState] = {}
            self.states: dict[str, JointState] = {}
            physics_sub = self.create_subscription(JointState, P.PHYSICS, self.on_physics, STEP_QOS)
            self.set_state = self.create_client(SetParametersAtomically, P.SET_STATE_SERVICE)
            ready.update({"a publisher on sim/physics_state": publishers(physics_sub),
                          "the sim/set_state service": self.set_state.service_is_ready})
        else:
            self.observation_pub = self.create_publisher(JointState, P.OBSERVATION, STEP_QOS)
            ready["2 subscribers on observation (the policy, the recorder)"] = subscribers(self.observation_pub, 2)

        if self.timing:  # the recorder records it; under an action delay the simulator applies what it says
            self.timing_pub = self.create_publisher(JointState, P.TIMING, STEP_QOS)
            ready["subscribers on attack/timing"] = subscribers(self.timing_pub, 1 + bool(timing.budget.action_delay))
        if self.probes is not None:  # the policy answers the probes, the recorder records them
            ready.update(self.probes.checks(listeners=2))
        self.ready = ReadyAnnouncer(self, ready)
        self.get_logger().info(f"{self.mode} attack {self.attack.name} eps={self.attack.eps}")

    def perturbation(self, state: JointState) -> tuple[np.ndarray, np.ndarray]:
        tag = StepTag.parse(state.header.frame_id)
        if tag.step == 0:  # a (re)started episode draws its noise from the start again
            self.rng = episode_rng(self.seed, tag.episode)
        true_obs = np.asarray(state.position, dtype=np.float64)
        if self.probes is not None:
            self.probes.begin_step(tag, Time.from_msg(state.header.stamp).nanoseconds)
        try:
            return true_obs, self.attack.perturb(true_obs[None], [self.rng])[0]
        except RemotePolicyError as err:  # the policy node stopped answering probes, or answered nonsense
            raise FatalNodeError(f"step {tag}: {err}") from None

    def on_state(self, msg: JointState) -> None:
        if self.mode == "physical":
            self.states[msg.header.frame_id] = msg
            self.try_physical(msg.header.frame_id)
            return
        true_obs, delta = self.perturbation(msg)
        observation = self.timed(msg.header, sensory_observation(true_obs, delta))
        # the policy waits for the observation, the recorder alone for the perturbation
        self.observation_pub.publish(joint_state(msg.header, self.layout.names, observation))
        self.perturbation_pub.publish(joint_state(msg.header, self.layout.names, delta))

    def timed(self, header, observation: np.ndarray) -> np.ndarray:
        """Under a timing attack, the observation delivered at this step (an earlier one, or the last delivered
        again), its ``attack/timing`` published first; else ``observation``. Physical: on time (no delay, no drop
        here), the timing saying the applied action's age alone."""
        if not self.timing:
            return observation
        tag = StepTag.parse(header.frame_id)
        if tag.step == 0:  # each episode's timing from its own stream, as on the engine
            self.timeline = self.timing.timeline(1, self.layout.obs_dim, self.layout.act_dim,
                                                 [timing_rng(self.seed, tag.episode)])
        shown, age, dropped = self.timeline.deliver(tag.step, observation[None], np.zeros(1, dtype=np.int64))
        self.timing_pub.publish(joint_state(header, P.TIMING_NAMES,
                                            [float(age[0]), float(dropped[0]), float(self.timeline.action_age()[0])]))
        return shown[0]

    def on_physics(self, msg: JointState) -> None:
        self.physics[msg.header.frame_id] = msg
        self.try_physical(msg.header.frame_id)

    def try_physical(self, tag: str) -> None:
        if tag not in self.states or tag not in self.physics:
            return  # the other half of this step has not arrived yet
        state, physics = self.states.pop(tag), self.physics.pop(tag)
        true_obs, delta = self.perturbation(state)
        self.timed(state.header, true_obs)  # on time: its timing says how old the action applied will be
        request = SetParametersAtomically.Request()
        request.parameters = [param_msg("state", physical_state(self.layout, physics.position, delta)),
                              param_msg("tag", tag)]
        future = self.set_state.call_async(request)
        future.add_done_callback(lambda f: self.on_set_state_done(f, state.header, delta))

    def on_set_state_done(self, future, header, delta) -> None:
        result = future.result().result
        if not result.successful:
            raise FatalNodeError(f"sim/set_state refused step {header.frame_id}: {result.reason}")
        self.perturbation_pub.publish(joint_state(header, self.layout.names, delta))

    def destroy_node(self):
        if self.probes is not None:
            self.probes.close()
        super().destroy_node()


def main(args=None):
    main_for(AttackerNode, args)


if __name__ == "__main__":
    main()

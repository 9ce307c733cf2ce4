"""Simulator node: one MuJoCo env, stepped in lockstep with the policy's actions.

Parameters: ``env`` (gymnasium MuJoCo id), ``horizon`` (steps per episode), ``mode`` (clean |
sensory | physical: which peers it waits for before announcing itself ready), ``render_every``
(0: off; n: a JPEG frame of every n-th step of an episode on ``sim/camera/image/compressed``, rendered offscreen,
which needs ``MUJOCO_GL=egl`` or ``osmesa`` in the node's environment) and ``render_size``
(``"<width>x<height>"``), ``action_delay`` (0: off; J: a timing attack's action delay, :mod:`aril_ros.timing`: the
action applied at step t is the policy's of step t - j, j <= J as the attacker's ``attack/timing`` of step t says,
rest before the episode's first; the step waits for both).

After ``sim/reset`` (seed, episode) it publishes step 0: ``sim/state``, ``sim/physics_state`` and
``/clock``. It steps only when the ``action`` tagged with the current step arrives (an action for
any other step is ignored with a warning, so no step is skipped or repeated; the answer to a probe,
tagged ``"<episode>/<step>/probe/<k>"``, is ignored without one), publishes
``sim/reward`` for that step and then the next step's state, until the episode ends.
``sim/set_state`` replaces the whole physical state at once (the physical attack; a state equal to the current one
is not written, :meth:`aril_ros.envs.MujocoSim.set_state`, so a zero perturbation is no perturbation) and publishes
the ``observation`` of the new state for the policy. A malformed action (wrong length, non-finite) stops
the node with a clear error.

Who it takes orders from is fixed at the first ``sim/reset``: the publisher on ``action`` then (one at most: the
policy) and the clients of its two services. A publisher or client that appears later is an intruder: the node
stops, naming its node and GID, before it applies anything (:class:`aril_ros_nodes.common.PublisherGuard`).
See msgs_doc/README.md.
"""
from __future__ import annotations

import numpy as np
from rcl_interfaces.srv import SetParametersAtomically
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from aril_ros import protocol as P
from aril_ros.envs import HORIZON, MujocoSim
from aril_ros.protocol import StepTag, stamp_ns
from aril_ros.registry import DEFAULT_ENV
from aril_ros.timing import ActionQueue
from aril_ros_nodes.common import (STEP_QOS, FatalNodeError, PublisherGuard, ReadyAnnouncer, declared,
                                   endpoint_text, guarded_subscription, joint_state, main_for, publishers,
                                   request_params, step_header, subscribers)


class SimulatorNode(Node):
    def __init__(self):
        super().__init__("simulator")
        self.sim = MujocoSim(declared(self, "env", DEFAULT_ENV), declared(self, "horizon", HORIZON))
        self.obs_names = list(self.sim.layout.names)
        self.state_names = self.sim.state_names  # built from the model on every call: once, not every step
        self.act_dim = self.sim.layout.act_dim
        self.tag: StepTag | None = None  # the step waiting for its action; None between episodes
        self.global_step = 0  # steps completed in this run: the sim clock
        self.clock_pub = self.create_publisher(Clock, P.CLOCK, STEP_QOS)
        self.physics_pub = self.create_publisher(JointState, P.PHYSICS, STEP_QOS)
        self.state_pub = self.create_publisher(JointState, P.STATE, STEP_QOS)
        self.reward_pub = self.create_publisher(JointState, P.REWARD, STEP_QOS)
        self.observation_pub = self.create_publisher(JointState, P.OBSERVATION, STEP_QOS)
        self.action_guard = guarded_subscription(self, JointState, P.ACTION, self.on_action, STEP_QOS)
        self.action_delay = declared(self, "action_delay", 0)
        self.order_guards = [(self.action_guard, P.ACTION, "the policy")]
        if self.action_delay:  # the attacker says how old the action applied is: it takes orders from it too
            self.timing_guard = guarded_subscription(self, JointState, P.TIMING, self.on_timing, STEP_QOS)
            self.order_guards.append((self.timing_guard, P.TIMING, "the attacker"))
        self.waiting: dict[str, object] = {}  # the current step's action and, under an action delay, its timing
        self.create_service(SetParametersAtomically, P.RESET_SERVICE, self.on_reset)
        self.create_service(SetParametersAtomically, P.SET_STATE_SERVICE, self.on_set_state)
        self.service_guards = {name: PublisherGuard(self, name, service=True)
                               for name in (P.RESET_SERVICE, P.SET_STATE_SERVICE)}
        self.render_every = declared(self, "render_every", 0)
        self.camera = self._camera(declared(self, "render_size", "320x240")) if self.render_every > 0 else None
        physical = declared(self, "mode", "sensory") == "physical"
        self.ready = ReadyAnnouncer(self, {  # the attacker, the expert and the recorder listen; the policy answers
            "3 subscribers on sim/state": subscribers(self.state_pub, 3),
            "subscribers on sim/physics_state": subscribers(self.physics_pub, 2 if physical else 1),
            "a subscriber on sim/reward": subscribers(self.reward_pub, 1),
            "a subscriber on /clock": subscribers(self.clock_pub, 1),
            "2 subscribers on observation": subscribers(self.observation_pub, 2 if physical else 0),
            "a publisher on action (the policy)": publishers(self.action_guard.subscription),
            **({"a publisher on attack/timing (the attacker)": publishers(self.timing_guard.subscription)}
               if self.action_delay else {}),
            **({"a subscriber on the camera": subscribers(self.camera_pub, 1)} if self.camera else {}),
        })
        self.get_logger().info(f"{self.sim.layout.env_id}: obs {len(self.obs_names)}, act {self.act_dim}")

    def _camera(self, size: str):
        from sensor_msgs.msg import CompressedImage

        from aril_ros.render import FrameRenderer, RenderError, frame_size

        try:
            camera = FrameRenderer(self.sim, *frame_size(size))
        except (ValueError, RenderError) as err:  # a bad size, one beyond MuJoCo's framebuffer, or no GL
            raise FatalNodeError(str(err)) from None
        self.camera_pub = self.create_publisher(CompressedImage, P.CAMERA, STEP_QOS)
        self._image_type = CompressedImage
        return camera

    def header(self):
        return step_header(self.tag, stamp_ns(self.global_step, self.sim.dt))

    def publish_step(self) -> None:
        """The step's messages, what the next hop waits for first: the attacker and the expert wait for sim/state
        (and the physical attacker for sim/physics_state), the recorder alone for /clock."""
        header = self.header()
        self.state_pub.publish(joint_state(header, self.obs_names, self.sim.observe()))
        self.physics_pub.publish(joint_state(header, self.state_names, self.sim.get_state()))
        self.clock_pub.publish(Clock(clock=header.stamp))
        if self.camera is not None and self.tag.step % self.render_every == 0:
            self.camera_pub.publish(self._image_type(header=header, format="jpeg", data=self.camera.jpeg()))

    def admit_peers(self) -> None:
        """At the first reset: the one publisher on action (the policy) and the services' clients of now are
        the ones this node takes orders from for the rest of the run."""
        if self.action_guard.admitted is not None:
            return
        for guard, topic, who in self.order_guards:
            publishers_now = guard.admit()
            if len(publishers_now) > 1:
                raise FatalNodeError(f"{len(publishers_now)} publishers on {topic}, one ({who}) expected: "
                                     + ", ".join(endpoint_text(info) for info in publishers_now))
        for guard in self.service_guards.values():
            guard.admit()

    def on_reset(self, request, response):
        self.admit_peers()
        self.service_guards[P.RESET_SERVICE].check()
        params = request_params(request)
        try:
            seed, episode = int(params["seed"]), int(params["episode"])
        except (KeyError, TypeError, ValueError):
            response.result.successful = False
            response.result.reason = f"reset takes integer parameters seed and episode, got {sorted(params)}"
            return response
        self.sim.reset(seed)
        self.tag = StepTag(episode, 0)
        self.waiting = {}
        self.queue = ActionQueue(1, self.act_dim, self.action_delay)  # this episode's actions, for a late one
        self.publish_step()
        response.result.successful = True
        return response

    def on_set_state(self, request, response):
        self.service_guards[P.SET_STATE_SERVICE].check()
        params = request_params(request)
        response.result.successful = False
        if self.tag is None or params.get("tag") != str(self.tag):
            response.result.reason = f"set_state for step {params.get('tag')!r}, but the current step is {self.tag}"
            return response
        try:
            self.sim.set_state(np.asarray(params.get("state", []), dtype=np.float64))
        except ValueError as err:
            response.result.reason = str(err)
            return response
        self.observation_pub.publish(joint_state(self.header(), self.obs_names, self.sim.observe()))
        response.result.successful = True
        return response

    def current_step(self, msg, guard, what: str) -> StepTag | None:
        """The tag of ``msg`` (``what``: an action, attack/timing), from a publisher ``guard`` admits, when it is the
        current step's; None (warned) for another step's."""
        guard.check()
        try:
            tag = StepTag.parse(msg.header.frame_id)
        except ValueError as err:
            raise FatalNodeError(f"{what} with a bad header from {guard.describe()}: {err}") from None
        if tag != self.tag:
            self.get_logger().warning(f"ignoring {what} for step {tag}; waiting for step {self.tag}")
            return None
        return tag

    def on_action(self, msg) -> None:
        if P.is_probe(msg.header.frame_id):
            self.action_guard.check()
            return  # a query-based attack's question to the policy, not the step's action
        tag = self.current_step(msg, self.action_guard, "an action")
        if tag is None:
            return
        action = np.asarray(msg.effort, dtype=np.float64)
        if action.shape != (self.act_dim,):
            raise FatalNodeError(f"action for step {tag} has {action.size} values, {self.sim.layout.env_id} takes "
                                 f"{self.act_dim}")
        if not np.all(np.isfinite(action)):
            raise FatalNodeError(f"action for step {tag} is not finite: {action.tolist()}")
        self.waiting[P.ACTION] = action
        self.try_step()

    def on_timing(self, msg) -> None:
        tag = self.current_step(msg, self.timing_guard, P.TIMING)
        if tag is None:
            return
        age = np.asarray(msg.position, dtype=np.float64)
        if age.shape != (len(P.TIMING_NAMES),) or not 0 <= age[2] <= self.action_delay or age[2] != int(age[2]):
            raise FatalNodeError(f"attack/timing for step {tag} is not {', '.join(P.TIMING_NAMES)} with an action age "
                                 f"in 0..{self.action_delay}: {age.tolist()}")
        self.waiting[P.TIMING] = int(age[2])
        self.try_step()

    def try_step(self) -> None:
        """Step once the current step's action is in, and under an action delay its timing too: the action applied
        is then the one the timing names (:class:`aril_ros.timing.ActionQueue`)."""
        if P.ACTION not in self.waiting or (self.action_delay and P.TIMING not in self.waiting):
            return
        tag, action = self.tag, self.waiting[P.ACTION]
        if self.action_delay:
            rows = np.zeros(1, dtype=np.int64)
            self.queue.push(tag.step, action[None], rows)
            action = self.queue.applied(tag.step, np.array([self.waiting[P.TIMING]]), rows)[0]
        self.waiting = {}
        _, reward, terminated, truncated = self.sim.step(action)
        self.reward_pub.publish(joint_state(self.header(), P.REWARD_NAMES, [reward, terminated, truncated]))
        self.global_step += 1
        if terminated or truncated:
            self.tag = None
            return
        self.tag = StepTag(tag.episode, tag.step + 1)
        self.publish_step()


def main(args=None):
    main_for(SimulatorNode, args)


if __name__ == "__main__":
    main()

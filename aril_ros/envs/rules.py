"""gymnasium v5's observation, reward and termination of its locomotion envs, in numpy over a batch of rows.

For the classes in :data:`BATCHED_RULES` (HalfCheetah, Ant, Swimmer, Hopper, Walker2d) the step
(:func:`aril_ros.envs.sim.step_sims`) runs gymnasium's physics on each simulator, reads a :class:`Frame`
of them all, and computes what gymnasium's ``step`` returns here, bit for bit (``tests/test_envs.py``). These
rules are the env-specific physics accessors: the only code besides the physical attack's write that reads raw
``qpos`` indices (a torso's height, a hinge's angle).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import mujoco
import numpy as np
from gymnasium.envs.mujoco import MujocoEnv
from gymnasium.envs.mujoco.ant_v5 import AntEnv
from gymnasium.envs.mujoco.half_cheetah_v5 import HalfCheetahEnv
from gymnasium.envs.mujoco.hopper_v5 import HopperEnv
from gymnasium.envs.mujoco.swimmer_v5 import SwimmerEnv
from gymnasium.envs.mujoco.walker2d_v5 import Walker2dEnv

from .layout import ObsLayout


class SimulatorArrays(Protocol):
    """What the rules read of a simulator (a :class:`~aril_ros.envs.sim.MujocoSim`): views of its ``MjData``."""

    qpos: np.ndarray
    qvel: np.ndarray
    xpos: np.ndarray
    cfrc_ext: np.ndarray


class ForwardRules:
    """gymnasium v5's observation, reward and termination of HalfCheetah and Swimmer, over rows.

    Each method is gymnasium's own expression (``<class>.step``, ``_get_obs``, ``_get_rew``,
    ``is_healthy``) applied to arrays ``[n, ...]`` in the same order of operations and on the same dtypes,
    so every row is bit for bit what gymnasium computes for that env (``tests/test_envs.py`` checks it on
    random states and actions). The weights and ranges are read from the env, so its ``gym.make`` keyword
    arguments hold. Subclasses add what their env adds: being healthy (Hopper, Walker2d, Ant), contact
    forces (Ant).
    """

    needs_contact_forces = False
    reads_kinematics = False
    """Whether the progress or the observation reads what MuJoCo derives from the state (a body's ``xpos``):
    a state moved by the physical attack then needs ``mj_forward`` before they are read. Rules that read
    ``qpos``/``qvel`` alone need nothing: the next ``mj_step`` recomputes every derived quantity from the state
    (``mj_forward`` writes none of its inputs), so the step is bit for bit the same without it."""
    velocity_clip: float | None = None
    """Hopper and Walker2d observe ``clip(qvel, -10, 10)``."""

    def __init__(self, env: MujocoEnv, layout: ObsLayout):
        self.position_start = layout.qpos_offset
        self.forward_weight = env._forward_reward_weight
        self.ctrl_weight = env._ctrl_cost_weight
        self.dt = env.dt

    def progress(self, sim: SimulatorArrays) -> float:
        """The coordinate whose rate is the forward reward, read before and after the physics."""
        return sim.qpos[0]

    def observe(self, frame: Frame) -> np.ndarray:
        velocity = frame.qvel if self.velocity_clip is None else np.clip(frame.qvel, -self.velocity_clip,
                                                                          self.velocity_clip)
        return np.concatenate((frame.qpos[:, self.position_start:], velocity), axis=1)

    def control_cost(self, action: np.ndarray) -> np.ndarray:
        return self.ctrl_weight * np.sum(np.square(action), axis=1)

    def outcome(self, frame: Frame, x_velocity: np.ndarray, action: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Reward and terminated per row."""
        forward_reward = self.forward_weight * x_velocity
        return forward_reward - self.control_cost(action), np.zeros(len(x_velocity), dtype=bool)


class HealthyRules(ForwardRules):
    """Hopper, Walker2d and Ant: a reward for being healthy, and the episode ends when the robot is not
    (with ``terminate_when_unhealthy``)."""

    def __init__(self, env: MujocoEnv, layout: ObsLayout):
        super().__init__(env, layout)
        self.healthy_weight = env._healthy_reward
        self.terminate_when_unhealthy = env._terminate_when_unhealthy
        self.min_z, self.max_z = env._healthy_z_range

    def is_healthy(self, frame: Frame) -> np.ndarray:
        raise NotImplementedError

    def costs(self, frame: Frame, action: np.ndarray) -> np.ndarray:
        return self.control_cost(action)

    def outcome(self, frame, x_velocity, action):
        healthy = self.is_healthy(frame)
        forward_reward = self.forward_weight * x_velocity
        rewards = forward_reward + healthy * self.healthy_weight
        return rewards - self.costs(frame, action), ~healthy & bool(self.terminate_when_unhealthy)


class Walker2dRules(HealthyRules):
    """Walker2d (and Hopper): healthy while the torso's height and angle are in their ranges."""

    velocity_clip = 10.0

    def __init__(self, env: MujocoEnv, layout: ObsLayout):
        super().__init__(env, layout)
        self.min_angle, self.max_angle = env._healthy_angle_range

    def is_healthy(self, frame):
        z, angle = frame.qpos[:, 1], frame.qpos[:, 2]
        return (self.min_z < z) & (z < self.max_z) & (self.min_angle < angle) & (angle < self.max_angle)


class HopperRules(Walker2dRules):
    """Hopper: also every entry of the state past ``qpos[:2]`` inside its range."""

    def __init__(self, env: MujocoEnv, layout: ObsLayout):
        super().__init__(env, layout)
        self.min_state, self.max_state = env._healthy_state_range

    def is_healthy(self, frame):
        state = np.concatenate((frame.qpos, frame.qvel), axis=1)[:, 2:]
        healthy_state = np.all((self.min_state < state) & (state < self.max_state), axis=1)
        return healthy_state & super().is_healthy(frame)


class AntRules(HealthyRules):
    """Ant-v5: progress of its main body's ``xpos`` (one substep behind, as gymnasium reads it), a cost on
    the clipped external contact forces ``cfrc_ext``, which its observation ends with."""

    needs_contact_forces = True
    reads_kinematics = True

    def __init__(self, env: MujocoEnv, layout: ObsLayout):
        super().__init__(env, layout)
        self.main_body = env.data.body(env._main_body).id
        self.contact_weight = env._contact_cost_weight
        self.min_force, self.max_force = env._contact_force_range
        self.observes_contact_forces = env._include_cfrc_ext_in_observation

    def progress(self, sim):
        return sim.xpos[self.main_body, 0]

    def contact_forces(self, frame: Frame) -> np.ndarray:
        return np.clip(frame.cfrc_ext, self.min_force, self.max_force)

    def observe(self, frame):
        observation = super().observe(frame)
        if not self.observes_contact_forces:
            return observation
        return np.concatenate((observation, self.contact_forces(frame)[:, 1:].reshape(len(observation), -1)), axis=1)

    def is_healthy(self, frame):
        z = frame.qpos[:, 2]
        finite = np.isfinite(frame.qpos).all(axis=1) & np.isfinite(frame.qvel).all(axis=1)
        return finite & (self.min_z <= z) & (z <= self.max_z)

    def costs(self, frame, action):
        contact_cost = self.contact_weight * np.sum(np.square(self.contact_forces(frame)), axis=(1, 2))
        return self.control_cost(action) + contact_cost


BATCHED_RULES: dict[type, type[ForwardRules]] = {
    HalfCheetahEnv: ForwardRules, SwimmerEnv: ForwardRules, HopperEnv: HopperRules, Walker2dEnv: Walker2dRules,
    AntEnv: AntRules,
}
"""The gymnasium v5 classes whose step :func:`~aril_ros.envs.sim.step_sims` computes itself (by exact class: a
subclass may step otherwise)."""


@dataclass
class Frame:
    """What the rules read from ``n`` simulators after their physics: ``qpos [n, nq]``, ``qvel [n, nv]``,
    and (Ant) ``cfrc_ext [n, nbody, 6]``."""

    qpos: np.ndarray
    qvel: np.ndarray
    cfrc_ext: np.ndarray | None

    @classmethod
    def empty(cls, model: mujoco.MjModel, n: int, rules: ForwardRules) -> Frame:
        contact = np.empty((n, model.nbody, 6)) if rules.needs_contact_forces else None
        return cls(np.empty((n, model.nq)), np.empty((n, model.nv)), contact)

    def read(self, row: int, sim: SimulatorArrays) -> None:
        self.qpos[row] = sim.qpos
        self.qvel[row] = sim.qvel
        if self.cfrc_ext is not None:
            self.cfrc_ext[row] = sim.cfrc_ext

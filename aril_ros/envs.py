"""Gymnasium MuJoCo environments with a known observation layout.

Every gymnasium MuJoCo locomotion env observes ``qpos[k:]`` (the zero-order part: positions and
angles, minus the ``k`` global coordinates the task excludes), then ``qvel`` (the first-order part),
then optionally more (Ant-v5 appends contact forces). :func:`layout_of` finds ``k`` by setting random
states and comparing ``_get_obs()`` with ``qpos``/``qvel``, so any such id works, and refuses ids whose
observation does not start that way (Reacher, InvertedDoublePendulum) or that are not MuJoCo envs.

This module and the step rules (:func:`aril_ros.step.perturb_qpos`, which writes a physical
perturbation through :class:`ObsLayout`) are the only places that know raw ``qpos`` indices: the
attacks and the rollout engine speak in observation coordinates.

Stepping: for the gymnasium v5 classes in :data:`BATCHED_RULES` (HalfCheetah, Ant, Swimmer, Hopper,
Walker2d) a step is gymnasium's ``do_simulation`` (``ctrl``, ``mj_step(nstep=frame_skip)``,
``mj_rnePostConstraint``) called on the env's own ``MjData``, then gymnasium's observation, reward and
termination written over a batch of rows in numpy (:class:`ForwardRules` and its subclasses).
:func:`step_sims` runs the physics of many simulators on a :class:`PhysicsPool`, a thread per core
taking simulators one at a time: MuJoCo's bindings release the GIL inside ``mj_step``, so they run in
parallel.
A single :class:`MujocoSim` (the ROS simulator node's) steps through the same function, so the graph
and the engine compute the same bits. Any other id is stepped through gymnasium's own ``step``, one
simulator at a time (:attr:`MujocoSim.batched` says why). Resets are always gymnasium's.
"""
from __future__ import annotations

import functools
import os
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium.envs.mujoco import MujocoEnv
from gymnasium.envs.mujoco.ant_v5 import AntEnv
from gymnasium.envs.mujoco.half_cheetah_v5 import HalfCheetahEnv
from gymnasium.envs.mujoco.hopper_v5 import HopperEnv
from gymnasium.envs.mujoco.swimmer_v5 import SwimmerEnv
from gymnasium.envs.mujoco.walker2d_v5 import Walker2dEnv

from .registry import PAPER_ENVS
from .step import perturb_qpos

HORIZON = 1000  # the paper's episode length for every env

POSITION, VELOCITY, OTHER = "position", "velocity", "other"


def _mujoco_warning(message: str) -> None:
    # gymnasium's Ant XML still uses 'settotalmass', which MuJoCo >= 4 flags at every compile and
    # writes to MUJOCO_LOG.TXT in the working directory. It is harmless; every other warning is
    # passed on as a Python warning instead of a stray log file.
    if "settotalmass" not in message:
        warnings.warn(f"MuJoCo: {message}", RuntimeWarning, stacklevel=2)


mujoco.set_mju_user_warning(_mujoco_warning)


class EnvLayoutError(ValueError):
    """The env id is unknown, not a MuJoCo env, or its observation has no qpos/qvel layout."""


@dataclass(frozen=True)
class ObsLayout:
    """Where each observation entry comes from, for one env id."""

    env_id: str
    obs_dim: int
    act_dim: int
    action_low: tuple[float, ...]
    action_high: tuple[float, ...]
    qpos_offset: int
    """``obs[position]`` equals ``qpos[qpos_offset:]``: the global coordinates the task hides."""
    n_position: int
    n_velocity: int
    names: tuple[str, ...]
    """One name per observation entry, e.g. ``rooty:pos``, ``bthigh:vel``, ``other[3]``."""
    action_names: tuple[str, ...]
    """One name per action entry: the MuJoCo actuators."""

    @property
    def position(self) -> slice:
        return slice(0, self.n_position)

    @property
    def velocity(self) -> slice:
        return slice(self.n_position, self.n_position + self.n_velocity)

    @property
    def other(self) -> slice:
        return slice(self.n_position + self.n_velocity, self.obs_dim)

    @property
    def kinds(self) -> tuple[str, ...]:
        """``position``, ``velocity`` or ``other`` for every observation entry."""
        return (POSITION,) * self.n_position + (VELOCITY,) * self.n_velocity + (OTHER,) * (
            self.obs_dim - self.n_position - self.n_velocity
        )

    @property
    def zero_order_mask(self) -> np.ndarray:
        """Boolean mask of the entries an attack may perturb (positions and angles)."""
        mask = np.zeros(self.obs_dim, dtype=bool)
        mask[self.position] = True
        return mask


def make_gym_env(env_id: str, horizon: int = HORIZON) -> gym.Env:
    """``gym.make`` with a clear error for ids that are unknown or not MuJoCo envs."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            env = gym.make(env_id, max_episode_steps=horizon)
    except gym.error.Error as err:
        raise EnvLayoutError(f"unknown gymnasium env id {env_id!r}: {err}") from None
    if not isinstance(env.unwrapped, MujocoEnv):
        name = type(env.unwrapped).__name__
        env.close()
        raise EnvLayoutError(
            f"{env_id!r} is not a gymnasium MuJoCo environment (it is {name}); "
            f"use a MuJoCo id such as {', '.join(PAPER_ENVS)}"
        )
    return env


def _entry_names(model: mujoco.MjModel, address_of: str, width_of: dict[int, int], suffix: str) -> list[str]:
    """Names of qpos (or qvel) entries from the model's joints: ``joint:pos`` or ``joint[i]:pos``."""
    names = []
    for j in range(model.njnt):
        joint = model.joint(j).name or f"joint{j}"
        width = width_of[int(model.jnt_type[j])]
        names += [f"{joint}:{suffix}"] if width == 1 else [f"{joint}[{i}]:{suffix}" for i in range(width)]
    return names


_QPOS_WIDTH = {0: 7, 1: 4, 2: 1, 3: 1}  # free, ball, slide, hinge
_QVEL_WIDTH = {0: 6, 1: 3, 2: 1, 3: 1}


@functools.lru_cache(maxsize=None)
def layout_of(env_id: str) -> ObsLayout:
    """The observation layout of a gymnasium MuJoCo env id, found and verified on random states."""
    env = make_gym_env(env_id)
    try:
        sim = env.unwrapped
        model, data = sim.model, sim.data
        env.reset(seed=0)
        rng = np.random.default_rng(0)
        candidates = set(range(model.nq + 1))
        for _ in range(3):
            data.qpos[:] = sim.init_qpos + rng.uniform(-0.1, 0.1, model.nq)
            data.qvel[:] = rng.uniform(-0.5, 0.5, model.nv)
            mujoco.mj_forward(model, data)
            obs = sim._get_obs()
            candidates = {
                k
                for k in candidates
                if model.nq - k + model.nv <= obs.size
                and np.array_equal(obs[: model.nq - k], data.qpos[k:])
                and np.array_equal(obs[model.nq - k : model.nq - k + model.nv], data.qvel)
            }
        if not candidates:
            raise EnvLayoutError(
                f"{env_id!r}: its observation does not start with qpos[k:] followed by qvel, so its "
                "zero-order entries are unknown; aril_ros supports MuJoCo envs laid out like "
                f"{', '.join(PAPER_ENVS)}"
            )
        k = min(candidates)
        n_position, n_velocity = model.nq - k, model.nv
        obs_dim = env.observation_space.shape[0]
        names = (
            _entry_names(model, "qpos", _QPOS_WIDTH, "pos")[k:]
            + _entry_names(model, "qvel", _QVEL_WIDTH, "vel")
            + [f"other[{i}]" for i in range(obs_dim - n_position - n_velocity)]
        )
        return ObsLayout(
            env_id=env_id,
            obs_dim=obs_dim,
            act_dim=env.action_space.shape[0],
            action_low=tuple(float(x) for x in env.action_space.low),
            action_high=tuple(float(x) for x in env.action_space.high),
            qpos_offset=k,
            n_position=n_position,
            n_velocity=n_velocity,
            names=tuple(names),
            action_names=tuple(model.actuator(i).name or f"actuator{i}" for i in range(model.nu)),
        )
    finally:
        env.close()


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

    def progress(self, sim: MujocoSim) -> float:
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
"""The gymnasium v5 classes whose step :func:`step_sims` computes itself (by exact class: a subclass may
step otherwise)."""


@dataclass
class Frame:
    """What the rules read from ``n`` simulators after their physics: ``qpos [n, nq]``, ``qvel [n, nv]``,
    and (Ant) ``cfrc_ext [n, nbody, 6]``."""

    qpos: np.ndarray
    qvel: np.ndarray
    cfrc_ext: np.ndarray | None

    @classmethod
    def empty(cls, sims: list[MujocoSim]) -> Frame:
        model, n = sims[0].model, len(sims)
        contact = np.empty((n, model.nbody, 6)) if sims[0].rules.needs_contact_forces else None
        return cls(np.empty((n, model.nq)), np.empty((n, model.nv)), contact)

    def read(self, row: int, sim: MujocoSim) -> None:
        self.qpos[row] = sim.qpos
        self.qvel[row] = sim.qvel
        if self.cfrc_ext is not None:
            self.cfrc_ext[row] = sim.cfrc_ext


class PhysicsPool:
    """Runs ``work(i)`` for every row ``i`` of ``range(n)`` on ``threads`` threads, the calling one
    included: each takes the next row not yet taken until none is left. The rows' MuJoCo calls run in
    parallel (the bindings release the GIL inside them); the Python between them takes turns. Rows are
    taken, not dealt in fixed groups, so a pool thread the OS runs late (a busy machine) costs at most
    the row it holds: the caller takes the rest, and a helper that has not started is cancelled."""

    def __init__(self, threads: int):
        self.threads = max(1, int(threads))
        self._executor = (ThreadPoolExecutor(self.threads - 1, thread_name_prefix="aril-physics")
                          if self.threads > 1 else None)

    def run(self, work, n: int) -> None:
        rows = iter(range(n))  # shared: next() on it is atomic under the GIL

        def take_rows() -> None:
            for i in rows:
                work(i)

        helpers = [self._executor.submit(take_rows) for _ in range(min(self.threads, n) - 1)]
        take_rows()
        for helper in helpers:
            if not helper.cancel():
                helper.result()

    def close(self) -> None:
        if self._executor is not None:
            self._executor.shutdown()


def physics_threads() -> int:
    """The default size of a :class:`PhysicsPool`: the cores this process may run on, or fewer where
    ``OMP_NUM_THREADS`` caps a process's threads (a Ray task's: its CPUs, so two tasks on two cores do not run
    four physics threads)."""
    cores = len(os.sched_getaffinity(0))
    cap = os.environ.get("OMP_NUM_THREADS", "")
    return min(cores, int(cap)) if cap.isdigit() and int(cap) > 0 else cores


SERIAL = PhysicsPool(1)
"""The calling thread alone: one simulator's step, and any batch built with ``threads=1``."""


def step_sims(sims: list[MujocoSim], action: np.ndarray, pool: PhysicsPool = SERIAL
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One control step of each simulator (``action[i]`` for ``sims[i]``): observation, reward,
    terminated, truncated (``truncated`` at the simulator's horizon: gymnasium's time-limit rule, counted
    here because its wrappers are not stepped)."""
    action = np.asarray(action)
    act_dim = sims[0].layout.act_dim
    if action.shape != (len(sims), act_dim):
        raise ValueError(f"{sims[0].layout.env_id}: actions must have shape ({len(sims)}, {act_dim}), "
                         f"got {action.shape}")
    rules = sims[0].rules
    if rules is None:
        obs, reward, terminated = _gymnasium_step(sims, action)
    else:
        frame, x_before, x_after = Frame.empty(sims), np.empty(len(sims)), np.empty(len(sims))
        # every simulator's MjData stepped with the first one's MjModel: the models are compiled from one XML,
        # equal field for field, and one 0.5 MB model stays in cache where 32 of them did not (mj_step 15-25%
        # slower round-robin over 32 models than over one)
        model = sims[0].model

        def simulate(i: int) -> None:  # gymnasium's do_simulation on the simulator's own MjData
            sim = sims[i]
            x_before[i] = rules.progress(sim)
            sim.ctrl[:] = action[i]
            mujoco.mj_step(model, sim.data, nstep=sim.frame_skip)
            # force-related quantities (cfrc_ext) are not computed by mj_step without force sensors
            mujoco.mj_rnePostConstraint(model, sim.data)
            x_after[i] = rules.progress(sim)
            frame.read(i, sim)

        pool.run(simulate, len(sims))
        obs = rules.observe(frame)
        reward, terminated = rules.outcome(frame, (x_after - x_before) / rules.dt, action)
    truncated = np.empty(len(sims), dtype=bool)
    for i, sim in enumerate(sims):
        sim.elapsed += 1
        truncated[i] = sim.elapsed >= sim.horizon
    return obs, reward, terminated, truncated


def _gymnasium_step(sims: list[MujocoSim], action: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An env without batched rules: gymnasium's own unwrapped ``step``, one simulator after the other
    (its checker and time-limit wrappers cost a third of a HalfCheetah step and add nothing)."""
    obs, reward, terminated = [], np.empty(len(sims)), np.empty(len(sims), dtype=bool)
    for i, sim in enumerate(sims):
        o, reward[i], terminated[i], _, _ = sim.gym_env.step(action[i])
        obs.append(o)
    return np.stack(obs), reward, terminated


def observe_sims(sims: list[MujocoSim]) -> np.ndarray:
    """The observation of each simulator's current state, ``[n, obs_dim]``."""
    rules = sims[0].rules
    if rules is None:
        return np.stack([sim.gym_env._get_obs() for sim in sims])
    frame = Frame.empty(sims)
    for i, sim in enumerate(sims):
        frame.read(i, sim)
    return rules.observe(frame)


def perturb_sims(sims: list[MujocoSim], delta: np.ndarray, pool: PhysicsPool = SERIAL,
                 observation: np.ndarray | None = None) -> np.ndarray:
    """The physical attack on each simulator (``delta[i]`` for ``sims[i]``, observation coordinates): its
    real zero-order state moved by the one rule the graph's attacker applies too
    (:func:`aril_ros.step.perturb_qpos`), then ``mj_forward`` where the env's rules read derived quantities
    (:attr:`ForwardRules.reads_kinematics`; always for an env gymnasium steps itself). Returns the new
    observations; ``observation``, the simulators' observations before the move, spares reading them again where
    no ``mj_forward`` is needed."""

    rules = sims[0].rules
    if rules is None or rules.reads_kinematics:
        model = sims[0].model  # one model for all, as in step_sims

        def move(i: int) -> None:
            perturb_qpos(sims[i].layout, sims[i].qpos, delta[i])
            mujoco.mj_forward(model, sims[i].data)

        pool.run(move, len(sims))
        return observe_sims(sims)
    # a few numpy additions per simulator: handing them to the pool's threads costs more than them
    layout = sims[0].layout
    for sim, row in zip(sims, delta):
        perturb_qpos(layout, sim.qpos, row)
    if observation is None:
        return observe_sims(sims)
    # these rules observe the moved qpos entries as they are (ForwardRules.observe), so the same additions on the
    # old observation give the new one bit for bit, without a pass over every simulator (54 -> 36 us for 32
    # HalfCheetahs, with the loop above off the pool: about 1% of a physical step)
    moved = np.array(observation, dtype=np.float64)
    moved[:, layout.position] += delta[:, layout.position]
    return moved


class MujocoSim:
    """One gymnasium MuJoCo env with full-state access and the physical attack's qpos mapping.

    Randomness comes only from ``reset(seed)`` (gymnasium's per-env generator), never global state.
    Its step is :func:`step_sims` on itself alone, the engine's step on many.
    """

    def __init__(self, env_id: str, horizon: int = HORIZON):
        self.layout = layout_of(env_id)
        self.horizon = horizon
        self.env = make_gym_env(env_id, horizon)
        self.gym_env = self.env.unwrapped
        self.model, self.data = self.gym_env.model, self.gym_env.data
        self.frame_skip = self.gym_env.frame_skip
        # views of this MjData's arrays, taken once: the step reads them for every simulator every step
        self.ctrl, self.qpos, self.qvel = self.data.ctrl, self.data.qpos, self.data.qvel
        self.xpos, self.cfrc_ext = self.data.xpos, self.data.cfrc_ext
        rules = BATCHED_RULES.get(type(self.gym_env))
        self.rules = None if rules is None else rules(self.gym_env, self.layout)
        # whether the step computes gymnasium's rules itself, and if not why (the engine benchmark prints it)
        self.batched = ("batched: gymnasium v5's rules in numpy" if rules is not None else
                        f"not batched: {type(self.gym_env).__module__}.{type(self.gym_env).__name__} has no "
                        "batched rules (aril_ros.envs.BATCHED_RULES), so gymnasium steps it one env at a time")
        self.elapsed = 0
        self._state_size = mujoco.mj_stateSize(self.model, mujoco.mjtState.mjSTATE_INTEGRATION)

    def reset(self, seed: int) -> np.ndarray:
        obs, _ = self.env.reset(seed=int(seed))
        self.elapsed = 0
        return obs

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool]:
        """Advance one control step; returns (observation, reward, terminated, truncated)."""
        obs, reward, terminated, truncated = step_sims([self], np.asarray(action)[None])
        return obs[0], float(reward[0]), bool(terminated[0]), bool(truncated[0])

    def observe(self) -> np.ndarray:
        return observe_sims([self])[0]

    @property
    def state_size(self) -> int:
        return self._state_size

    def get_state(self) -> np.ndarray:
        """The full integration state (time, qpos, qvel, act, warm start, ...) as float64."""
        state = np.empty(self._state_size)
        mujoco.mj_getState(self.model, self.data, state, mujoco.mjtState.mjSTATE_INTEGRATION)
        return state

    def set_state(self, state: np.ndarray) -> None:
        """Restore a state from :meth:`get_state`; rejects wrong sizes and non-finite values."""
        state = np.asarray(state, dtype=np.float64)
        if state.shape != (self._state_size,):
            raise ValueError(f"state must have {self._state_size} entries, got shape {state.shape}")
        if not np.all(np.isfinite(state)):
            raise ValueError("state contains non-finite values")
        mujoco.mj_setState(self.model, self.data, state, mujoco.mjtState.mjSTATE_INTEGRATION)
        mujoco.mj_forward(self.model, self.data)

    @property
    def dt(self) -> float:
        """Seconds of sim time per control step."""
        return float(self.gym_env.dt)

    @property
    def state_names(self) -> list[str]:
        """Names of the :meth:`get_state` entries: time, every qpos and qvel, then the rest."""
        names = ["time"] + _entry_names(self.model, "qpos", _QPOS_WIDTH, "pos")
        names += _entry_names(self.model, "qvel", _QVEL_WIDTH, "vel")
        return names + [f"state[{i}]" for i in range(len(names), self._state_size)]

    def perturb(self, delta: np.ndarray) -> np.ndarray:
        """Physical attack: move the real zero-order state by ``delta`` (observation coordinates), by
        :func:`perturb_sims`. Returns the new observation."""
        return perturb_sims([self], np.asarray(delta)[None])[0]

    def close(self) -> None:
        self.env.close()

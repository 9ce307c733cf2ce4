"""Where each observation entry of a gymnasium MuJoCo env comes from.

Every gymnasium MuJoCo locomotion env observes ``qpos[k:]`` (the zero-order part: positions and
angles, minus the ``k`` global coordinates the task excludes), then ``qvel`` (the first-order part),
then optionally more (Ant-v5 appends contact forces). :func:`layout_of` finds ``k`` by setting random
states and comparing ``_get_obs()`` with ``qpos``/``qvel``, so any such id works, and refuses ids whose
observation does not start that way (Reacher, InvertedDoublePendulum) or that are not MuJoCo envs.
"""
from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium.envs.mujoco import MujocoEnv

from ..registry import PAPER_ENVS

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


def _entry_names(model: mujoco.MjModel, width_of: dict[int, int], suffix: str) -> list[str]:
    """Names of qpos (or qvel) entries from the model's joints: ``joint:pos`` or ``joint[i]:pos``."""
    names = []
    for j in range(model.njnt):
        joint = model.joint(j).name or f"joint{j}"
        width = width_of[int(model.jnt_type[j])]
        names += [f"{joint}:{suffix}"] if width == 1 else [f"{joint}[{i}]:{suffix}" for i in range(width)]
    return names


_QPOS_WIDTH = {0: 7, 1: 4, 2: 1, 3: 1}  # free, ball, slide, hinge
_QVEL_WIDTH = {0: 6, 1: 3, 2: 1, 3: 1}


def qpos_names(model: mujoco.MjModel) -> list[str]:
    """One name per ``qpos`` entry: ``joint:pos``, or ``joint[i]:pos`` for a joint of several."""
    return _entry_names(model, _QPOS_WIDTH, "pos")


def qvel_names(model: mujoco.MjModel) -> list[str]:
    """One name per ``qvel`` entry: ``joint:vel``, or ``joint[i]:vel`` for a joint of several."""
    return _entry_names(model, _QVEL_WIDTH, "vel")


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
        names = qpos_names(model)[k:] + qvel_names(model) + [
            f"other[{i}]" for i in range(obs_dim - n_position - n_velocity)]
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

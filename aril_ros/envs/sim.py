"""A gymnasium MuJoCo env with full-state access, and the step of many at once.

For the gymnasium v5 classes in :data:`~aril_ros.envs.rules.BATCHED_RULES` a step is gymnasium's
``do_simulation`` (``ctrl``, ``mj_step(nstep=frame_skip)``, ``mj_rnePostConstraint``) called on the env's own
``MjData``, then gymnasium's observation, reward and termination written over a batch of rows in numpy
(:mod:`aril_ros.envs.rules`). :func:`step_sims` runs the physics of many simulators on the
:class:`~aril_ros.envs.pool.PhysicsPool` their owner gives it. A single :class:`MujocoSim` (the ROS simulator
node's) steps through the same function on a pool of its own, so the graph and the engine compute the same bits.
Any other id is stepped through gymnasium's own ``step``, one simulator at a time (:attr:`MujocoSim.batched` says
why). Resets are always gymnasium's.

This module and the step rules (:func:`aril_ros.step.perturb_qpos`, which writes a physical perturbation through
:class:`~aril_ros.envs.layout.ObsLayout`) are, with the env rules, the only places that know raw ``qpos``
indices: the attacks and the rollout engine speak in observation coordinates.
"""
from __future__ import annotations

import mujoco
import numpy as np

from ..step import perturb_qpos, state_moved
from .layout import HORIZON, layout_of, make_gym_env, qpos_names, qvel_names
from .pool import PhysicsPool
from .rules import BATCHED_RULES, Frame


def step_sims(sims: list[MujocoSim], action: np.ndarray, pool: PhysicsPool
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
        # every simulator's MjData stepped with the first one's MjModel: the models are compiled from one XML,
        # equal field for field, and one 0.5 MB model stays in cache where 32 of them did not (mj_step 15-25%
        # slower round-robin over 32 models than over one)
        model = sims[0].model
        frame, x_before, x_after = Frame.empty(model, len(sims), rules), np.empty(len(sims)), np.empty(len(sims))

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
    frame = Frame.empty(sims[0].model, len(sims), rules)
    for i, sim in enumerate(sims):
        frame.read(i, sim)
    return rules.observe(frame)


def perturb_sims(sims: list[MujocoSim], delta: np.ndarray, pool: PhysicsPool,
                 observation: np.ndarray | None = None) -> np.ndarray:
    """The physical attack on each simulator (``delta[i]`` for ``sims[i]``, observation coordinates): its
    real zero-order state moved by the one rule the graph's attacker applies too
    (:func:`aril_ros.step.perturb_qpos`), then ``mj_forward`` where the env's rules read derived quantities
    (:attr:`~aril_ros.envs.rules.ForwardRules.reads_kinematics`; always for an env gymnasium steps itself). A
    simulator whose state ``delta`` leaves unchanged is not written (:func:`aril_ros.step.state_moved`), as the
    graph's simulator does not write it. Returns the new observations; ``observation``, the simulators'
    observations before the move, spares reading them again where no ``mj_forward`` is needed."""
    rules, layout = sims[0].rules, sims[0].layout
    qpos = np.stack([sim.qpos for sim in sims])
    moved = qpos.copy()
    perturb_qpos(layout, moved, delta)
    rows = np.flatnonzero(state_moved(qpos, moved))
    if rules is None or rules.reads_kinematics:
        model = sims[0].model  # one model for all, as in step_sims

        def move(k: int) -> None:
            i = rows[k]
            sims[i].qpos[:] = moved[i]
            mujoco.mj_forward(model, sims[i].data)

        pool.run(move, len(rows))
        return observe_sims(sims)
    # a copy per simulator: handing them to the pool's threads costs more than them
    for i in rows:
        sims[i].qpos[:] = moved[i]
    if observation is None:
        return observe_sims(sims)
    # these rules observe the moved qpos entries as they are (ForwardRules.observe), so the same additions on the
    # old observation give the new one bit for bit, without a pass over every simulator (54 -> 36 us for 32
    # HalfCheetahs, with the loop above off the pool: about 1% of a physical step)
    seen = np.array(observation, dtype=np.float64)
    seen[rows, layout.position] += delta[rows, layout.position]
    return seen


class MujocoSim:
    """One gymnasium MuJoCo env with full-state access and the physical attack's qpos mapping.

    Randomness comes only from ``reset(seed)`` (gymnasium's per-env generator), never global state.
    Its step is :func:`step_sims` on itself alone, the engine's step on many, on a pool of one thread: the
    calling one.
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
        self.pool = PhysicsPool(1)
        self._state_size = mujoco.mj_stateSize(self.model, mujoco.mjtState.mjSTATE_INTEGRATION)

    def reset(self, seed: int) -> np.ndarray:
        obs, _ = self.env.reset(seed=int(seed))
        self.elapsed = 0
        return obs

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool]:
        """Advance one control step; returns (observation, reward, terminated, truncated)."""
        obs, reward, terminated, truncated = step_sims([self], np.asarray(action)[None], self.pool)
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
        """Restore a state from :meth:`get_state`; rejects wrong sizes and non-finite values. The state the simulator
        is in already is not written (:func:`aril_ros.step.state_moved`): the physical attack's zero perturbation,
        sent through the graph, leaves the step as clean as the engine's does."""
        state = np.asarray(state, dtype=np.float64)
        if state.shape != (self._state_size,):
            raise ValueError(f"state must have {self._state_size} entries, got shape {state.shape}")
        if not np.all(np.isfinite(state)):
            raise ValueError("state contains non-finite values")
        if not state_moved(self.get_state(), state):
            return
        mujoco.mj_setState(self.model, self.data, state, mujoco.mjtState.mjSTATE_INTEGRATION)
        mujoco.mj_forward(self.model, self.data)

    @property
    def dt(self) -> float:
        """Seconds of sim time per control step."""
        return float(self.gym_env.dt)

    @property
    def state_names(self) -> list[str]:
        """Names of the :meth:`get_state` entries: time, every qpos and qvel, then the rest."""
        names = ["time"] + qpos_names(self.model) + qvel_names(self.model)
        return names + [f"state[{i}]" for i in range(len(names), self._state_size)]

    def perturb(self, delta: np.ndarray) -> np.ndarray:
        """Physical attack: move the real zero-order state by ``delta`` (observation coordinates), by
        :func:`perturb_sims`. Returns the new observation."""
        return perturb_sims([self], np.asarray(delta)[None], self.pool)[0]

    def close(self) -> None:
        self.pool.close()
        self.env.close()

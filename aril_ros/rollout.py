"""The in-process rollout engine: ``policy ∘ attack`` on N MuJoCo envs at once, expert-labelled.

Per step and per running episode the engine produces the true observation ``s``, the perturbation
``delta`` (from the attack, on the true observation), the observation the policy sees, the policy's
action ``a``, the expert's action on the *true* observation ``a_e``, the reward and ``done``.

Modes (the paper's eqs. 5 and 6):

- ``clean``: the policy sees ``s``; no attack.
- ``sensory``: the policy sees ``s + delta``; the simulator is untouched.
- ``physical``: the simulator's zero-order state is moved by ``delta`` before the policy acts, so the
  policy sees the observation of the moved state and the dynamics continue from it. The expert
  labels ``s``, the state before the attack, as in eq. 6.

Episode ``i`` of a rollout with ``seed`` resets its env with ``seed + i`` and draws attack noise
from ``np.random.default_rng([seed, i])``, so its trajectory does not depend on how many envs run
side by side, and the same seed gives identical arrays.
"""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from .attacks import Attack, NoAttack
from .envs import HORIZON, MujocoSim, layout_of
from .policy import MLPPolicy

MODES = ("clean", "sensory", "physical")


@dataclass
class StepArrays:
    """What every step records, whether run in-process or read back from a graph's log."""

    true_obs: np.ndarray
    """the true observation, which the expert labels"""
    obs: np.ndarray
    """the observation the policy saw"""
    delta: np.ndarray
    """the attack's perturbation (observation coordinates)"""
    action: np.ndarray
    """the policy's action"""
    expert_action: np.ndarray
    """the expert's action on the true observation"""
    reward: np.ndarray


@dataclass
class StepBatch(StepArrays):
    """One control step of the episodes that are still running (row k is episode ``episodes[k]``)."""

    t: int
    episodes: np.ndarray
    done: np.ndarray


@dataclass
class Trajectories(StepArrays):
    """Arrays ``[episode, step, ...]`` padded with zeros past each episode's ``length``."""

    length: np.ndarray
    seed: int

    @property
    def returns(self) -> np.ndarray:
        return self.reward.sum(axis=1)

    @property
    def step_mask(self) -> np.ndarray:
        return np.arange(self.reward.shape[1])[None, :] < self.length[:, None]

    @property
    def expert_loss(self) -> np.ndarray:
        """Per episode, the mean over its steps of ``||a - a_e||^2``."""
        sq = ((self.action - self.expert_action) ** 2).sum(axis=2)
        return sq.sum(axis=1) / self.length

    @property
    def mean_expert_loss(self) -> float:
        """``||a - a_e||^2`` averaged over every step of every episode."""
        sq = ((self.action - self.expert_action) ** 2).sum(axis=2)
        return float(sq.sum() / self.length.sum())


def apply_perturbation(mode: str, sims: list[MujocoSim], true_obs: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """What the policy sees: ``s + delta`` (sensory, clean) or, physical, the observation of each
    simulator after its real state has been moved by ``delta``."""
    if mode == "physical":
        return np.stack([sim.perturb(d) for sim, d in zip(sims, delta)])
    return true_obs + delta


def episode_rng(seed: int, episode: int) -> np.random.Generator:
    return np.random.default_rng([seed, episode])


class RolloutEngine:
    """Runs ``policy ∘ attack`` on ``n_envs`` simulators in lockstep, labelling with ``expert``."""

    def __init__(
        self,
        env_id: str,
        policy: MLPPolicy,
        expert: MLPPolicy,
        attack: Attack | None = None,
        mode: str = "clean",
        n_envs: int = 8,
        horizon: int = HORIZON,
    ):
        if mode not in MODES:
            raise ValueError(f"unknown mode {mode!r}; choose one of {', '.join(MODES)}")
        self.layout = layout_of(env_id)
        for who, net in (("policy", policy), ("expert", expert)):
            try:
                net.check_env(env_id, self.layout.obs_dim, self.layout.act_dim)
            except ValueError as err:
                raise ValueError(f"{who}: {err}") from None
        if mode == "clean" and attack is not None and not isinstance(attack, NoAttack):
            raise ValueError(f"mode clean runs no attack, got attack {attack.name!r}")
        self.policy, self.expert, self.mode, self.horizon = policy, expert, mode, horizon
        self.attack = attack if attack is not None else NoAttack(self.layout, 0.0)
        self.sims = [MujocoSim(env_id, horizon) for _ in range(max(1, int(n_envs)))]

    def close(self) -> None:
        for sim in self.sims:
            sim.close()

    def iter_steps(self, episodes: int, seed: int = 0) -> Iterator[StepBatch]:
        """Yield a :class:`StepBatch` per step, running ``len(self.sims)`` episodes at a time."""
        n = len(self.sims)
        for first in range(0, episodes, n):
            yield from self._run_group(np.arange(first, min(first + n, episodes)), seed)

    def _run_group(self, episode_ids: np.ndarray, seed: int) -> Iterator[StepBatch]:
        sims = self.sims[: len(episode_ids)]
        rngs = [episode_rng(seed, int(i)) for i in episode_ids]
        obs = np.stack([sim.reset(seed + int(i)) for sim, i in zip(sims, episode_ids)])
        running = np.arange(len(episode_ids))
        for t in range(self.horizon):
            true_obs = obs[running]
            delta = self.attack.perturb(true_obs, [rngs[k] for k in running])
            seen = apply_perturbation(self.mode, [sims[k] for k in running], true_obs, delta)
            action = self.policy.act(seen)
            expert_action = self.expert.act(true_obs)
            reward = np.empty(len(running))
            done = np.empty(len(running), dtype=bool)
            for row, k in enumerate(running):
                obs[k], reward[row], terminated, truncated = sims[k].step(action[row])
                done[row] = terminated or truncated
            yield StepBatch(true_obs=true_obs, obs=seen, delta=delta, action=action, expert_action=expert_action,
                            reward=reward, t=t, episodes=episode_ids[running], done=done)
            running = running[~done]
            if running.size == 0:
                return

    def rollout(self, episodes: int, seed: int = 0) -> Trajectories:
        """Run ``episodes`` episodes and return their padded arrays."""
        lay, H = self.layout, self.horizon
        obs_arrays = {k: np.zeros((episodes, H, lay.obs_dim)) for k in ("true_obs", "obs", "delta")}
        act_arrays = {k: np.zeros((episodes, H, lay.act_dim)) for k in ("action", "expert_action")}
        reward = np.zeros((episodes, H))
        length = np.zeros(episodes, dtype=np.int64)
        for step in self.iter_steps(episodes, seed):
            e, t = step.episodes, step.t
            for name, arr in {**obs_arrays, **act_arrays}.items():
                arr[e, t] = getattr(step, name)
            reward[e, t] = step.reward
            length[e] = t + 1
        return Trajectories(**obs_arrays, **act_arrays, reward=reward, length=length, seed=seed)

"""The in-process rollout engine: ``policy ∘ attack`` on N MuJoCo envs at once, expert-labelled.

Per step and per running episode the engine produces the true observation ``s``, the perturbation
``delta`` (from the attack, on the true observation), the observation the policy sees, the policy's
action ``a``, the expert's action on the *true* observation ``a_e``, the reward and ``done`` — by the
rules of :mod:`aril_ros.step` (modes, per-episode seeds and noise), which the ROS graph follows too.
:class:`SimBatch` is the N simulators stepped side by side; the adversary trainer steps through it too.
"""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from .attacks import Attack, NoAttack
from .envs import HORIZON, MujocoSim, PhysicsPool, layout_of, perturb_sims, physics_threads, step_sims
from .policy import MLPPolicy
from .registry import MODES, check_name
from .step import StepArrays, disagreement, episode_rng, episode_seed, sensory_observation, timing_rng
from .timing import TimingAttack


@dataclass
class StepBatch(StepArrays):
    """One control step of the episodes that are still running (row k is episode ``episodes[k]``)."""

    t: int
    episodes: np.ndarray
    done: np.ndarray
    applied_action: np.ndarray
    """the action the simulator applied: the policy's, or under an action delay an older one of it"""
    timing: np.ndarray | None = None
    """under a timing attack, per row :data:`aril_ros.protocol.TIMING_NAMES`: how many steps old the observation the
    policy saw was, whether it was dropped (the last one seen, shown again), how old the applied action was"""


@dataclass
class Trajectories(StepArrays):
    """Arrays ``[episode, step, ...]`` padded with zeros past each episode's ``length``."""

    length: np.ndarray
    seed: int
    timing: np.ndarray | None = None
    """``[episode, step, 3]`` under a timing attack (:attr:`StepBatch.timing`), else None"""
    applied_action: np.ndarray | None = None
    """under a timing attack, the actions the simulator applied (late under an action delay), else None"""

    @property
    def returns(self) -> np.ndarray:
        return self.reward.sum(axis=1)

    @property
    def step_mask(self) -> np.ndarray:
        return np.arange(self.reward.shape[1])[None, :] < self.length[:, None]

    @property
    def mean_expert_loss(self) -> float:
        """``||a - a_e||^2`` averaged over every step of every episode, ``a`` the action applied."""
        applied = self.action if self.applied_action is None else self.applied_action
        return float(disagreement(applied, self.expert_action).sum() / self.length.sum())


class SimBatch:
    """``n`` simulators of one env stepped side by side; ``rows`` picks the ones a call concerns.

    Their physics runs on a :class:`~aril_ros.envs.PhysicsPool` of ``threads`` threads (default: one per
    core); a row's results do not depend on ``n``, ``threads`` or the other rows.
    """

    def __init__(self, env_id: str, n: int, horizon: int = HORIZON, threads: int | None = None):
        self.sims = [MujocoSim(env_id, horizon) for _ in range(max(1, int(n)))]
        self.pool = PhysicsPool(min(len(self.sims), threads or physics_threads()))

    def __len__(self) -> int:
        return len(self.sims)

    def reset(self, seeds, rows=None) -> np.ndarray:
        """Reset the simulators of ``rows`` (default: the first ``len(seeds)``) with ``seeds``; their observations."""
        rows = range(len(seeds)) if rows is None else rows
        return np.stack([self.sims[k].reset(int(seed)) for k, seed in zip(rows, seeds)])

    def seen(self, mode: str, true_obs: np.ndarray, delta: np.ndarray, rows) -> np.ndarray:
        """What the policy sees, by the mode's rule: ``s + delta``, or (physical) the observation of each
        simulator after its real state has been moved by ``delta``."""
        if mode == "physical":
            return perturb_sims(self._rows(rows), delta, self.pool, observation=true_obs)
        return sensory_observation(true_obs, delta)

    def step(self, action: np.ndarray, rows) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Advance the simulators of ``rows`` one control step: observation, reward, terminated, truncated."""
        return step_sims(self._rows(rows), action, self.pool)

    def _rows(self, rows) -> list[MujocoSim]:
        return [self.sims[k] for k in rows]

    def close(self) -> None:
        self.pool.close()
        for sim in self.sims:
            sim.close()


class RolloutEngine:
    """Runs ``policy ∘ attack`` on ``n_envs`` simulators in lockstep, labelling with ``expert``; their physics
    on ``physics_threads`` threads (default: one per core), which changes no result. Under a ``timing`` attack
    (:mod:`aril_ros.timing`) the policy may see a late or a stale observation and the simulator apply a late
    action, each episode's timing drawn from its own stream."""

    def __init__(
        self,
        env_id: str,
        policy: MLPPolicy,
        expert: MLPPolicy,
        attack: Attack | None = None,
        mode: str = "clean",
        n_envs: int = 8,
        horizon: int = HORIZON,
        physics_threads: int | None = None,
        timing: TimingAttack | None = None,
    ):
        check_name("mode", mode, MODES)
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
        self.timing = timing if timing is not None and timing.budget.any else None
        self.sims = SimBatch(env_id, n_envs, horizon, physics_threads)

    def close(self) -> None:
        self.sims.close()

    def iter_steps(self, episodes: int, seed: int = 0) -> Iterator[StepBatch]:
        """Yield a :class:`StepBatch` per step, running ``len(self.sims)`` episodes at a time."""
        n = len(self.sims)
        for first in range(0, episodes, n):
            yield from self._run_group(np.arange(first, min(first + n, episodes)), seed)

    def _run_group(self, episode_ids: np.ndarray, seed: int) -> Iterator[StepBatch]:
        rngs = [episode_rng(seed, int(i)) for i in episode_ids]
        timeline = self.timing and self.timing.timeline(len(episode_ids), self.layout.obs_dim, self.layout.act_dim,
                                                        [timing_rng(seed, int(i)) for i in episode_ids])
        obs = self.sims.reset([episode_seed(seed, int(i)) for i in episode_ids])
        running = np.arange(len(episode_ids))
        for t in range(self.horizon):
            true_obs = obs[running]
            delta = self.attack.perturb(true_obs, [rngs[k] for k in running])
            seen = self.sims.seen(self.mode, true_obs, delta, running)
            timing = None
            if timeline:
                seen, obs_age, dropped = timeline.deliver(t, seen, running)
            action = applied = self.policy.act(seen)
            if timeline:
                applied, action_age = timeline.apply(t, action, running)
                timing = np.stack([obs_age, dropped, action_age], axis=1).astype(np.float64)
            expert_action = self.expert.act(true_obs)
            obs[running], reward, terminated, truncated = self.sims.step(applied, running)
            done = terminated | truncated
            yield StepBatch(true_obs=true_obs, obs=seen, delta=delta, action=action, expert_action=expert_action,
                            reward=reward, t=t, episodes=episode_ids[running], done=done, applied_action=applied,
                            timing=timing)
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
        timing = np.zeros((episodes, H, 3)) if self.timing else None
        applied = np.zeros((episodes, H, lay.act_dim)) if self.timing else None
        for step in self.iter_steps(episodes, seed):
            e, t = step.episodes, step.t
            for name, arr in {**obs_arrays, **act_arrays}.items():
                arr[e, t] = getattr(step, name)
            reward[e, t] = step.reward
            length[e] = t + 1
            if timing is not None:
                timing[e, t], applied[e, t] = step.timing, step.applied_action
        return Trajectories(**obs_arrays, **act_arrays, reward=reward, length=length, seed=seed, timing=timing,
                            applied_action=applied)

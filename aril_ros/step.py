"""One control step, as the paper defines it (eqs. 5 and 6): the only place its rules are written.

The in-process engine (:mod:`aril_ros.rollout`), the ROS nodes (simulator, attacker, recorder), the
adversary trainer and the log reader all call these, so the graph and the engine cannot drift apart.

A step of an episode, given the true observation ``s`` and a perturbation ``delta`` of its
zero-order entries (``|delta| <= eps``):

- ``clean``: the policy sees ``s``; no attack (``delta = 0``).
- ``sensory``: the policy sees ``s + delta`` (:func:`sensory_observation`); the simulator is untouched.
- ``physical``: the simulator's zero-order state is moved by ``delta`` before the policy acts
  (:func:`physical_state` writes it into the full MuJoCo state), so the policy sees the observation
  of the moved state and the dynamics continue from it. A state that ``delta`` leaves unchanged is not
  written (:func:`state_moved`), so a zero perturbation is no perturbation: the step is clean's.

Under a timing attack (:mod:`aril_ros.timing`) the policy may see an earlier step's observation, or the last one it
saw again (:func:`seen_step`, a drop within its share: :func:`may_drop`), and the simulator apply an earlier step's
action (:func:`applied_step`; before the episode's first, :data:`DEFAULT_ACTION`), drawn from a stream of the episode's
own (:func:`timing_rng`).

In every mode the expert labels ``s``, the true state before the attack, and the step's loss is the
disagreement ``||a - pi_e(s)||^2`` (:func:`disagreement`). Episode ``e`` of a run with ``seed``
resets its env with ``seed + e`` and draws its attack noise from :func:`episode_rng`, so its
trajectory does not depend on what runs beside it. A step is complete when every step topic has
arrived (:func:`missing_topics`). This module imports neither torch, MuJoCo nor rclpy.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import protocol as P

# mjSTATE_INTEGRATION vectors start with time, then qpos (MuJoCo orders components by mjtState bit).
STATE_QPOS_START = 1


def episode_rng(seed: int, episode: int) -> np.random.Generator:
    """The attack noise of episode ``episode`` of a run with ``seed``, drawn from its step 0 on."""
    return np.random.default_rng([seed, episode])


def timing_rng(seed: int, episode: int) -> np.random.Generator:
    """The timing noise of episode ``episode`` (:mod:`aril_ros.timing`): a stream of its own, so a run with timing
    attacked keeps the value attack's perturbations of the same run without it."""
    return np.random.default_rng([seed, episode, TIMING_STREAM])


TIMING_STREAM = 1
"""The third word of :func:`timing_rng`'s seed, which :func:`episode_rng` (two words) never draws."""


def seen_step(t: int, age: np.ndarray, dropped: np.ndarray, last_seen: np.ndarray) -> np.ndarray:
    """The step whose observation the policy sees at step ``t``, per row: the last one it saw again where the
    observation was ``dropped``, else the one ``age`` steps old (late: the newest to have arrived may be older
    than one seen before, as messages overtaking each other do)."""
    return np.where(dropped, last_seen, t - age)


def may_drop(drops: np.ndarray, t: int, share: float) -> np.ndarray:
    """Whether one more drop at step ``t`` keeps every prefix of the episode at or below ``share`` of its steps
    dropped, per row (``drops``: the drops before ``t``): so the share holds at whatever step the episode ends."""
    return drops + 1 <= np.floor(share * (t + 1) + 1e-9)


def applied_step(t: int, age: np.ndarray) -> np.ndarray:
    """The step whose action the simulator applies at step ``t``, per row: the one ``age`` steps old; before the
    episode's first (negative), :data:`DEFAULT_ACTION` is applied."""
    return t - age


DEFAULT_ACTION = 0.0
"""What a delayed action's simulator applies before the episode's first action has reached it: every actuator at
rest (zero torque), which MuJoCo's own default control is too."""


def episode_seed(seed: int, episode: int) -> int:
    """The env seed episode ``episode`` of a run with ``seed`` resets with."""
    return seed + episode


def sensory_observation(true_obs: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """What the policy sees under a sensory attack (and clean, with ``delta = 0``)."""
    return true_obs + delta


def perturb_qpos(layout, qpos: np.ndarray, delta: np.ndarray) -> None:
    """A physical attack, in place: ``delta[position]`` added to ``qpos[qpos_offset:]`` (the entries the
    observation's zero-order part shows), for one state or for rows of them (``[n, nq]`` and ``[n, obs_dim]``).
    The engine applies it to MuJoCo's ``qpos``.

    A free joint's quaternion is left unnormalised: MuJoCo normalises it wherever it is used, so the
    bound ``|delta| <= eps`` holds exactly on what is written.
    """
    qpos[..., layout.qpos_offset : layout.qpos_offset + layout.n_position] += delta[..., layout.position]


def state_moved(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """Whether a physical attack moved a state (per row of ``[..., n]`` arrays). A state it leaves unchanged is not
    written: writing one has MuJoCo derive the bodies' positions from it anew (``mj_forward``), where a step
    leaves them as they were one substep earlier, and Ant's reward reads them, so rewriting an unchanged state
    would make a zero perturbation change the episode. Compared by value: ``-0.0 + 0.0`` moves nothing."""
    return np.any(np.asarray(after) != np.asarray(before), axis=-1)


def physical_state(layout, state: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """The ``mjSTATE_INTEGRATION`` vector ``state`` moved by :func:`perturb_qpos`: what the attacker node
    sends the simulator, which gives bit-for-bit the engine's state."""
    new = np.array(state, dtype=np.float64)
    perturb_qpos(layout, new[STATE_QPOS_START:], delta)
    return new


def disagreement(action: np.ndarray, expert_action: np.ndarray) -> np.ndarray:
    """``||a - a_e||^2`` per row: the step's loss, which ARIL-A maximises and DAgger's learner minimises."""
    return ((np.asarray(action) - np.asarray(expert_action)) ** 2).sum(axis=-1)


@dataclass
class EpisodeStats:
    """One episode's figures, accumulated step by step: return, disagreement, length, largest |delta|."""

    episode: int = 0
    reward: float = 0.0
    squared_loss: float = 0.0
    steps: int = 0
    max_delta: float = 0.0
    done: bool = False

    def add(self, reward: float, action: np.ndarray, expert_action: np.ndarray, delta: np.ndarray,
            done: bool = False) -> None:
        self.reward += float(reward)
        self.squared_loss += float(disagreement(action, expert_action))
        self.max_delta = max(self.max_delta, float(np.abs(delta).max(initial=0.0)))
        self.steps += 1
        self.done = bool(done)

    @property
    def expert_loss(self) -> float:
        """The mean over its steps of ``||a - a_e||^2``."""
        return self.squared_loss / max(self.steps, 1)

    def line(self) -> str:
        """How a run prints a finished episode."""
        return (f"episode {self.episode:3d}  return {self.reward:9.1f}  expert loss {self.expert_loss:.4f}  "
                f"steps {self.steps:4d}  max|delta| {self.max_delta:.4f}")


def summarise_episodes(episodes: list[EpisodeStats]) -> dict:
    """The figures a run reports for its episodes (``aril eval`` and ``run_graph.py`` alike)."""
    returns = np.array([e.reward for e in episodes])
    steps = sum(e.steps for e in episodes)
    return {"episodes": len(episodes), "mean_return": round(float(returns.mean()), 3),
            "std_return": round(float(returns.std()), 3),
            "mean_expert_loss": round(sum(e.squared_loss for e in episodes) / steps, 6),
            "max_abs_delta": round(max(e.max_delta for e in episodes), 6), "steps": int(steps),
            "returns": [round(float(r), 3) for r in returns]}


def missing_topics(have, topics: tuple[str, ...] = P.STEP_TOPICS) -> list[str]:
    """The step topics (``topics``: the run's, :func:`aril_ros.protocol.step_topics`) a step still lacks (``have``:
    the topics it has); empty when it is complete."""
    return [t for t in topics if t not in have]


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

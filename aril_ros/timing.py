"""Timing attacks: observations that arrive late or not at all, and actions applied late, within a budget -- what a
policy running on ROS 2 meets besides wrong values.

At step ``t`` of an episode, by the rules of :mod:`aril_ros.step`:

- **delay** (``delay:=K``): the policy sees the observation of step ``t - k``, ``k <= min(K, t)``. Ages chosen per
  step may show an older observation after a newer one, as messages overtaking each other do.
- **drop** (``drop:=rho``): the policy sees again the observation it saw last, on at most a share ``rho`` of the
  episode's steps, counted over every prefix of it (:func:`~aril_ros.step.may_drop`), so the share holds wherever
  the episode ends.
- **action delay** (``action_delay:=J``): the simulator applies the action the policy computed at step ``t - j``,
  ``j <= J``; where that step is before the episode's first, :data:`~aril_ros.step.DEFAULT_ACTION` (rest).

A timing attack composes with the mode's value attack: what is delayed or dropped is the observation the policy
would have seen at that step (``s + delta`` sensory, the moved state's physical). The expert labels the true state
of step ``t``; the step's disagreement is the applied action's with it (late, the action acting at ``t`` is an older
one), while DAgger learns the action the policy computed from what it saw.

Who picks ``k``, the drops and ``j`` within the budget (:data:`CHOOSERS`): ``fixed``, the most every step (a constant
latency; a drop whenever the share allows one); ``random``, drawn per step from the episode's own stream
(:func:`~aril_ros.step.timing_rng`): ``k`` and ``j`` uniform over ``0..budget``, a drop with probability ``rho``
where the share allows it; or ``learned``, a timing adversary (:mod:`aril_ros.timing_adversary`, trained by PPO on
the paper's expert-disagreement objective) that chooses from the observation due at the step when to be late, drawing
from the same stream. Whoever picks, the budget's rules bound what is played.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .args import arg
from .step import DEFAULT_ACTION, applied_step, may_drop, seen_step

CHOOSERS = ("fixed", "random", "learned")
TIMING_ROWS = {"delay": "every observation {k} step(s) late", "action_delay": "every action {k} step(s) late",
               "drop": "{k}0% of the observations dropped",
               "drop_learned": "{k}0% of the observations dropped when a timing adversary trained against it picks"}
"""The timing rows of ``aril scorecard`` (the policy otherwise clean) at its timing budget ``k`` (``timing:=``), as its
page names each: the fixed chooser's (the most every step), and the learned one's where a learned adversary was
measured to find far more than the most every step (drops; results/timing_tuning.md)."""
LEARNED_TIMING_ROW = "drop_learned"


def timing_arg(name: str, where: str = ""):
    """The argument ``name`` (``delay``, ``drop``, ``action_delay``, ``timing``, ``timing_file``) of a command that plays timing
    attacks, ``where`` saying where it plays them if not everywhere: one help text for every command."""
    scope = f"timing attack{f' ({where})' if where else ''}: "
    if name == "delay":
        return arg(0, scope + "the oldest observation the policy may be shown, in steps (aril_ros.timing)",
                   low=0, high=1000)
    if name == "drop":
        return arg(0.0, scope + "the share of each episode's steps on which the policy may be shown the observation it "
                                "was shown last, again", low=0.0, high=0.99)
    if name == "action_delay":
        return arg(0, scope + "the oldest action the simulator may apply, in steps (before the episode's first: every "
                              "actuator at rest)", low=0, high=1000)
    if name == "timing_file":
        return arg("", scope + "timing:=learned's timing adversary file (aril train-adversary mode:=clean with a timing "
                               "budget)")
    return arg("fixed", f"who picks within the timing budget: {', '.join(CHOOSERS)} (fixed: the most every step; "
                        "random: drawn per step; learned: a timing adversary, timing_file:=)")


@dataclass(frozen=True)
class TimingBudget:
    """How far a timing attack may go; all zero: no timing attack."""

    delay: int = 0
    """the oldest observation the policy may be shown, in steps"""
    drop: float = 0.0
    """the share of an episode's steps on which the policy may be shown the last observation it saw again"""
    action_delay: int = 0
    """the oldest action the simulator may apply, in steps"""

    def __post_init__(self):
        if self.delay < 0 or self.action_delay < 0:
            raise ValueError(f"delay:= and action_delay:= are steps, 0 or more: got {self.delay}, {self.action_delay}")
        if not 0.0 <= self.drop < 1.0:
            raise ValueError(f"drop:= is a share of an episode's steps, from 0 up to (not including) 1: "
                             f"got {self.drop}")

    @property
    def any(self) -> bool:
        return bool(self.delay or self.drop or self.action_delay)

    def described(self) -> str:
        """The budget as a line of text names it: its settings that are set (``delay 1, drop 0.1``)."""
        return ", ".join(f"{k.replace('_', ' ')} {v:g}" for k, v in dataclasses.asdict(self).items() if v)


@dataclass(frozen=True)
class TimingAttack:
    """A timing attack: its budget, who picks within it (one of :data:`CHOOSERS`) and, for ``learned``, the timing
    adversary's file."""

    budget: TimingBudget
    chooser: str = "fixed"
    file: str = ""

    def __post_init__(self):
        if self.chooser not in CHOOSERS:
            raise ValueError(f"unknown timing chooser {self.chooser!r}; choose one of {', '.join(CHOOSERS)}")
        if self.chooser == "learned" and not self.file:
            raise ValueError("timing:=learned plays a timing adversary: give its file as timing_file:=")
        if self.file and self.chooser != "learned":
            raise ValueError(f"timing_file:={self.file} is played by timing:=learned, got timing:={self.chooser}")

    @classmethod
    def of(cls, settings) -> TimingAttack:
        """The timing attack a command's settings name: their ``delay``, ``drop``, ``action_delay``, ``timing`` and
        ``timing_file`` (:func:`timing_arg`'s arguments)."""
        return cls(TimingBudget(settings.delay, settings.drop, settings.action_delay), settings.timing,
                   getattr(settings, "timing_file", ""))

    def record(self) -> dict:
        """The attack as a log, a summary or a result records it: its budget, its chooser and a learned one's file."""
        return {**dataclasses.asdict(self.budget), "chooser": self.chooser, **({"file": self.file} if self.file else {})}

    def timeline(self, n: int, obs_dim: int, act_dim: int, rngs: list[np.random.Generator]) -> Timeline:
        """The timing of ``n`` episodes run side by side, each drawing from its own stream in ``rngs``."""
        chooser = self.pick()
        if isinstance(chooser, LearnedChooser) and chooser.net.meta["obs_dim"] != obs_dim:
            raise ValueError(f"timing_file:={self.file} was trained on {chooser.net.meta['env_id']}'s observations "
                             f"({chooser.net.meta['obs_dim']} entries), not these ({obs_dim})")
        return Timeline(self.budget, chooser, n, obs_dim, act_dim, rngs)

    def pick(self) -> Chooser | LearnedChooser:
        """Who picks within the budget; a learned one's file is loaded (and checked against the budget) once."""
        if self.chooser != "learned":
            return Chooser(self.chooser, self.budget)
        if "net" not in self.__dict__:  # frozen: the loaded network is a cache, not a field
            from .timing_adversary import load_timing_adversary  # torch, for the learned chooser alone
            object.__setattr__(self, "net", load_timing_adversary(self.file, dataclasses.asdict(self.budget)))
        return LearnedChooser(self.__dict__["net"])


@dataclass
class TimingChoice:
    """What a chooser asks for at one step, per row: budgets and rules then bound it (:class:`Timeline`)."""

    obs_age: np.ndarray
    drop: np.ndarray
    action_age: np.ndarray


class Chooser:
    """The ``fixed`` or the ``random`` chooser (:data:`CHOOSERS`) within ``budget``."""

    def __init__(self, name: str, budget: TimingBudget):
        self.name, self.budget = name, budget

    def ask(self, observation: np.ndarray, may_drop_now: np.ndarray, rngs: list[np.random.Generator]) -> TimingChoice:
        """A step's asks for the rows whose on-time observation is ``observation``, which may drop one now where
        ``may_drop_now``, and whose timing streams are ``rngs``."""
        n, budget = len(rngs), self.budget
        if self.name == "fixed":
            return TimingChoice(np.full(n, budget.delay), np.full(n, budget.drop > 0), np.full(n, budget.action_delay))
        # random: each row three draws a step, in this order, whatever the budget: streams stay aligned
        draws = [(rng.integers(0, budget.delay + 1), rng.random() < budget.drop,
                  rng.integers(0, budget.action_delay + 1)) for rng in rngs]
        obs_age, drop, action_age = (np.array(column) for column in zip(*draws)) if draws else ([], [], [])
        return TimingChoice(np.asarray(obs_age, dtype=np.int64), np.asarray(drop, dtype=bool),
                            np.asarray(action_age, dtype=np.int64))


class LearnedChooser:
    """The ``learned`` chooser: a timing adversary's choices, each drawn per row from its distribution by one uniform
    draw of the row's stream, three a step whatever the budget (as ``random`` draws three)."""

    def __init__(self, net):
        self.net = net

    def ask(self, observation: np.ndarray, may_drop_now: np.ndarray, rngs: list[np.random.Generator]) -> TimingChoice:
        probabilities = self.net.probabilities(observation, may_drop_now)
        uniform = np.array([rng.random(len(probabilities)) for rng in rngs]).reshape(len(rngs), len(probabilities))
        picked = [(uniform[:, [choice]] >= p.cumsum(-1)[:, :-1]).sum(-1) for choice, p in enumerate(probabilities)]
        return TimingChoice(picked[0].astype(np.int64), picked[1].astype(bool), picked[2].astype(np.int64))


class Timeline:
    """The timing of a group of episodes run side by side (row ``r`` of each call is episode ``rows[r]``): the
    observations each could still be shown, the last it was shown, the actions it computed, and its drops so far.

    Its episodes may be at different steps (the timing adversary's trainer begins each anew where it ends): ``t`` is
    then one step per row, and :meth:`restart` begins a row's next episode."""

    def __init__(self, budget: TimingBudget, chooser: Chooser | LearnedChooser | None, n: int, obs_dim: int,
                 act_dim: int, rngs: list[np.random.Generator]):
        self.budget, self.chooser, self.rngs = budget, chooser, rngs
        self.observations = np.zeros((n, budget.delay + 1, obs_dim))  # step t's at t % (delay + 1)
        self.actions = ActionQueue(n, act_dim, budget.action_delay)
        self.last_obs = np.zeros((n, obs_dim))
        self.last_seen = np.zeros(n, dtype=np.int64)
        self.drops = np.zeros(n, dtype=np.int64)
        self.asked: TimingChoice | None = None

    def may_drop_now(self, t, rows: np.ndarray) -> np.ndarray:
        """Whether the ``rows`` at step ``t`` may be shown their last observation again within the drop share."""
        return may_drop(self.drops[rows], t, self.budget.drop)

    def deliver(self, t, observation: np.ndarray, rows: np.ndarray, asked: TimingChoice | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What the policy sees at step ``t`` of the ``rows`` whose observation would be ``observation``, how many
        steps old it is (0: on time), and whether it was dropped (the last one seen, shown again): as the chooser
        asks, or as ``asked`` (the timing adversary's trainer asks, from its own draws)."""
        allowed = self.may_drop_now(t, rows)
        self.asked = asked or self.chooser.ask(observation, allowed, [self.rngs[r] for r in rows])
        self.observations[rows, t % (self.budget.delay + 1)] = observation
        age = np.minimum(self.asked.obs_age, np.minimum(self.budget.delay, t))
        dropped = self.asked.drop & allowed
        step = seen_step(t, age, dropped, self.last_seen[rows])
        shown = np.where(dropped[:, None], self.last_obs[rows],
                         self.observations[rows, step % (self.budget.delay + 1)])
        self.drops[rows] += dropped
        self.last_seen[rows], self.last_obs[rows] = step, shown
        return shown, t - step, dropped

    def action_age(self) -> np.ndarray:
        """How old the action applied at the step :meth:`deliver` last timed is to be, per row: the asked age within
        the action delay (an age reaching before the episode's first step applies rest, :class:`ActionQueue`)."""
        return np.minimum(self.asked.action_age, self.budget.action_delay)

    def restart(self, rows) -> None:
        """The ``rows`` begin a new episode at step 0, none of its observations dropped yet (what it saw and computed
        before is never reached again: an age never reaches before step 0)."""
        self.drops[rows] = 0

    def apply(self, t, action: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The actions the simulator applies at step ``t`` of the ``rows`` whose policy computed ``action``
        (after :meth:`deliver` of the same step), and how many steps old each is."""
        age = self.action_age()
        self.actions.push(t, action, rows)
        return self.actions.applied(t, age, rows), age


class ActionQueue:
    """The actions a simulator may still apply late, per row (step t's at ``t % (action_delay + 1)``): the engine's
    (:class:`Timeline`) and the simulator node's, which applies what the attacker node's ``attack/timing`` says."""

    def __init__(self, n: int, act_dim: int, action_delay: int):
        self.size = action_delay + 1
        self.actions = np.zeros((n, self.size, act_dim))

    def push(self, t: int, action: np.ndarray, rows: np.ndarray) -> None:
        self.actions[rows, t % self.size] = action

    def applied(self, t: int, age: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """The actions applied at step ``t`` of ``rows``, each ``age`` steps old: rest before the episode's first."""
        step = applied_step(t, age)
        return np.where((step >= 0)[:, None], self.actions[rows, step % self.size], DEFAULT_ACTION)

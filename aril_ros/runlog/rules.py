"""The rules a run log's steps must keep, read from its run's metadata: every reader applies them (the reader
refuses a step that breaks one, recovery drops it), so whatever a reader accepts is what the run applied."""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass

import numpy as np

from .. import protocol as P
from ..protocol import StepTag
from ..registry import MODES
from ..step import may_drop, missing_topics, sensory_observation
from ..timing import TimingBudget
from .layout import DELTA_TOLERANCE, RUN, TIMING_KEY, VALUES, RunLogError, maybe_json


@dataclass(frozen=True)
class RunRules:
    """What the run's metadata (:data:`~aril_ros.runlog.layout.RUN`) says each of its steps must be."""

    mode: str
    eps: float
    obs_names: tuple[str, ...]
    action_names: tuple[str, ...]
    zero_order: np.ndarray
    """which observation entries an attack may perturb (positions and angles)"""
    timing: TimingBudget | None = None
    """a run with a timing attack's budget (its record's ``timing``), else None"""

    @property
    def topics(self) -> tuple[str, ...]:
        return P.step_topics(self.timing is not None)

    @classmethod
    def of(cls, meta: dict[str, str]) -> "RunRules":
        missing = [key for key in ("mode", "eps", "obs_names", "action_names", "zero_order") if key not in meta]
        if missing:
            raise RunLogError(f"its {RUN} metadata lacks {', '.join(missing)} (recorded by an older aril_ros?)")
        try:
            rules = cls(mode=maybe_json(meta["mode"]), eps=float(json.loads(meta["eps"])),
                        obs_names=tuple(json.loads(meta["obs_names"])),
                        action_names=tuple(json.loads(meta["action_names"])),
                        zero_order=np.array(json.loads(meta["zero_order"]), dtype=bool))
            if TIMING_KEY in meta:
                timing = maybe_json(meta[TIMING_KEY])
                rules = dataclasses.replace(rules, timing=TimingBudget(
                    int(timing["delay"]), float(timing["drop"]), int(timing["action_delay"])))
        except (TypeError, ValueError, KeyError) as err:
            raise RunLogError(f"its {RUN} metadata is malformed ({type(err).__name__}: {err})") from None
        if rules.mode not in MODES:
            raise RunLogError(f"its {RUN} metadata has mode {rules.mode!r}, none of {', '.join(MODES)}")
        if not rules.eps >= 0:
            raise RunLogError(f"its {RUN} metadata has eps {rules.eps}")
        if rules.zero_order.shape != (len(rules.obs_names),):
            raise RunLogError(f"its {RUN} metadata has {rules.zero_order.size} zero_order flags for "
                              f"{len(rules.obs_names)} obs_names")
        return rules

    def sizes(self, physics_size: int | None) -> dict[str, int | None]:
        obs, act = len(self.obs_names), len(self.action_names)
        return {P.PHYSICS: physics_size, P.STATE: obs, P.PERTURBATION: obs, P.OBSERVATION: obs, P.ACTION: act,
                P.EXPERT_ACTION: act, P.REWARD: len(P.REWARD_NAMES),
                **({P.TIMING: len(P.TIMING_NAMES)} if self.timing else {})}


def step_fault(rules: RunRules, tag: StepTag, step: dict, probes: dict, physics_size: int | None) -> str | None:
    """What breaks the run's rules in step ``tag`` (``step``: its decoded messages by topic, every copy;
    ``probes``: its probes' by probe tag and topic; ``physics_size``: the log's first step's), or None."""
    missing = missing_topics({topic for topic, copies in step.items() if copies}, rules.topics)
    if missing:
        return f"step {tag} misses {', '.join(missing)}"
    extra = [topic for topic, copies in step.items() if copies and topic not in rules.topics]
    if extra:
        return f"step {tag} has {', '.join(extra)}, which a run without a timing attack has not"
    for topic, copies in step.items():
        if len(copies) > 1:
            return f"step {tag} has {len(copies)} messages on {topic}, one per step is the rule"
    log_time = step[P.STATE][0].log_time
    for topic, (message,) in step.items():
        if message.log_time != log_time:
            return f"step {tag} {topic}: log time {message.log_time}, its step's is {log_time}"
    values = {topic: np.asarray(getattr(step[topic][0].decoded, field), dtype=np.float64)
              for topic, field in VALUES.items() if topic in rules.topics}
    for topic, size in rules.sizes(physics_size).items():
        if size is not None and len(values[topic]) != size:
            return f"step {tag} {topic}: {len(values[topic])} values where the run's layout has {size}"
    delta = values[P.PERTURBATION]
    allowed = np.where(rules.zero_order, np.abs(delta) <= rules.eps + DELTA_TOLERANCE, delta == 0)
    if not allowed.all():
        i = int(np.argmin(allowed))
        bound = f"beyond eps {rules.eps}" if rules.zero_order[i] else "on an entry that is not zero-order (must be 0)"
        return f"step {tag} {P.PERTURBATION}: delta[{i}] ({rules.obs_names[i]}) = {float(delta[i])!r}, {bound}"
    # a physical step moves the state by delta: its zero-order entries show that move, the rest its physics; under
    # a timing attack a clean or sensory step may show an earlier step's (judged with the episode's past: judged())
    shown = rules.zero_order if rules.mode == "physical" else np.ones_like(rules.zero_order)
    on_time = rules.timing is None or rules.mode == "physical"
    if on_time and not np.array_equal(values[P.OBSERVATION][shown], sensory_observation(values[P.STATE], delta)[shown]):
        return (f"step {tag} {P.OBSERVATION}: not {P.STATE} + {P.PERTURBATION}"
                + (" on its zero-order entries" if rules.mode == "physical" else "")
                + f", what a {rules.mode} step shows the policy")
    sizes = {P.OBSERVATION: len(rules.obs_names), P.ACTION: len(rules.action_names)}
    for probe, halves in probes.items():
        for topic, size in sizes.items():
            copies = halves.get(topic, [])
            if len(copies) != 1:
                return f"probe {probe} has {len(copies)} messages on {P.PROBE_CHANNELS[topic]}, one is the rule"
            values = len(getattr(copies[0].decoded, VALUES[topic]))
            if values != size * probe.rows:
                return (f"probe {probe} {P.PROBE_CHANNELS[topic]}: {values} values, the run's layout has {size}"
                        + (f" a probe, {probe.rows} probes" if probe.rows > 1 else ""))
    return None


def judged(rules: RunRules, collected):
    """Each step of ``collected`` (:class:`aril_ros.runlog.reader.Collected`), in log order, with what is wrong
    with it (None: nothing)."""
    physics_size, past = None, None
    for tag in collected.order:
        step = collected.step(tag)
        fault = step_fault(rules, tag, step, collected.probes.get(tag, {}), physics_size)
        if fault is None and physics_size is None:
            physics_size = len(step[P.PHYSICS][0].decoded.position)
        if fault is None and rules.timing is not None:
            if past is None or past.episode != tag.episode:
                past = EpisodeTiming(tag.episode)
            fault = timing_fault(rules, tag, step, past)
        yield tag, fault


@dataclass
class EpisodeTiming:
    """What an episode of a timed run showed so far: each step's observation before its timing, its drops, and the
    step whose observation the policy saw last."""

    episode: int
    shown: dict = dataclasses.field(default_factory=dict)
    drops: int = 0
    last_seen: int = -1


def timing_fault(rules: RunRules, tag: StepTag, step: dict, past: EpisodeTiming) -> str | None:
    """What breaks the timing rules (:mod:`aril_ros.timing`) in step ``tag`` of a timed run (``past``: its
    episode's steps before it), or None: the observation is the one of the step its age names, that age within the
    delay (or a drop, within its share of every prefix, showing the last one seen), the action's age within its
    budget."""
    def value(topic):
        return np.asarray(getattr(step[topic][0].decoded, VALUES[topic]), dtype=np.float64)

    t, budget, (age, dropped, action_age) = tag.step, rules.timing, value(P.TIMING)
    past.shown[t] = sensory_observation(value(P.STATE), value(P.PERTURBATION))
    if not (age == int(age) >= 0 and dropped in (0.0, 1.0) and action_age == int(action_age) >= 0):
        return f"step {tag} {P.TIMING}: {[float(age), float(dropped), float(action_age)]} are no ages and drop flag"
    if action_age > budget.action_delay:
        return f"step {tag} {P.TIMING}: action age {int(action_age)}, beyond the action delay {budget.action_delay}"
    if rules.mode == "physical":  # the simulator shows the moved state's observation itself, on time
        return f"step {tag} {P.TIMING}: a physical step's observation is on time, age {int(age)}" if age else None
    if dropped:
        if not may_drop(np.array([past.drops]), t, budget.drop)[0]:
            return f"step {tag} {P.TIMING}: drop {past.drops + 1} of {t + 1} steps, beyond the share {budget.drop}"
        if t - age != past.last_seen:
            return (f"step {tag} {P.TIMING}: dropped, but shows step {t - int(age)}'s, not the last seen "
                    f"({past.last_seen})")
        past.drops += 1
    elif age > min(budget.delay, t):
        return f"step {tag} {P.TIMING}: observation age {int(age)}, beyond the delay {budget.delay} (or the step)"
    seen = t - int(age)
    if seen not in past.shown:
        return f"step {tag} {P.TIMING}: shows step {seen}'s observation, which the log does not hold"
    if not np.array_equal(value(P.OBSERVATION), past.shown[seen]):
        return (f"step {tag} {P.OBSERVATION}: not step {seen}'s {P.STATE} + {P.PERTURBATION}, what its "
                f"{P.TIMING} says the policy was shown")
    past.last_seen = seen
    return None


def gap(order: list[StepTag], missing_steps: set[StepTag]) -> str | None:
    """Where an episode of the log does not run from step 0 on without a gap, but for the steps its end
    record declares missing (a recovered log's), or None."""
    last_step: dict[int, int] = {}
    for tag in order:
        after = last_step.get(tag.episode, -1)
        if tag.step <= after or any(StepTag(tag.episode, s) not in missing_steps for s in range(after + 1, tag.step)):
            return f"episode {tag.episode} jumps to step {tag.step} after {after}"
        last_step[tag.episode] = tag.step
    return None

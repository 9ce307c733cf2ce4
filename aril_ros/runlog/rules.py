"""The rules a run log's steps must keep, read from its run's metadata: every reader applies them (the reader
refuses a step that breaks one, recovery drops it), so whatever a reader accepts is what the run applied."""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from .. import protocol as P
from ..protocol import StepTag
from ..registry import MODES
from ..step import missing_topics, sensory_observation
from .layout import DELTA_TOLERANCE, RUN, VALUES, RunLogError, maybe_json


@dataclass(frozen=True)
class RunRules:
    """What the run's metadata (:data:`~aril_ros.runlog.layout.RUN`) says each of its steps must be."""

    mode: str
    eps: float
    obs_names: tuple[str, ...]
    action_names: tuple[str, ...]
    zero_order: np.ndarray
    """which observation entries an attack may perturb (positions and angles)"""

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
        except (TypeError, ValueError) as err:
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
                P.EXPERT_ACTION: act, P.REWARD: len(P.REWARD_NAMES)}


def step_fault(rules: RunRules, tag: StepTag, step: dict, probes: dict, physics_size: int | None) -> str | None:
    """What breaks the run's rules in step ``tag`` (``step``: its decoded messages by topic, every copy;
    ``probes``: its probes' by probe tag and topic; ``physics_size``: the log's first step's), or None."""
    missing = missing_topics({topic for topic, copies in step.items() if copies})
    if missing:
        return f"step {tag} misses {', '.join(missing)}"
    for topic, copies in step.items():
        if len(copies) > 1:
            return f"step {tag} has {len(copies)} messages on {topic}, one per step is the rule"
    log_time = step[P.STATE][0].log_time
    for topic, (message,) in step.items():
        if message.log_time != log_time:
            return f"step {tag} {topic}: log time {message.log_time}, its step's is {log_time}"
    values = {topic: np.asarray(getattr(step[topic][0].decoded, field), dtype=np.float64)
              for topic, field in VALUES.items()}
    for topic, size in rules.sizes(physics_size).items():
        if size is not None and len(values[topic]) != size:
            return f"step {tag} {topic}: {len(values[topic])} values where the run's layout has {size}"
    delta = values[P.PERTURBATION]
    allowed = np.where(rules.zero_order, np.abs(delta) <= rules.eps + DELTA_TOLERANCE, delta == 0)
    if not allowed.all():
        i = int(np.argmin(allowed))
        bound = f"beyond eps {rules.eps}" if rules.zero_order[i] else "on an entry that is not zero-order (must be 0)"
        return f"step {tag} {P.PERTURBATION}: delta[{i}] ({rules.obs_names[i]}) = {float(delta[i])!r}, {bound}"
    # a physical step moves the state by delta: its zero-order entries show that move, the rest its physics
    shown = rules.zero_order if rules.mode == "physical" else np.ones_like(rules.zero_order)
    if not np.array_equal(values[P.OBSERVATION][shown], sensory_observation(values[P.STATE], delta)[shown]):
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
    physics_size = None
    for tag in collected.order:
        step = collected.step(tag)
        fault = step_fault(rules, tag, step, collected.probes.get(tag, {}), physics_size)
        if fault is None and physics_size is None:
            physics_size = len(step[P.PHYSICS][0].decoded.position)
        yield tag, fault


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

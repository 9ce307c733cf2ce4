"""The step recorder behind a graph run, fed the raw CDR of every message on the step topics (no rclpy here): it
joins each step's messages by step tag and the probes asked during it by probe tag, writes a step once it is
complete, in order, and takes each episode's figures as it writes its steps, once: they go into the log's end
record (:attr:`aril_ros.runlog.reader.RunLog.episode_stats`), where a reader finds them without summing the steps."""
from __future__ import annotations

import hashlib

import numpy as np

from .. import protocol as P
from ..protocol import ProbeTag, StepTag
from ..step import DEFAULT_ACTION, EpisodeStats, applied_step, missing_topics
from . import cdr
from .layout import VALUES
from .writer import RunLogWriter

PRODUCERS = {P.CLOCK: "simulator", P.STATE: "simulator", P.PHYSICS: "simulator", P.REWARD: "simulator",
             P.PERTURBATION: "attacker", P.OBSERVATION: "attacker, or simulator when physical", P.ACTION: "policy",
             P.EXPERT_ACTION: "expert", P.TIMING: "attacker"}
"""Which node publishes each step topic, for saying what a stuck step waits for."""


class StepFault(ValueError):
    """A step message the recorder refuses: a second, different copy, or a malformed frame_id."""


def add_step(episode: EpisodeStats, messages: dict[str, bytes], actions: dict[int, np.ndarray]) -> dict:
    """A step's figures (``messages``: its CDR bytes by topic) into its episode's, and returned (``reward``,
    ``action`` applied, ``expert_action``, ``perturbation``); the episode ends with the step whose reward says
    terminated or truncated. ``actions``: a timed run's episode's actions so far by step, this one's added: under an
    action delay (the step's ``attack/timing``) the action applied, whose disagreement counts, is an earlier one
    (:func:`aril_ros.step.applied_step`)."""
    def values(topic):
        return cdr.joint_values(messages[topic], VALUES[topic])

    t, action = episode.steps, values(P.ACTION)
    if P.TIMING in messages:  # kept only where an action delay may apply it later
        actions[t] = action
        earlier = int(applied_step(t, int(values(P.TIMING)[2])))
        action = actions[earlier] if earlier >= 0 else np.full_like(action, DEFAULT_ACTION)
    reward, terminated, truncated = values(P.REWARD)
    figures = {"reward": reward, "action": action, "expert_action": values(P.EXPERT_ACTION),
               "perturbation": values(P.PERTURBATION)}
    episode.add(reward, action, figures["expert_action"], figures["perturbation"], done=bool(terminated or truncated))
    return figures


class StepRecorder:
    """Collects each step's raw messages by step tag, and the probes asked during it by probe tag; writes a
    step with its probes once it is complete, in order, to ``writer`` (None: figures only), and shows it on ``live``
    (a :class:`aril_ros.runlog.live.LiveView`; None: no live view).

    Exactly one message per topic per step: a second copy of a step message, whether the step is still open or
    already written, is counted as a harmless duplicate (``duplicates``) when it is byte for byte the first, and
    is a :class:`StepFault` otherwise (the step keeps the first, which is what the simulator applied). A written
    step is never reopened. Copies are compared by digest, kept for the steps of this episode and the last.
    """

    def __init__(self, writer: RunLogWriter | None, topics: tuple[str, ...] = P.STEP_TOPICS, live=None):
        self.writer = writer
        self.live = live
        self.topics = topics  # the run's step topics (aril_ros.protocol.step_topics): what completes a step
        self.pending: dict[StepTag, dict[str, bytes]] = {}
        self.clock: dict[int, bytes] = {}
        self.stamp: dict[StepTag, int] = {}
        self.episode_stats: list[EpisodeStats] = []  # the finished episodes
        self.steps_written = 0
        self.episode = -1
        self.frames: dict[StepTag, tuple[int, bytes]] = {}  # camera frames whose step is not written yet
        self.last_written: StepTag | None = None
        self.frames_written = 0
        self.probes: dict[StepTag, dict[ProbeTag, dict[str, bytes]]] = {}  # of the steps not written yet
        self.probes_answered = 0
        self.written: dict[StepTag, dict[str, bytes]] = {}  # digests of the written steps' messages, by tag
        self.last_stamp = -1  # the sim time of the last written step (its /clock)
        self.duplicates = 0  # harmless byte-identical copies of step messages

    def start_episode(self, episode: int) -> None:
        self.episode, self.episode_done = episode, False
        self.current = EpisodeStats(episode)
        self.actions: dict[int, np.ndarray] = {}  # the episode's, by step: an action delay applies an earlier one
        self.written = {tag: digests for tag, digests in self.written.items() if tag.episode >= episode - 1}

    def close(self, interrupted: bool, reason: str = "") -> None:
        """Close the log, its end record holding the finished episodes' figures."""
        if self.writer is not None:
            self.writer.close(interrupted=interrupted, reason=reason, episodes=self.episode_stats)

    def on_frame(self, raw: bytes) -> None:
        """A camera frame goes into the log right after its step (log times stay in sim-time order)."""
        stamp, frame_id = cdr.header(raw)
        tag = step_tag_of(P.CAMERA, frame_id)
        if self.last_written is not None and tag <= self.last_written:
            self._write_frame(stamp, raw)
        else:
            self.frames[tag] = (stamp, raw)

    def _write_frame(self, stamp: int, raw: bytes) -> None:
        if self.writer is not None:
            self.writer.write_frame(stamp, raw)
        if self.live is not None:
            self.live.show_frame(stamp, raw)
        self.frames_written += 1

    def on_message(self, topic: str, raw: bytes) -> None:
        if topic == P.CLOCK:
            stamp = cdr.clock_stamp(raw)
            if stamp <= self.last_stamp or stamp in self.clock:
                self.duplicates += 1  # a Clock is its stamp alone: a second one for a stamp is the same bytes
                return
            self.clock[stamp] = raw
        else:
            stamp, frame_id = cdr.header(raw)
            if P.is_probe(frame_id):  # a query-based attack's question to the policy, or the answer
                probe = ProbeTag.parse(frame_id)
                if self.last_written is None or probe.step > self.last_written:  # else a late repeat of a probe
                    self.probes.setdefault(probe.step, {}).setdefault(probe, {})[topic] = raw
            else:
                tag = step_tag_of(topic, frame_id)
                if self.last_written is not None and tag <= self.last_written:
                    self.repeated(tag, topic, raw, self.written.get(tag, {}).get(topic), "was written already")
                    return
                if topic in self.pending.get(tag, {}):
                    self.repeated(tag, topic, raw, digest(self.pending[tag][topic]), "has one already")
                    return
                self.pending.setdefault(tag, {})[topic] = raw
                if topic == P.STATE:
                    self.stamp[tag] = stamp
        self.flush()

    def repeated(self, tag: StepTag, topic: str, raw: bytes, first: bytes | None, step_has: str) -> None:
        """A second message on ``topic`` for step ``tag``, whose first has digest ``first`` (None: forgotten)."""
        if first == digest(raw):
            self.duplicates += 1
            return
        raise StepFault(f"step {tag}: a second message on {topic}, different from the first (the step {step_has}; "
                        "one message per topic per step)" if first is not None else
                        f"step {tag}: a message on {topic} for a step written more than an episode ago")

    def arrived(self, tag: StepTag) -> set[str]:
        """The step topics of ``tag`` heard so far (its ``/clock`` joins it by the state's stamp)."""
        return {*self.pending[tag], *([P.CLOCK] if self.stamp.get(tag) in self.clock else [])}

    def half_heard(self, tag: StepTag) -> int:
        """Probes of ``tag`` heard on one of observation and action only. The policy answers a step's probes
        before it acts, on one publisher, so once the step's action is in so is every probe's answer; but a
        probe's observation comes from another publisher (the attacker's probe client) and may still be on its way."""
        return sum(len(probe) < len(P.PROBE_CHANNELS) for probe in self.probes.get(tag, {}).values())

    def complete(self, tag: StepTag) -> bool:
        return not missing_topics(self.arrived(tag), self.topics) and not self.half_heard(tag)

    def flush(self) -> None:
        # the step to write is the waiting one, not the first heard: a stray action's tag (a policy that does not
        # copy the observation's header) must not hold up the steps after it
        while (tag := self.waiting_for()) in self.pending and self.complete(tag):
            msgs = self.pending.pop(tag)
            stamp = self.stamp.pop(tag)
            msgs[P.CLOCK] = self.clock.pop(stamp)
            asked = self.probes.pop(tag, {})
            probes = [asked[probe] for probe in sorted(asked)]
            if self.writer is not None:
                self.writer.write_step(stamp, msgs, probes)
            self.written[tag] = {topic: digest(raw) for topic, raw in msgs.items()}
            self.last_stamp = stamp
            self.probes_answered += sum(probe.rows for probe in asked)  # a probe batch answers its rows
            self.last_written = tag
            figures = self.count_step(msgs)
            if self.live is not None:
                self.live.show_step(stamp, msgs, probes, figures, self.current)
            if tag in self.frames:
                self._write_frame(*self.frames.pop(tag))

    def count_step(self, messages: dict[str, bytes]) -> dict:
        """A written step's figures into the episode's, and returned; the episode ends with its last step."""
        figures = add_step(self.current, messages, self.actions)
        self.steps_written += 1
        if self.current.done:
            self.episode_stats.append(self.current)
            self.episode_done = True
        return figures

    def waiting_for(self) -> StepTag:
        """The step to be written next: steps are written in order, from 0 in each episode."""
        return StepTag(self.episode, self.current.steps)

    def missing_text(self) -> str:
        tag = self.waiting_for()
        if tag not in self.pending:
            return f"no {P.STATE} from the simulator"
        missing = [f"{t} ({PRODUCERS[t]})" for t in missing_topics(self.arrived(tag), self.topics)]
        half_heard = self.half_heard(tag)
        if half_heard:
            missing.append(f"{half_heard} probes' observation or answer (attacker, policy)")
        return "waiting for " + ", ".join(missing)

    def stray_text(self) -> str:
        """Why the waiting step's action never came, if actions for other steps did; else ``""``."""
        tag, strays = self.waiting_for(), self.stray_actions()
        if not strays or P.ACTION in self.pending.get(tag, {}):
            return ""
        shown = ", ".join(map(str, strays[:3])) + (f" and {len(strays) - 3} more" if len(strays) > 3 else "")
        return (f"actions arrived tagged {shown} while step {tag} was waiting: the policy must answer with the "
                "observation's header (its frame_id, the step tag, is what the simulator steps on)")

    def stray_actions(self) -> list[StepTag]:
        """Tags of the actions heard for a step other than the one waiting, which no step can use: in lockstep the
        simulator publishes no step before its predecessor's action, so these come from a policy that tags its
        answers with something else than the observation's frame_id."""
        waiting = self.waiting_for()
        return sorted(tag for tag, msgs in self.pending.items() if tag != waiting and P.ACTION in msgs)


def step_tag_of(topic: str, frame_id: str) -> StepTag:
    try:
        return StepTag.parse(frame_id)
    except ValueError as err:
        raise StepFault(f"a message on {topic} with a malformed frame_id: {err}"
                        + (" (a policy must answer with the observation's header)" if topic == P.ACTION else "")
                        ) from None


def digest(raw: bytes) -> bytes:
    return hashlib.blake2b(raw, digest_size=16).digest()

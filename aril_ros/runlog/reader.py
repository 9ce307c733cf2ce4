"""The run log's reader: a log, checked against its run's rules (:mod:`aril_ros.runlog.rules`), as arrays."""
from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.reader import make_reader

from .. import protocol as P
from ..protocol import ProbeTag, StepTag
from ..step import EpisodeStats, StepArrays
from . import cdr
from .layout import (CAMERA_CHANNEL, END, PROBE_CHANNELS, RUN, SCHEMAS, STEP_CHANNELS, VALUES, RunLogError,
                     decoded)
from .rules import RunRules, gap, judged
from .stream import MAGIC


@dataclass
class RunLog(StepArrays):
    """A run log as arrays, one row per step in log order; the probes one row per probe, in the order asked."""

    metadata: dict
    """the run's record (:data:`~aril_ros.runlog.layout.RUN`): env, mode, ``attack_settings``, ``files``, ..."""
    end: dict
    """how it ended (:data:`~aril_ros.runlog.layout.END`)"""
    tags: list[StepTag]
    stamp_ns: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    physics_state: np.ndarray
    probe_obs: np.ndarray
    """the observations a query-based attack put to the policy"""
    probe_action: np.ndarray
    """the policy's answers to them"""
    probe_row: np.ndarray
    """the step (its row) each probe was asked during"""
    timing: np.ndarray | None = None
    """a run with a timing attack's ``attack/timing`` per step (:data:`aril_ros.protocol.TIMING_NAMES`: the age of
    the observation the policy saw, whether it was dropped, the age of the applied action), else None"""

    @property
    def episodes(self) -> np.ndarray:
        return np.array([t.episode for t in self.tags])

    @property
    def probes_per_step(self) -> np.ndarray:
        return np.bincount(self.probe_row, minlength=len(self.tags))

    @property
    def episode_stats(self) -> list[EpisodeStats]:
        """The completed episodes' figures, as the recorder took them while the run went (its end record's)."""
        if "episode_stats" not in self.end:
            raise RunLogError("the log's end record has no episode_stats (recorded by an aril_ros older than them): "
                              "its steps are all there is")
        return [EpisodeStats(**figures) for figures in self.end["episode_stats"]]


@dataclass
class Message:
    log_time: int
    decoded: object
    raw: bytes | None


class Collected:
    """A log's messages by step (step tag; a ``/clock`` joins the step whose log time is its stamp) and by probe
    (probe tag), in log order. Every copy is kept, so a second message for a step is seen, never overwritten."""

    def __init__(self, keep_raw: bool):
        from mcap.records import Schema
        from mcap_ros2.decoder import DecoderFactory

        factory = DecoderFactory()
        self._decoders = {name: factory.decoder_for("cdr", Schema(id=i, name=name, encoding="ros2msg",
                                                                  data=text.encode()))
                          for i, (name, text) in enumerate(SCHEMAS.items(), 1)}
        self._keep_raw = keep_raw
        self.order: list[StepTag] = []
        self.steps: dict[StepTag, dict[str, list[Message]]] = {}
        self.clocks: dict[int, list[Message]] = defaultdict(list)
        self.probes: dict[StepTag, dict[ProbeTag, dict[str, list[Message]]]] = defaultdict(dict)
        self.frames: dict[StepTag, list[Message]] = defaultdict(list)

    def add(self, channel: str, log_time: int, raw: bytes) -> None:
        """File one message of the log's ``channel`` (an absolute topic); a RunLogError if it is undecodable
        or its frame_id is no tag of its channel."""
        if channel == CAMERA_CHANNEL:  # kept whole, for recovery: the readers do not decode frames
            tag = self._parse(channel, log_time, lambda: StepTag.parse(cdr.header(raw)[1]))
            self.frames[tag].append(Message(log_time, None, raw))
            return
        topic = STEP_CHANNELS.get(channel) or PROBE_CHANNELS[channel]
        decode = self._decoders[P.MESSAGE_TYPES[topic]]
        message = Message(log_time, self._parse(channel, log_time, lambda: decode(raw)),
                          raw if self._keep_raw else None)
        if channel in PROBE_CHANNELS:
            probe = self._parse(channel, log_time, lambda: ProbeTag.parse(message.decoded.header.frame_id))
            self.probes[probe.step].setdefault(probe, defaultdict(list))[topic].append(message)
        elif topic == P.CLOCK:
            self.clocks[log_time].append(message)
        else:
            tag = self._parse(channel, log_time, lambda: StepTag.parse(message.decoded.header.frame_id))
            if tag not in self.steps:
                self.steps[tag] = defaultdict(list)
                self.order.append(tag)
            self.steps[tag][topic].append(message)

    @staticmethod
    def _parse(channel: str, log_time: int, parse):
        try:
            return parse()
        except Exception as err:  # the CDR decoder raises several types for damaged bytes
            raise RunLogError(f"a {channel} message at log time {log_time} is damaged "
                              f"({type(err).__name__}: {err})") from None

    def step(self, tag: StepTag) -> dict[str, list[Message]]:
        """The messages of step ``tag`` by topic, its ``/clock`` included."""
        messages = self.steps[tag]
        states = messages.get(P.STATE)
        return {**messages, **({P.CLOCK: self.clocks.get(states[0].log_time, [])} if states else {})}

    def stray(self) -> list[str]:
        """Messages that belong to no step of the log: a ``/clock`` at no step's log time, a probe of no step."""
        step_times = {messages[P.STATE][0].log_time for messages in self.steps.values() if messages.get(P.STATE)}
        return ([f"{P.CLOCK} at log time {t}" for t in self.clocks if t not in step_times]
                + [f"probe {p}" for tag, asked in self.probes.items() if tag not in self.steps for p in asked])


def open_checked(path: Path) -> None:
    """Refuse a path that is no file, or no MCAP file."""
    if not path.is_file():
        raise RunLogError(f"{path}: no such run log")
    with open(path, "rb") as f:
        if f.read(8) != MAGIC:
            raise RunLogError(f"{path}: not an MCAP file")


def read_run(path: str | Path, allow_interrupted: bool = False) -> RunLog:
    """Read a run log, checking it against its run's metadata: every step has exactly one message on each step
    topic, sized by the run's layout, its perturbation within eps on the zero-order entries and 0 elsewhere (and,
    clean or sensory, the observation is the state plus it); every episode runs from step 0 without a gap; and
    the run was not cut short or interrupted (unless ``allow_interrupted``). A RunLogError names what breaks."""
    path = Path(path)
    open_checked(path)
    with open(path, "rb") as f:
        try:
            reader = make_reader(f, validate_crcs=True)
            header = reader.get_header()
            summary = reader.get_summary()
            metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        except Exception as err:  # the mcap reader raises several types for a damaged file
            raise RunLogError(f"{path}: truncated or damaged MCAP ({type(err).__name__}: {err}); "
                              f"`aril log-recover input:={path}` rewrites its intact steps") from None
        if header.profile != "ros2" or RUN not in metadata:
            raise RunLogError(f"{path}: not an aril_ros run log (profile {header.profile!r}, "
                              f"metadata {sorted(metadata)})")
        if summary is None or END not in metadata:
            raise RunLogError(f"{path}: the run log was cut short (no summary or end record); "
                              f"`aril log-recover input:={path}` rewrites its intact steps")
        end = decoded(metadata[END])
        if end.get("interrupted") and not allow_interrupted:
            raise RunLogError(f"{path}: the run was interrupted mid-episode ({end.get('reason', '')}); "
                              "read it with allow_interrupted=True to use its complete steps")
        collected = Collected(keep_raw=False)
        try:
            rules = RunRules.of(metadata[RUN])
            for _, channel, message in reader.iter_messages(topics=[*STEP_CHANNELS, *PROBE_CHANNELS],
                                                            log_time_order=False):
                collected.add(channel.topic, message.log_time, message.data)
        except RunLogError as err:
            raise RunLogError(f"{path}: {err}") from None
        except Exception as err:  # the mcap reader raises several types for a damaged chunk
            raise RunLogError(f"{path}: damaged message data ({type(err).__name__}: {err}); "
                              f"`aril log-recover input:={path}` rewrites its intact steps") from None
    return _assemble(path, rules, metadata[RUN], end, collected)


def _assemble(path: Path, rules: RunRules, meta: dict, end: dict, collected: Collected) -> RunLog:
    for tag, fault in judged(rules, collected):
        if fault:
            raise RunLogError(f"{path}: {fault}")
    stray = collected.stray()
    if stray:
        raise RunLogError(f"{path}: {len(stray)} messages belong to no step of the log, first {stray[0]}")
    order = collected.order
    missing_steps = {StepTag.parse(text) for text in end.get("missing_steps", [])}
    jump = gap(order, missing_steps)
    if jump:
        raise RunLogError(f"{path}: {jump}")
    if end.get("steps") != len(order):
        raise RunLogError(f"{path}: its end record counts {end.get('steps')} steps, the log holds {len(order)}")

    def column(topic, width):  # shaped by the run's layout, so a log without rows has (0, width)
        return np.array([getattr(collected.steps[tag][topic][0].decoded, VALUES[topic]) for tag in order],
                        dtype=np.float64).reshape(len(order), width)

    row = {tag: i for i, tag in enumerate(order)}
    asked = sorted(((tag, probe) for tag in order for probe in collected.probes.get(tag, {})),
                   key=lambda pair: (row[pair[0]], pair[1].index))

    def probe_column(topic, width):  # a probe batch's message holds its rows one after the other
        return np.array([value for tag, probe in asked
                         for value in getattr(collected.probes[tag][probe][topic][0].decoded, VALUES[topic])],
                        dtype=np.float64).reshape(-1, width)

    obs, act = len(rules.obs_names), len(rules.action_names)
    physics = len(collected.steps[order[0]][P.PHYSICS][0].decoded.position) if order else 0
    reward = column(P.REWARD, len(P.REWARD_NAMES))
    return RunLog(
        metadata=decoded(meta),
        end=end,
        tags=order,
        stamp_ns=np.array([collected.steps[tag][P.STATE][0].log_time for tag in order], dtype=np.int64),
        true_obs=column(P.STATE, obs),
        obs=column(P.OBSERVATION, obs),
        delta=column(P.PERTURBATION, obs),
        action=column(P.ACTION, act),
        expert_action=column(P.EXPERT_ACTION, act),
        reward=reward[:, 0],
        terminated=reward[:, 1].astype(bool),
        truncated=reward[:, 2].astype(bool),
        physics_state=column(P.PHYSICS, physics),
        probe_obs=probe_column(P.OBSERVATION, obs),
        probe_action=probe_column(P.ACTION, act),
        probe_row=np.array([row[tag] for tag, probe in asked for _ in range(probe.rows)], dtype=np.int64),
        timing=column(P.TIMING, len(P.TIMING_NAMES)) if rules.timing else None,
    )

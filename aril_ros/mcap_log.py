"""Run logs: ROS 2 bags in MCAP, written step by step, read back into arrays and DAgger datasets.

Layout of a run log (``runs/*.mcap``), readable by ``rosbags`` (``AnyReader``), ``mcap_ros2`` and
Foxglove:

- header profile ``ros2``; schemas ``sensor_msgs/msg/JointState`` and ``rosgraph_msgs/msg/Clock``
  in ``ros2msg`` encoding; messages in ``cdr``, byte for byte as the nodes published them;
- one channel per step topic (:data:`aril_ros.protocol.STEP_TOPICS`) with rosbag2's
  ``offered_qos_profiles`` metadata; with ``run_graph.py render:=true`` also
  ``/sim/camera/image/compressed`` (``sensor_msgs/msg/CompressedImage``, JPEG, stamped and tagged like
  its step, written right after its step), which Foxglove shows as video beside the state plots;
- log time = publish time = the step's sim time, so log times are monotonic and a player paces by
  sim time; each step's messages are written together, in ``STEP_TOPICS`` order, once the step is
  complete, and the file is flushed after every step (a killed run loses no complete step);
- the probes of a query-based attack (observations put to the policy only to read its answer, tagged
  ``"<episode>/<step>/probe/<k>"``) on channels of their own, ``/probe/observation`` and
  ``/probe/action`` (:data:`aril_ros.protocol.PROBE_CHANNELS`), byte for byte as published on
  ``observation`` and ``action``, right after their step at its log time, in the order asked; the step
  channels hold the steps alone, and :func:`read_run` returns the probes beside them;
- metadata ``aril_run`` (env, mode, attack, eps, seed, episodes, policy and expert provenance as
  JSON strings) at the start, and ``aril_run_end`` (steps, episodes completed, interrupted) at the
  end. A file without ``aril_run_end`` or without its summary was cut short: :func:`read_run`
  refuses it, :func:`recover` rewrites its complete steps into a valid log.
"""
from __future__ import annotations

import json
import struct
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from . import protocol as P
from .dataset import DaggerDataset
from .protocol import ProbeTag, StepTag
from .step import StepArrays, missing_topics

_TIME = "int32 sec\nuint32 nanosec\n"
SCHEMAS = {
    "sensor_msgs/msg/JointState": (
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n"
        + "=" * 80 + "\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
        + "=" * 80 + "\nMSG: builtin_interfaces/Time\n" + _TIME
    ),
    P.CAMERA_TYPE: (
        "std_msgs/Header header\nstring format\nuint8[] data\n"
        + "=" * 80 + "\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
        + "=" * 80 + "\nMSG: builtin_interfaces/Time\n" + _TIME
    ),
    "rosgraph_msgs/msg/Clock": (
        "builtin_interfaces/Time clock\n" + "=" * 80 + "\nMSG: builtin_interfaces/Time\n" + _TIME
    ),
}
# rosbag2's (Jazzy) serialisation of the publishers' QoS: reliable, keep all, volatile.
QOS_YAML = (
    "- history: keep_all\n  depth: 0\n  reliability: reliable\n  durability: volatile\n"
    "  deadline:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  liveliness: automatic\n"
    "  liveliness_lease_duration:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  avoid_ros_namespace_conventions: false\n"
)


class RunLogError(ValueError):
    """A file is not an aril_ros run log, or was cut short, or misses part of a step."""


def cdr_header(raw: bytes) -> tuple[int, str]:
    """``(stamp_ns, frame_id)`` of a CDR-encoded message that starts with a ``std_msgs/Header``."""
    sec, nanosec, length = struct.unpack_from("<iII", raw, 4)
    return sec * 1_000_000_000 + nanosec, raw[16 : 16 + length - 1].decode()


def cdr_stamp(raw: bytes) -> int:
    """Stamp in ns of a CDR-encoded ``builtin_interfaces/Time`` first field (``Clock``)."""
    sec, nanosec = struct.unpack_from("<iI", raw, 4)
    return sec * 1_000_000_000 + nanosec


class RunLogWriter:
    """Writes complete steps of a run to MCAP; :meth:`close` adds the end metadata and the summary."""

    def __init__(self, path: str | Path, run_metadata: dict, camera: bool = False):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "wb")
        self._writer = Writer(self._file, compression=CompressionType.ZSTD)
        self._writer.start(profile="ros2", library="aril_ros")
        self._schema_ids = {name: self._writer.register_schema(name, "ros2msg", text.encode())
                            for name, text in SCHEMAS.items()}
        self._channels = {}
        for topic, msg_type in {**P.MESSAGE_TYPES, **({P.CAMERA: P.CAMERA_TYPE} if camera else {})}.items():
            self._register(topic, msg_type)
        self._sequence = 0
        self._writer.add_metadata("aril_run", {k: _text(v) for k, v in run_metadata.items()})
        self.steps = 0

    def write_step(self, stamp_ns: int, messages: dict[str, bytes], probes=()) -> None:
        """Write one complete step (``{topic: cdr bytes}`` for every step topic), then its ``probes`` (each
        ``{observation: cdr bytes, action: cdr bytes}``, in the order asked), and flush it to disk."""
        for topic in P.STEP_TOPICS:
            self._add(topic, stamp_ns, messages[topic])
        for probe in probes:
            for topic, channel in P.PROBE_CHANNELS.items():
                if channel not in self._channels:  # only a run with probes has their channels
                    self._register(channel, P.MESSAGE_TYPES[topic])
                self._add(channel, stamp_ns, probe[topic])
        self._writer.flush()
        self.steps += 1

    def write_frame(self, stamp_ns: int, raw: bytes) -> None:
        """Write one camera frame (CDR ``CompressedImage``) at its step's sim time."""
        self._add(P.CAMERA, stamp_ns, raw)

    def _register(self, channel: str, msg_type: str) -> None:
        self._channels[channel] = self._writer.register_channel(
            topic=_absolute(channel), message_encoding="cdr", schema_id=self._schema_ids[msg_type],
            metadata={"offered_qos_profiles": QOS_YAML})

    def _add(self, channel: str, stamp_ns: int, raw: bytes) -> None:
        self._sequence += 1
        self._writer.add_message(self._channels[channel], log_time=stamp_ns, data=raw, publish_time=stamp_ns,
                                 sequence=self._sequence)

    def close(self, **end_metadata) -> None:
        if self._file.closed:
            return
        self._writer.add_metadata("aril_run_end", {k: _text(v) for k, v in {"steps": self.steps,
                                                                            **end_metadata}.items()})
        self._writer.finish()
        self._file.close()


def _absolute(topic: str) -> str:
    return topic if topic.startswith("/") else "/" + topic


def _text(value) -> str:
    return value if isinstance(value, str) else json.dumps(value)


@dataclass
class RunLog(StepArrays):
    """A run log as arrays, one row per step in log order; the probes one row per probe, in the order asked."""

    metadata: dict
    end: dict
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

    @property
    def episodes(self) -> np.ndarray:
        return np.array([t.episode for t in self.tags])

    @property
    def probes_per_step(self) -> np.ndarray:
        return np.bincount(self.probe_row, minlength=len(self.tags))


def _open_checked(path: Path):
    if not path.is_file():
        raise RunLogError(f"{path}: no such run log")
    with open(path, "rb") as f:
        if f.read(8) != b"\x89MCAP0\r\n":
            raise RunLogError(f"{path}: not an MCAP file")


def read_run(path: str | Path, allow_interrupted: bool = False) -> RunLog:
    """Read a run log, checking that it is complete: every step has every topic, every episode runs
    from step 0 without a gap, and the run was not cut short (unless ``allow_interrupted``)."""
    from mcap_ros2.decoder import DecoderFactory

    path = Path(path)
    _open_checked(path)
    with open(path, "rb") as f:
        try:
            reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
            header = reader.get_header()
            summary = reader.get_summary()
            metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        except Exception as err:  # the mcap reader raises several types for a damaged file
            raise RunLogError(f"{path}: truncated or damaged MCAP ({type(err).__name__}: {err}); "
                              f"`aril log-recover input:={path}` rewrites its complete steps") from None
        if header.profile != "ros2" or "aril_run" not in metadata:
            raise RunLogError(f"{path}: not an aril_ros run log (profile {header.profile!r}, "
                              f"metadata {sorted(metadata)})")
        if summary is None or "aril_run_end" not in metadata:
            raise RunLogError(f"{path}: the run log was cut short (no summary or end record); "
                              f"`aril log-recover input:={path}` rewrites its complete steps")
        end = metadata["aril_run_end"]
        if json.loads(end.get("interrupted", "false")) and not allow_interrupted:
            raise RunLogError(f"{path}: the run was interrupted mid-episode ({end.get('reason', '')}); "
                              "read it with allow_interrupted=True to use its complete steps")
        steps: dict[StepTag, dict] = defaultdict(dict)
        order: list[StepTag] = []
        clock_by_stamp = {}
        probes: dict[ProbeTag, dict] = defaultdict(dict)
        probe_topics = {_absolute(channel): topic for topic, channel in P.PROBE_CHANNELS.items()}
        try:
            topics = [_absolute(t) for t in P.STEP_TOPICS] + list(probe_topics)  # camera frames are not read
            for _, channel, message, decoded in reader.iter_decoded_messages(topics=topics, log_time_order=False):
                topic = channel.topic
                if topic == P.CLOCK:
                    clock_by_stamp[message.log_time] = decoded
                    continue
                if topic in probe_topics:
                    probes[ProbeTag.parse(decoded.header.frame_id)][probe_topics[topic]] = decoded
                    continue
                tag = StepTag.parse(decoded.header.frame_id)
                if tag not in steps:
                    order.append(tag)
                steps[tag][topic.lstrip("/")] = decoded
                steps[tag]["stamp"] = message.log_time
        except Exception as err:
            raise RunLogError(f"{path}: damaged message data ({type(err).__name__}: {err})") from None
    return _assemble(path, metadata["aril_run"], end, order, steps, clock_by_stamp, probes)


def _assemble(path, meta, end, order, steps, clock_by_stamp, probes) -> RunLog:
    for tag in order:
        have = {*steps[tag], *([P.CLOCK] if steps[tag]["stamp"] in clock_by_stamp else [])}
        missing = missing_topics(have)
        if missing:
            raise RunLogError(f"{path}: step {tag} misses {', '.join(missing)}")
    last_step: dict[int, int] = {}
    for tag in order:
        if tag.step != last_step.get(tag.episode, -1) + 1:
            raise RunLogError(f"{path}: episode {tag.episode} jumps to step {tag.step} after "
                              f"{last_step.get(tag.episode, -1)}")
        last_step[tag.episode] = tag.step

    def column(topic, field):
        return np.array([getattr(steps[tag][topic.lstrip("/")], field) for tag in order], dtype=np.float64)

    row = {tag: i for i, tag in enumerate(order)}
    for probe, halves in probes.items():
        if probe.step not in row:
            raise RunLogError(f"{path}: probe {probe} belongs to no step of the log")
        if len(halves) < len(P.PROBE_CHANNELS):
            raise RunLogError(f"{path}: probe {probe} misses its {', '.join(set(P.PROBE_CHANNELS) - set(halves))}")
    asked = sorted(probes, key=lambda probe: (row[probe.step], probe.index))

    def probe_column(topic, field, names):  # shaped by the run's names, so a run without probes has (0, n)
        return np.array([getattr(probes[p][topic], field) for p in asked],
                        dtype=np.float64).reshape(len(asked), len(json.loads(meta[names])))

    reward = column(P.REWARD, "position")
    return RunLog(
        metadata={k: _maybe_json(v) for k, v in meta.items()},
        end={k: _maybe_json(v) for k, v in end.items()},
        tags=order,
        stamp_ns=np.array([steps[tag]["stamp"] for tag in order], dtype=np.int64),
        true_obs=column(P.STATE, "position"),
        obs=column(P.OBSERVATION, "position"),
        delta=column(P.PERTURBATION, "position"),
        action=column(P.ACTION, "effort"),
        expert_action=column(P.EXPERT_ACTION, "effort"),
        reward=reward[:, 0] if len(order) else np.zeros(0),
        terminated=reward[:, 1].astype(bool) if len(order) else np.zeros(0, bool),
        truncated=reward[:, 2].astype(bool) if len(order) else np.zeros(0, bool),
        physics_state=column(P.PHYSICS, "position"),
        probe_obs=probe_column(P.OBSERVATION, "position", "obs_names"),
        probe_action=probe_column(P.ACTION, "effort", "action_names"),
        probe_row=np.array([row[p.step] for p in asked], dtype=np.int64),
    )


def _maybe_json(text: str):
    try:
        return json.loads(text)
    except ValueError:
        return text


def recover(path: str | Path, out: str | Path) -> int:
    """Rewrite the complete steps of a cut-short run log (with their probes) into a valid one; returns how many."""
    path, out = Path(path), Path(out)
    _open_checked(path)
    metadata: dict[str, dict] = {}
    channels: dict[int, str] = {}
    pending: dict[int, dict[str, bytes]] = defaultdict(dict)
    probes: dict[int, dict[ProbeTag, dict[str, bytes]]] = defaultdict(lambda: defaultdict(dict))
    probe_topics = {_absolute(channel): topic for topic, channel in P.PROBE_CHANNELS.items()}
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False).records:
                kind = type(record).__name__
                if kind == "Metadata":
                    metadata[record.name] = dict(record.metadata)
                elif kind == "Channel":
                    channels[record.id] = record.topic
                elif kind == "Message" and channels[record.channel_id] in probe_topics:  # several per log time
                    probe = ProbeTag.parse(cdr_header(record.data)[1])
                    probes[record.log_time][probe][probe_topics[channels[record.channel_id]]] = record.data
                elif kind == "Message":
                    pending[record.log_time][channels[record.channel_id]] = record.data
        except Exception:  # the cut: everything before it has been collected
            pass
    if "aril_run" not in metadata:
        raise RunLogError(f"{path}: not an aril_ros run log; nothing to recover")
    camera = _absolute(P.CAMERA)
    writer = RunLogWriter(out, metadata["aril_run"], camera=camera in channels.values())
    for stamp in sorted(pending):
        messages = {t: pending[stamp][_absolute(t)] for t in P.STEP_TOPICS if _absolute(t) in pending[stamp]}
        if not missing_topics(messages):
            asked = probes[stamp]  # a probe cut in half is dropped, its step kept
            writer.write_step(stamp, messages, [asked[p] for p in sorted(asked) if len(asked[p]) == len(probe_topics)])
            if camera in pending[stamp]:
                writer.write_frame(stamp, pending[stamp][camera])
    writer.close(interrupted=True, reason=f"recovered from {path.name}")
    return writer.steps


def load_dagger_dataset(paths, env_id: str | None = None, allow_interrupted: bool = False) -> DaggerDataset:
    """Aggregate one or many run logs, in the order given; all must be of the same env."""
    paths = [paths] if isinstance(paths, (str, Path)) else list(paths)
    if not paths:
        raise RunLogError("no run logs given")
    runs = [read_run(p, allow_interrupted) for p in paths]
    envs = {run.metadata["env"] for run in runs}
    if env_id is not None:
        envs.add(env_id)
    if len(envs) > 1:
        raise RunLogError(f"run logs of different envs cannot make one dataset: {sorted(envs)}")
    return DaggerDataset.concatenate([dataset_of_run(r, p) for p, r in zip(paths, runs)])


def dataset_of_run(run: RunLog, path) -> DaggerDataset:
    """The (observation seen, expert action) pairs of one run log already read from ``path``."""
    return DaggerDataset(obs=run.obs, expert_action=run.expert_action, episode=run.episodes,
                         source=[str(path)] * len(run.tags))

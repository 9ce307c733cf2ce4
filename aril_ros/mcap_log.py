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
  complete, as one chunk (:class:`aril_ros.mcap_stream.ChunkStreamWriter`), and the file is flushed after
  every step (a killed run loses no complete step);
- the probes of a query-based attack (observations put to the policy only to read its answer, tagged
  ``"<episode>/<step>/probe/<k>"``) on channels of their own, ``/probe/observation`` and
  ``/probe/action`` (:data:`aril_ros.protocol.PROBE_CHANNELS`), byte for byte as published on
  ``observation`` and ``action``, right after their step at its log time, in the order asked; the step
  channels hold the steps alone, and :func:`read_run` returns the probes beside them;
- metadata ``aril_run`` (env, mode, attack, eps, seed, episodes, the observation layout with its
  zero-order entries, policy and expert provenance as JSON strings) at the start, and ``aril_run_end``
  (steps, episodes completed, interrupted, reason, missing steps) at the end. A file without
  ``aril_run_end`` or without its summary was cut short: :func:`read_run` refuses it, :func:`recover`
  rewrites its intact steps into a valid log.

The readers check every step against the run's metadata (:func:`_step_fault`): what they accept is what the
run applied, one message per topic per step, sized by its layout, the perturbation within its bounds.
"""
from __future__ import annotations

import contextlib
import io
import json
import struct
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Footer, Message, Metadata
from mcap.stream_reader import StreamReader, breakup_chunk

from . import protocol as P
from .dataset import DaggerDataset
from .mcap_stream import MAGIC, ChunkStreamWriter
from .protocol import ProbeTag, StepTag
from .registry import MODES
from .step import StepArrays, missing_topics, sensory_observation

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
    """A file is not an aril_ros run log, was cut short or damaged, breaks a rule of its run, or cannot be written."""


DELTA_TOLERANCE = 1e-9
"""How far a logged ``|delta|`` may exceed eps. The attacks clip exactly (:meth:`aril_ros.attacks.Attack.project`)
and eps round-trips exactly through the metadata's JSON, so this spares only another writer's float noise."""


def cdr_header(raw: bytes) -> tuple[int, str]:
    """``(stamp_ns, frame_id)`` of a CDR-encoded message that starts with a ``std_msgs/Header``."""
    sec, nanosec, length = struct.unpack_from("<iII", raw, 4)
    return sec * 1_000_000_000 + nanosec, raw[16 : 16 + length - 1].decode()


_JOINT_STATE_ARRAYS = ("position", "velocity", "effort")


def cdr_joint_values(raw: bytes, field: str) -> np.ndarray:
    """The float64 array ``field`` (``position``, ``velocity`` or ``effort``) of a CDR-encoded ``JointState``, read
    in place: a quarter of the time of deserialising the message (the recorder reads four of every step's)."""
    def aligned(pos: int, size: int) -> int:  # CDR aligns to the field's size, counted after the 4-byte header
        return 4 + -(-(pos - 4) // size) * size

    pos = 16 + struct.unpack_from("<I", raw, 12)[0]  # past the stamp and the frame_id
    pos = aligned(pos, 4)
    (names,) = struct.unpack_from("<I", raw, pos)
    pos += 4
    for _ in range(names):
        pos = aligned(pos, 4)
        pos += 4 + struct.unpack_from("<I", raw, pos)[0]
    for name in _JOINT_STATE_ARRAYS:
        pos = aligned(pos, 4)
        (count,) = struct.unpack_from("<I", raw, pos)
        pos = aligned(pos + 4, 8) if count else pos + 4
        if name == field:
            return np.frombuffer(raw, dtype="<f8", count=count, offset=pos).copy()
        pos += 8 * count
    raise ValueError(f"JointState has no float64 array {field!r}")


def cdr_stamp(raw: bytes) -> int:
    """Stamp in ns of a CDR-encoded ``builtin_interfaces/Time`` first field (``Clock``)."""
    sec, nanosec = struct.unpack_from("<iI", raw, 4)
    return sec * 1_000_000_000 + nanosec


class RunLogWriter:
    """Writes complete steps of a run to MCAP; :meth:`close` adds the end metadata and the summary.

    The file is created exclusively: a path that exists (another run's log) is refused, never written into.
    An OS error while writing (read-only or full disk, file size limit) raises a :class:`RunLogError` naming the
    file and the OS's reason, and the log is then closed as interrupted (or, if the disk allows nothing more,
    left cut short for :func:`recover`)."""

    def __init__(self, path: str | Path, run_metadata: dict, camera: bool = False):
        self.path = Path(path)
        self.steps = 0
        self.failure = ""  # why writing failed, once it has: the log can then only be interrupted
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise RunLogError(f"cannot create the run log's folder {self.path.parent}: "
                              f"{err.strerror or err}") from None
        try:
            self._file = open(self.path, "xb")
        except FileExistsError:
            raise RunLogError(f"{self.path} exists (another run's log?): left untouched; "
                              "record to a new path") from None
        except OSError as err:
            raise RunLogError(f"cannot create the run log {self.path}: {err.strerror or err}") from None
        try:
            self._start(run_metadata, camera)
        except RunLogError:
            for undo in (self._file.close, self.path.unlink):  # the file is ours and empty of any run: not left
                with contextlib.suppress(OSError):
                    undo()
            raise

    def _start(self, run_metadata: dict, camera: bool) -> None:
        with self._writing():
            self._writer = ChunkStreamWriter(self._file, profile="ros2", library="aril_ros")
            self._schema_ids = {name: self._writer.register_schema(name, "ros2msg", text.encode())
                                for name, text in SCHEMAS.items()}
            self._channels = {}
            for topic, msg_type in {**P.MESSAGE_TYPES, **({P.CAMERA: P.CAMERA_TYPE} if camera else {})}.items():
                self._register(topic, msg_type)
            self._sequence = 0
            self._writer.add_metadata("aril_run", {k: _text(v) for k, v in run_metadata.items()})
            self._file.flush()  # a full disk shows now, before the run starts

    @contextlib.contextmanager
    def _writing(self):
        try:
            yield
        except OSError as err:
            self.failure = f"writing the run log {self.path} failed after {self.steps} steps: {err.strerror or err}"
            raise RunLogError(self.failure) from None

    def write_step(self, stamp_ns: int, messages: dict[str, bytes], probes=()) -> None:
        """Write one complete step (``{topic: cdr bytes}`` for every step topic), then its ``probes`` (each
        ``{observation: cdr bytes, action: cdr bytes}``, in the order asked), and flush it to disk."""
        with self._writing():
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
        with self._writing():
            self._add(P.CAMERA, stamp_ns, raw)

    def _register(self, channel: str, msg_type: str) -> None:
        self._channels[channel] = self._writer.register_channel(
            topic=_absolute(channel), message_encoding="cdr", schema_id=self._schema_ids[msg_type],
            metadata={"offered_qos_profiles": QOS_YAML})

    def _add(self, channel: str, stamp_ns: int, raw: bytes) -> None:
        self._sequence += 1
        self._writer.add_message(self._channels[channel], log_time=stamp_ns, data=raw, publish_time=stamp_ns,
                                 sequence=self._sequence)

    def close(self, *, interrupted: bool, episodes_completed: int, reason: str = "", missing_steps=()) -> None:
        """Write the end record, exactly the keys msgs_doc lists (``missing_steps``: the step tags a recovered
        log lacks inside its episodes), and the summary. After a write failure the log is interrupted whatever
        the caller says, and a second failure here is not raised again (the first is on its way)."""
        if self._file.closed:
            return
        failed_before = bool(self.failure)
        if failed_before:
            interrupted, reason = True, self.failure
        end = {"steps": self.steps, "episodes_completed": episodes_completed, "interrupted": interrupted,
               "reason": reason, "missing_steps": [str(tag) for tag in missing_steps]}
        try:
            with self._writing():
                self._writer.add_metadata("aril_run_end", {k: _text(v) for k, v in end.items()})
                self._writer.finish()
                self._file.flush()
        except RunLogError:
            if not failed_before:
                raise
        finally:
            with contextlib.suppress(OSError):  # what it could not write is the failure reported
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


# ------------------------------------------------------------------------------------------ reading
_STEP_CHANNELS = {_absolute(topic): topic for topic in P.STEP_TOPICS}
_PROBE_CHANNELS = {_absolute(channel): topic for topic, channel in P.PROBE_CHANNELS.items()}
_CAMERA_CHANNEL = _absolute(P.CAMERA)
_VALUES = {P.PHYSICS: "position", P.STATE: "position", P.PERTURBATION: "position", P.OBSERVATION: "position",
           P.ACTION: "effort", P.EXPERT_ACTION: "effort", P.REWARD: "position"}
"""The field of each step topic's JointState that holds its values."""


@dataclass(frozen=True)
class _RunRules:
    """What the run's metadata (``aril_run``) says each of its steps must be."""

    mode: str
    eps: float
    obs_names: tuple[str, ...]
    action_names: tuple[str, ...]
    zero_order: np.ndarray
    """which observation entries an attack may perturb (positions and angles)"""

    @classmethod
    def of(cls, meta: dict[str, str]) -> "_RunRules":
        missing = [key for key in ("mode", "eps", "obs_names", "action_names", "zero_order") if key not in meta]
        if missing:
            raise RunLogError(f"its aril_run metadata lacks {', '.join(missing)} (recorded by an older aril_ros?)")
        try:
            rules = cls(mode=_maybe_json(meta["mode"]), eps=float(json.loads(meta["eps"])),
                        obs_names=tuple(json.loads(meta["obs_names"])),
                        action_names=tuple(json.loads(meta["action_names"])),
                        zero_order=np.array(json.loads(meta["zero_order"]), dtype=bool))
        except (TypeError, ValueError) as err:
            raise RunLogError(f"its aril_run metadata is malformed ({type(err).__name__}: {err})") from None
        if rules.mode not in MODES:
            raise RunLogError(f"its aril_run metadata has mode {rules.mode!r}, none of {', '.join(MODES)}")
        if not rules.eps >= 0:
            raise RunLogError(f"its aril_run metadata has eps {rules.eps}")
        if rules.zero_order.shape != (len(rules.obs_names),):
            raise RunLogError(f"its aril_run metadata has {rules.zero_order.size} zero_order flags for "
                              f"{len(rules.obs_names)} obs_names")
        return rules

    def sizes(self, physics_size: int | None) -> dict[str, int | None]:
        obs, act = len(self.obs_names), len(self.action_names)
        return {P.PHYSICS: physics_size, P.STATE: obs, P.PERTURBATION: obs, P.OBSERVATION: obs, P.ACTION: act,
                P.EXPERT_ACTION: act, P.REWARD: len(P.REWARD_NAMES)}


@dataclass
class _Message:
    log_time: int
    decoded: object
    raw: bytes | None


class _Collected:
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
        self.steps: dict[StepTag, dict[str, list[_Message]]] = {}
        self.clocks: dict[int, list[_Message]] = defaultdict(list)
        self.probes: dict[StepTag, dict[ProbeTag, dict[str, list[_Message]]]] = defaultdict(dict)
        self.frames: dict[StepTag, list[_Message]] = defaultdict(list)

    def add(self, channel: str, log_time: int, raw: bytes) -> None:
        """File one message of the log's ``channel`` (an absolute topic); a RunLogError if it is undecodable
        or its frame_id is no tag of its channel."""
        if channel == _CAMERA_CHANNEL:  # kept whole, for recover: the readers do not decode frames
            tag = self._parse(channel, log_time, lambda: StepTag.parse(cdr_header(raw)[1]))
            self.frames[tag].append(_Message(log_time, None, raw))
            return
        topic = _STEP_CHANNELS.get(channel) or _PROBE_CHANNELS[channel]
        decode = self._decoders[P.MESSAGE_TYPES[topic]]
        message = _Message(log_time, self._parse(channel, log_time, lambda: decode(raw)),
                           raw if self._keep_raw else None)
        if channel in _PROBE_CHANNELS:
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

    def step(self, tag: StepTag) -> dict[str, list[_Message]]:
        """The messages of step ``tag`` by topic, its ``/clock`` included."""
        messages = self.steps[tag]
        states = messages.get(P.STATE)
        return {**messages, **({P.CLOCK: self.clocks.get(states[0].log_time, [])} if states else {})}

    def stray(self) -> list[str]:
        """Messages that belong to no step of the log: a ``/clock`` at no step's log time, a probe of no step."""
        step_times = {messages[P.STATE][0].log_time for messages in self.steps.values() if messages.get(P.STATE)}
        return ([f"{P.CLOCK} at log time {t}" for t in self.clocks if t not in step_times]
                + [f"probe {p}" for tag, asked in self.probes.items() if tag not in self.steps for p in asked])


def _step_fault(rules: _RunRules, tag: StepTag, step: dict[str, list[_Message]],
                probes: dict[ProbeTag, dict[str, list[_Message]]], physics_size: int | None) -> str | None:
    """What breaks the run's rules in step ``tag`` (``physics_size``: the log's first step's), or None. Every
    reader applies these, so whatever :func:`read_run` accepts is what the run applied and nothing else."""
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
              for topic, field in _VALUES.items()}
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
            if len(getattr(copies[0].decoded, _VALUES[topic])) != size:
                return f"probe {probe} {P.PROBE_CHANNELS[topic]}: the run's layout has {size} values"
    return None


def _judged(rules: _RunRules, collected: _Collected):
    """Each step of the log, in log order, with what is wrong with it (None: nothing)."""
    physics_size = None
    for tag in collected.order:
        step = collected.step(tag)
        fault = _step_fault(rules, tag, step, collected.probes.get(tag, {}), physics_size)
        if fault is None and physics_size is None:
            physics_size = len(step[P.PHYSICS][0].decoded.position)
        yield tag, fault


def _gap(order: list[StepTag], missing_steps: set[StepTag]) -> str | None:
    """Where an episode of the log does not run from step 0 on without a gap, but for the steps its end
    record declares missing (a recovered log's), or None."""
    last_step: dict[int, int] = {}
    for tag in order:
        after = last_step.get(tag.episode, -1)
        if tag.step <= after or any(StepTag(tag.episode, s) not in missing_steps for s in range(after + 1, tag.step)):
            return f"episode {tag.episode} jumps to step {tag.step} after {after}"
        last_step[tag.episode] = tag.step
    return None


def _open_checked(path: Path):
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
    _open_checked(path)
    with open(path, "rb") as f:
        try:
            reader = make_reader(f, validate_crcs=True)
            header = reader.get_header()
            summary = reader.get_summary()
            metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        except Exception as err:  # the mcap reader raises several types for a damaged file
            raise RunLogError(f"{path}: truncated or damaged MCAP ({type(err).__name__}: {err}); "
                              f"`aril log-recover input:={path}` rewrites its intact steps") from None
        if header.profile != "ros2" or "aril_run" not in metadata:
            raise RunLogError(f"{path}: not an aril_ros run log (profile {header.profile!r}, "
                              f"metadata {sorted(metadata)})")
        if summary is None or "aril_run_end" not in metadata:
            raise RunLogError(f"{path}: the run log was cut short (no summary or end record); "
                              f"`aril log-recover input:={path}` rewrites its intact steps")
        end = {k: _maybe_json(v) for k, v in metadata["aril_run_end"].items()}
        if end.get("interrupted") and not allow_interrupted:
            raise RunLogError(f"{path}: the run was interrupted mid-episode ({end.get('reason', '')}); "
                              "read it with allow_interrupted=True to use its complete steps")
        collected = _Collected(keep_raw=False)
        try:
            rules = _RunRules.of(metadata["aril_run"])
            for _, channel, message in reader.iter_messages(topics=[*_STEP_CHANNELS, *_PROBE_CHANNELS],
                                                            log_time_order=False):
                collected.add(channel.topic, message.log_time, message.data)
        except RunLogError as err:
            raise RunLogError(f"{path}: {err}") from None
        except Exception as err:  # the mcap reader raises several types for a damaged chunk
            raise RunLogError(f"{path}: damaged message data ({type(err).__name__}: {err}); "
                              f"`aril log-recover input:={path}` rewrites its intact steps") from None
    return _assemble(path, rules, metadata["aril_run"], end, collected)


def _assemble(path: Path, rules: _RunRules, meta: dict, end: dict, collected: _Collected) -> RunLog:
    for tag, fault in _judged(rules, collected):
        if fault:
            raise RunLogError(f"{path}: {fault}")
    stray = collected.stray()
    if stray:
        raise RunLogError(f"{path}: {len(stray)} messages belong to no step of the log, first {stray[0]}")
    order = collected.order
    missing_steps = {StepTag.parse(text) for text in end.get("missing_steps", [])}
    gap = _gap(order, missing_steps)
    if gap:
        raise RunLogError(f"{path}: {gap}")
    if end.get("steps") != len(order):
        raise RunLogError(f"{path}: its end record counts {end.get('steps')} steps, the log holds {len(order)}")

    def column(topic, width):  # shaped by the run's layout, so a log without rows has (0, width)
        return np.array([getattr(collected.steps[tag][topic][0].decoded, _VALUES[topic]) for tag in order],
                        dtype=np.float64).reshape(len(order), width)

    row = {tag: i for i, tag in enumerate(order)}
    asked = sorted(((tag, probe) for tag in order for probe in collected.probes.get(tag, {})),
                   key=lambda pair: (row[pair[0]], pair[1].index))

    def probe_column(topic, width):
        return np.array([getattr(collected.probes[tag][probe][topic][0].decoded, _VALUES[topic])
                         for tag, probe in asked], dtype=np.float64).reshape(len(asked), width)

    obs, act = len(rules.obs_names), len(rules.action_names)
    physics = len(collected.steps[order[0]][P.PHYSICS][0].decoded.position) if order else 0
    reward = column(P.REWARD, len(P.REWARD_NAMES))
    return RunLog(
        metadata={k: _maybe_json(v) for k, v in meta.items()},
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
        probe_row=np.array([row[tag] for tag, _ in asked], dtype=np.int64),
    )


def _maybe_json(text: str):
    try:
        return json.loads(text)
    except ValueError:
        return text


# ----------------------------------------------------------------------------------------- recovery
@dataclass
class Recovery:
    """What :func:`recover` wrote and what it left out, and why."""

    out: Path
    steps: int
    dropped: dict[StepTag, str]
    """the steps left out, each with why (a message missing or damaged, a rule of the run broken)"""
    damage: list[str]
    """the parts of the file that could not be read, and the messages of no step"""
    missing_steps: list[StepTag]
    """the steps the recovered log lacks inside its episodes (the dropped ones and those in damaged parts)"""

    def text(self) -> str:
        lines = [f"recovered {self.steps} complete steps into {self.out}"]
        lines += [f"  dropped step {tag}: {why}" for tag, why in self.dropped.items()]
        lines += [f"  skipped {what}" for what in self.damage]
        if self.missing_steps:
            lines.append(f"  the recovered log lacks {len(self.missing_steps)} steps inside its episodes "
                         f"(its end record lists them as missing_steps)")
        return "\n".join(lines)


def recover(path: str | Path, out: str | Path) -> Recovery:
    """Rewrite the intact steps of a cut-short or damaged run log (with their probes and camera frames) into a
    log that ``read_run(out, allow_interrupted=True)`` reads; a closed, readable log is refused, not rewritten.

    The file is read record by record and chunk by chunk: a damaged chunk is skipped, not the rest of the file;
    a step that misses a message or breaks a rule of its run is dropped; each is said in the :class:`Recovery`."""
    path, out = Path(path), Path(out)
    _open_checked(path)
    try:
        closed = read_run(path, allow_interrupted=True)
    except RunLogError:
        pass  # cut short or damaged: what recovery is for
    else:
        raise RunLogError(f"{path}: a closed, readable run log ({closed.end['steps']} steps, interrupted: "
                          f"{str(closed.end['interrupted']).lower()}); log-recover only rewrites cut-short or "
                          "damaged ones, so nothing was written")
    metadata, channels, messages, damage = _intact_records(path.read_bytes())
    if "aril_run" not in metadata:
        raise RunLogError(f"{path}: no readable aril_run metadata (not an aril_ros run log?); nothing to recover")
    try:
        rules = _RunRules.of(metadata["aril_run"])
    except RunLogError as err:
        raise RunLogError(f"{path}: {err}") from None
    collected = _Collected(keep_raw=True)
    for channel_id, log_time, raw in messages:
        channel = channels.get(channel_id)
        if channel is None:
            damage.append(f"a message of channel {channel_id} at log time {log_time}, whose Channel record is lost")
        elif channel in (*_STEP_CHANNELS, *_PROBE_CHANNELS, _CAMERA_CHANNEL):
            try:
                collected.add(channel, log_time, raw)
            except RunLogError as err:
                damage.append(str(err))
    kept: list[StepTag] = []
    dropped: dict[StepTag, str] = {}
    last_kept: dict[int, StepTag] = {}
    for tag, fault in _judged(rules, collected):
        if fault is None and tag.episode in last_kept and tag.step < last_kept[tag.episode].step:
            fault = f"step {tag} comes after step {last_kept[tag.episode]} in the log"  # the reader's order rule
        if fault is None:
            kept.append(tag)
            last_kept[tag.episode] = tag
        else:
            dropped[tag] = fault
    damage += [f"{what}: it belongs to no step" for what in collected.stray()]
    present = set(kept)
    missing_steps = [StepTag(e, s) for e, last in last_kept.items() for s in range(last.step)
                     if StepTag(e, s) not in present]
    completed = 0
    for episode, last in last_kept.items():
        _, terminated, truncated = collected.steps[last][P.REWARD][0].decoded.position
        completed += bool(terminated or truncated) and not any(t.episode == episode for t in missing_steps)
    writer = RunLogWriter(out, metadata["aril_run"], camera=_CAMERA_CHANNEL in channels.values())
    for tag in kept:
        step = collected.step(tag)
        asked = collected.probes.get(tag, {})
        writer.write_step(step[P.STATE][0].log_time, {topic: copies[0].raw for topic, copies in step.items()},
                          [{topic: copies[0].raw for topic, copies in asked[probe].items()} for probe in sorted(asked)])
        for frame in collected.frames.get(tag, []):
            writer.write_frame(frame.log_time, frame.raw)
    writer.close(interrupted=True, episodes_completed=completed, missing_steps=missing_steps,
                 reason=f"recovered from {path.name}: {len(kept)} steps kept, {len(dropped)} dropped, "
                        f"{len(damage)} damaged or stray parts skipped")
    return Recovery(out, writer.steps, dropped, damage, missing_steps)


def _intact_records(data: bytes):
    """The metadata, channels (id: topic) and messages (channel id, log time, bytes) of an MCAP file's intact
    records, chunk contents included, and what could not be read. Past damage (a chunk whose CRC fails, a record
    that does not parse, a length that runs off the file) reading resumes at the next intact chunk."""
    metadata: dict[str, dict] = {}
    channels: dict[int, str] = {}
    messages: list[tuple[int, int, bytes]] = []
    damage: list[str] = []
    pos = len(MAGIC)
    while pos < len(data):
        records = _records_at(data, pos)
        if records is None:
            resume = _next_chunk(data, pos + 1)
            damage.append(f"bytes {pos}..{resume if resume is not None else len(data)} of the file: "
                          + ("damaged" if resume is not None else "cut short or damaged to its end"))
            if resume is None:
                break
            pos = resume
            continue
        pos, found = records
        for record in found:
            if isinstance(record, Metadata):
                metadata.setdefault(record.name, dict(record.metadata))
            elif isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, Message):
                messages.append((record.channel_id, record.log_time, record.data))
            elif isinstance(record, Footer):
                return metadata, channels, messages, damage
    return metadata, channels, messages, damage


def _records_at(data: bytes, pos: int):
    """``(end, records)`` of the record at ``pos`` (a chunk's: those inside it, its CRC checked), or None if it
    is damaged or runs off the file."""
    if pos + 9 > len(data):
        return None
    opcode, length = struct.unpack_from("<BQ", data, pos)
    end = pos + 9 + length
    if end > len(data) or opcode not in _OPCODES:
        return None
    try:
        record = next(iter(StreamReader(io.BytesIO(data[pos:end]), skip_magic=True, emit_chunks=True).records))
        return end, breakup_chunk(record, validate_crc=True) if isinstance(record, Chunk) else [record]
    except Exception:  # a damaged record fails in many ways: bad lengths, strings, compression, CRC
        return None


def _next_chunk(data: bytes, start: int) -> int | None:
    """Where the next intact chunk at or after ``start`` begins (its CRC holds), or None."""
    pos = data.find(bytes([Opcode.CHUNK]), start)
    while pos != -1:
        found = _records_at(data, pos)
        if found is not None:
            return pos
        pos = data.find(bytes([Opcode.CHUNK]), pos + 1)
    return None


_OPCODES = {int(op) for op in Opcode}


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

"""The run log's writer: complete steps, their probes and camera frames, then the end record and the summary."""
from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path

from .. import protocol as P
from ..step import EpisodeStats
from .layout import END, QOS_YAML, RUN, SCHEMAS, TIMING_KEY, RunLogError, absolute, encoded
from .stream import ChunkStreamWriter


class RunLogWriter:
    """Writes complete steps of a run to MCAP (:mod:`aril_ros.runlog.layout`); :meth:`close` adds the end record
    and the summary.

    The file is created exclusively: a path that exists (another run's log) is refused, never written into.
    An OS error while writing (read-only or full disk, file size limit) raises a :class:`RunLogError` naming the
    file and the OS's reason, and the log is then closed as interrupted (or, if the disk allows nothing more,
    left cut short for recovery)."""

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
            # a run with a timing attack (its record says which) has the attacker's timing channel too
            self.topics = P.step_topics(TIMING_KEY in run_metadata)
            for topic, msg_type in {**P.MESSAGE_TYPES, **({P.CAMERA: P.CAMERA_TYPE} if camera else {})}.items():
                if topic in self.topics or topic not in P.TIMED_STEP_TOPICS:
                    self._register(topic, msg_type)
            self._sequence = 0
            self._writer.add_metadata(RUN, encoded(run_metadata))
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
            for topic in self.topics:
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
            topic=absolute(channel), message_encoding="cdr", schema_id=self._schema_ids[msg_type],
            metadata={"offered_qos_profiles": QOS_YAML})

    def _add(self, channel: str, stamp_ns: int, raw: bytes) -> None:
        self._sequence += 1
        self._writer.add_message(self._channels[channel], log_time=stamp_ns, data=raw, publish_time=stamp_ns,
                                 sequence=self._sequence)

    def close(self, *, interrupted: bool, episodes: list[EpisodeStats], reason: str = "", missing_steps=()) -> None:
        """Write the end record (:data:`~aril_ros.runlog.layout.END`; ``episodes``: the completed episodes' figures,
        ``missing_steps``: the step tags a recovered log lacks inside its episodes) and the summary. After
        a write failure the log is interrupted whatever the caller says, and a second failure here is not raised
        again (the first is on its way)."""
        if self._file.closed:
            return
        failed_before = bool(self.failure)
        if failed_before:
            interrupted, reason = True, self.failure
        end = {"steps": self.steps, "episodes_completed": len(episodes), "interrupted": interrupted,
               "reason": reason, "missing_steps": [str(tag) for tag in missing_steps],
               "episode_stats": [dataclasses.asdict(stats) for stats in episodes]}
        try:
            with self._writing():
                self._writer.add_metadata(END, encoded(end))
                self._writer.finish()
                self._file.flush()
        except RunLogError:
            if not failed_before:
                raise
        finally:
            with contextlib.suppress(OSError):  # what it could not write is the failure reported
                self._file.close()

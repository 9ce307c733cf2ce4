"""Recovery of a cut-short or damaged run log: its intact steps, with their probes and frames, rewritten into a log
the reader reads (``aril log-recover``)."""
from __future__ import annotations

import io
import struct
from dataclasses import dataclass, field
from pathlib import Path

from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Footer, Message, Metadata
from mcap.stream_reader import StreamReader, breakup_chunk

from .. import protocol as P
from ..protocol import StepTag
from ..step import EpisodeStats
from .layout import CAMERA_CHANNEL, PROBE_CHANNELS, RUN, STEP_CHANNELS, RunLogError
from .reader import Collected, open_checked, read_run
from .recorder import add_step
from .rules import RunRules, judged
from .stream import MAGIC
from .writer import RunLogWriter


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
    _refuse_a_readable_log(path)
    salvage = _salvage(path.read_bytes())
    rules = _rules_of(path, salvage.metadata)
    collected = _collect(salvage)
    kept, dropped = _keep_in_order(rules, collected)
    salvage.damage += [f"{what}: it belongs to no step" for what in collected.stray()]
    missing_steps = _missing_steps(kept)
    writer = RunLogWriter(out, salvage.metadata[RUN], camera=CAMERA_CHANNEL in salvage.channels.values())
    _rewrite(writer, collected, kept)
    writer.close(interrupted=True, episodes=_completed_episodes(collected, kept, missing_steps),
                 missing_steps=missing_steps,
                 reason=f"recovered from {path.name}: {len(kept)} steps kept, {len(dropped)} dropped, "
                        f"{len(salvage.damage)} damaged or stray parts skipped")
    return Recovery(out, writer.steps, dropped, salvage.damage, missing_steps)


def _refuse_a_readable_log(path: Path) -> None:
    open_checked(path)
    try:
        closed = read_run(path, allow_interrupted=True)
    except RunLogError:
        return  # cut short or damaged: what recovery is for
    raise RunLogError(f"{path}: a closed, readable run log ({closed.end['steps']} steps, interrupted: "
                      f"{str(closed.end['interrupted']).lower()}); log-recover only rewrites cut-short or "
                      "damaged ones, so nothing was written")


@dataclass
class _Salvage:
    """An MCAP file's intact records, chunk contents included, and what could not be read."""

    metadata: dict[str, dict] = field(default_factory=dict)
    channels: dict[int, str] = field(default_factory=dict)
    """topic by channel id"""
    messages: list[tuple[int, int, bytes]] = field(default_factory=list)
    """(channel id, log time, bytes)"""
    damage: list[str] = field(default_factory=list)

    def take(self, records) -> bool:
        """File ``records``; False once the footer is among them (the file's end)."""
        for record in records:
            if isinstance(record, Metadata):
                self.metadata.setdefault(record.name, dict(record.metadata))
            elif isinstance(record, Channel):
                self.channels[record.id] = record.topic
            elif isinstance(record, Message):
                self.messages.append((record.channel_id, record.log_time, record.data))
            elif isinstance(record, Footer):
                return False
        return True


def _salvage(data: bytes) -> _Salvage:
    """The intact records of ``data``, an MCAP file. Past damage (a chunk whose CRC fails, a record that does not
    parse, a length that runs off the file) reading resumes at the next intact chunk."""
    salvage = _Salvage()
    pos = len(MAGIC)
    while pos < len(data):
        parsed = _records_at(data, pos)
        if parsed is None:
            pos = _past_damage(data, pos, salvage.damage)
        else:
            pos, records = parsed
            if not salvage.take(records):
                break
    return salvage


def _past_damage(data: bytes, pos: int, damage: list[str]) -> int:
    """Where reading resumes after the damaged record at ``pos`` (the file's end if no intact chunk follows),
    noting the bytes skipped in ``damage``."""
    resume = _next_chunk(data, pos + 1)
    if resume is None:
        damage.append(f"bytes {pos}..{len(data)} of the file: cut short or damaged to its end")
        return len(data)
    damage.append(f"bytes {pos}..{resume} of the file: damaged")
    return resume


_OPCODES = {int(op) for op in Opcode}


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
    while pos != -1 and _records_at(data, pos) is None:
        pos = data.find(bytes([Opcode.CHUNK]), pos + 1)
    return None if pos == -1 else pos


def _rules_of(path: Path, metadata: dict[str, dict]) -> RunRules:
    if RUN not in metadata:
        raise RunLogError(f"{path}: no readable {RUN} metadata (not an aril_ros run log?); nothing to recover")
    try:
        return RunRules.of(metadata[RUN])
    except RunLogError as err:
        raise RunLogError(f"{path}: {err}") from None


def _collect(salvage: _Salvage) -> Collected:
    """The salvaged messages of the log's channels by step; a message that cannot be filed is damage."""
    collected = Collected(keep_raw=True)
    for channel_id, log_time, raw in salvage.messages:
        channel = salvage.channels.get(channel_id)
        if channel is None:
            salvage.damage.append(f"a message of channel {channel_id} at log time {log_time}, whose Channel record "
                                  "is lost")
        elif channel in (*STEP_CHANNELS, *PROBE_CHANNELS, CAMERA_CHANNEL):
            try:
                collected.add(channel, log_time, raw)
            except RunLogError as err:
                salvage.damage.append(str(err))
    return collected


def _keep_in_order(rules: RunRules, collected: Collected) -> tuple[list[StepTag], dict[StepTag, str]]:
    """The steps kept, in log order, and those dropped with why: a step that breaks a rule of its run, or comes
    after a later step of its episode (the reader's order rule)."""
    kept: list[StepTag] = []
    dropped: dict[StepTag, str] = {}
    last_kept: dict[int, StepTag] = {}
    for tag, fault in judged(rules, collected):
        if fault is None and tag.episode in last_kept and tag.step < last_kept[tag.episode].step:
            fault = f"step {tag} comes after step {last_kept[tag.episode]} in the log"
        if fault is None:
            kept.append(tag)
            last_kept[tag.episode] = tag
        else:
            dropped[tag] = fault
    return kept, dropped


def _missing_steps(kept: list[StepTag]) -> list[StepTag]:
    """The steps each episode lacks before its last kept one."""
    last = {tag.episode: tag.step for tag in kept}
    present = set(kept)
    return [StepTag(e, s) for e, end in last.items() for s in range(end) if StepTag(e, s) not in present]


def _completed_episodes(collected: Collected, kept: list[StepTag], missing_steps: list[StepTag]) -> list[EpisodeStats]:
    """The figures of the episodes kept whole: from step 0 to their end, without a missing step."""
    episodes: dict[int, EpisodeStats] = {}
    actions: dict[int, dict] = {}
    for tag in kept:
        add_step(episodes.setdefault(tag.episode, EpisodeStats(tag.episode)), _raw_step(collected, tag),
                 actions.setdefault(tag.episode, {}))
    incomplete = {tag.episode for tag in missing_steps}
    return [stats for episode, stats in episodes.items() if stats.done and episode not in incomplete]


def _raw_step(collected: Collected, tag: StepTag) -> dict[str, bytes]:
    return {topic: copies[0].raw for topic, copies in collected.step(tag).items()}


def _rewrite(writer: RunLogWriter, collected: Collected, kept: list[StepTag]) -> None:
    """Write the kept steps, each with its probes and camera frames."""
    for tag in kept:
        asked = collected.probes.get(tag, {})
        writer.write_step(collected.step(tag)[P.STATE][0].log_time, _raw_step(collected, tag),
                          [{topic: copies[0].raw for topic, copies in asked[probe].items()} for probe in sorted(asked)])
        for frame in collected.frames.get(tag, []):
            writer.write_frame(frame.log_time, frame.raw)

"""An MCAP writer for a log written chunk by chunk for hours: flat in memory, closed in milliseconds.

A run log closes one chunk per step, so that a killed run loses no complete step. ``mcap.writer.Writer`` keeps the
index of every chunk it has written in memory until ``finish()`` and serialises them one by one there: with one
chunk per step a 50-episode run grew its recorder by ~45 MB and took seconds to close. This writer writes the
same format — header, schemas and channels, metadata, compressed chunks each followed by its message indexes, and
a summary of schemas, channels, statistics, chunk indexes and metadata indexes with its offsets and a CRC'd footer
— but serialises each chunk's index as soon as the chunk is on disk, into an unnamed temporary file (gone with
the process, however it ends), and copies those bytes into the summary at :meth:`ChunkStreamWriter.finish`.
Readers (``mcap``, ``rosbags``, Foxglove) see an ordinary indexed MCAP file.
"""
from __future__ import annotations

import struct
import tempfile
import zlib
from collections import defaultdict
from typing import BinaryIO

import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (Channel, ChunkIndex, DataEnd, Footer, Header, Metadata, MetadataIndex, Schema, Statistics,
                          SummaryOffset)

MAGIC = b"\x89MCAP0\r\n"
"""Opens and closes every MCAP file."""

# The records written for every step, packed directly: opcode, record length, then the fields up to the variable part
_MESSAGE = struct.Struct("<BQHIQQ")  # channel id, sequence, log time, publish time; then the data
_CHUNK = struct.Struct("<BQQQQII")  # start and end time, uncompressed size and CRC, compression's length; then it
_MESSAGE_INDEX = struct.Struct("<BQHI")  # channel id, byte length of the (log time, offset) pairs that follow
_ZSTD = b"zstd"


class ChunkStreamWriter:
    """Writes an MCAP file to ``stream`` (opened for binary writing, positioned at its start).

    Schemas and channels are written to the data section when registered (so they may be added mid-run);
    messages go into the open chunk, which :meth:`flush` writes (zstd-compressed, its CRC, then one message
    index per channel in it) and flushes to the OS."""

    def __init__(self, stream: BinaryIO, profile: str, library: str):
        self._stream = stream
        self._records = RecordBuilder()
        self._chunk = bytearray()  # the open chunk's records: packed here, the hot path (mcap's builder: 5x slower)
        self._chunk_messages: dict[int, list[tuple[int, int]]] = defaultdict(list)  # channel -> (log time, offset)
        self._chunk_times: tuple[int, int] | None = None
        # one compressor for every chunk, at zstd's fastest level: zstandard.compress() builds its tables anew per
        # call, and a step's chunk (a few kB) compresses as small at level 1 as at 3 (the recorder's largest cost)
        self._compressor = zstandard.ZstdCompressor(level=1)
        self._chunk_indexes = tempfile.TemporaryFile(prefix="aril_ros-chunk-indexes-")
        self._schemas: list[Schema] = []
        self._channels: list[Channel] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._counts: dict[int, int] = defaultdict(int)
        self._times: tuple[int, int] | None = None
        self._chunk_count = 0
        self._stream.write(MAGIC)
        Header(profile=profile, library=library).write(self._records)
        self._emit()

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema = Schema(id=len(self._schemas) + 1, name=name, encoding=encoding, data=data)
        self._schemas.append(schema)
        schema.write(self._records)
        self._emit()
        return schema.id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int, metadata: dict[str, str]) -> int:
        channel = Channel(id=len(self._channels) + 1, topic=topic, message_encoding=message_encoding,
                          schema_id=schema_id, metadata=metadata)
        self._channels.append(channel)
        channel.write(self._records)
        self._emit()
        return channel.id

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        offset = self._stream.tell()
        Metadata(name=name, metadata=data).write(self._records)
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=self._records.count, name=name))
        self._emit()

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int) -> None:
        """Add a message to the open chunk (on disk at the next :meth:`flush`)."""
        self._chunk_messages[channel_id].append((log_time, len(self._chunk)))
        self._chunk += _MESSAGE.pack(Opcode.MESSAGE, _MESSAGE.size - 9 + len(data), channel_id, sequence, log_time,
                                     publish_time)
        self._chunk += data
        self._counts[channel_id] += 1
        self._chunk_times = _span(self._chunk_times, log_time)
        self._times = _span(self._times, log_time)

    def flush(self) -> None:
        """Write the open chunk, if it holds a message, with its message indexes, and flush the file."""
        if self._chunk_times is not None:
            self._write_chunk()
        self._stream.flush()

    def _write_chunk(self) -> None:
        content = bytes(self._chunk)
        compressed = self._compressor.compress(content)
        start, end = self._chunk_times
        chunk_offset = self._stream.tell()
        records = bytearray(_CHUNK.pack(Opcode.CHUNK, _CHUNK.size - 9 + len(_ZSTD) + 8 + len(compressed), start, end,
                                        len(content), zlib.crc32(content), len(_ZSTD)))
        records += _ZSTD
        records += struct.pack("<Q", len(compressed))
        records += compressed
        chunk_length = len(records)
        index_offsets = {}
        for channel_id, entries in self._chunk_messages.items():
            index_offsets[channel_id] = chunk_offset + len(records)
            size = 16 * len(entries)
            records += _MESSAGE_INDEX.pack(Opcode.MESSAGE_INDEX, 2 + 4 + size, channel_id, size)
            records += struct.pack(f"<{2 * len(entries)}Q", *(value for entry in entries for value in entry))
        index = ChunkIndex(message_start_time=start, message_end_time=end, chunk_start_offset=chunk_offset,
                           chunk_length=chunk_length, message_index_offsets=index_offsets,
                           message_index_length=len(records) - chunk_length, compression="zstd",
                           compressed_size=len(compressed), uncompressed_size=len(content))
        self._stream.write(records)
        self._chunk.clear()
        spill = RecordBuilder()
        index.write(spill)
        self._chunk_indexes.write(spill.end())
        self._chunk_messages.clear()
        self._chunk_times = None
        self._chunk_count += 1

    def finish(self) -> None:
        """Write the open chunk, the end of the data section, the summary and the footer (the stream stays open)."""
        self.flush()
        DataEnd(data_section_crc=0).write(self._records)
        self._emit()
        summary_start = self._stream.tell()
        crc = 0
        offsets = []

        def group(opcode: Opcode, records) -> None:
            nonlocal crc
            builder = RecordBuilder()
            for record in records:
                record.write(builder)
            crc = self._summary_part(builder.end(), opcode, offsets, crc)

        group(Opcode.SCHEMA, self._schemas)
        group(Opcode.CHANNEL, self._channels)
        start, end = self._times or (0, 0)
        group(Opcode.STATISTICS, [Statistics(
            message_count=sum(self._counts.values()), schema_count=len(self._schemas),
            channel_count=len(self._channels), attachment_count=0, metadata_count=len(self._metadata_indexes),
            chunk_count=self._chunk_count, message_start_time=start, message_end_time=end,
            channel_message_counts=dict(self._counts))])
        offset = self._stream.tell()
        self._chunk_indexes.seek(0)
        crc = _copy(self._chunk_indexes, self._stream, crc)
        offsets.append(SummaryOffset(group_opcode=Opcode.CHUNK_INDEX, group_start=offset,
                                     group_length=self._stream.tell() - offset))
        self._chunk_indexes.close()
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = self._stream.tell()
        for summary_offset in offsets:
            summary_offset.write(self._records)
        tail = self._records.end()
        crc = zlib.crc32(tail, crc)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start, summary_offset_start), crc)
        self._stream.write(tail)
        Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc).write(
            self._records)
        self._emit()
        self._stream.write(MAGIC)
        self._stream.flush()

    def _summary_part(self, data: bytes, opcode: Opcode, offsets: list, crc: int) -> int:
        offsets.append(SummaryOffset(group_opcode=opcode, group_start=self._stream.tell(), group_length=len(data)))
        self._stream.write(data)
        return zlib.crc32(data, crc)

    def _emit(self) -> None:
        self._stream.write(self._records.end())


def _span(times: tuple[int, int] | None, t: int) -> tuple[int, int]:
    return (t, t) if times is None else (min(times[0], t), max(times[1], t))


def _copy(source: BinaryIO, target: BinaryIO, crc: int) -> int:
    """Copy ``source`` to ``target`` from where each stands; the CRC-32 of the bytes copied, continued from ``crc``."""
    while block := source.read(1 << 20):
        target.write(block)
        crc = zlib.crc32(block, crc)
    return crc

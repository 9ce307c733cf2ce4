"""The chunk-by-chunk MCAP writer: the same file as mcap's own writer, flat in memory however long the run."""
import io
import random
import struct
import tracemalloc
import zlib

from mcap.reader import SeekingReader
from mcap.writer import CompressionType, Writer

from aril_ros.runlog.stream import MAGIC, ChunkStreamWriter


def _write(writer, steps: int, flush, finish) -> None:
    """A run-like file: a schema, two channels, metadata before and after, a chunk per step (one with a third
    message), a channel registered mid-file."""
    schema = writer.register_schema("pkg/msg/T", "ros2msg", b"int32 x")
    first = writer.register_channel(topic="/x", message_encoding="cdr", schema_id=schema, metadata={"k": "v"})
    second = writer.register_channel(topic="/y", message_encoding="cdr", schema_id=schema, metadata={})
    writer.add_metadata("start", {"a": "1"})
    rng = random.Random(0)
    late = None
    for step in range(steps):
        for channel in (first, second):
            writer.add_message(channel, log_time=step * 10, data=rng.randbytes(20), publish_time=step * 10,
                               sequence=step)
        if step == steps // 2:
            late = writer.register_channel(topic="/late", message_encoding="cdr", schema_id=schema, metadata={})
        if late and step % 3 == 0:
            writer.add_message(late, log_time=step * 10, data=b"probe", publish_time=step * 10, sequence=0)
        flush()
    writer.add_metadata("end", {"b": "2"})
    finish()


def _contents(data: bytes):
    reader = SeekingReader(io.BytesIO(data), validate_crcs=True)
    summary = reader.get_summary()
    messages = [(c.topic, m.log_time, m.publish_time, m.sequence, m.data) for _, c, m in reader.iter_messages()]
    backwards = [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages(reverse=True)]
    metadata = [(m.name, m.metadata) for m in reader.iter_metadata()]
    # (mcap's writer also repeats a channel's record inside the first chunk that uses it: sizes differ)
    chunks = [(i.message_start_time, i.message_end_time, sorted(i.message_index_offsets))
              for i in summary.chunk_indexes]
    return summary.statistics, messages, backwards, metadata, chunks


def test_the_file_holds_what_mcaps_own_writer_writes_and_its_summary_crc_holds():
    theirs = io.BytesIO()
    writer = Writer(theirs, compression=CompressionType.ZSTD)
    writer.start(profile="ros2", library="test")
    _write(writer, 200, writer.flush, writer.finish)
    ours = io.BytesIO()
    writer = ChunkStreamWriter(ours, profile="ros2", library="test")
    _write(writer, 200, writer.flush, writer.finish)

    assert _contents(ours.getvalue()) == _contents(theirs.getvalue())
    data = ours.getvalue()
    assert data.startswith(MAGIC) and data.endswith(MAGIC)
    footer = len(data) - len(MAGIC) - (1 + 8 + 8 + 8 + 4)
    summary_start, _, crc = struct.unpack_from("<QQI", data, footer + 9)
    assert crc == zlib.crc32(data[summary_start:footer + 9 + 16])


def test_memory_stays_flat_however_many_chunks_are_written():
    """mcap's own writer keeps every chunk's index in memory until it finishes (~1 KB per chunk): over the
    4000 chunks between the two readings that would be megabytes."""
    writer = ChunkStreamWriter(io.BytesIO(), profile="ros2", library="test")
    channel = writer.register_channel(topic="/x", message_encoding="cdr",
                                      schema_id=writer.register_schema("pkg/msg/T", "ros2msg", b""), metadata={})
    stream = writer._stream

    def chunks(n):
        for _ in range(n):
            writer.add_message(channel, log_time=1, data=b"x" * 200, publish_time=1, sequence=0)
            writer.flush()
        stream.seek(0)
        stream.truncate()  # the file's bytes are the stream's business, not the writer's memory

    tracemalloc.start()
    try:
        chunks(1000)
        before = tracemalloc.get_traced_memory()[0]
        chunks(4000)
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert grown < 50_000, f"the writer grew by {grown} bytes over 4000 chunks"

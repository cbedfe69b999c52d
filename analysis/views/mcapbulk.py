"""An MCAP writer for millions of messages: every message record, chunk and message
index built by numpy over whole arrays, never a Python call per message.

The `mcap` package's Writer takes one message per call (about 150 000 a second here,
measured): a run of 10^7 process cycles would take a minute in that loop alone. This
writer takes every message at once as MessageSource arrays (channel, sequence, times,
payload size) and a fill function that writes the payloads straight into each chunk,
sorts them by log time, cuts chunks of about CHUNK_BYTES, and writes what the spec asks
of an indexed file: chunk and message indexes, statistics, attachment and metadata
indexes, summary offsets. The records that are few (header, schemas, channels,
attachments, metadata, the summary) are the `mcap` package's own record classes.
"""

from __future__ import annotations

import collections
import itertools
import struct
import zlib
from collections.abc import Callable, Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import IO, Any

import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from ..read.parallel import WORKERS

MAGIC = bytes([137, 77, 67, 65, 80, 48, 13, 10])
CHUNK_BYTES = 4 << 20  # uncompressed: Foxglove's and the mcap tools' usual size
ATTACH_BYTES = 256 << 20  # of an attachment written at once
# A message record: opcode, record length, channel id, sequence, log time, publish time.
MESSAGE_HEAD = np.dtype([("op", "u1"), ("length", "<u8"), ("channel", "<u2"), ("sequence", "<u4"),
                         ("log_time", "<u8"), ("publish_time", "<u8")])  # fmt: skip
INDEX_HEAD = np.dtype([("op", "u1"), ("length", "<u8"), ("channel", "<u2"), ("bytes", "<u4")])
INDEX_ENTRY = np.dtype([("log_time", "<u8"), ("offset", "<u8")])

# fill(chunk, ids, at): write the payloads of this source's messages `ids` at byte
# offsets `at` of `chunk` (uint8), each exactly as long as the source said.
Fill = Callable[[np.ndarray, np.ndarray, np.ndarray], None]


@dataclass
class MessageSource:
    """Messages of one kind, by arrays of equal length."""

    channel: np.ndarray  # MCAP channel id
    sequence: np.ndarray
    log_time: np.ndarray  # ns
    publish_time: np.ndarray  # ns
    size: np.ndarray  # payload bytes
    fill: Fill

    @classmethod
    def of_bytes(cls, channel: list[int], sequence: list[int], log_time: list[int], publish_time: list[int],
                 payloads: list[bytes]) -> MessageSource:  # fmt: skip
        """Few messages with payloads already encoded (copied one by one)."""

        def fill(chunk: np.ndarray, ids: np.ndarray, at: np.ndarray) -> None:
            for i, a in zip(ids.tolist(), at.tolist(), strict=True):
                chunk[a : a + len(payloads[i])] = np.frombuffer(payloads[i], dtype=np.uint8)

        return cls(np.asarray(channel, dtype=np.uint16), np.asarray(sequence, dtype=np.int64),
                   np.asarray(log_time, dtype=np.int64), np.asarray(publish_time, dtype=np.int64),
                   np.array([len(p) for p in payloads], dtype=np.int64), fill)  # fmt: skip


def scatter(chunk: np.ndarray, at: np.ndarray, items: np.ndarray) -> None:
    """chunk[at[i] : at[i] + width] = the bytes of items[i] (a structured or opaque array
    of one width), for every i in one fancy assignment."""
    width = items.dtype.itemsize
    if not len(at):
        return
    view = np.ndarray(shape=(len(chunk) - width + 1,), dtype=np.dtype((np.void, width)), buffer=chunk,
                      strides=(1,))  # fmt: skip
    view[at] = items.view(np.dtype((np.void, width)))


class BulkWriter:
    """Writes one MCAP file: start(), schema()/channel(), messages() once, attach() and
    metadata() any number of times, finish()."""

    def __init__(self, stream: IO[bytes], library: str, compression: str = "zstd") -> None:
        self.stream = stream
        self.compression = compression
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.chunk_indexes: list[ChunkIndex] = []
        self.attachment_indexes: list[AttachmentIndex] = []
        self.metadata_indexes: list[MetadataIndex] = []
        self.counts: dict[int, int] = {}
        self.times = (0, 0)
        self.messages_written = 0
        stream.write(MAGIC)
        self._put(Header(profile="", library=library))

    def _put(self, record: Any) -> tuple[int, int]:
        """Write one record; its (offset, length) in the file."""
        builder = RecordBuilder()
        record.write(builder)
        data = builder.end()
        offset = self.stream.tell()
        self.stream.write(data)
        return offset, len(data)

    def schema(self, name: str, encoding: str, data: bytes) -> int:
        schema = Schema(id=len(self.schemas) + 1, name=name, encoding=encoding, data=data)
        self.schemas[schema.id] = schema
        self._put(schema)
        return schema.id

    def channel(self, topic: str, message_encoding: str, schema_id: int, metadata: Mapping[str, str]) -> int:
        channel = Channel(id=len(self.channels) + 1, topic=topic, message_encoding=message_encoding,
                          schema_id=schema_id, metadata=dict(metadata))  # fmt: skip
        self.channels[channel.id] = channel
        self._put(channel)
        return channel.id

    def messages(self, sources: list[MessageSource]) -> None:
        """Every message of the file, in log-time order (ties: in the order given), chunked."""
        which = np.concatenate([np.full(len(s.size), k, dtype=np.int64) for k, s in enumerate(sources)])
        local = np.concatenate([np.arange(len(s.size), dtype=np.int64) for s in sources])
        log_time = np.concatenate([s.log_time for s in sources]).astype(np.int64)
        order = np.argsort(log_time, kind="stable")
        which, local, log_time = which[order], local[order], log_time[order]
        size = np.concatenate([s.size for s in sources]).astype(np.int64)[order] + MESSAGE_HEAD.itemsize
        channel = np.concatenate([s.channel for s in sources]).astype(np.uint16)[order]
        sequence = np.concatenate([s.sequence for s in sources]).astype(np.int64)[order]
        publish = np.concatenate([s.publish_time for s in sources]).astype(np.int64)[order]
        if len(order):
            self.times = (int(log_time[0]), int(log_time[-1]))
        self.messages_written = len(order)
        for c, n in zip(*np.unique(channel, return_counts=True), strict=True):
            self.counts[int(c)] = int(n)
        # chunk k holds the messages whose record starts before (k + 1) * CHUNK_BYTES
        ends = np.cumsum(size)
        total = int(ends[-1]) if len(ends) else 0
        cuts = np.searchsorted(ends - size, np.arange(CHUNK_BYTES, total, CHUNK_BYTES))
        bounds = [0, *np.unique(cuts).tolist(), len(order)]
        spans = [(a, b) for a, b in itertools.pairwise(bounds) if b > a]

        def build(span: tuple[int, int]) -> tuple[bytes, int, bytes, dict[int, int], int, int]:
            a, b = span
            at = ends[a:b] - size[a:b] - (ends[a] - size[a])
            chunk = np.empty(int(ends[b - 1] - ends[a] + size[a]), dtype=np.uint8)
            head = np.empty(b - a, dtype=MESSAGE_HEAD)
            head["op"] = Opcode.MESSAGE
            head["length"] = size[a:b] - 9
            head["channel"] = channel[a:b]
            head["sequence"] = sequence[a:b] & 0xFFFFFFFF
            head["log_time"] = np.maximum(log_time[a:b], 0)
            head["publish_time"] = np.maximum(publish[a:b], 0)
            scatter(chunk, at, head)
            for k, source in enumerate(sources):
                mine = np.flatnonzero(which[a:b] == k)
                if len(mine):
                    source.fill(chunk, local[a:b][mine], at[mine] + MESSAGE_HEAD.itemsize)
            # zstd reads the array itself: no copy of the chunk as bytes first
            packed = zstandard.ZstdCompressor(level=1).compress(chunk) if self.compression == "zstd" \
                else chunk.tobytes()  # fmt: skip
            index, offsets = _message_index(channel[a:b], log_time[a:b], at)
            return packed, len(chunk), index, offsets, int(log_time[a]), int(log_time[b - 1])

        # Chunks are built and compressed side by side (numpy and zstd release the GIL) and
        # written in order, each as soon as it and those before it are: at most 2 * WORKERS in
        # hand, so memory stays bounded and the workers never wait for a batch's last one.
        pool = ThreadPoolExecutor(WORKERS)
        building: collections.deque[Future[tuple[bytes, int, bytes, dict[int, int], int, int]]] = \
            collections.deque()  # fmt: skip
        try:
            for span in spans:
                building.append(pool.submit(build, span))
                if len(building) == 2 * WORKERS:
                    self._chunk(*building.popleft().result())
            while building:
                self._chunk(*building.popleft().result())
        finally:
            # After a failed write or Ctrl-C, the chunks not started are not built (a with-block
            # would build them all first).
            pool.shutdown(cancel_futures=True)

    def _chunk(self, packed: bytes, size: int, index: bytes, offsets: dict[int, int], start: int,
               end: int) -> None:  # fmt: skip
        chunk = Chunk(compression=self.compression if self.compression == "zstd" else "", data=b"",
                      message_start_time=max(start, 0), message_end_time=max(end, 0),
                      uncompressed_crc=0, uncompressed_size=size)  # fmt: skip
        # The record written as its fields and then the data itself: through the package's
        # RecordBuilder the data, most of the file, would be copied twice on the way.
        head = RecordBuilder()
        chunk.write(head)
        fields = head.end()[9:-8]  # less its opcode and length, and the empty data's length
        offset = self.stream.tell()
        self.stream.write(struct.pack("<BQ", Opcode.CHUNK, len(fields) + 8 + len(packed)) + fields
                          + struct.pack("<Q", len(packed)))  # fmt: skip
        self.stream.write(packed)
        length = self.stream.tell() - offset
        index_at = self.stream.tell()
        self.stream.write(index)
        self.chunk_indexes.append(ChunkIndex(
            message_start_time=chunk.message_start_time, message_end_time=chunk.message_end_time,
            chunk_start_offset=offset, chunk_length=length,
            message_index_offsets={c: index_at + o for c, o in offsets.items()},
            message_index_length=len(index), compression=chunk.compression,
            compressed_size=len(packed), uncompressed_size=size,
        ))  # fmt: skip

    def attach(self, name: str, media_type: str, data: bytes | memoryview, log_time: int,
               written: Callable[[int, int], None] | None = None) -> None:
        """An attachment written straight from `data` (a memory map stays unread until
        written: no copy of a large log), ATTACH_BYTES at a time, `written(start, end)` told
        of each (Log.release gives a map's pages back). Its CRC is 0, "not computed" in the spec."""
        fields = RecordBuilder()
        fields.write8(log_time)
        fields.write8(log_time)
        fields.write_prefixed_string(name)
        fields.write_prefixed_string(media_type)
        view = memoryview(data).cast("B")
        fields.write8(view.nbytes)
        head = fields.end()
        offset = self.stream.tell()
        self.stream.write(struct.pack("<BQ", Opcode.ATTACHMENT, len(head) + view.nbytes + 4) + head)
        for start in range(0, len(view), ATTACH_BYTES):
            end = min(len(view), start + ATTACH_BYTES)
            self.stream.write(view[start:end])
            if written is not None:
                written(start, end)
        self.stream.write(struct.pack("<I", 0))
        self.attachment_indexes.append(AttachmentIndex(
            offset=offset, length=9 + len(head) + view.nbytes + 4, log_time=log_time, create_time=log_time,
            data_size=view.nbytes, name=name, media_type=media_type,
        ))  # fmt: skip

    def metadata(self, name: str, values: Mapping[str, str]) -> None:
        offset, length = self._put(Metadata(name=name, metadata=dict(values)))
        self.metadata_indexes.append(MetadataIndex(offset=offset, length=length, name=name))

    def finish(self) -> None:
        self._put(DataEnd(data_section_crc=0))
        summary_start = self.stream.tell()
        summary = RecordBuilder()
        offsets: list[SummaryOffset] = []
        statistics = Statistics(
            message_count=self.messages_written, schema_count=len(self.schemas),
            channel_count=len(self.channels), attachment_count=len(self.attachment_indexes),
            metadata_count=len(self.metadata_indexes), chunk_count=len(self.chunk_indexes),
            message_start_time=max(self.times[0], 0), message_end_time=max(self.times[1], 0),
            channel_message_counts=self.counts,
        )  # fmt: skip
        groups: list[tuple[Opcode, list[Any]]] = [
            (Opcode.SCHEMA, list(self.schemas.values())), (Opcode.CHANNEL, list(self.channels.values())),
            (Opcode.STATISTICS, [statistics]), (Opcode.CHUNK_INDEX, self.chunk_indexes),
            (Opcode.ATTACHMENT_INDEX, self.attachment_indexes),
            (Opcode.METADATA_INDEX, self.metadata_indexes),
        ]  # fmt: skip
        for opcode, records in groups:
            if records:
                start = summary.count
                for record in records:
                    record.write(summary)
                offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + start,
                                             group_length=summary.count - start))  # fmt: skip
        summary_offset_start = summary_start + summary.count
        for offset in offsets:
            offset.write(summary)
        data = summary.end()
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start),
                         zlib.crc32(data))  # fmt: skip
        self.stream.write(data)
        self._put(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
                         summary_crc=crc))  # fmt: skip
        self.stream.write(MAGIC)


def _message_index(channel: np.ndarray, log_time: np.ndarray, at: np.ndarray) -> tuple[bytes, dict[int, int]]:
    """The MessageIndex records of one chunk (one per channel, entries in log-time order,
    as the chunk's messages are) and where each channel's starts among them."""
    order = np.argsort(channel, kind="stable")
    ids, first, counts = np.unique(channel[order], return_index=True, return_counts=True)
    sizes = INDEX_HEAD.itemsize + counts * INDEX_ENTRY.itemsize
    starts = np.cumsum(sizes) - sizes
    out = np.empty(int(sizes.sum()), dtype=np.uint8)
    head = np.empty(len(ids), dtype=INDEX_HEAD)
    head["op"] = Opcode.MESSAGE_INDEX
    head["length"] = sizes - 9
    head["channel"] = ids
    head["bytes"] = counts * INDEX_ENTRY.itemsize
    scatter(out, starts, head)
    entries = np.empty(len(order), dtype=INDEX_ENTRY)
    entries["log_time"] = np.maximum(log_time[order], 0)
    entries["offset"] = at[order]
    entry_at = np.repeat(starts + INDEX_HEAD.itemsize - first * INDEX_ENTRY.itemsize, counts)
    scatter(out, entry_at + np.arange(len(order)) * INDEX_ENTRY.itemsize, entries)
    return out.tobytes(), dict(zip(ids.tolist(), starts.tolist(), strict=True))

"""A long run's log made from a short real one: the run's timing, status and clock
messages repeated back to back (`copies` times), every time, cycle, minor cycle, batch
and buffer sequence number moved on by one tile, so that the analysis reads one long
consistent run (the report at its end counts every batch). Used by `make bench` to
time the analysis and the export on 10^6-10^7 records without running for hours.

Each message is decoded once with the generated types to find where its moving fields
lie; every copy is then the same bytes with those big-endian int64 values moved on
(numpy over all the messages of one tile at once).

Usage: .venv/bin/python bench/biglog.py SOURCE.lcm OUT.lcm RECORDS
"""

from __future__ import annotations

import math
import struct
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

import skelmsg
from skeleton.analysis.read.logreader import HEADER_BYTES, SYNC, read_log
from skeleton.analysis.read.records import load_records
from skelmsg.contract import (
    CLOCK_CHANNEL,
    COMMAND_CHANNEL,
    CONFIG_CHANNEL,
    REPORT_CHANNEL,
    STATUS_CHANNEL,
    TIMING_CHANNEL,  # fmt: skip
)

_HEADER = struct.Struct(">Iqqii")


def _positions(msg: Any, field: str, count: int) -> np.ndarray:
    """Byte offsets of the `count` int64 values of `field` in msg.encode(): the bytes that
    differ between two encodings with different values there (the encoding keeps its
    length). A search for one sentinel's bytes would also match them straddling two
    neighbouring values: a blocked_ns ending in the sentinel's first bytes did."""
    value = getattr(msg, field)
    many = isinstance(value, (list, tuple))
    encoded = []
    for fill in (0x1111_1111_1111_1111, 0x2222_2222_2222_2222):  # every byte differs
        setattr(msg, field, [fill + i for i in range(count)] if many else fill)
        encoded.append(np.frombuffer(msg.encode(), dtype=np.uint8))
    setattr(msg, field, value)
    differ = np.flatnonzero(encoded[0] != encoded[1])
    if len(differ) != 8 * count:
        raise ValueError(f"{type(msg).__name__}.{field}: not found")
    return int(differ[0]) + 8 * np.arange(count, dtype=np.int64)


class _Tile:
    """The messages of one tile and, per copy, how their moving fields move."""

    def __init__(self) -> None:
        self.data: list[bytes] = []
        self.channel: list[str] = []
        self.utime: list[int] = []
        self.at: list[np.ndarray] = []  # per message: byte offsets of moving int64 values
        self.step: list[np.ndarray] = []  # ... and how far each moves per copy

    def add(self, channel: str, utime: int, data: bytes, moves: list[tuple[np.ndarray, np.ndarray]]
            ) -> None:  # fmt: skip
        self.data.append(data)
        self.channel.append(channel)
        self.utime.append(utime)
        self.at.append(np.concatenate([a for a, _ in moves]) if moves else np.zeros(0, np.int64))
        self.step.append(np.concatenate([s for _, s in moves]) if moves else np.zeros(0, np.int64))

    def copies(self, count: int, tile_ns: int) -> Callable[[int], bytes]:
        """copy(k): tile k in the LCM log format (event numbers from 0 in each tile; the
        reader does not need them in order)."""
        names = [c.encode() for c in self.channel]
        heads = [_HEADER.pack(SYNC, i, 0, len(n), len(d))
                 for i, (n, d) in enumerate(zip(names, self.data, strict=True))]  # fmt: skip
        pieces = [h + n + d for h, n, d in zip(heads, names, self.data, strict=True)]
        base = np.frombuffer(b"".join(pieces), dtype=np.uint8)
        starts = np.cumsum([0] + [len(p) for p in pieces[:-1]])
        header_utime = starts + 12  # sync (4) + event number (8)
        data_at = starts + HEADER_BYTES + np.array([len(n) for n in names])
        at = np.concatenate([data_at[i] + a for i, a in enumerate(self.at)] + [np.zeros(0, np.int64)])
        step = np.concatenate([*self.step, np.zeros(0, np.int64)])
        utime = np.array(self.utime, dtype=np.int64)
        values = _read_i8(base, at)

        def copy(k: int) -> bytes:
            out = base.copy()
            _write_i8(out, at, values + k * step)
            _write_i8(out, header_utime, utime + k * (tile_ns // 1000))
            return out.tobytes()

        return copy


def _read_i8(buf: np.ndarray, at: np.ndarray) -> np.ndarray:
    items = np.ndarray(shape=(len(buf) - 7,), dtype=np.dtype((np.void, 8)), buffer=buf, strides=(1,))
    return items[at].view(">i8").astype(np.int64)


def _write_i8(buf: np.ndarray, at: np.ndarray, values: np.ndarray) -> None:
    items = np.ndarray(shape=(len(buf) - 7,), dtype=np.dtype((np.void, 8)), buffer=buf, strides=(1,))
    items[at] = values.astype(">i8").view(np.dtype((np.void, 8)))


def grow(source: Path, out: Path, records: int) -> int:
    """Write `out`: the last run of `source` repeated until it holds at least `records`
    timing records. Returns how many it holds."""
    log = read_log(source)
    run = load_records(log)
    recs = run.records
    config = skelmsg.config_t.decode(bytes(log.messages(CONFIG_CHANNEL)[-1][1]))
    periods = {p.id: p.period_us * 1000 for p in config.processes}
    minors = {d.id: d.minor_cycle_us * 1000 for d in config.dpus}
    hyper = math.lcm(*[v for v in (*periods.values(), *minors.values()) if v > 0])
    span = int(recs["release_ns"].max() - recs["release_ns"].min()) + hyper
    tile_ns = -(-span // hyper) * hyper
    cycles = {p: tile_ns // per if per else int(recs["cycle"][recs["process"] == p].max()) + 1
              for p, per in periods.items()}  # fmt: skip
    minor_step = {d: tile_ns // m if m else 0 for d, m in minors.items()}
    batches = {int(d): int(recs["batch_seq"][recs["dpu"] == d].max()) + 1 for d in np.unique(recs["dpu"])}
    writer = {b.id: b.writer for b in config.buffers}
    copies = max(1, -(-records // len(recs)))
    first_timing = int(log.utime_us[log.indices(TIMING_CHANNEL)].min())
    # The statuses and clock estimates heard during one tile are repeated with it; those
    # before the run (the DPUs' heartbeats while idle) and after stay at its two ends.
    window = (first_timing, first_timing + tile_ns // 1000)

    tile, start, end = _Tile(), [], []
    for event in log.iter_events():
        data = event.data
        if event.channel == TIMING_CHANNEL:
            t = skelmsg.timing_t.decode(data)
            if t.run_id != run.run_id:
                continue
            n, m = t.n, t.ninputs
            moves = [(_positions(t, "batch_seq", 1), np.array([batches[t.dpu]])),
                     (_positions(t, "cycle", n), np.array([cycles[p] for p in t.process])),
                     (_positions(t, "minor", n), np.full(n, minor_step.get(t.dpu, 0)))]
            moves += [(_positions(t, f, n), np.full(n, tile_ns))
                      for f in ("release_ns", "sched_ns", "start_ns")]  # fmt: skip
            moves.append((_positions(t, "event_ns", n), np.where(np.array(t.event_ns) >= 0, tile_ns, 0)))
            if m:
                seq = [cycles.get(writer.get(b, -1), 0) if s >= 0 else 0
                       for b, s in zip(t.in_buffer, t.in_seq, strict=True)]  # fmt: skip
                moves.append((_positions(t, "in_seq", m), np.array(seq)))
                for f in ("in_sent_ns", "in_recv_ns"):
                    moves.append((_positions(t, f, m), np.where(np.array(getattr(t, f)) > 0, tile_ns, 0)))
            tile.add(event.channel, event.utime_us, data, moves)
        elif event.channel in (STATUS_CHANNEL, CLOCK_CHANNEL) and not window[0] <= event.utime_us < window[1]:
            (start if event.utime_us < window[0] else end).append((event.channel, event.utime_us, data))
        elif event.channel == STATUS_CHANNEL:
            s = skelmsg.status_t.decode(data)
            moves = [(_positions(s, f, 1), np.array([tile_ns])) for f in ("mono_ns", "utc_ns")]
            tile.add(event.channel, event.utime_us, data, moves)
        elif event.channel == CLOCK_CHANNEL:
            c = skelmsg.clock_offset_t.decode(data)
            moves = [(_positions(c, "host_mono_ns", 1), np.array([tile_ns]))]
            tile.add(event.channel, event.utime_us, data, moves)
        elif event.channel == REPORT_CHANNEL:
            r = skelmsg.report_t.decode(data)
            for f in ("elapsed_ns", "minor_cycles", "compute_ns", "communicate_ns", "wait_ns",
                      "timing_batches", "stall_ns"):
                setattr(r, f, getattr(r, f) * copies)
            for p in r.processes:
                for f in ("cycles", "overruns", "compute_ns", "communicate_ns", "wait_ns"):
                    setattr(p, f, getattr(p, f) * copies)
            end.append((event.channel, event.utime_us, r.encode()))
        elif event.channel in (CONFIG_CHANNEL, COMMAND_CHANNEL) and event.utime_us <= first_timing:
            start.append((event.channel, event.utime_us, data))
        else:
            end.append((event.channel, event.utime_us, data))
    copy = tile.copies(copies, tile_ns)
    shift_us = (copies - 1) * (tile_ns // 1000)
    with open(out, "wb") as f:
        f.write(_events(start, 0))
        for k in range(copies):
            f.write(copy(k))
        f.write(_events(end, shift_us))
    return copies * len(recs)


def _events(events: list[tuple[str, int, bytes]], shift_us: int) -> bytes:
    return b"".join(_HEADER.pack(SYNC, i, u + shift_us, len(c), len(d)) + c.encode() + d
                    for i, (c, u, d) in enumerate(events))  # fmt: skip


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__.rsplit("Usage: ", 1)[1].strip())
    held = grow(Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]))
    print(f"{sys.argv[2]}: {held} timing records")

"""A run's file opened and its control-plane messages decoded, once.

`open_run_log(path)` reads an LCM log, or an MCAP written by `skel export` served as
one (mcapsource.py). `read_messages(log, generations)` decodes, in one pass per
channel, what the analysis needs besides the timing records: the config_t of each
generation, every command_t with when it was heard, the DPUs' report_t and the clock
offset estimates; of the statuses, the many, only their integers (`Messages.status_columns`:
the export reads them whole in bulk, lcmjson.to_json_many). A message that does not decode
is counted by channel, never fatal.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

import skelmsg
from skeleton.host.model import from_config
from skelmsg.contract import CLOCK_CHANNEL, COMMAND_CHANNEL, CONFIG_CHANNEL, REPORT_CHANNEL, STATUS_CHANNEL

from ..errors import EXIT_BAD_INPUT, SkelError
from .flatdecode import FlatLayout, decode_many
from .logreader import Log, read_log
from .mcapsource import read_as_log

T = TypeVar("T")


class LogError(SkelError):
    """The file cannot be analysed (unreadable, not an LCM log, no run in it)."""

    exit_code = EXIT_BAD_INPUT


def run_log_path(path: str | os.PathLike[str]) -> Path:
    """A run directory (`skel run --out DIR`) stands for its run.lcm."""
    path = Path(path)
    return path / "run.lcm" if path.is_dir() else path


def open_run_log(path: str | os.PathLike[str]) -> Log:
    """The log (or exported MCAP, or run directory) of a run; LogError, one line for the
    user, when unreadable."""
    path = run_log_path(path)
    try:
        if path.suffix == ".mcap":
            return read_as_log(path)
        return read_log(path)
    except OSError as e:
        raise LogError(e.strerror or str(e)) from e


@dataclass
class Messages:
    """The decoded control-plane messages of a log."""

    log: Log = field(repr=False)  # where the statuses are decoded from
    configs: dict[int, skelmsg.config_t]  # generation -> its last config_t (only the generations asked for)
    reports: list[Any]  # report_t, in log order
    clock_offsets: list[Any]  # clock_offset_t, in log order
    commands: list[tuple[int, Any]] = field(default_factory=list)  # (utime_us heard, command_t), in log order
    malformed: dict[str, int] = field(default_factory=dict)  # channel -> undecodable messages

    def status_columns(self, *names: str) -> StatusColumns:
        """The integer fields `names` of every decodable status, without an object each: a long
        run logs hundreds of thousands, which decoded one by one in Python took 1.9 s, and held
        the GIL from the records' decode beside them. Decoded one by one: those the bulk decode
        refuses, so that the generated decoder alone says which are malformed (as for the
        export's, lcmjson.to_json_many), and those that name lockouts, kept whole, but for a
        DPU's heartbeats that repeat the lockouts of its last one (a DPU names its run's lockouts
        in every heartbeat after them): what lockouts_from_status reads of each status is the same."""
        log = self.log
        idx = log.indices(STATUS_CHANNEL)
        bulk = decode_many(_STATUS, log.buf, log.data_offset[idx], log.data_len[idx], log.release)
        decoded = bulk.ok.copy()
        columns = {name: bulk.scalars[name].astype(np.int64) for name in names}
        dpu, run_id = bulk.scalars["dpu"].tolist(), bulk.scalars["run_id"].tolist()
        first, end = (a.tolist() for a in bulk.passed["lockouts"])
        named: dict[int, tuple[int, bytes]] = {}  # dpu -> the run and lockouts of its last status kept
        locking = []
        damaged = 0
        for i in np.flatnonzero(~bulk.ok | (bulk.scalars["nlockouts"] != 0)).tolist():
            if bulk.ok[i]:
                lockouts = (run_id[i], log.buf[first[i] : end[i]].tobytes())
                if named.get(dpu[i]) == lockouts:
                    continue
                named[dpu[i]] = lockouts
            try:
                status = skelmsg.status_t.decode(bytes(log.data(int(idx[i]))))
            except Exception:  # any decoder failure means "malformed", never a crash
                damaged += 1
                continue
            decoded[i] = True
            for name in names:
                columns[name][i] = getattr(status, name)
            if status.lockouts:
                locking.append(status)
        if damaged:
            self.malformed[STATUS_CHANNEL] = damaged
        return StatusColumns(log.utime_us[idx][decoded], {n: c[decoded] for n, c in columns.items()}, locking)


# status_t's integers: its strings and lockouts are passed over (flatdecode)
_STATUS = FlatLayout.of(skelmsg.status_t, skipping=True)


@dataclass(frozen=True)
class StatusColumns:
    """Messages.status_columns: of the decodable statuses, in log order, when each was logged
    and the fields asked for, a column each; and the statuses that name lockouts, whole (a
    DPU's repeats of its last one's left out)."""

    heard_us: np.ndarray
    fields: dict[str, np.ndarray]
    locking: list[Any]


def read_messages(log: Log, generations: Iterable[int]) -> Messages:
    """Every message but the statuses (Messages.status_columns), decoded."""
    malformed: dict[str, int] = {}
    return Messages(
        log=log,
        configs=configs_of(log, generations, malformed),
        reports=[m for _, m in decode_timed(log, REPORT_CHANNEL, skelmsg.report_t.decode, malformed)],
        clock_offsets=[m for _, m in decode_timed(log, CLOCK_CHANNEL, skelmsg.clock_offset_t.decode,
                                                  malformed)],
        commands=decode_timed(log, COMMAND_CHANNEL, skelmsg.command_t.decode, malformed),
        malformed=malformed,
    )


def int_columns(messages: Sequence[Any], *fields: str) -> list[np.ndarray]:
    """The integer `fields` of decoded messages, an int64 column each (hundreds of thousands
    of statuses: one numpy pass a field, not an object a message)."""
    return [np.fromiter((getattr(m, f) for m in messages), dtype=np.int64, count=len(messages))
            for f in fields]  # fmt: skip


def published_batches(log: Log, run_id: int) -> dict[int, int]:
    """dpu -> the timing batches its report_t says it published in `run_id` (the few reports
    decoded on their own, before the rest: read_messages counts their damage)."""
    reports = decode_timed(log, REPORT_CHANNEL, skelmsg.report_t.decode, {})
    return {r.dpu: r.timing_batches for _, r in reports if r.run_id == run_id}


# A channel's messages are decoded in file order, the log's pages behind them given back every
# this many bytes: a run's heartbeats lie all through its log, and read they left 1.7 GB of a
# 2.3 GB log resident (Log.release).
_RELEASE_BYTES = 64 << 20


def decode_timed(log: Log, channel: str, decode: Callable[[bytes], T],
                 malformed: dict[str, int]) -> list[tuple[int, T]]:
    """(utime_us, message) of every message on a channel; malformed ones are counted and skipped."""
    out = []
    idx = log.indices(channel)
    ends = (log.data_offset[idx] + log.data_len[idx]).tolist()
    released = 0
    for (utime, data), end in zip(log.messages(channel), ends, strict=True):
        try:
            out.append((utime, decode(bytes(data))))
        except Exception:  # any decoder failure means "malformed", never a crash
            malformed[channel] = malformed.get(channel, 0) + 1
        if end - released > _RELEASE_BYTES:
            log.release(released, end)
            released = end
    return out


_CONFIG_HEAD = struct.Struct(">q")  # config_t starts with its generation


def configs_of(log: Log, generations: Iterable[int],
               malformed: dict[str, int]) -> dict[int, skelmsg.config_t]:
    """The last config_t of each generation asked for. Only the header of the others is read:
    a config (with the system file text) is re-sent periodically and is slow to decode."""
    wanted = set(generations)
    found: dict[int, skelmsg.config_t] = {}
    fingerprint = skelmsg.config_t._get_packed_fingerprint()
    for _, data in reversed(log.messages(CONFIG_CHANNEL)):
        if len(data) < 16 or data[:8] != fingerprint:
            malformed[CONFIG_CHANNEL] = malformed.get(CONFIG_CHANNEL, 0) + 1
            continue
        generation = _CONFIG_HEAD.unpack_from(data, 8)[0]
        if generation not in wanted or generation in found:
            continue
        try:
            config = skelmsg.config_t.decode(bytes(data))
            from_config(config)  # what the analysis reads of it: a damaged enum is malformed too
        except Exception:
            malformed[CONFIG_CHANNEL] = malformed.get(CONFIG_CHANNEL, 0) + 1
            continue
        found[generation] = config
    return found

"""Signed control, the Python side of dpu/seal.c (the layout: lcmtypes/seal_t.lcm).

With a key, a message goes out as its encoding followed by a seal_t: the sender's id, a
counter that only grows (its UTC clock in ns) and HMAC-SHA256(key, channel || 0 || message
|| the seal's first SEAL_SIGNED_BYTES). `Signer` makes seals, `Verifier` judges received
messages as the DPU does (a counter not newer than the sender's last is a replay), and
`authenticate` keeps only a log's genuine messages for the analysis.

The key is read from a file (`load_key`), never printed, logged or written anywhere else.
"""

from __future__ import annotations

import dataclasses
import hashlib
import hmac
import os
import secrets
import stat
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

import skelmsg
from skelmsg.contract import KEY_BYTES, KEY_ENV, SEAL_BYTES, SEAL_FRESH_S, SEAL_SIGNED_BYTES

from ..errors import EXIT_BAD_INPUT, SkelError

if TYPE_CHECKING:
    from .logreader import Log

_FINGERPRINT = skelmsg.seal_t._get_packed_fingerprint()
SENDERS_KEPT = 1024  # senders whose last counter a Verifier keeps (a flood of ids cannot grow it)


class KeyFileError(SkelError):
    """The key file cannot be used: one line for the user."""

    exit_code = EXIT_BAD_INPUT


class Verdict(Enum):
    GENUINE = "genuine"    # sealed with our key, counter newer; or no key on either side
    UNSIGNED = "unsigned"  # we have a key, the message no seal
    SIGNED = "signed"      # we have no key, the message a seal
    FORGED = "forged"      # the MAC does not match: another key, or altered
    REPLAYED = "replayed"  # a counter not newer than the sender's last, or stale


def key_path(arg: Path | None) -> Path | None:
    """--key when given, else $SKEL_KEY_FILE when set, else None (unauthenticated)."""
    if arg is not None:
        return arg
    env = os.environ.get(KEY_ENV, "")
    return Path(env) if env else None


def load_key(path: Path) -> bytes:
    """The key in `path`: exactly KEY_BYTES bytes, readable by its owner only."""
    try:
        with open(path, "rb") as f:
            mode = os.fstat(f.fileno()).st_mode
            data = f.read(KEY_BYTES + 1)
    except OSError as e:
        raise KeyFileError(f"key file {path}: {e.strerror} (make one with `skel keygen {path}`)") from e
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        # Anyone who reads the key can reconfigure every DPU: refused, as ssh refuses.
        raise KeyFileError(f"key file {path}: readable by others (mode {stat.S_IMODE(mode):03o}): "
                           f"chmod 600 {path}")
    if len(data) != KEY_BYTES:
        raise KeyFileError(f"key file {path}: not a key: it must hold exactly {KEY_BYTES} bytes "
                           "(`skel keygen`)")
    return data


def write_key(path: Path) -> None:
    """A new random key in `path`, mode 0600 from its creation; an existing file is kept."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(secrets.token_bytes(KEY_BYTES))


def _mac(key: bytes, channel: str, message: bytes | memoryview, head: bytes | memoryview) -> bytes:
    h = hmac.new(key, channel.encode() + b"\0", hashlib.sha256)
    h.update(message)
    h.update(head)
    return h.digest()


def split(data: bytes | memoryview) -> tuple[memoryview, skelmsg.seal_t | None]:
    """A received message's own bytes and its seal (None: not sealed)."""
    view = memoryview(data)
    if len(view) >= SEAL_BYTES and view[len(view) - SEAL_BYTES:len(view) - SEAL_BYTES + 8] == _FINGERPRINT:
        try:
            return view[:len(view) - SEAL_BYTES], skelmsg.seal_t.decode(bytes(view[len(view) - SEAL_BYTES:]))
        except Exception:  # a fingerprint by chance, then no seal: judged as unsealed
            pass
    return view, None


class Signer:
    """Seals what one sender publishes; counters strictly increase (UTC ns, bumped)."""

    def __init__(self, key: bytes, sender: int, clock: Callable[[], int] = time.time_ns) -> None:
        self._key = key
        self.sender = sender
        self._clock = clock  # UTC ns
        self._counter = 0

    def seal(self, channel: str, message: bytes) -> bytes:
        self._counter = max(self._clock(), self._counter + 1)
        seal = skelmsg.seal_t()
        seal.sender, seal.counter, seal.mac = self.sender, self._counter, b"\0" * 32
        head = seal.encode()[:SEAL_SIGNED_BYTES]
        return message + head + _mac(self._key, channel, message, head)


@dataclass
class Verifier:
    """Judges received messages. `fresh_s`: a sender first heard may not be older than
    this (None: no window, e.g. for a log recorded long ago, where only an exact repeat of
    a (sender, counter) is a replay)."""

    key: bytes | None
    fresh_s: float | None = SEAL_FRESH_S
    _last: dict[int, int] = field(default_factory=dict)
    _seen: set[tuple[int, int]] = field(default_factory=set)

    def check(self, channel: str, data: bytes | memoryview) -> tuple[Verdict, memoryview, int]:
        """(verdict, the message's own bytes, the seal's sender or 0)."""
        message, seal = split(data)
        if seal is None:
            return (Verdict.UNSIGNED if self.key is not None else Verdict.GENUINE), message, 0
        if self.key is None:
            return Verdict.SIGNED, message, seal.sender
        view = memoryview(data)
        head = view[len(message):len(message) + SEAL_SIGNED_BYTES]
        if not hmac.compare_digest(_mac(self.key, channel, message, head), bytes(seal.mac)):
            return Verdict.FORGED, message, seal.sender
        return (Verdict.GENUINE if self._fresh(seal) else Verdict.REPLAYED), message, seal.sender

    def _fresh(self, seal: skelmsg.seal_t) -> bool:
        if self.fresh_s is None:
            if (seal.sender, seal.counter) in self._seen:
                return False
            self._seen.add((seal.sender, seal.counter))
            return True
        last = self._last.get(seal.sender)
        if last is None and seal.counter < time.time_ns() - int(self.fresh_s * 1e9):
            return False
        if last is not None and seal.counter <= last:
            return False
        if last is None and len(self._last) >= SENDERS_KEPT:
            self._last.pop(next(iter(self._last)))
        self._last[seal.sender] = seal.counter
        return True


@dataclass(frozen=True)
class Authentication:
    """What `authenticate` found in a log."""

    keyed: bool = False          # some message carries a seal: the run was signed
    checked: bool = False        # a key was given and it signed the run: only genuine messages kept
    unauthenticated: int = 0     # messages left out: unsigned, forged or replayed
    by_verdict: dict[str, int] = field(default_factory=dict)


# Events whose ends are looked at per step: the log's pages behind them are given back after
# each (Log.release), or the look at every event's end left a 2.3 GB log resident.
_EVENTS_AT_ONCE = 1 << 16


def _sealed(log: Log) -> np.ndarray:
    """Which events end with a seal_t's fingerprint where a seal would start."""
    lens = log.data_len
    long_enough = np.flatnonzero(lens >= SEAL_BYTES)
    at = log.data_offset[long_enough] + lens[long_enough] - SEAL_BYTES
    out = np.zeros(len(log), dtype=bool)
    fingerprint = np.frombuffer(_FINGERPRINT, dtype=np.uint8)
    for lo in range(0, len(at), _EVENTS_AT_ONCE):
        part = at[lo : lo + _EVENTS_AT_ONCE]
        ends = log.buf[part[:, None] + np.arange(8)]
        out[long_enough[lo : lo + len(part)]] = (ends == fingerprint).all(axis=1)
        log.release(0 if lo == 0 else int(at[lo - 1]), int(part[-1]))
    return out


def authenticate(log: Log, key: bytes | None) -> tuple[Log, Authentication]:
    """The log's messages without their seals. With the key that signed the run, only the
    genuine ones (the others are counted); a run nobody signed is taken whole, and a key
    that signed none of a signed run's messages is a KeyFileError."""
    sealed = _sealed(log)
    if not sealed.any():
        return log, Authentication()
    keep = np.ones(len(log), dtype=bool)
    counts: dict[str, int] = {}
    if key is not None:
        verifier = Verifier(key, fresh_s=None)
        view = memoryview(log.buf)
        for i in range(len(log)):
            a, n = int(log.data_offset[i]), int(log.data_len[i])
            verdict, _, _ = verifier.check(log.channels[int(log.channel_id[i])], view[a:a + n])
            if verdict is not Verdict.GENUINE:
                keep[i] = False
                counts[verdict.value] = counts.get(verdict.value, 0) + 1
        if not (keep & sealed).any():
            raise KeyFileError("no message of this log is signed with this key: the run was signed "
                               "with another")
    found = Authentication(keyed=True, checked=key is not None, unauthenticated=int((~keep).sum()),
                           by_verdict=counts)
    out = dataclasses.replace(
        log, offset=log.offset[keep], eventnum=log.eventnum[keep], utime_us=log.utime_us[keep],
        channel_id=log.channel_id[keep], data_offset=log.data_offset[keep],
        data_len=(log.data_len - sealed * SEAL_BYTES)[keep],
        integrity=dataclasses.replace(log.integrity, signed=True, checked=found.checked,
                                      unauthenticated=found.unauthenticated))
    return out, found

"""Clock offsets of the DPUs: the four-timestamp ping/pong of NTP, best of several.

The host sends PING with t1 (its CLOCK_MONOTONIC); the DPU's status_t echoes t1
with t2 (received) and t3 (replied) on the DPU's clock; the host's LCM thread
notes t4 when that status arrives. The sample with the smallest round trip is
the one least disturbed by queueing, so its offset is kept. Estimates go out as
clock_offset_t on SKEL_CLOCK so they are in the run's log: the analysis turns
DPU time into host time with `dpu_ns - offset_ns`, which makes latencies across
hosts comparable. The error of one estimate is at most half its round trip.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass

import skelmsg
from skelmsg.contract import CLOCK_CHANNEL

from .control import Control, PingSample

SAMPLES = 8
SPACING_S = 0.004          # between pings: a burst would queue behind itself
REPLY_TIMEOUT_S = 0.3      # after the last ping; a DPU that has not answered by then is skipped
REFRESH_S = 5.0            # re-estimated this often during a run (clocks drift)


@dataclass(frozen=True)
class ClockEstimate:
    """One DPU's offset (DPU clock - host clock) from the best of `samples` round trips."""

    dpu: int
    offset_ns: int
    rtt_ns: int
    samples: int
    host_mono_ns: int

    def to_message(self) -> skelmsg.clock_offset_t:
        msg = skelmsg.clock_offset_t()
        msg.dpu = self.dpu
        msg.host_mono_ns = self.host_mono_ns
        msg.offset_ns = self.offset_ns
        msg.rtt_ns = self.rtt_ns
        msg.samples = self.samples
        return msg

    def to_json(self) -> dict[str, int]:
        return {"dpu": self.dpu, "offset_ns": self.offset_ns, "rtt_ns": self.rtt_ns,
                "samples": self.samples, "host_mono_ns": self.host_mono_ns}


def best(dpu: int, samples: list[PingSample]) -> ClockEstimate | None:
    """The estimate from the sample with the smallest round trip (None without a usable one)."""
    # A negative round trip means a corrupt echo (t2/t3 not from one PING): never trust it.
    usable = [s for s in samples if s.rtt_ns >= 0]
    if not usable:
        return None
    chosen = min(usable, key=lambda s: s.rtt_ns)
    return ClockEstimate(dpu, chosen.offset_ns, chosen.rtt_ns, len(usable), chosen.t4)


def estimate(control: Control, dpu_ids: Iterable[int], samples: int = SAMPLES, spacing_s: float = SPACING_S,
             reply_timeout_s: float = REPLY_TIMEOUT_S) -> dict[int, ClockEstimate]:
    """Ping every DPU `samples` times (one PING reaches all) and keep each one's best sample."""
    wanted = sorted(set(dpu_ids))
    seqs = []
    for i in range(samples):
        if i:
            time.sleep(spacing_s)
        seqs.append(control.ping())
    control.wait_pongs(seqs, wanted, reply_timeout_s)
    answers = control.pongs(seqs)
    estimates = {}
    for dpu in wanted:
        found = best(dpu, answers.get(dpu, []))
        if found is not None:
            estimates[dpu] = found
    return estimates


def publish(control: Control, estimates: dict[int, ClockEstimate]) -> None:
    for found in estimates.values():
        control.record(CLOCK_CHANNEL, found.to_message())


class ClockKeeper:
    """Estimates before a run and every REFRESH_S during it, publishing each estimate."""

    def __init__(self, control: Control, dpu_ids: Iterable[int], refresh_s: float = REFRESH_S) -> None:
        self.control = control
        self.dpu_ids = sorted(set(dpu_ids))
        self.refresh_s = refresh_s
        self.latest: dict[int, ClockEstimate] = {}
        self._last = float("-inf")

    def refresh(self, skip: Iterable[int] = ()) -> dict[int, ClockEstimate]:
        skipped = set(skip)
        found = estimate(self.control, [i for i in self.dpu_ids if i not in skipped])
        publish(self.control, found)
        self.latest.update(found)
        self._last = time.monotonic()
        return found

    def due(self) -> bool:
        return time.monotonic() - self._last >= self.refresh_s

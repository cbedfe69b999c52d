"""Summary statistics shared by every measure: percentiles, histograms, grouping.
Nothing here knows what a record is."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class LatencyUs:
    p50: float | None
    p99: float | None
    max: float | None


@dataclass
class Histogram:
    """Counts of samples in len(bins) - 1 equal bins; bins are the edges."""

    bins: list[float] = field(default_factory=list)
    counts: list[int] = field(default_factory=list)


HISTOGRAM_BINS = 40


def latency_us(samples_us: np.ndarray) -> LatencyUs:
    """p50 / p99 (linear interpolation) / max of samples in µs; None when empty."""
    if len(samples_us) == 0:
        return LatencyUs(None, None, None)
    p50, p99 = np.percentile(samples_us, [50, 99])
    return LatencyUs(float(p50), float(p99), float(samples_us.max()))


def histogram(samples: np.ndarray, bins: int = HISTOGRAM_BINS) -> Histogram:
    """An equal-width histogram from the smallest to the largest sample (a 1-wide
    range around the value when they are all equal)."""
    samples = samples[np.isfinite(samples)]
    if len(samples) == 0:
        return Histogram()
    low, high = float(samples.min()), float(samples.max())
    # Equal values, or values so large that their range holds no `bins` distinct edges (a
    # damaged record's 1e18 ns: Hypothesis found numpy refusing it): a range wide enough.
    pad = max(0.5, abs(low) * 1e-12 * bins, abs(high) * 1e-12 * bins)
    if high - low < pad:
        low, high = low - pad, high + pad
    counts, edges = np.histogram(samples, bins=bins, range=(low, high))
    return Histogram([round(float(e), 3) for e in edges], [int(c) for c in counts])


def group_slices(keys: np.ndarray) -> tuple[np.ndarray, dict[int, slice]]:
    """A stable sort order of `keys` and, per key, its slice of the sorted rows: one
    sort instead of one full-array mask per group. Keys of 16 bits or fewer (process and
    DPU ids as the records hold them) sort by radix, several times faster than int64."""
    if len(keys) == 0:
        return np.zeros(0, dtype=np.intp), {}
    order = np.argsort(_narrow(keys), kind="stable")
    sorted_keys = keys[order]
    cuts = np.flatnonzero(sorted_keys[1:] != sorted_keys[:-1]) + 1
    firsts, ends = np.r_[0, cuts].tolist(), np.r_[cuts, len(keys)].tolist()
    values = sorted_keys[firsts].tolist()
    return order, {int(v): slice(f, e) for v, f, e in zip(values, firsts, ends, strict=True)}


def _narrow(keys: np.ndarray) -> np.ndarray:
    """Wider keys that span fewer than 2^16 values, as uint16 from their smallest: numpy
    sorts those by radix too."""
    if keys.dtype.itemsize <= 2 or keys.dtype.kind not in "iu":
        return keys
    low, high = int(keys.min()), int(keys.max())
    return (keys - low).astype(np.uint16) if high - low < 1 << 16 else keys

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


# What np.percentile(samples, [50, 99]) makes of its q.
_QUANTILES = np.true_divide(np.array([50, 99]), 100)


def latency_us(samples_us: np.ndarray) -> LatencyUs:
    """p50 / p99 / max of samples in µs (as np.percentile's linear method, to the bit); None
    when empty. The samples are sorted, not selected: numpy sorts numbers with SIMD, and a sort
    then three reads took 31 ms of 3·10^6 samples against 51 ms for np.percentile (an
    introselect of six positions) and max (best of 7); a report of 10^7 records asks six
    of these per process."""
    return _latency_of_sorted(np.sort(samples_us))


def distribution(samples_us: np.ndarray, bins: int = HISTOGRAM_BINS) -> tuple[LatencyUs, Histogram]:
    """latency_us and histogram of the same samples, from one sort: the histogram's range and
    counts are then a few binary searches, not another pass (or three) over the samples."""
    ordered = np.sort(samples_us)
    return _latency_of_sorted(ordered), _histogram_of_sorted(ordered, bins)


def _latency_of_sorted(ordered: np.ndarray) -> LatencyUs:
    if len(ordered) == 0:
        return LatencyUs(None, None, None)
    top = ordered[-1]
    if ordered.dtype.kind == "f" and np.isnan(top):  # NaN sorts last; np.percentile gives NaN
        return LatencyUs(float("nan"), float("nan"), float("nan"))
    # np.percentile's own steps (numpy/lib/_function_base_impl.py: _quantile, _get_indexes,
    # _get_gamma, _lerp): the same operations on the same values give the same bits.
    n = len(ordered)
    virtual = (n - 1) * _QUANTILES
    previous = np.floor(virtual)
    following = previous + 1
    above = virtual >= n - 1  # the largest sample
    previous[above] = following[above] = -1
    previous_at, following_at = previous.astype(np.intp), following.astype(np.intp)
    gamma = virtual - previous_at
    low, high = ordered[previous_at], ordered[following_at]
    diff = high - low
    p = np.add(low, diff * gamma)
    np.subtract(high, diff * (1 - gamma), out=p, where=gamma >= 0.5, casting="unsafe", dtype=p.dtype.type)
    return LatencyUs(float(p[0]), float(p[1]), float(top))


def _histogram_of_sorted(ordered: np.ndarray, bins: int) -> Histogram:
    # -inf sort first, +inf then NaN last: the finite samples are one run between them.
    if ordered.dtype.kind == "f":
        ordered = ordered[np.searchsorted(ordered, -np.inf, side="right"):
                          np.searchsorted(ordered, np.inf, side="left")]
    if len(ordered) == 0:
        return Histogram()
    low, high = float(ordered[0]), float(ordered[-1])
    # Equal values, or values so large that their range holds no `bins` distinct edges (a
    # damaged record's 1e18 ns: Hypothesis found numpy refusing it): a range wide enough.
    pad = max(0.5, abs(low) * 1e-12 * bins, abs(high) * 1e-12 * bins)
    if high - low < pad:
        low, high = low - pad, high + pad
    # np.histogram's edges; its bins are [edge, next edge), the last one closed: what lies
    # below each edge, by binary search.
    edges = np.linspace(low, high, bins + 1)
    below = np.searchsorted(ordered, edges, side="left")
    below[-1] = len(ordered)
    return Histogram([round(float(e), 3) for e in edges], [int(c) for c in np.diff(below)])


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

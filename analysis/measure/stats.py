"""Summary statistics shared by every measure: percentiles, histograms, grouping.
Nothing here knows what a record is."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

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


class SortedSamples:
    """Samples kept sorted as they come, in two runs: a large one and the newest few. New
    samples go into the small run, which is merged into the large one once it holds an eighth
    of it: a sample is copied about nine times in all by the merges, and an insertion copies at
    most an eighth of what is held, where one sorted array copies all of it. latency_us reads
    the percentiles from the two runs by binary search, to the bit what it reads from one sorted
    array."""

    def __init__(self, least: int = 4096) -> None:
        self.least = least  # the small run merges past max(least, an eighth of the large one)
        self.large = np.zeros(0, dtype=np.float64)
        self.small = np.zeros(0, dtype=np.float64)

    def __len__(self) -> int:
        return len(self.large) + len(self.small)

    def add(self, samples: np.ndarray) -> None:
        new = np.sort(samples)
        self.small = np.insert(self.small, np.searchsorted(self.small, new), new)
        if len(self.small) > max(self.least, len(self.large) // 8):
            self.large = np.sort(np.concatenate([self.large, self.small]), kind="stable")  # two runs: a merge
            self.small = np.zeros(0, dtype=np.float64)

    def latency_us(self) -> LatencyUs:
        if np.isnan(self.large[-1:]).any() or np.isnan(self.small[-1:]).any():
            return LatencyUs(float("nan"), float("nan"), float("nan"))
        return _latency_of_sorted(_Union(self.large, self.small))


class _Union:
    """Two sorted runs read as one sorted array: its length, and its k-th elements."""

    dtype = np.dtype(np.float64)

    def __init__(self, a: np.ndarray, b: np.ndarray) -> None:
        self.a, self.b = a, b

    def __len__(self) -> int:
        return len(self.a) + len(self.b)

    def __getitem__(self, k: Any) -> Any:
        if isinstance(k, np.ndarray):
            return np.array([self._kth(int(i)) for i in k], dtype=self.dtype)
        return self.dtype.type(self._kth(int(k)))

    def _kth(self, k: int) -> float:
        """The k-th smallest (from 0; -1: the largest): i of them from a, the rest from b."""
        a, b = self.a, self.b
        if k < 0:
            k += len(a) + len(b)
        low, high = max(0, k + 1 - len(b)), min(k + 1, len(a))
        # the fewest i with a[i] >= b[k - i]: a[:i] and b[:k + 1 - i] are then the k + 1 smallest
        while low < high:
            i = (low + high) // 2
            if a[i] < b[k - i]:
                low = i + 1
            else:
                high = i
        i, j = low, k + 1 - low
        return float(max(a[i - 1] if i else -np.inf, b[j - 1] if j else -np.inf))


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

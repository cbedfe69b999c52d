"""The report's percentiles come from a sort and numpy's own interpolation steps, not from
np.percentile, and its histograms from binary searches in that sort, not np.histogram: for any
samples they must be numpy's, to the bit (report.json does not change with the speed-up)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from skeleton.analysis.measure.stats import HISTOGRAM_BINS, SortedSamples, distribution, latency_us

# What the report holds: integer ns, in µs (ns / 1000), and integer samples as they are.
NS = hnp.arrays(np.int64, st.integers(1, 400), elements=st.integers(-(2**53), 2**53))
FLOATS = hnp.arrays(np.float64, st.integers(1, 400),
                    elements=st.floats(-1e15, 1e15, allow_nan=False, allow_infinity=False))


def _percentile(samples: np.ndarray) -> tuple[float, float, float]:
    p50, p99 = np.percentile(samples, [50, 99])
    return float(p50), float(p99), float(samples.max())


@given(NS, st.booleans())
def test_percentiles_of_integer_samples_are_numpys(ns: np.ndarray, in_us: bool) -> None:
    samples = ns.astype(np.float64) / 1000.0 if in_us else ns
    got = latency_us(samples)
    assert repr((got.p50, got.p99, got.max)) == repr(_percentile(samples))


@given(FLOATS)
def test_percentiles_of_float_samples_are_numpys(samples: np.ndarray) -> None:
    got = latency_us(samples + 0.0)  # no -0.0: sorted or selected, it ties with 0.0 either way
    assert repr((got.p50, got.p99, got.max)) == repr(_percentile(samples + 0.0))


@given(FLOATS)
def test_a_nan_sample_makes_every_percentile_nan_as_numpy_does(samples: np.ndarray) -> None:
    samples = np.append(samples, np.nan)
    got = latency_us(samples)
    assert all(math.isnan(v) for v in (got.p50, got.p99, got.max))
    assert all(math.isnan(v) for v in _percentile(samples))


@given(st.lists(FLOATS, min_size=1, max_size=30), st.integers(0, 2), st.integers(1, 64))
def test_samples_added_chunk_by_chunk_give_numpys_percentiles(chunks: list[np.ndarray], nans: int,
                                                              least: int) -> None:
    """The live tables' SortedSamples (two sorted runs, read by binary search): any chunks, the
    percentiles of all of them, to the bit, whenever the small run merges (`least`, 4096 live);
    a NaN anywhere makes every figure NaN."""
    chunks = [c + 0.0 for c in chunks] + [np.full(1, np.nan)] * nans
    kept = SortedSamples(least)
    for chunk in chunks:
        kept.add(chunk)
    got = kept.latency_us()
    if nans:
        assert all(math.isnan(v) for v in (got.p50, got.p99, got.max))
    else:
        assert repr((got.p50, got.p99, got.max)) == repr(_percentile(np.concatenate(chunks)))


def test_no_samples_no_percentiles() -> None:
    got = latency_us(np.zeros(0))
    assert (got.p50, got.p99, got.max) == (None, None, None)


# Floats as large as a difference of two int64 times can make, infinities and NaN (a damaged
# record), and ranges too narrow for 40 edges. (Near 1.8e308, where a padded range overflows,
# np.histogram itself refuses: no report sample comes near.)
ANY_FLOATS = hnp.arrays(np.float64, st.integers(0, 400),
                        elements=st.floats(-1e20, 1e20, allow_subnormal=False)
                        | st.sampled_from([np.inf, -np.inf, np.nan]))


def _numpy_histogram(samples: np.ndarray) -> tuple[list[float], list[int]]:
    """np.histogram over the finite samples, from the smallest to the largest (widened when
    they are too close for distinct edges), as the report's histograms are defined."""
    samples = samples[np.isfinite(samples)]
    if len(samples) == 0:
        return [], []
    low, high = float(samples.min()), float(samples.max())
    pad = max(0.5, abs(low) * 1e-12 * HISTOGRAM_BINS, abs(high) * 1e-12 * HISTOGRAM_BINS)
    if high - low < pad:
        low, high = low - pad, high + pad
    counts, edges = np.histogram(samples, bins=HISTOGRAM_BINS, range=(low, high))
    return [round(float(e), 3) for e in edges], [int(c) for c in counts]


@given(st.one_of(ANY_FLOATS, FLOATS, NS.map(lambda ns: ns.astype(np.float64) / 1000.0)))
def test_a_histogram_from_the_sorted_samples_is_numpys(samples: np.ndarray) -> None:
    with np.errstate(invalid="ignore"):  # inf - inf between two percentiles' samples: NaN, as numpy's
        latency, histogram = distribution(samples)
        assert repr(latency) == repr(latency_us(samples))
    assert (histogram.bins, histogram.counts) == _numpy_histogram(samples)

"""Compute times that vary: a system file's `compute_us: {dist: ...}` or `{samples: FILE}`
turned into the quantile table the DPU draws from (process_t.quantiles_us).

The table is the distribution's quantile function, truncated to [min, max], at
contract.QUANTILES evenly spaced probabilities from 0 to 1; the DPU draws u in [0, 1)
and computes for the table's value at u, linear between points. Its mean (what the
schedule and the static load use) and its maximum (the worst case) are those of the
table, so what `skel check` says is exactly what the DPUs will draw.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from statistics import NormalDist

import numpy as np

from skeleton.analysis.errors import EXIT_BAD_INPUT, SkelError
from skelmsg import contract

from ..model import Varying
from .schema import ComputeSpec

# Bounds holding less of a distribution than this are a mistake (e.g. a max far below
# the mean): what is left is too thin to draw from faithfully.
MIN_MASS = 1e-6


class ComputeError(SkelError):
    """A distribution or samples file that cannot be drawn from: (field path suffix, problem)."""

    exit_code = EXIT_BAD_INPUT

    def __init__(self, key: str, problem: str) -> None:
        self.key, self.problem = key, problem
        super().__init__(f"{key}: {problem}")


def varying(spec: ComputeSpec, base: Path) -> Varying:
    """The table of a distribution, or of the samples file `spec.samples` (relative to `base`)."""
    given = spec.model_dump(exclude_none=True)
    if spec.samples is not None:
        return Varying("samples", table_of_samples(_read_samples(base / spec.samples, spec.samples)), given)
    assert spec.dist is not None and spec.max is not None  # the schema's rules
    low, high = spec.min or 0.0, spec.max
    if spec.dist == "uniform":
        return Varying("uniform", tuple(np.linspace(low, high, contract.QUANTILES).tolist()), given)
    cdf, inv = _cdf_and_inverse(spec)
    mass = cdf(high) - cdf(low)
    if mass < MIN_MASS:
        raise ComputeError("max", f"the bounds {low:g}..{high:g} us hold {mass:.1e} of this {spec.dist} "
                           "distribution: nothing to draw from; widen them or fix mean/sd")
    probs = cdf(low) + np.linspace(0.0, 1.0, contract.QUANTILES) * mass
    table = [low, *(min(max(inv(float(p)), low), high) for p in probs[1:-1]), high]
    return Varying(spec.dist, tuple(table), given)


def _cdf_and_inverse(spec: ComputeSpec) -> tuple[Callable[[float], float], Callable[[float], float]]:
    mean = spec.mean
    assert mean is not None
    if spec.dist == "exponential":
        return (lambda x: 1.0 - math.exp(-x / mean)), (lambda p: -mean * math.log1p(-p))
    assert spec.sd is not None
    if spec.dist == "normal":
        normal = NormalDist(mean, spec.sd)
        return normal.cdf, normal.inv_cdf
    # lognormal, given by the mean and sd of the compute time itself
    sigma = math.sqrt(math.log1p((spec.sd / mean) ** 2))
    under = NormalDist(math.log(mean) - sigma**2 / 2, sigma)
    return (lambda x: under.cdf(math.log(x)) if x > 0 else 0.0), (lambda p: math.exp(under.inv_cdf(p)))


def _read_samples(path: Path, given: str) -> list[float]:
    """Compute times in us, the first column of a CSV; a first line that is not a number is
    its header."""
    try:
        with path.open(newline="") as f:
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        reason = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
        raise ComputeError("samples", f"cannot read {given}: {reason}") from None
    values: list[float] = []
    for line, row in enumerate(rows, start=1):
        cell = row[0].strip() if row else ""
        if not cell:
            continue
        try:
            value = float(cell)
        except ValueError:
            if line == 1:
                continue
            raise ComputeError("samples", f"{given} line {line}: {cell[:40]!r} is not a number") from None
        if not (math.isfinite(value) and 0 <= value <= contract.MAX_PERIOD_US):
            raise ComputeError("samples", f"{given} line {line}: {cell[:40]} is not a compute time in us")
        values.append(value)
    if not values:
        raise ComputeError("samples", f"{given} holds no compute times")
    return values


def table_of_samples(values: Sequence[float]) -> tuple[float, ...]:
    """The quantile table of measured compute times (us): all of them, in order, or QUANTILES of
    their quantiles when there are more."""
    ordered = np.sort(np.asarray(values, dtype=float))
    if len(ordered) == 1:
        ordered = np.repeat(ordered, 2)
    if len(ordered) > contract.QUANTILES:
        ordered = np.quantile(ordered, np.linspace(0.0, 1.0, contract.QUANTILES))
    return tuple(ordered.tolist())

"""Compute times that vary: the quantile tables the host makes, the samples file, and real
DPU runs whose draws repeat exactly for one seed."""

from __future__ import annotations

import math
from pathlib import Path
from statistics import NormalDist

import pytest
from conftest import skel

from skeleton.host.sysfile.compute import varying
from skeleton.host.sysfile.schema import ComputeSpec
from skelmsg import contract


def test_a_truncated_normal_table_has_the_truncated_mean_and_its_bounds(tmp_path: Path) -> None:
    spec = ComputeSpec(dist="normal", mean=1000, sd=300, min=800, max=1900)
    table = varying(spec, tmp_path)
    unit = NormalDist()
    a, b = (800 - 1000) / 300, (1900 - 1000) / 300
    exact = 1000 + 300 * (unit.pdf(a) - unit.pdf(b)) / (unit.cdf(b) - unit.cdf(a))
    assert table.mean_us == pytest.approx(exact, rel=0.002)
    assert (table.min_us, table.max_us) == (800, 1900) and len(table.quantiles_us) == contract.QUANTILES
    assert list(table.quantiles_us) == sorted(table.quantiles_us)


def test_an_exponential_table_has_the_truncated_mean(tmp_path: Path) -> None:
    table = varying(ComputeSpec(dist="exponential", mean=300, max=2000), tmp_path)
    exact = 300 - 2000 * math.exp(-2000 / 300) / (1 - math.exp(-2000 / 300))
    assert table.mean_us == pytest.approx(exact, rel=0.01)


def test_many_samples_become_their_quantiles_keeping_min_and_max(tmp_path: Path) -> None:
    values = [100 + (i * 7919) % 1000 for i in range(10_000)]
    (tmp_path / "measured.csv").write_text("compute_us\n" + "\n".join(map(str, values)) + "\n")
    table = varying(ComputeSpec(samples="measured.csv"), tmp_path)
    assert len(table.quantiles_us) == contract.QUANTILES
    assert (table.min_us, table.max_us) == (min(values), max(values))
    assert table.mean_us == pytest.approx(sum(values) / len(values), rel=0.005)


def test_a_samples_file_with_a_non_number_is_one_line_and_exit_2(tmp_path: Path) -> None:
    (tmp_path / "measured.csv").write_text("compute_us\n1200\n12OO\n1300\n")
    path = tmp_path / "system.yaml"
    path.write_text("system: s\ndpus: [{id: 1}]\nprocesses:\n"
                    "  - {id: 1, name: a, dpu: 1, period_us: 5000, compute_us: {samples: measured.csv}}\n")
    result = skel("check", str(path))
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr == (f"{path}: processes.a.compute_us.samples: measured.csv line 3: '12OO' is not "
                             "a number\n")

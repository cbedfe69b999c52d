"""Compute times that vary: the quantile tables the host makes, the samples file, and real
DPU runs whose draws repeat exactly for one seed."""

from __future__ import annotations

import json
import math
from pathlib import Path
from statistics import NormalDist

import pytest
from conftest import EXAMPLES, skel

from skeleton.analysis.measure.run import load_run
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


VARYING = """\
system: varying
dpus: [{id: 1, compute: sleep}]
processes:
  - {id: 1, name: steady, dpu: 1, period_us: 5000, compute_us: 500}
  - {id: 2, name: jittery, dpu: 1, period_us: 5000,
     compute_us: {dist: lognormal, mean: 1200, sd: 400, min: 400, max: 3000}}
run: {cycles: 300, warmup_cycles: 20}
"""


def _draws(out: Path) -> list[int]:
    timing = load_run(out).timing.to_pandas()
    mine = timing[timing["process_name"] == "jittery"].sort_values("cycle")
    return [int(v) for v in mine["asked_ns"] if v > 0]  # the cycles that computed


@pytest.mark.timing
def test_one_seed_gives_the_same_draws_run_after_run(tmp_path: Path, url: str) -> None:
    """Real DPUs: two runs of seed 7 draw the same compute times cycle by cycle, seed 8
    others; what the DPU computed follows the draws, and the report shows both."""
    path = tmp_path / "varying.yaml"
    path.write_text(VARYING)
    outs = {}
    for name, seed in (("first", 7), ("again", 7), ("other", 8)):
        outs[name] = tmp_path / name
        run = skel("run", str(path), "--spawn", "--url", url, "-s", f"run.seed={seed}",
                   "--out", str(outs[name]))
        assert run.returncode == 0, run.stdout + run.stderr
    first, again, other = (_draws(outs[n]) for n in ("first", "again", "other"))
    n = min(len(first), len(again))
    assert n >= 280 and first[:n] == again[:n]
    assert sum(a != b for a, b in zip(first, other, strict=False)) > 0.9 * min(len(first), len(other))
    assert min(first) >= 400_000 and max(first) <= 3_000_000 and len(set(first)) > 250

    report = json.loads((outs["first"] / "report.json").read_text())
    jittery = next(p for p in report["processes"] if p["name"] == "jittery")
    steady = next(p for p in report["processes"] if p["name"] == "steady")
    assert jittery["varying"] and not steady["varying"]
    assert jittery["asked_mean_us"] == pytest.approx(1200, rel=0.1)
    assert jittery["compute_mean_us"] == pytest.approx(jittery["asked_mean_us"], rel=0.01)
    assert jittery["asked_us"]["max"] <= 3000 and jittery["compute_us"]["p99"] > 2000
    assert steady["asked_us"]["max"] == pytest.approx(500)
    printed = skel("report", str(outs["first"]))
    assert "per process whose compute varies" in printed.stdout and "jittery" in printed.stdout


@pytest.mark.timing
def test_servo_with_a_varying_compute_locks_out_where_the_constant_one_does_not(
        tmp_path: Path, url: str) -> None:
    """examples/servo-jitter.yaml: DPU 1 at 96 % on average. Constant, it runs clean; with the
    forward kinematics drawn from its lognormal (the same mean), DPU 1 falls behind and its
    processes lock out."""
    system = str(EXAMPLES / "servo-jitter.yaml")
    constant = skel("run", system, "--spawn", "--url", url, "--cycles", "600",
                    "-s", "process.forward_kinematics.compute_us=3315", "--out", str(tmp_path / "constant"))
    assert constant.returncode == 0, constant.stdout + constant.stderr
    varying_run = skel("run", system, "--spawn", "--url", url, "--cycles", "600",
                       "--out", str(tmp_path / "jitter"))
    assert varying_run.returncode == 3, varying_run.stdout + varying_run.stderr
    report = json.loads((tmp_path / "jitter" / "report.json").read_text())
    locked = {(f["process"], f["dpu"]) for f in report["faults"] if f["kind"] == "lockout"}
    assert ("forward_kinematics", 1) in locked, report["faults"]

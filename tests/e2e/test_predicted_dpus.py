"""tests/unit/test_predicted.py's tests that start skel-dpu (it says what they check)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import EXAMPLES, skel

from skeleton.analysis.measure.predicted import PLATFORM


def _run(tmp_path: Path, url: str, path: Path, *args: str) -> tuple[dict, str]:
    out = tmp_path / f"run-{path.stem}"
    run = skel("run", str(path), "--spawn", "--url", url, "--out", str(out), "--all", *args)
    assert run.returncode in (0, 1, 3), run.stdout + run.stderr
    report = json.loads((out / "report.json").read_text())
    again = skel("report", str(out), "--json")
    # from the log alone (the system file its config carries), the same figures beside
    assert json.loads(again.stdout)["predicted"] == report["predicted"], again.stderr
    return report, run.stdout


@pytest.mark.timing
def test_servo_measures_its_prediction(tmp_path: Path, url: str) -> None:
    report, stdout = _run(tmp_path, url, EXAMPLES / "servo.yaml", "--cycles", "600",
                          "-s", "run.warmup_cycles=20", "-s", "run.lockout_cycles=20")
    predicted = report["predicted"]
    assert predicted["generation"] == report["generation"]
    assert [d["id"] for d in predicted["dpus"]] == [1, 2, 3, 4]
    # A stall of the platform as long as a period (a `stall` fault: this shared VM's hypervisor
    # takes its CPUs for 5-70 ms at times) is the platform's, whatever the design: what the
    # prediction bounds is judged on the DPUs it left alone (below), and on those whose data
    # it did not delay: a data reader skips a release its data comes a period late for (DPU 3
    # once computed 81 % against 86 predicted so, with 4 % of the CPUs stolen)
    stalled = {d for f in report["faults"] if f["kind"] == "stall" and f["duration_ms"] >= 5.0
               for d in f["dpus"]}
    skipping = {p["dpu"] for p in report["processes"] if p["releases_skipped"] > 0} if stalled else set()
    for d in predicted["dpus"]:
        if d["id"] not in skipping:
            assert abs(d["compute_pct"]["delta"]) <= 2.0 and not d["compute_pct"]["outside"], d
    assert "per process: worst response predicted, p99 measured" in stdout
    # the shares that follow from two rates (a 23.8 ms writer read every 5 ms, the reverse)
    rated = [i for i in predicted["inputs"] if i["new"]["predicted"] < 1 or i["dropped"]["predicted"] > 0]
    assert len(rated) == 6
    for i in rated:
        assert not (i["new"]["outside"] or i["dropped"]["outside"]), i
    # computations in sleep mode end no sooner than predicted: the platform only adds, less than a
    # period at p99; a period-long stall delays the responses after it as long as their DPU takes
    # to catch up (SERVO's DPU 1, at 90 % load, 0.5 ms a frame)
    for p in predicted["processes"]:
        assert -100 <= p["response_us"]["delta"], p
        assert p["dpu"] in stalled or p["response_us"]["delta"] < 5000, (p, report["faults"])
    assert {c["name"] for c in predicted["chains"]} == {c["name"] for c in report["chains"]}


SHARED_CPU = """\
system: shared_cpu
dpus:            # two DPUs spinning (cpu mode) on one CPU: each computes on a processor it shares
  - {id: 1, compute: cpu, cpu: 0}
  - {id: 2, compute: cpu, cpu: 0}
buffers: [{id: 1, name: left_out, bytes: 64}]
processes:
  - {id: 1, name: left, dpu: 1, period_us: 20000, compute_us: 6000, outputs: [left_out]}
  - {id: 2, name: right, dpu: 2, period_us: 20000, compute_us: 6000, inputs: [left_out]}
run: {duration_s: 3, warmup_cycles: 10, late_pct: 5}
"""


@pytest.mark.timing
def test_interference_is_flagged_as_the_platforms_cost(tmp_path: Path, url: str) -> None:
    """The two computations take turns on CPU 0, so a cycle that meets the other's computation
    ends later than predicted by however much of it the kernel ran first: up to 6 ms when both
    release together, 1.5-2 ms measured in CI where the kernel interleaved them otherwise.
    Either way beyond late_pct (5 %, 1 ms) of the 20 ms period: flagged as the platform's cost.
    The computation itself is what was asked (cpu mode measures CPU time): % compute is not."""
    path = tmp_path / "shared.yaml"
    path.write_text(SHARED_CPU)
    report, stdout = _run(tmp_path, url, path)
    predicted = report["predicted"]
    for d in predicted["dpus"]:
        assert not d["compute_pct"]["outside"], d
    worse = max(predicted["processes"], key=lambda p: p["response_us"]["delta"])
    assert worse["response_us"]["outside"] and worse["response_us"]["delta"] > 1000, predicted["processes"]
    line = next(line for line in predicted["outside"] if line.startswith(f"{worse['name']} (DPU"))
    assert line.endswith(PLATFORM)
    assert line.split(":")[0] in stdout

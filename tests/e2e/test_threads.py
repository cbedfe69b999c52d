"""The tasking executive's two ways (its own schedule in compute mode sleep, SCHED_FIFO kernel
threads in cpu) wait for data, lock out and stop as the cyclic executive does: real DPUs run
by `skel run --spawn`, judged from their report and timing records. The live switch and
events on kernel threads are tested with the others (test_tasking_reconfig.py, test_event.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import SANITIZER_ERROR, skel

import skeleton

pytestmark = pytest.mark.timing  # judges the DPUs' timing: tests/steal.py

MS = 1_000_000  # ns

# One DPU. `reader` (5 ms) waits for `writer`'s buffer (10 ms) on an in-process link: it runs
# once per write and skips the releases in between. `starved` waits for a buffer written once
# in the run (period 10 s): it locks out, naming the buffer, and the lockout stops the run
# while its thread is blocked in its data wait.
DATA = """\
system: threads-data
links: [{{name: bus, url: "{url}"}}, {{name: mem, url: local}}]
dpus: [{{id: 1, executive: threads, compute: {compute}}}]
buffers:
  - {{id: 1, name: near, bytes: 64, link: mem}}
  - {{id: 2, name: rare, bytes: 64, link: mem}}
processes:
  - {{id: 1, name: writer, dpu: 1, period_us: 10000, compute_us: 1000, outputs: [near]}}
  - {{id: 2, name: reader, dpu: 1, period_us: 5000, compute_us: 500, sync: data, inputs: [near]}}
  - {{id: 3, name: once, dpu: 1, period_us: 10000000, compute_us: 100, outputs: [rare]}}
  - {{id: 4, name: starved, dpu: 1, period_us: 5000, compute_us: 500, sync: data, inputs: [rare]}}
run: {{duration_s: 4, warmup_cycles: 0, lockout_cycles: 10, stop_on: [lockout]}}
"""

# U = 6/8 + 5/10 = 125 %: `hog` (rate-monotonic, first) leaves `victim` a quarter of the
# processor for the half it needs, so victim's releases age until one locks out.
OVERLOAD = """\
system: threads-overload
links: [{{name: bus, url: "{url}"}}]
dpus: [{{id: 1, executive: threads, compute: {compute}}}]
processes:
  - {{id: 1, name: hog, dpu: 1, period_us: 8000, compute_us: 6000}}
  - {{id: 2, name: victim, dpu: 1, period_us: 10000, compute_us: 5000}}
run: {{duration_s: 4, warmup_cycles: 0, lockout_cycles: 10, stop_on: [lockout]}}
"""

MODES = pytest.mark.parametrize("compute", ["sleep", "cpu"])


def _run(tmp_path: Path, url: str, text: str, compute: str) -> tuple[Path, dict, str]:
    path = tmp_path / "system.yaml"
    path.write_text(text.format(url=url, compute=compute))
    out = tmp_path / "run"
    run = skel("run", str(path), "--spawn", "--url", url, "--out", str(out))
    log = (out / "logs" / "dpu1.log").read_text(errors="replace")
    assert not SANITIZER_ERROR.search(log.encode()), log
    assert run.returncode == 3, run.stdout + run.stderr  # a lockout is a fatal flaw
    return out, json.loads((out / "report.json").read_text()), log


@MODES
def test_data_waits_lock_out_naming_the_buffer_and_stop_ends_a_blocked_wait(tmp_path: Path, url: str,
                                                                          compute: str) -> None:
    out, report, log = _run(tmp_path, url, DATA, compute)
    lockouts = [f for f in report["faults"] if f["kind"] == "lockout"]
    named = [(f["process"], f["buffer"], f["writer"]) for f in lockouts]
    assert named == [("starved", "rare", "once")], lockouts
    # stop_on: the run ended a lockout window (capped at 1 s) after it, not after its 4 s,
    # with starved's thread waiting: the STOP reached it and the DPU reported.
    timing = skeleton.load_run(out).timing.to_pandas()
    t0 = timing.release_ns.min()
    assert timing.release_ns.max() - t0 < 2_500 * MS, (timing.release_ns.max() - t0) / MS
    assert "STOP" in log and "ended:" in log, log
    # The reader runs once per write, on new data each time, and skips the releases between.
    inputs = {(p["name"], i["buffer"]): i for p in report["processes"] for i in p["inputs"]}
    near = inputs["reader", "near"]
    writes = timing[(timing.process_name == "writer") & timing.completed]
    reads = timing[(timing.process_name == "reader") & timing.completed]
    assert near["stale"] == 0 and abs(near["new"] - len(writes)) <= 1, (near, len(writes))
    assert abs(len(reads) - len(writes)) <= 1, (len(reads), len(writes))
    # It is released with the writer but starts once the writer's 1 ms of compute wrote its data.
    waited = (reads.start_ns - reads.release_ns) / MS
    assert (waited > 0.9).mean() > 0.9, waited.describe()


@MODES
def test_an_overloaded_dpu_locks_out_the_process_it_cannot_run(tmp_path: Path, url: str,
                                                               compute: str) -> None:
    _, report, _ = _run(tmp_path, url, OVERLOAD, compute)
    lockouts = [f for f in report["faults"] if f["kind"] == "lockout"]
    assert [(f["process"], f["buffer"]) for f in lockouts] == [("victim", None)], lockouts
    assert "its DPU cannot run it" in lockouts[0]["detail"], lockouts

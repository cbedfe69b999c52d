"""tests/unit/test_listener.py's tests that start skel-dpu (it says what they check)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

from conftest import LOCKOUT_SYSTEM, REPO, skel
from test_run_dpus import DEADLOCK_SYSTEM

FaultKey = tuple[str, ...]


def _keys(faults: list[dict]) -> set[FaultKey]:
    """The lockouts and jams: (kind, process, DPU) and (kind, chain...)."""
    out: set[FaultKey] = set()
    for f in faults:
        if f["kind"] == "lockout":
            out.add(("lockout", f["process"], str(f["dpu"])))
        elif f["kind"] == "jam":
            out.add(("jam", *f["chain"]))
    return out


def _printed(stdout: str) -> set[FaultKey]:
    lockouts = re.findall(r"FAULT lockout: (\w+) \(DPU (\d+)\)", stdout)
    out: set[FaultKey] = {("lockout", name, dpu) for name, dpu in lockouts}
    out |= {("jam", *m.split(" -> ")) for m in re.findall(r"FAULT jam: ([\w >-]+?): ", stdout)}
    return out


def _run_watched(tmp_path: Path, url: str, system_text: str, name: str, *run_args: str) -> None:
    system = tmp_path / f"{name}.yaml"
    system.write_text(system_text)
    out = tmp_path / name
    watch = subprocess.Popen([sys.executable, "-m", "skeleton.host.cli", "watch", "--once", "--json",
                              "--url", url, "--duration", "60"], cwd=REPO, text=True,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert watch.stderr is not None
    assert "waiting for a run" in watch.stderr.readline()  # subscribed: it hears the whole run
    run = skel("run", str(system), "--spawn", "--url", url, "--out", str(out), *run_args)
    watched, err = watch.communicate(timeout=90)
    assert run.returncode == 3, run.stdout + run.stderr
    assert watch.returncode == 3, err
    report = json.loads((out / "report.json").read_text())
    again = json.loads(skel("report", str(out / "run.lcm"), "--json").stdout)
    faults = _keys(report["faults"])
    assert faults and any(k[0] == "lockout" for k in faults), report["faults"]
    assert _keys(again["faults"]) == faults, again["faults"]
    assert _printed(run.stdout) == faults, run.stdout
    assert _keys(json.loads(watched)["faults"]) == faults, watched


def test_watch_run_and_report_agree_on_a_lockout(tmp_path: Path, url: str) -> None:
    _run_watched(tmp_path, url, LOCKOUT_SYSTEM, "lockout")


def test_watch_run_and_report_agree_on_a_jam(tmp_path: Path, url: str) -> None:
    # skel check refuses the deadlock it predicts; run anyway, it jams as predicted
    _run_watched(tmp_path, url, DEADLOCK_SYSTEM.format(right_dpu=1), "deadlock", "--no-check")

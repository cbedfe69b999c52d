"""The lab tutorial (docs/tutorial/lab.md) runs on three network namespaces joined by a
bridge, standing for its machines rt-a, rt-b (the DPUs) and rt-c (the host tool) on a switch.

Each machine has a checkout of its own (a directory holding build/, .venv/ and examples/ of
this one) and its host name (a UTS namespace), so `skel-dpu --id auto` finds its DPU by name
as on a real lab. The steps run in the page's order, each on the machines its title names;
the DPUs a step leaves running end with the namespaces.
"""

from __future__ import annotations

import json
import os
import subprocess

import pytest
from blocks import blocks
from conftest import REPO
from netns import hosts_fixture
from netns.hosts import _wrap

PAGE = REPO / "docs" / "tutorial" / "lab.md"
MACHINES = ["rt-a", "rt-b", "rt-c"]
netns_lab_hosts = hosts_fixture(len(MACHINES), prefix="skeldoc")


def test_netns_the_lab_tutorial_runs(netns_lab_hosts, tmp_path) -> None:
    hosts = dict(zip(MACHINES, netns_lab_hosts.names, strict=True))
    steps = [b for b in blocks(PAGE) if b.machines(MACHINES)]
    assert steps and {m for b in steps for m in b.machines(MACHINES)} == set(MACHINES)
    for machine in MACHINES:
        checkout = tmp_path / machine
        checkout.mkdir()
        for name in ("build", ".venv", "examples"):
            (checkout / name).symlink_to(REPO / name)
    env = {**os.environ, "COLUMNS": "160", "SKEL_STATE_DIR": str(tmp_path / "state")}
    for block in steps:
        for machine in block.machines(MACHINES):
            argv = _wrap(netns_lab_hosts.netns(hosts[machine]), machine,
                         ["bash", "-e", "-o", "pipefail", "-c", block.text])
            done = subprocess.run(argv, cwd=tmp_path / machine, env=env, stdin=subprocess.DEVNULL,
                                  capture_output=True, text=True, timeout=180)
            if done.returncode != 0:
                pytest.fail(f"{PAGE.relative_to(REPO)}:{block.line} on {machine}: exited "
                            f"{done.returncode}:\n{(done.stdout + done.stderr)[-4000:]}", pytrace=False)
            print(f"--- {machine}: {block.text}{done.stdout}{done.stderr}")
    reports = sorted((tmp_path / "rt-c" / "runs").glob("lab-*/report.json"))
    assert len(reports) == 1, reports
    report = json.loads(reports[0].read_text())
    assert sorted(d["id"] for d in report["dpus"]) == [1, 2]
    assert all(d["compute_pct"] for d in report["dpus"]), report["dpus"]

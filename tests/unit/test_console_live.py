"""The console's live view (host/console/live.py): what the page is sent of what `skel watch`
hears, faults with what the graph marks (the chain from the process struck back to the root
cause), and how far the run has come."""

from __future__ import annotations

from skeleton.analysis.measure.faults import Fault
from skeleton.host.cli.watch import Heard
from skeleton.host.console.live import live_view


def test_before_a_run_and_its_faults_as_the_graph_marks_them() -> None:
    heard = Heard(keep_events=False)
    assert live_view(heard, "udpm://x") == {"url": "udpm://x", "run_id": None, "states": {}, "faults": []}
    jam = Fault(kind="jam", process="executor", dpu=2, root_dpu=3, at_s=1.5,
                chain=["executor", "force_control", "jacobian_transpose"])
    lockout = Fault(kind="lockout", process="jacobian_transpose", dpu=3, writer="joint_sensors", at_s=1.2)
    overloaded = Fault(kind="lockout", process="dynamics", dpu=4, at_s=1.3)  # waits for nobody
    heard.listener.announce(None, running=False, heard=[lockout, overloaded, jam])
    faults = live_view(heard, "udpm://x")["faults"]
    assert [(f["kind"], f["fatal"], f["process"], f["chain"]) for f in faults] == [
        ("lockout", True, "jacobian_transpose", ["jacobian_transpose", "joint_sensors"]),
        ("lockout", True, "dynamics", ["dynamics"]),
        ("jam", True, "executor", ["executor", "force_control", "jacobian_transpose"])]
    assert all(f["text"] for f in faults)

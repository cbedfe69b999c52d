"""`skel margin --simulate`: the same search on the executives themselves, on virtual time."""

from __future__ import annotations

import json

from conftest import REPO, skel


def test_servos_simulated_margins_are_the_predicted_ones() -> None:
    done = skel("margin", str(REPO / "examples" / "servo.yaml"), "--simulate", "--json", "--dpu", "4",
                "--process", "executor")
    assert done.returncode == 0, done.stderr
    rows = {r["scope"]: r for r in json.loads(done.stdout)["margins"]}
    assert set(rows) == {"DPU 4", "process executor"}
    for row in rows.values():
        predicted, simulated = row["predicted"]["factor"], row["simulated"]["factor"]
        assert abs(simulated - predicted) <= 2e-4 * predicted, row  # the search's own precision
    assert rows["DPU 4"]["simulated"]["breaks"][0].startswith("overrun:")
    assert "(DPU 4)" in rows["DPU 4"]["simulated"]["breaks"][0]

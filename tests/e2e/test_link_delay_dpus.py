"""A link's emulated latency on real DPUs (tests/sim/test_links.py has the exact figures on simulated
time): one writer sends the same buffer on two links of one machine, one of them with latency_us:
2000, so the run measures its own floor (the real loopback transport and wake-up) beside it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import fresh_url, skel

# Each reader waits for its buffer (sync: data), so its chain measures when the DPU could first
# see the value: its wake-up on arrival, or at the instant the emulated link made it due.
TWO_LINKS = """\
system: two-links
links:
  - {{name: bus, url: "{bus}"}}
  - {{name: slow, url: "{slow}", latency_us: 2000}}
dpus: [{{id: 1}}, {{id: 2}}, {{id: 3}}]
buffers:
  - {{id: 1, name: near, bytes: 64, link: bus}}
  - {{id: 2, name: far, bytes: 64, link: slow}}
processes:
  - {{id: 1, name: writer, dpu: 1, period_us: 10000, compute_us: 1000, outputs: [near, far]}}
  - {{id: 2, name: near_reader, dpu: 2, period_us: 10000, compute_us: 500, sync: data, inputs: [near]}}
  - {{id: 3, name: far_reader, dpu: 3, period_us: 10000, compute_us: 500, sync: data, inputs: [far]}}
chains:
  - [writer, near_reader]
  - [writer, far_reader]
run: {{duration_s: 1.5, warmup_cycles: 10, lockout_cycles: 50}}
"""


@pytest.mark.timing
def test_a_latency_of_2_ms_adds_2_ms_to_the_transport_and_the_readers_first_sight(tmp_path: Path, url: str
                                                                                   ) -> None:
    fresh_url(), fresh_url()  # the bus's writer takes the port after its own
    system = tmp_path / "two.yaml"
    system.write_text(TWO_LINKS.format(bus=url, slow=fresh_url()))
    out = tmp_path / "run"
    run = skel("run", str(system), "--spawn", "--url", url, "--out", str(out))
    assert run.returncode == 0, run.stdout + run.stderr
    report = json.loads((out / "report.json").read_text())
    transport = {b["buffer"]: b["latency_us"]["p50"] for b in report["buffers"]}
    chains = {c["processes"][-1]: c["latency_us"]["p50"] for c in report["chains"]}
    assert 1800 <= transport["far"] - transport["near"] <= 2200, transport
    assert 1800 <= chains["far_reader"] - chains["near_reader"] <= 2200, chains
    for b in report["buffers"]:
        assert b["published"] > 100 and b["lost"] == 0, b
    (far,) = (i for i in report["predicted"]["inputs"] if i["buffer"] == "far")
    assert far["transport_us"]["predicted"] == 2000.0

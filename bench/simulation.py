"""`make bench` part (l) simulate (bench/run.py runs it): how fast the executives run on virtual
time, and what the design of the simulation rests on.

- speed: ten minutes of SERVO (about a million process-cycles and a million buffer
  deliveries) through `skel-dpu --simulate`, three times: simulated seconds per wall second
  (goal: 100, the floor being real time's 1), and the events a wall second;
- `skel simulate` end to end (the input written, the simulation, the analysis of its log, the
  one screen) for a minute of SERVO;
- bench/switch.c: a handover between two DPUs as a fiber switch on one thread (the design) and
  as a handover between two threads (the alternative), side by side.
"""

from __future__ import annotations

import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

from skeleton.host.live.simulate import write_input
from skeleton.host.sysfile.system import load

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
SERVO = REPO / "examples" / "servo.yaml"
SIMULATED_S = 600
RUNS = 3
GOAL_SPEED = 100.0
_SAID = re.compile(r"simulation: (\d+) events, (\d+) messages delivered, ([\d.]+) s of virtual time")


def _switch(tmp: Path) -> str:
    binary = tmp / "switch"
    subprocess.run(["gcc", "-O2", "-std=c11", "-D_GNU_SOURCE", "-Wall", "-Wextra", "-Werror",
                    str(BENCH / "switch.c"), "-o", str(binary), "-lpthread"], check=True)
    return subprocess.run([str(binary)], check=True, capture_output=True, text=True).stdout.strip()


def part_simulate(tmp: Path) -> list[str]:
    given, out = tmp / "sim-input.lcm", tmp / "sim-output.lcm"
    write_input(load(SERVO), given, SIMULATED_S * 1_000_000_000)
    walls, said = [], None
    for _ in range(RUNS):
        began = time.perf_counter()
        done = subprocess.run([str(REPO / "build" / "skel-dpu"), "--simulate", str(given), str(out)],
                              capture_output=True, text=True, check=True)
        walls.append(time.perf_counter() - began)
        said = _SAID.search(done.stderr)
    assert said is not None, "skel-dpu --simulate said nothing of what it did"
    events, virtual_s = int(said.group(1)), float(said.group(3))
    speeds = sorted(virtual_s / w for w in walls)
    verdict = "PASS" if speeds[0] >= GOAL_SPEED else "FAIL"
    began = time.perf_counter()
    subprocess.run([sys.executable, "-m", "skeleton.host.cli", "simulate", str(SERVO), "--duration", "60",
                    "--out", str(tmp / "sim-60")], capture_output=True, check=True, cwd=REPO)
    end_to_end = time.perf_counter() - began
    return [
        f"simulation: SERVO on virtual time at {speeds[0]:.0f} to {speeds[-1]:.0f} times real time "
        f"(goal {GOAL_SPEED:.0f}, real time being 1): {verdict}",
        f"# {virtual_s:.0f} s of SERVO simulated {RUNS} times: {min(walls):.2f} / "
        f"{statistics.median(walls):.2f} / {max(walls):.2f} s of wall time (min / median / max), {events} "
        f"events, {said.group(2)} messages delivered, {events / statistics.median(walls) / 1e6:.2f} M events "
        "per wall second",
        f"skel simulate of 60 s of SERVO, end to end (the simulation, the analysis of its log, the "
        f"one screen): {end_to_end:.1f} s",
        f"a handover between two DPUs (bench/switch.c, 10^6 rounds): {_switch(tmp)}",
    ]

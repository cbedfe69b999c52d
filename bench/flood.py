"""A signed SERVO run flooded with hostile messages, against the same run clean.

`flood_servo(tmp, rate, seconds)` runs SERVO twice on local DPUs with a key (`skel run
--spawn`, speed 3): once clean, once while build/flood sends RATE hostile messages a second
for SECONDS to its control channels and every buffer channel (garbage, a foreign
fingerprint, our fingerprints with lying lengths, well-formed unsigned commands). It returns
what each DPU was sent, what it counted as refused, what the kernel dropped at its sockets
before it could see them (/proc/net/udp), and both runs' reports. tests/e2e/test_flood.py runs
it at a rate this 2-core machine delivers whole; `make bench` (bench/run.py, part flood) at
100 000 a second.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import skelmsg
from skeleton.analysis.read.logreader import read_log
from skeleton.analysis.read.seal import Verdict, Verifier, load_key, write_key
from skeleton.host.live.spawn import running
from skeleton.host.sysfile.system import load, with_url
from skelmsg import contract

REPO = Path(__file__).resolve().parent.parent
FLOOD = REPO / "build" / "flood"
SERVO = REPO / "examples" / "servo.yaml"
SPEED = 3      # ~30 % load: the machine's own noise does not lock SERVO out
SETTLE_S = 2.0  # after the logger's file appears: START has gone out, the run is under way


@dataclass
class DpuFlood:
    dpu: int
    sent: int               # hostile messages on the channels it subscribes to
    refused: int            # what it counted: unsigned control + malformed buffers
    socket_drops: int       # what the kernel dropped at its sockets (hostile or not)
    compute_clean: float
    compute_flooded: float


@dataclass
class FloodResult:
    rate_sent: float        # hostile messages a second the flooder achieved
    seconds: float
    dpus: list[DpuFlood] = field(default_factory=list)
    clean: dict[str, Any] = field(default_factory=dict)      # report.json of the clean run
    flooded: dict[str, Any] = field(default_factory=dict)    # ... and of the flooded one
    exit_codes: tuple[int, int] = (0, 0)


def _skel(*args: str) -> list[str]:
    return [sys.executable, "-m", "skeleton.host.cli", *args]


def _dpu_pids(url: str) -> dict[int, int]:
    """The running skel-dpu processes on `url`: DPU id -> pid."""
    return {int(argv[argv.index(b"--id") + 1]): pid for pid, argv in running("skel-dpu").items()
            if url.encode() in argv and b"--id" in argv}


def socket_drops(pid: int) -> int:
    """Datagrams the kernel dropped at the UDP sockets of process `pid` (its receive buffers full)."""
    inodes = set()
    if not Path(f"/proc/{pid}/fd").exists():
        raise RuntimeError(f"process {pid} is gone: the run ended before the flood did")
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        with_target = re.fullmatch(r"socket:\[(\d+)\]", os.readlink(fd)) if fd.is_symlink() else None
        if with_target:
            inodes.add(with_target.group(1))
    drops = 0
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        with open(table) as f:
            next(f)
            for line in f:
                cols = line.split()
                if cols[9] in inodes:
                    drops += int(cols[-1])
    return drops


def last_statuses(log: Path, key: bytes) -> dict[int, Any]:
    """Each DPU's last genuine status_t in a signed run's log."""
    verifier = Verifier(key, fresh_s=None)
    last: dict[int, Any] = {}
    for _, data in read_log(log).messages(contract.STATUS_CHANNEL):
        verdict, message, _ = verifier.check(contract.STATUS_CHANNEL, data)
        if verdict is Verdict.GENUINE:
            status = skelmsg.status_t.decode(bytes(message))
            last[status.dpu] = status
    return last


def flood_servo(tmp: Path, url: str, rate: int, seconds: float) -> FloodResult:
    key_file = tmp / "key"
    if not key_file.exists():
        write_key(key_file)
    key = load_key(key_file)
    system = load(SERVO)
    common = ["--spawn", "--url", url, "--key", str(key_file), "--duration", f"{seconds + 6:g}",
              "-s", "run.stop_on=[]", *(a for d in system.dpus for a in ("-s", f"dpu.{d.id}.speed={SPEED}"))]
    env = {**os.environ, "COLUMNS": "160"}
    clean = subprocess.run(_skel("run", str(SERVO), *common, "--out", str(tmp / "clean")), cwd=REPO, env=env,
                           capture_output=True, text=True, timeout=seconds + 120)
    flooded_dir = tmp / "flooded"
    run = subprocess.Popen(_skel("run", str(SERVO), *common, "--out", str(flooded_dir)), cwd=REPO, env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while not (flooded_dir / "run.lcm").exists() and time.monotonic() < deadline and run.poll() is None:
        time.sleep(0.1)
    time.sleep(SETTLE_S)
    pids = _dpu_pids(url)
    drops_before = {d: socket_drops(p) for d, p in pids.items()}
    # Each buffer's channel on its writer's port, where its readers listen (a local one: nowhere).
    on_url = with_url(system, url)
    wire = {b.channel: on_url.buffer_url(b.id) for b in system.buffers}
    channels = [contract.CONFIG_CHANNEL, contract.COMMAND_CHANNEL,
                *(f"{channel}@{on}" for channel, on in wire.items() if on)]
    flood = subprocess.run([str(FLOOD), url, str(rate), f"{seconds:g}", *channels], capture_output=True,
                           text=True, timeout=seconds * 10 + 60)
    if flood.returncode != 0:
        raise RuntimeError(f"flood failed: {flood.stderr}")
    time.sleep(0.5)  # what is queued is handled
    drops = {d: socket_drops(p) - drops_before[d] for d, p in pids.items()}
    code = run.wait(timeout=seconds * 10 + 120)
    told = json.loads(flood.stdout)
    sent = {c: sum(n) for c, n in told["sent"].items()}
    result = FloodResult(rate_sent=sum(sent.values()) / told["seconds"], seconds=told["seconds"],
                         clean=json.loads((tmp / "clean" / "report.json").read_text()),
                         flooded=json.loads((flooded_dir / "report.json").read_text()),
                         exit_codes=(clean.returncode, code))
    statuses = last_statuses(flooded_dir / "run.lcm", key)
    compute = {d["id"]: d["compute_pct"] for d in result.clean["dpus"]}
    flooded_compute = {d["id"]: d["compute_pct"] for d in result.flooded["dpus"]}
    by_id = {b.id: b for b in system.buffers}
    for dpu in system.dpus:
        read = {by_id[i].channel for p in system.processes if p.dpu == dpu.id for i in p.inputs}
        status = statuses[dpu.id]
        result.dpus.append(DpuFlood(
            dpu=dpu.id,
            sent=sent[contract.CONFIG_CHANNEL] + sent[contract.COMMAND_CHANNEL] + sum(sent[c] for c in read),
            refused=status.rejected_unsigned + status.rejected_messages,
            socket_drops=drops.get(dpu.id, 0),
            compute_clean=compute[dpu.id], compute_flooded=flooded_compute[dpu.id]))
    return result


def lines(result: FloodResult, rate: int, goal_points: float) -> list[str]:
    """The bench's lines: per DPU, counted / sent and the compute delta; the verdict."""
    worst = max(abs(d.compute_flooded - d.compute_clean) for d in result.dpus)
    counted = min(d.refused / d.sent for d in result.dpus)
    ok = worst <= goal_points and counted == 1.0 and result.exit_codes[1] in (0, 1)
    out = [f"flood: {rate} hostile messages/s asked, {result.rate_sent:.0f}/s sent for "
           f"{result.seconds:.1f} s: the least counted share {counted:.3f} (goal 1), % compute within "
           f"{worst:.2f} points of a clean run (goal {goal_points:g}): {'PASS' if ok else 'FAIL'}"]
    for d in result.dpus:
        out.append(f"# DPU {d.dpu}: sent {d.sent}, counted as refused {d.refused}, dropped at its "
                   f"sockets {d.socket_drops}; % compute {d.compute_clean:.2f} clean, "
                   f"{d.compute_flooded:.2f} flooded")
    kinds = ", ".join(sorted({f["kind"] for f in result.flooded["faults"]})) or "none"
    out.append(f"# exit codes: clean {result.exit_codes[0]}, flooded {result.exit_codes[1]}; "
               f"faults flooded: {kinds}")
    return out

"""The DPU daemon seen from the wire: self-configuration, and hostile input."""

from __future__ import annotations

import os
import struct
import time
from pathlib import Path

import lcm
from conftest import EXAMPLES, DpuFarm

import skelmsg
from skeleton.host.live.control import Control
from skeleton.host.live.wire import config_message
from skeleton.host.sysfile.system import load, with_url
from skelmsg.contract import COMMAND_CHANNEL, CONFIG_CHANNEL


def _servo(url: str):  # type: ignore[no-untyped-def]
    return with_url(load(EXAMPLES / "servo.yaml", ["run.warmup_cycles=5"]), url)


def test_dpus_configure_themselves_from_one_broadcast(dpus: DpuFarm, url: str) -> None:
    system = _servo(url)
    dpus.start(1, 2, 3, 4)
    control = Control(url)
    try:
        assert control.wait_heard([1, 2, 3, 4], 5.0) == []
        generation = control.next_generation()
        result = control.push(config_message(system, generation, 0, committed=False), [1, 2, 3, 4])
        assert result.ok and result.applied == [1, 2, 3, 4], result
        run_id = 4242
        control.start(generation, run_id, time.time_ns() + 200_000_000, 300_000_000)
        assert control.wait_for(lambda: all((d, run_id) in control.reports for d in (1, 2, 3, 4)), 5.0)
        for dpu in system.dpus:
            report = control.reports[(dpu.id, run_id)]
            own = sorted(p.id for p in system.processes if p.dpu == dpu.id)
            assert sorted(p.process for p in report.processes) == own
            assert report.generation == generation
            assert all(p.cycles > 0 for p in report.processes)
    finally:
        control.close()


def _negative_length_buffer() -> bytes:
    msg = skelmsg.buffer_t()
    msg.nbytes, msg.payload = 4, b"\0" * 4
    data = bytearray(msg.encode())
    # fingerprint 8, run_id 8, writer 2, buffer 2, seq 8, send_ns 8 -> nbytes at 36
    struct.pack_into(">i", data, 36, -5)
    return bytes(data)


def _huge_length_config(system) -> bytes:  # type: ignore[no-untyped-def]
    data = bytearray(config_message(system, 99, 0, committed=False).encode())
    # fingerprint, generation, run_id, sent_utc_ns, committed, system string, four int32, seed -> nlinks
    name_len = struct.unpack_from(">i", data, 33)[0]
    offset = 33 + 4 + name_len + 16 + 8
    struct.pack_into(">h", data, offset, -1)
    negative = bytes(data)
    struct.pack_into(">h", data, offset, 32767)
    return negative + b"|" + bytes(data)


def test_dpu_ignores_undecodable_messages(dpus: DpuFarm, url: str) -> None:
    system = _servo(url)
    dpus.start(2)
    control = Control(url)
    sender = lcm.LCM(url)
    try:
        assert control.wait_heard([2], 5.0) == []
        negative_config, huge_config = _huge_length_config(system).split(b"|", 1)
        hostile = [
            (CONFIG_CHANNEL, b""), (CONFIG_CHANNEL, b"\x01\x02\x03"), (CONFIG_CHANNEL, negative_config),
            (CONFIG_CHANNEL, huge_config),
            (COMMAND_CHANNEL, b"\xff" * 40), (COMMAND_CHANNEL, skelmsg.status_t().encode()),
        ]
        buffer_channels = [b.channel for b in system.buffers if b.id in (3, 5, 6, 7, 8)]
        hostile += [(ch, _negative_length_buffer()) for ch in buffer_channels]
        hostile += [(ch, b"garbage") for ch in buffer_channels]
        # a buffer's channel is heard on its writer's port (host/sysfile/link.py), not on the control URL
        on_port = {b.channel: lcm.LCM(system.buffer_url(b.id))
                   for b in system.buffers if b.channel in buffer_channels}
        generation = control.next_generation()
        assert control.push(config_message(system, generation, 0, committed=False), [2]).ok
        # During a run the DPU drains its buffer channels too: send everything then.
        control.start(generation, 6, time.time_ns() + 100_000_000, 1_000_000_000)
        assert control.wait_for(lambda: control.dpus[2].status.run_id == 6
                                and control.dpus[2].status.minor_cycles > 10, 5.0)
        for channel, data in hostile:
            on_port.get(channel, sender).publish(channel, data)
        assert control.wait_for(lambda: (2, 6) in control.reports, 5.0)
        assert control.reports[(2, 6)].rejected_messages >= len(hostile), control.reports[(2, 6)]
        assert dpus.daemons[2].alive()
        # Still fully working: a new generation is applied and a run completes.
        result = control.push(config_message(system, generation + 1, 0, committed=False), [2])
        assert result.ok, result
        control.start(generation + 1, 7, time.time_ns() + 100_000_000, 200_000_000)
        assert control.wait_for(lambda: (2, 7) in control.reports, 5.0)
    finally:
        control.close()


# A DPU in `sleep` mode and one in `wall` mode, each one process.
MODES_SYSTEM = """\
system: modes
dpus: [{id: 1, compute: sleep}, {id: 2, compute: wall}]
processes:
  - {id: 1, name: sleeper, dpu: 1, period_us: 5000, compute_us: 500}
  - {id: 2, name: spinner, dpu: 2, period_us: 5000, compute_us: 500}
run: {duration_s: 2, warmup_cycles: 5}
"""


def _exec_sched(pid: int) -> tuple[int, int]:
    """(policy, rt priority) of a DPU's cycle thread: 0 SCHED_OTHER, 1 SCHED_FIFO."""
    for task in Path(f"/proc/{pid}/task").iterdir():
        if (task / "comm").read_text().strip() == "skel-exec":
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()  # from field 3, state
            return int(fields[41 - 3]), int(fields[40 - 3])
    raise AssertionError(f"no skel-exec thread in process {pid}")


def _holds_idle(pid: int) -> bool:
    """Whether a DPU holds /dev/cpu_dma_latency open (its request that the CPUs stay out of
    deep idle states)."""
    return any(os.readlink(fd) == "/dev/cpu_dma_latency" for fd in Path(f"/proc/{pid}/fd").iterdir())


def test_sleep_mode_cycles_run_sched_fifo_where_permitted(dpus: DpuFarm, url: str, tmp_path: Path) -> None:
    """`sleep` models a dedicated processor: its cycles run SCHED_FIFO (when the DPU may),
    so a busy machine does not stretch them; `wall` spins, and stays SCHED_OTHER. Both keep
    the CPUs out of deep idle states for the run."""
    system_file = tmp_path / "modes.yaml"
    system_file.write_text(MODES_SYSTEM)
    system = with_url(load(system_file, []), url)
    dpus.start(1, 2)
    pids = {i: dpus.daemons[i].process.pid for i in (1, 2)}
    control = Control(url)
    permitted = os.geteuid() == 0
    try:
        assert control.wait_heard([1, 2], 5.0) == []
        generation = control.next_generation()
        assert control.push(config_message(system, generation, 0, committed=False), [1, 2]).ok
        assert {i: _exec_sched(pids[i])[0] for i in (1, 2)} == {1: 0, 2: 0}  # between runs
        control.start(generation, 77, time.time_ns() + 200_000_000, 2_000_000_000)
        assert control.wait_for(lambda: all(control.dpus[i].status.state == skelmsg.status_t.STATE_RUNNING
                                            for i in (1, 2)), 3.0)
        during = {i: _exec_sched(pids[i]) for i in (1, 2)}
        holding = {i: _holds_idle(pids[i]) for i in (1, 2)}
        target = Path("/dev/cpu_dma_latency").read_bytes()[:4] if permitted else None
        assert control.wait_for(lambda: all((i, 77) in control.reports for i in (1, 2)), 5.0)
        time.sleep(0.2)
        after = {i: _exec_sched(pids[i])[0] for i in (1, 2)}
        held_after = {i: _holds_idle(pids[i]) for i in (1, 2)}
    finally:
        control.close()
    assert during == ({1: (1, 10), 2: (0, 0)} if permitted else {1: (0, 0), 2: (0, 0)})
    assert after == {1: 0, 2: 0}
    # A run keeps the CPUs out of deep idle states (as cyclictest does), in every mode, and
    # only for the run: a wake-up from one lengthens every release.
    assert holding == {1: permitted, 2: permitted}
    assert held_after == {1: False, 2: False}
    if permitted:
        assert target is not None and struct.unpack("i", target)[0] == 0  # the kernel's, while held
        assert "run 77 started (1 processes, SCHED_FIFO 10)" in dpus.log(1)
    else:
        assert "cannot run cycles under SCHED_FIFO" in dpus.log(1)
    assert "run 77 started (1 processes, SCHED_OTHER)" in dpus.log(2)

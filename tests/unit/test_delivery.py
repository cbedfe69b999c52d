"""Large buffers: each DPU sizes its sockets for them, `skel check` says when this machine
cannot, and a buffer that never reaches its reader is a delivery failure, not a lockout.

Real DPUs, real runs: the large buffer gets a link (a port) of its own so that only the
two DPUs' sockets carry it on this shared machine. No sysctl is changed: a socket too
small for the buffer is asked for in the link's URL (`recv_buf_size`), as a user may.
"""

from __future__ import annotations

from pathlib import Path

from conftest import fresh_url, skel

from skeleton.analysis.measure.faults import recv_buf_needed
from skelmsg.contract import DEFAULT_URL

BIG = 1_000_000


def _system(tmp_path: Path, big_url: str, bytes_: int = BIG, period_us: int = 20000) -> Path:
    path = tmp_path / "big.yaml"
    path.write_text(f"""\
system: big
links:
  - {{name: bus, url: "{DEFAULT_URL}"}}
  - {{name: wide, url: "{big_url}"}}
dpus: [{{id: 1}}, {{id: 2}}]
buffers:
  - {{id: 1, name: joint_state, bytes: {bytes_}, link: wide}}
processes:
  - {{id: 1, name: joint_sensors, dpu: 1, period_us: {period_us}, compute_us: 500, outputs: [joint_state]}}
  - {{id: 2, name: jacobian_transpose, dpu: 2, period_us: {period_us}, compute_us: 500, sync: data,
     inputs: [joint_state]}}
run: {{warmup_cycles: 5, lockout_cycles: 10, stop_on: [lockout]}}
""")
    return path


def _big_url(extra: str = "") -> str:
    return fresh_url() + extra


def test_check_says_when_a_socket_cannot_receive_a_buffer_whole(tmp_path: Path) -> None:
    system = _system(tmp_path, _big_url("&recv_buf_size=100000"))
    done = skel("check", str(system))
    assert done.returncode == 0, done.stderr
    assert "buffer joint_state (link wide, read here by jacobian_transpose)" in done.stdout, done.stdout
    assert f"recv_buf_size={recv_buf_needed(BIG)}" in done.stdout, done.stdout
    small = skel("check", str(_system(tmp_path, _big_url(), bytes_=1000)))
    assert "joint_state" not in small.stdout, small.stdout


def test_doctor_check_of_a_buffer_names_the_sysctl() -> None:
    from skeleton.host.live.preflight import check_buffer_socket

    need = recv_buf_needed(BIG)
    assert check_buffer_socket("joint_state", BIG, need).ok
    short = check_buffer_socket("joint_state", BIG, 212992)
    assert not short.ok and short.fix == f"sysctl -w net.core.rmem_max={need}", short
    asked = check_buffer_socket("joint_state", BIG, None, recv_buf_size=4096)
    assert not asked.ok and f"recv_buf_size={need}" in asked.fix

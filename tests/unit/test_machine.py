"""bench/machine.py: the machine a bench part ran on, read from /proc."""

from __future__ import annotations

import sys

from conftest import REPO

sys.path.insert(0, str(REPO / "bench"))
from machine import Ticks, cpu_model, simd_level, steal_pct

CPUINFO = """processor\t: 0
model name\t: AMD EPYC 7B13
flags\t\t: fpu sse4_2 avx avx2 fma
"""


def test_the_cpu_and_its_widest_simd_are_read_from_cpuinfo() -> None:
    assert cpu_model(CPUINFO) == "AMD EPYC 7B13"
    assert simd_level(CPUINFO) == "AVX2"
    assert simd_level(CPUINFO.replace("avx2", "avx2 avx512f")) == "AVX-512"
    assert simd_level("flags\t: fpu\n") == "no SSE4.2"


def test_steal_is_its_share_of_every_cpus_time_between_two_readings() -> None:
    before = Ticks.now("cpu  100 0 100 700 0 0 0 100 0 0\n")
    after = Ticks.now("cpu  200 0 200 1300 0 0 0 300 0 0\n")
    assert (before.total, before.steal) == (1000, 100)
    assert steal_pct(before, after) == 200 / 1000 * 100
    assert steal_pct(after, after) == 0.0

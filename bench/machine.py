"""What each `make bench` part ran on, written beside its figures (bench/run.py): the CPU and its
SIMD level (numpy's sorts, and so the analysis, run several times slower without AVX-512), the
share of the CPUs' time the hypervisor stole during the part, and cyclictest's tail right
after it. A figure is a draw of this machine at that moment: these say which."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

SIMD = (("avx512f", "AVX-512"), ("avx2", "AVX2"), ("avx", "AVX"), ("sse4_2", "SSE4.2"))


def cpu_model(cpuinfo: str | None = None) -> str:
    text = cpuinfo if cpuinfo is not None else Path("/proc/cpuinfo").read_text()
    for line in text.splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "unknown CPU"


def simd_level(cpuinfo: str | None = None) -> str:
    """The widest vector extension the CPU offers, by its /proc/cpuinfo flags."""
    text = cpuinfo if cpuinfo is not None else Path("/proc/cpuinfo").read_text()
    flags = next((set(line.split(":", 1)[1].split()) for line in text.splitlines()
                  if line.startswith("flags")), set())
    return next((name for flag, name in SIMD if flag in flags), "no SSE4.2")


@dataclass(frozen=True)
class Ticks:
    """The CPUs' time so far from /proc/stat's `cpu` line, in ticks: all of it, and stolen."""

    total: int
    steal: int

    @staticmethod
    def now(stat: str | None = None) -> Ticks:
        text = stat if stat is not None else Path("/proc/stat").read_text()
        fields = [int(v) for v in text.splitlines()[0].split()[1:]]
        return Ticks(sum(fields[:8]), fields[7] if len(fields) > 7 else 0)  # user..steal; guests are in user


def steal_pct(before: Ticks, after: Ticks) -> float:
    spent = after.total - before.total
    return 100.0 * (after.steal - before.steal) / spent if spent > 0 else 0.0


def machine_line(before: Ticks, after: Ticks, cyclictest_p99_us: float | None) -> str:
    probe = ("no cyclictest" if cyclictest_p99_us is None
             else f"cyclictest p99 {cyclictest_p99_us:.0f} us over 2 s right after it")
    return (f"# machine: {cpu_model()} ({simd_level()}), {os.cpu_count()} CPUs; "
            f"{steal_pct(before, after):.1f} % of the CPUs' time stolen during the part; {probe}")

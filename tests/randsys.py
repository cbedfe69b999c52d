"""Seeded random systems for the measurement and prediction tests: several DPUs, each
running a mix of periods, in `sleep` mode, on the cyclic or the tasking executive, so
that a DPU's configured load (Σ compute / period) is what its % compute must measure."""

from __future__ import annotations

import random

import yaml

PERIODS_US = (5_000, 10_000, 20_000)


def random_system(seed: int, warmup_cycles: int = 40, duration_s: float = 2.0,
                  executive: str = "cyclic") -> tuple[str, dict[int, float]]:
    """(system file text, configured load in % per DPU) of 3-6 DPUs and 4-20 processes,
    every DPU on `executive` (cyclic, or threads: the tasking executive, rate-monotonic).

    Every DPU mixes periods; all its processes are due in its first minor cycle, so their
    compute together stays under the 5 ms minor cycle (no overrun needed to be right). The
    slow processes hold a large share of the load: a window that starts each process after
    its own warm-up, instead of one per DPU, misses much of it."""
    rng = random.Random(seed)
    ndpus = rng.randint(3, 6)
    nprocs = rng.randint(max(4, ndpus * 2), 20)
    owner = [d % ndpus + 1 for d in range(nprocs)]  # every DPU gets at least two
    rng.shuffle(owner)
    processes: list[dict[str, object]] = []
    for dpu in range(1, ndpus + 1):
        mine = [i for i, d in enumerate(owner) if d == dpu]
        periods = [PERIODS_US[0], PERIODS_US[-1]] + [rng.choice(PERIODS_US) for _ in mine[2:]]
        budget = rng.uniform(2_500, 4_000)  # µs of compute in the minor cycle where all are due
        weights = [rng.uniform(0.5, 1.0) * (3.0 if p == PERIODS_US[-1] else 1.0) for p in periods]
        for i, period, weight in zip(mine, periods, weights, strict=True):
            compute = max(100, int(budget * weight / sum(weights)))
            processes.append({"id": i + 1, "name": f"p{i + 1}", "dpu": dpu, "period_us": period,
                              "compute_us": compute})
    load = {dpu: 100.0 * sum(int(p["compute_us"]) / int(p["period_us"])  # type: ignore[call-overload]
                             for p in processes if p["dpu"] == dpu) for dpu in range(1, ndpus + 1)}
    system = {
        "system": f"random-{seed}",
        "dpus": [{"id": d, "compute": "sleep", "executive": executive} for d in range(1, ndpus + 1)],
        "processes": sorted(processes, key=lambda p: int(p["id"])),  # type: ignore[call-overload]
        "run": {"duration_s": duration_s, "warmup_cycles": warmup_cycles, "lockout_cycles": 50,
                "stop_on": []},
    }
    return yaml.safe_dump(system, sort_keys=False), load


def random_pipeline(seed: int, nprocs: int = 40, ndpus: int = 8) -> str:
    """A system file of NPROCS processes on NDPUS DPUs for the allocation: periods 5, 10 and
    20 ms, about 55 % of the DPUs' time in all, each process after the first few reading one
    or two earlier ones' buffers, a chain through four of them; allocated round robin."""
    rng = random.Random(seed)
    budget = 0.55 * ndpus / nprocs  # each process's share of a DPU, on average
    processes: list[dict[str, object]] = []
    buffers: list[dict[str, object]] = []
    for i in range(1, nprocs + 1):
        period = rng.choice(PERIODS_US)
        compute = max(50, min(period // 2, int(period * budget * rng.uniform(0.5, 1.5)) // 10 * 10))
        reads = sorted(rng.sample(range(1, i), min(i - 1, rng.randint(1, 2)))) if i > 3 else []
        buffers.append({"id": i, "name": f"b{i}", "bytes": rng.choice((64, 256, 1024))})
        processes.append({"id": i, "name": f"p{i}", "dpu": (i - 1) % ndpus + 1, "period_us": period,
                          "compute_us": compute, "inputs": [f"b{j}" for j in reads], "outputs": [f"b{i}"]})
    chain = ["p1"]
    for p in processes[1:]:
        if f"b{chain[-1][1:]}" in p["inputs"] and len(chain) < 4:  # type: ignore[operator]
            chain.append(str(p["name"]))
    dpus = [{"id": d, "compute": "sleep"} for d in range(1, ndpus + 1)]
    system = {"system": f"pipeline-{seed}", "dpus": dpus,
              "buffers": buffers, "processes": processes, "chains": [chain] if len(chain) > 1 else [],
              "run": {"duration_s": 2.0, "warmup_cycles": 20, "stop_on": []}}
    return yaml.safe_dump(system, sort_keys=False)

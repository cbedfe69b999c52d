"""host/model.py: the typed System; its lookups, and a System read back from the config_t it
is sent as (what the analysis reads from a run's log)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from conftest import REPO

from skeleton.host.live.wire import config_message
from skeleton.host.model import FROM_CONFIG, Link, RunRules, System, bus_of, from_config
from skeleton.host.sysfile.system import load
from skelmsg.contract import DEFAULT_URL

EXAMPLES = sorted((REPO / "examples").glob("*.yaml"))


def _as_sent(system: System) -> System:
    """What of SYSTEM a config carries (from_config's docstring): the rest at its default."""
    return dataclasses.replace(
        system, path=Path("system.yaml"), reference=None, overrides=(),
        processes=tuple(dataclasses.replace(p, varying=dataclasses.replace(p.varying, kind=FROM_CONFIG))
                        if p.varying else p for p in system.processes),
        run=RunRules(**{**dataclasses.asdict(system.run), "cycles": None, "duration_s": None,
                        "stop_on": ()}))


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_a_system_read_back_from_its_config_is_what_was_sent(path) -> None:  # type: ignore[no-untyped-def]
    system = load(path)
    back = from_config(config_message(system, generation=1, run_id=0, committed=False))
    assert back == _as_sent(system)
    assert back.buffer_urls == system.buffer_urls and back.writer_ports == system.writer_ports
    assert [p.required for p in back.processes] == [p.required for p in system.processes]


def test_lookups_by_id_and_by_name() -> None:
    system = load(REPO / "examples" / "servo.yaml")
    for p in system.processes:
        assert system.process(p.id) is p and system.process(p.name) is p
    for b in system.buffers:
        assert system.buffer(b.id) is b and system.buffer(b.name) is b
    assert system.dpu(system.dpus[-1].id) is system.dpus[-1]
    with pytest.raises(KeyError, match="no process 'nobody'"):
        system.process("nobody")


def test_each_process_is_charged_its_links_costs_as_the_dpu_charges_them(tmp_path: Path) -> None:
    """model.charges(), which dpu/plan.c mirrors: the writer per message, per byte and per byte
    for each other reading DPU; a reader per remote input every cycle; the DPU per message it
    receives, charged to its fastest reader of the buffer (the first in order among equals)."""
    (tmp_path / "s.yaml").write_text("""
system: charged
links: [{name: bus, url: "URL", per_message_us: 10, per_byte_ns: 2, push_byte_ns: 3, remote_read_us: 7}]
dpus: [{id: 1}, {id: 2}]
buffers: [{id: 1, name: a, bytes: 100}]
processes:
  - {id: 1, name: w, dpu: 1, period_us: 2000, compute_us: 100, outputs: [a]}
  - {id: 2, name: here, dpu: 1, period_us: 5000, compute_us: 100, inputs: [a]}
  - {id: 3, name: slow, dpu: 2, period_us: 10000, compute_us: 100, inputs: [a]}
  - {id: 4, name: fast, dpu: 2, period_us: 5000, compute_us: 100, inputs: [a]}
  - {id: 5, name: also, dpu: 2, period_us: 5000, compute_us: 100, inputs: [a]}
""".replace("URL", DEFAULT_URL))
    system = load(tmp_path / "s.yaml")
    message = 10 + 2 * 100 / 1000                      # us per message, as received
    # one other DPU reads it: 10 us + 2 ns x 100 B + 3 ns x 100 B x 1 DPU
    assert system.process("w").charge.out_us == pytest.approx(10.5)
    # DPU 1's only reader takes 2.5 of the writer's messages a cycle: 2 at least, 3 at most
    here = system.process("here").charge
    assert (here.in_us, here.in_best_us, here.in_worst_us) == pytest.approx((2.5 * message, 2 * message,
                                                                              3 * message))
    # DPU 2: `fast` pays (the shortest period, before `also` in order); every reader there reads remotely
    assert system.process("fast").charge.in_us == pytest.approx(7 + 2.5 * message)
    assert system.process("also").charge.in_us == pytest.approx(7)
    assert system.process("slow").charge.in_us == pytest.approx(7)
    back = from_config(config_message(system, generation=1, run_id=0, committed=False))
    assert [p.charge for p in back.processes] == [p.charge for p in system.processes]


BUS = Link(1, "bus", DEFAULT_URL, bandwidth_mbps=1.0, queue_us=100_000)


@pytest.mark.parametrize(("flows", "waits"), [
    # (buffer, period, wire time) in us: the synchronous busy period is the flows' own wire times
    ([(1, 1000, 300), (2, 2000, 500)], {1: 500, 2: 300}),
    # at 90 %, the later messages find the queue shorter: the first instant is the longest
    ([(1, 100, 50), (2, 300, 120)], {1: 120, 2: 50}),
    # one writer alone never waits
    ([(1, 100, 99)], {1: 0}),
])
def test_a_links_transmitter_is_longest_behind_every_writer_sending_at_once(flows, waits) -> None:  # type: ignore[no-untyped-def]
    bus = bus_of(BUS, flows)
    assert bus.waits_us == pytest.approx(waits)
    assert not bus.saturated and bus.dropped_pct == 0


def test_a_saturated_links_queue_fills_and_drops_what_is_over_its_bandwidth() -> None:
    bus = bus_of(dataclasses.replace(BUS, queue_us=2000), [(1, 1000, 600), (2, 1000, 900)])
    assert bus.saturated and bus.utilization == pytest.approx(1.5)
    assert bus.waits_us == {1: 2000.0, 2: 2000.0}
    assert bus.dropped_pct == pytest.approx(100 / 3)  # a third of what is offered: 1 - 1 / 1.5
    # a queue shorter than the burst: its whole length is the wait (and some may be dropped)
    assert bus_of(dataclasses.replace(BUS, queue_us=100), [(1, 1000, 300), (2, 2000, 500)]).waits_us == {
        1: 100.0, 2: 100.0}

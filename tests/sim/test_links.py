"""A link's emulated transport (latency, jitter, loss) on simulated time, with exact expectations.

The reading DPU holds each version back until its send time plus the link's delay (dpu/buffers.c);
on virtual time a buffer arrives when it is sent, so the transport the analysis measures is the
modelled delay itself, to the nanosecond, and the draws repeat with the seed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import skel
from e2e.test_link_delay_dpus import TWO_LINKS
from sim.test_executives import simulate

import skeleton
from skeleton.host.sysfile.system import load
from skelmsg.contract import DEFAULT_URL

# A writer on DPU 1, its reader on DPU 2, of one period: without a link model every version is
# seen when sent, and every cycle of the reader finds a new one.
PAIR = """\
system: pair
links:
  - {{name: net, url: "{url}", {link}}}
dpus:
  - {{id: 1}}
  - {{id: 2}}
buffers:
  - {{id: 1, name: sample, bytes: 64}}
processes:
  - {{id: 1, name: sensor, dpu: 1, period_us: {period}, compute_us: 100, outputs: [sample]}}
  - {{id: 2, name: control, dpu: 2, period_us: {period}, compute_us: 100, inputs: [sample]}}
chains:
  - {{name: loop, processes: [sensor, control]}}
run: {{duration_s: {duration}, warmup_cycles: 10}}
"""


def _pair(tmp_path: Path, link: str, period: int = 5000, duration: float = 1.0) -> Path:
    path = tmp_path / f"pair-{len(list(tmp_path.glob('pair-*.yaml')))}.yaml"
    path.write_text(PAIR.format(url=DEFAULT_URL, link=link or "loss_pct: 0", period=period,
                                duration=duration))
    return path


def _reader(report: dict) -> dict:
    (buffer,) = report["buffers"]
    (reader,) = buffer["readers"]
    return reader | {"published": buffer["published"]}


def _transport_us(out: Path) -> np.ndarray:
    inputs = skeleton.load_run(out).inputs
    new = np.asarray(inputs["new"]) != 0
    return (np.asarray(inputs["recv_ns"])[new] - np.asarray(inputs["sent_ns"])[new]) / 1000


def test_a_latency_of_2_ms_adds_exactly_2_ms_to_every_buffers_transport_and_the_prediction_says_so(
        tmp_path: Path) -> None:
    plain = simulate(tmp_path / "plain", str(_pair(tmp_path, "")))
    late = simulate(tmp_path / "late", str(_pair(tmp_path, "latency_us: 2000")))
    assert _reader(plain)["latency_us"]["max"] == 0.0
    assert set(_transport_us(tmp_path / "plain")) == {0.0}
    assert set(_transport_us(tmp_path / "late")) == {2000.0}  # every version, to the ns
    reader = _reader(late)
    assert reader["new"] == _reader(plain)["new"] and reader["lost"] == 0
    (i,) = late["predicted"]["inputs"]
    assert i["transport_us"] == {"predicted": 2000.0, "measured": 2000.0, "delta": 0.0, "outside": False}
    (chain,) = late["predicted"]["chains"]
    assert chain["network_us"]["predicted"] == chain["network_us"]["measured"] == 2000.0
    # the value is seen 2 ms after its send, then waits for the reader's next cycle
    assert chain["best_us"] == 2000.0
    # the link's row: its writer's 200 messages a second of 64 bytes and the headers on the wire
    (link,) = late["links"]
    wire = 8 * 200 * load(_pair(tmp_path, "")).buffer("sample").wire_bytes / 1e6
    assert (link["messages_per_s"], link["offered_mbps"], link["bandwidth_mbps"]) == (200.0, wire, None)
    assert (link["modelled_delay_us"], link["transport_p99_us"], link["transport_max_us"]) == (2000.0,) * 3


# Two writers on two DPUs send at the same instant (both compute 100 us from the same release)
# on one bandwidth-limited bus; a third DPU reads both.
SHARED = """\
system: shared
links:
  - {{name: bus, url: "{url}", bandwidth_mbps: {bandwidth}{queue}}}
dpus: [{{id: 1}}, {{id: 2}}, {{id: 3}}]
buffers:
  - {{id: 1, name: scan, bytes: {scan}}}
  - {{id: 2, name: pose, bytes: 200}}
processes:
  - {{id: 1, name: lidar, dpu: 1, period_us: {period}, compute_us: 100, outputs: [scan]}}
  - {{id: 2, name: odometry, dpu: 2, period_us: {period}, compute_us: 100, outputs: [pose]}}
  - {{id: 3, name: control, dpu: 3, period_us: {reader}, compute_us: 100, inputs: [scan, pose]}}
run: {{duration_s: {duration}, warmup_cycles: 10}}
"""


def _shared(tmp_path: Path, bandwidth: float, scan: int = 1000, period: int = 5000, queue: str = "",
            duration: float = 1.0, reader: int | None = None) -> Path:
    path = tmp_path / f"shared-{len(list(tmp_path.glob('shared-*.yaml')))}.yaml"
    path.write_text(SHARED.format(url=DEFAULT_URL, bandwidth=bandwidth, scan=scan, period=period,
                                  queue=queue and f", queue_us: {queue}", duration=duration,
                                  reader=reader or period))
    return path


def _transports_by_buffer(out: Path) -> dict[int, set[float]]:
    inputs = skeleton.load_run(out).inputs
    new = np.asarray(inputs["new"]) != 0
    transport = (np.asarray(inputs["recv_ns"]) - np.asarray(inputs["sent_ns"]))[new] / 1000
    buffer = np.asarray(inputs["buffer"])[new]
    return {int(b): set(transport[buffer == b]) for b in np.unique(buffer)}


@pytest.mark.parametrize("reader", [5000, 50_000])
def test_two_writers_sending_at_once_on_a_bus_queue_one_behind_the_other_as_predicted(
        tmp_path: Path, reader: int) -> None:
    """A reader of ten times the period reads ten messages of each writer at once, one socket after
    the other: the transmitter still takes them in the order they were sent (a 2 ms queue would
    drop most of the second socket's otherwise)."""
    path = _shared(tmp_path, bandwidth=10, queue="2000", reader=reader)
    system = load(path)
    bus = system.link("bus")
    wire = {b.id: bus.wire_us(b) for b in system.buffers}  # 8 bits a byte at 10 Mbit/s
    report = simulate(tmp_path / "run", str(path))
    seen = _transports_by_buffer(tmp_path / "run")
    # every cycle, one goes first and takes its own time on the wire; the other waits for it
    first, second = sorted(seen, key=lambda b: min(seen[b]))
    assert seen[first] == {wire[first]} and seen[second] == {wire[first] + wire[second]}
    # the prediction's least and most transport of each: its own wire time, and behind the other
    for b in (1, 2):
        least, mean, most = system.transport_us(b)
        assert (least, mean, most) == pytest.approx((wire[b], wire[b], wire[1] + wire[2]))
    assert max(max(t) for t in seen.values()) == pytest.approx(system.transport_us(second)[2])
    (link,) = report["links"]
    assert link["modelled_queue_us"] == pytest.approx(max(wire.values()), abs=1e-3)
    assert link["queue_p99_us"] == pytest.approx(wire[first], abs=1e-3)  # what the second waited
    assert not link["saturated"] and link["lost"] == 0


def test_a_link_offered_twice_its_bandwidth_fills_its_queue_and_drops_half_as_predicted(
        tmp_path: Path) -> None:
    """2 Mbit/s of buffers on a 1 Mbit/s link: `skel check` says it saturates, every message that
    gets through waits about the whole queue, and half of the bytes never do."""
    queue, period = 20_000, 5000
    path = _shared(tmp_path, bandwidth=1, scan=900, period=period, queue=str(queue), duration=4)
    system = load(path)
    bus = system.buses[system.link("bus").id]
    assert bus.saturated and 1.8 < bus.utilization < 2.2
    check = skel("check", str(path))
    assert "its transmit queue fills" in check.stdout + check.stderr, check.stdout + check.stderr
    report = simulate(tmp_path / "run", str(path))
    (link,) = report["links"]
    assert link["saturated"] and link["utilization_pct"] == pytest.approx(100 * bus.utilization, rel=0.01)
    assert link["modelled_loss_pct"] == pytest.approx(bus.dropped_pct, abs=1e-3)
    # once the queue is full, it drops what is over the bandwidth (the first 20 ms fill it): of the
    # bytes; of the messages, here more of the small ones, which come second
    assert link["lost_bytes_pct"] == pytest.approx(bus.dropped_pct, abs=1.0)
    wire = {b.id: system.link("bus").wire_us(b) for b in system.buffers}
    inputs = skeleton.load_run(tmp_path / "run").inputs
    new, buffer = np.asarray(inputs["new"]) != 0, np.asarray(inputs["buffer"])
    transport = (np.asarray(inputs["recv_ns"]) - np.asarray(inputs["sent_ns"])) / 1000
    # the scan, sent first each period, needs 1.6 times the bus alone: it keeps the queue full and
    # the pose behind it never fits again (FIFO starves it), once the queue has filled
    late = np.asarray(inputs["sent_ns"]) > np.asarray(inputs["sent_ns"])[new].min() + 1e9
    scan = transport[new & late & (buffer == 1)]
    assert len(scan) > 100 and not (new & late & (buffer == 2)).any()
    # admitted when its wait is at most the queue, which time has run down by at most a period
    assert scan.min() >= queue - period + wire[1] and scan.max() <= queue + wire[1]
    inputs = {i["buffer"]: i for i in report["predicted"]["inputs"]}
    assert inputs["scan"]["transport_us"]["predicted"] == pytest.approx(queue + wire[1], abs=1e-3)
    assert inputs["scan"]["lost_pct"]["predicted"] == pytest.approx(bus.dropped_pct, abs=1e-3)


def test_a_latency_longer_than_the_period_holds_several_versions_in_order(tmp_path: Path) -> None:
    out = tmp_path / "run"
    report = simulate(out, str(_pair(tmp_path, "latency_us: 12000", period=1000)))
    assert set(_transport_us(out)) == {12000.0}
    inputs = skeleton.load_run(out).inputs
    seq = np.asarray(inputs["seq"])[np.asarray(inputs["new"]) != 0]
    assert (np.diff(seq) == 1).all()  # one period each: every version seen, none skipped
    assert _reader(report)["lost"] == 0


@pytest.mark.parametrize("executive", ["cyclic", "threads"])
def test_a_data_reader_behind_a_slow_link_starts_2_ms_later_as_predicted(tmp_path: Path, executive: str
                                                                          ) -> None:
    text = TWO_LINKS.format(bus=DEFAULT_URL, slow=DEFAULT_URL.replace(":7667", ":7677"))
    if executive == "threads":  # the tasking executive's data wait (dpu/tasking.c on virtual time)
        text = text.replace("{id: 1}, {id: 2}, {id: 3}", ", ".join(
            f"{{id: {i}, executive: threads}}" for i in (1, 2, 3)))
        for before in (", sync: data", ", outputs"):
            text = text.replace(before, ", priority: 5" + before)
    path = tmp_path / "two.yaml"
    path.write_text(text)
    report = simulate(tmp_path / "run", str(path))
    chains = {c["name"]: c for c in report["predicted"]["chains"]}
    near, far = chains["writer->near_reader"], chains["writer->far_reader"]
    # each reader waits for its data: near sees it when sent, far when the link makes it due
    assert near["latency_us"]["measured"] == near["latency_max_us"] == 0.0
    assert far["latency_us"]["measured"] == far["latency_max_us"] == far["latency_us"]["predicted"] == 2000.0
    assert far["best_us"] == 2000.0 and far["network_us"]["measured"] == 2000.0
    assert not report["faults"]


LOCAL = """\
system: local
links:
  - {{name: bus, url: "{url}"}}
  - {{name: mem, url: local, latency_us: 1500}}
dpus: [{{id: 1, executive: {executive}}}]
buffers:
  - {{id: 1, name: near, bytes: 64, link: mem}}
processes:
  - {{id: 1, name: writer, dpu: 1, period_us: 10000, compute_us: 1000{high}, outputs: [near]}}
  - {{id: 2, name: reader, dpu: 1, period_us: 10000, compute_us: 500{low}, sync: data,
     inputs: [near]}}
chains:
  - [writer, reader]
run: {{duration_s: 1, warmup_cycles: 10}}
"""


@pytest.mark.parametrize("executive", ["cyclic", "threads"])
def test_a_local_link_delays_too_and_its_reader_waits_for_it_on_its_own_dpu(tmp_path: Path, executive: str
                                                                              ) -> None:
    path = tmp_path / "local.yaml"
    tasking = executive == "threads"
    high, low = (", priority: 5", ", priority: 3") if tasking else ("", "")
    path.write_text(LOCAL.format(url=DEFAULT_URL, executive=executive, high=high, low=low))
    report = simulate(tmp_path / "run", str(path))
    (chain,) = report["predicted"]["chains"]
    reader = next(p for p in report["predicted"]["processes"] if p["name"] == "reader")
    # the writer ends at 1 ms, its value is due at 2.5 ms: the reader computes from there
    assert chain["latency_us"]["measured"] == chain["latency_max_us"] == chain["best_us"] == 1500.0
    assert reader["response_us"]["measured"] == 3000.0
    if not tasking:  # the cyclic frame is exact; response-time analysis bounds it
        assert chain["latency_us"]["predicted"] == 1500.0 and reader["response_us"]["predicted"] == 3000.0
    assert not report["faults"] and not report["predicted"]["outside"]


@pytest.mark.parametrize("jitter", ["uniform", "normal"])
def test_jitter_spreads_the_delay_within_its_bounds_delivers_in_order_and_repeats_with_the_seed(
        tmp_path: Path, jitter: str) -> None:
    link = f"latency_us: 3000, jitter_us: 500, jitter: {jitter}"
    a, b = tmp_path / "a", tmp_path / "b"
    simulate(a, str(_pair(tmp_path, link, period=1000)))
    simulate(b, str(_pair(tmp_path, link, period=1000)))
    t = _transport_us(a)
    assert (_transport_us(b) == t).all()  # the same seed, the same draws
    spread = 1500 if jitter == "normal" else 500
    assert t.min() >= 3000 - spread and t.max() <= 3000 + spread + 1000  # + waiting behind an earlier one
    assert abs(np.median(t) - 3000) < 150 and t.std() > 100
    inputs = skeleton.load_run(a).inputs
    new = np.asarray(inputs["new"]) != 0
    seen = np.asarray(inputs["recv_ns"])[new]
    assert (np.diff(np.asarray(inputs["seq"])[new]) > 0).all() and (np.diff(seen) >= 0).all()


def _lost_pct(report: dict) -> float:
    reader = _reader(report)
    return 100 * reader["lost"] / reader["published"]


def _bursts(out: Path) -> list[int]:
    """The lengths of the runs of lost versions, from the reader's dropped counts (writer and reader of
    one period: a version is dropped only when the link lost it)."""
    inputs = skeleton.load_run(out).inputs
    dropped = np.asarray(inputs["dropped"])[np.asarray(inputs["new"]) != 0]
    return [int(d) for d in dropped if d > 0]


def test_a_loss_of_5_pct_loses_5_pct_of_10_000_buffers_the_same_twice_and_otherwise_with_another_seed(
        tmp_path: Path) -> None:
    path = str(_pair(tmp_path, "loss_pct: 5", period=1000, duration=10.5))
    a = simulate(tmp_path / "a", path)
    b = simulate(tmp_path / "b", path)
    c = simulate(tmp_path / "c", path, "-s", "run.seed=7")
    assert _reader(a)["published"] >= 10_000
    assert 3.5 <= _lost_pct(a) <= 6.5
    assert _reader(a)["lost"] == _reader(b)["lost"]
    assert _reader(a)["lost"] != _reader(c)["lost"]
    assert a["predicted"]["inputs"][0]["lost_pct"]["predicted"] == 5.0
    (link,) = a["links"]
    assert link["lost"] == _reader(a)["lost"] and link["modelled_loss_pct"] == 5.0
    assert link["lost_pct"] == pytest.approx(100 * link["lost"] / (_reader(a)["received"] + link["lost"]))
    # independent losses: a run of two or more is rare (5 % of the runs)
    runs = _bursts(tmp_path / "a")
    assert np.mean(runs) < 1.2


def test_a_burst_model_loses_in_bursts_as_long_as_it_says(tmp_path: Path) -> None:
    # good -> bad 1.25 % a version, bad -> good 25 %: bad 4.8 % of the time, bursts of 4 on average
    link = "loss_burst: {enter_pct: 1.25, leave_pct: 25}"
    out = tmp_path / "run"
    report = simulate(out, str(_pair(tmp_path, link, period=1000, duration=10.5)))
    assert 3.0 <= _lost_pct(report) <= 7.0
    runs = _bursts(out)
    assert 3.0 <= np.mean(runs) <= 5.0 and max(runs) >= 10
    predicted = report["predicted"]["inputs"][0]["lost_pct"]["predicted"]
    assert predicted == pytest.approx(100 * 1.25 / 26.25, abs=0.01)


@pytest.mark.parametrize(("given", "field"), [
    ("latency_us: -1", "links.net.latency_us"),
    ("jitter: triangle", "links.net.jitter"),
    ("loss_pct: 150", "links.net.loss_pct"),
    ("loss_burst: {enter_pct: 1, leave_pct: 0}", "links.net.loss_burst.leave_pct"),
])
def test_a_bad_value_is_one_line_naming_its_field(tmp_path: Path, given: str, field: str) -> None:
    done = skel("check", str(_pair(tmp_path, given)))
    assert done.returncode == 2
    (line,) = done.stderr.strip().splitlines() or done.stdout.strip().splitlines()
    assert f"{field}:" in line


def test_each_reading_dpu_loses_versions_of_its_own(tmp_path: Path) -> None:
    """Each reading DPU draws its own losses: two readers of one buffer on two DPUs lose different
    versions (a link loses a version for one receiver, not for all)."""
    text = PAIR.format(url=DEFAULT_URL, link="loss_pct: 10", period=1000, duration=2).replace(
        "  - {id: 2}\n", "  - {id: 2}\n  - {id: 3}\n").replace(
        "chains:", "  - {id: 3, name: logger, dpu: 3, period_us: 1000, compute_us: 100, inputs: [sample]}\n"
        "chains:")
    path = tmp_path / "two.yaml"
    path.write_text(text)
    out = tmp_path / "run"
    simulate(out, str(path))
    inputs = skeleton.load_run(out).inputs
    new = np.asarray(inputs["new"]) != 0
    seen = {dpu: set(np.asarray(inputs["seq"])[new & (np.asarray(inputs["dpu"]) == dpu)].tolist())
            for dpu in (2, 3)}
    assert seen[2] != seen[3] and len(seen[2] & seen[3]) > 0.7 * len(seen[2])

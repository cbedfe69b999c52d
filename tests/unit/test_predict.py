"""host/theory/predict.py: what a system will do, from its file alone, held to theory, to the
paper's Table 1 and to real runs (sanitizer DPUs, sleep mode, a private port)."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest
from conftest import EXAMPLES, HOST_EVENTS_SYSTEM, LOCKOUT_SYSTEM, skel

from skeleton.host.cli.check import check
from skeleton.host.model import System
from skeleton.host.sysfile.system import load, loads
from skeleton.host.theory.predict import predict
from skelmsg import contract

TABLE1 = {1: 90.3, 2: 73.4, 3: 86.0, 4: 96.5}


def _system(tmp_path: Path, text: str, name: str = "s.yaml"):  # type: ignore[no-untyped-def]
    path = tmp_path / name
    path.write_text(text)
    return load(path)


def test_servo_predicts_table1_schedulable_and_clean() -> None:
    pred = predict(load(EXAMPLES / "servo.yaml"))
    for d in pred.dpus:
        assert d.compute_pct == pytest.approx(TABLE1[d.id], abs=0.05), d
        assert d.schedulable and not d.overflowing and d.lockout_ms is None
    assert pred.warnings == () and pred.errors == ()
    # executor starts after joint_sensors in DPU 2's frame and ends 3.67 ms into it
    assert (pred.process("executor").start_max_us, pred.process("executor").response_us) == (170, 3670)
    best, worst = pred.chains[0].best_us, pred.chains[0].worst_us
    # jacobian_transpose waits for joint_state (0 extra), computes 2.8 ms, executor reads within a period
    assert (best, worst) == (2800, 2800 + 5000)
    assert json.loads(json.dumps(pred.to_json()))["dpus"][0]["overflowing_frames"] == []


def test_a_data_reader_waits_for_its_writer_of_the_same_cycle() -> None:
    """Trajectory moved to DPU 2 runs there before joint_sensors, so jacobian_transpose (DPU 3,
    sync: data on joint_state) finds last cycle's joint_state until joint_sensors ends, 1.37 ms
    into each cycle, and DPU 3's frame needs 1.37 + 2.8 + 1.5 ms of its 5 (a new user's
    walk-through: predicted 0..0 and no warning, and the run overran every cycle)."""
    pred = predict(load(EXAMPLES / "servo.yaml", ["process.trajectory.dpu=2"]))
    sensors, reader = pred.process("joint_sensors"), pred.process("jacobian_transpose")
    assert sensors.response_us == pytest.approx(1370)
    assert reader.start_min_us >= sensors.response_us and reader.start_max_us >= sensors.response_us
    assert reader.response_us == pytest.approx(1370 + 2800)
    assert pred.process("force_control").response_us == pytest.approx(5670)
    frame = pred.dpu(3).frames[0]
    assert (frame.demand_us, frame.wait_us) == (pytest.approx(4300), pytest.approx(1370)) and frame.overflows
    assert not pred.dpu(3).schedulable and not pred.schedulable
    assert pred.warnings == (
        "DPU 3: frames overflow the 5 ms minor cycle: minor cycle 0 (1 of every 1) demands 5.67 ms "
        "(jacobian_transpose, force_control), 1.37 ms of it waiting for data: jacobian_transpose waits "
        "for joint_state until joint_sensors (DPU 2) ends, at worst 1.37 ms after their release",)
    # the chain counts from joint_sensors' output: jacobian_transpose starts as it comes
    assert (pred.chains[0].best_us, pred.chains[0].worst_us) == (2800, 2800 + 5000)
    # on the tasking executive force_control computes while jacobian_transpose waits
    tasking = predict(load(EXAMPLES / "servo-tasking.yaml", ["process.trajectory.dpu=2"]))
    assert tasking.process("jacobian_transpose").start_max_us == pytest.approx(1370)
    assert tasking.process("jacobian_transpose").response_us == pytest.approx(1370 + 2800)
    assert tasking.process("force_control").response_us == pytest.approx(4300)
    assert tasking.dpu(3).schedulable


def test_servo_at_2_5_ms_predicts_overload_frames_and_lockout() -> None:
    pred = predict(load(EXAMPLES / "servo-2.5ms.yaml"))
    assert [d.schedulable for d in pred.dpus] == [False, False, False, True]
    assert [f.first for f in pred.dpu(1).overflowing] == [0]
    assert pred.dpu(1).overflowing[0].demand_us == pytest.approx(4515)
    # frame 0 (4.515 ms) back to back: forward_kinematics' cycle k ends at 4.515 (k + 1) ms,
    # past its limit 2.5 k + 25 ms from k = 11, at 52.5 ms (a run: cycle 10 or 11, 50-52.5 ms)
    assert pred.dpu(1).lockout_ms == pytest.approx(52.5)
    said = "\n".join(pred.warnings)
    assert "DPU 1: static load 180.6 % exceeds 100 %" in said
    assert "lockout predicted about 52 ms" in said
    assert "minor cycle 0 (1 of every 1) demands 4.515 ms (trajectory, forward_kinematics)" in said
    assert pred.chains[0].worst_us is None


def test_check_prints_the_prediction_and_json_carries_it() -> None:
    done = skel("check", str(EXAMPLES / "servo-2.5ms.yaml"))
    assert done.returncode == 0, done.stderr
    assert "prediction" in done.stdout and "0 (4.515 of 2.5 ms)" in done.stdout
    assert "lockout predicted" in done.stdout
    as_json = json.loads(skel("check", str(EXAMPLES / "servo.yaml"), "--json").stdout)
    assert [d["compute_pct"] for d in as_json["prediction"]["dpus"]] == [90.3, 73.4, 86.0, 96.5]


def test_tasking_responses_are_exact_rta_and_misses_are_named(tmp_path: Path) -> None:
    text = """\
system: rm
dpus: [{id: 1, executive: threads}]
processes:
  - {id: 1, name: a, dpu: 1, period_us: 8000, compute_us: 3000}
  - {id: 2, name: b, dpu: 1, period_us: 12000, compute_us: 3000}
  - {id: 3, name: c, dpu: 1, period_us: 24000, compute_us: CC}
"""
    ok = predict(_system(tmp_path, text.replace("CC", "7000")))
    assert [ok.process(n).response_us for n in "abc"] == [3000, 6000, 22000]
    assert ok.dpu(1).schedulable
    # Starts from the ideal schedule of a hyperperiod (24 ms): b's second job meets no a, c's
    # always starts behind both (the bound response - compute said up to 15 ms)
    assert [(ok.process(n).start_min_us, ok.process(n).start_max_us) for n in "abc"] == [
        (0, 0), (0, 3000), (6000, 6000)]
    # README's unschedulable set: 3/8, 6/20, 6/24 ms, R = 30 ms
    late = predict(_system(tmp_path, text.replace("CC", "6000").replace("12000, compute_us: 3000",
                                                                         "20000, compute_us: 6000")))
    assert late.process("c").response_us == 30000 and not late.dpu(1).schedulable
    assert any("DPU 1: c (priority 97) misses its deadline: worst response 30 ms > period 24 ms" in w
               for w in late.warnings), late.warnings


def test_cyclic_frames_of_mixed_periods(tmp_path: Path) -> None:
    text = """\
system: mixed
dpus: [{id: 1}]
processes:
  - {id: 1, name: fast, dpu: 1, period_us: 5000, compute_us: 1000}
  - {id: 2, name: mid, dpu: 1, period_us: 10000, compute_us: 2000}
  - {id: 3, name: slow, dpu: 1, period_us: 20000, compute_us: 3000}
"""
    d = predict(_system(tmp_path, text)).dpu(1)
    assert [(f.first, f.count, f.processes, f.demand_us) for f in d.frames] == [
        (0, 1, ("fast", "mid", "slow"), 6000), (1, 2, ("fast",), 1000), (2, 1, ("fast", "mid"), 3000)]
    assert [f.first for f in d.overflowing] == [0] and not d.schedulable
    assert d.load_pct == pytest.approx(55)


def test_input_shares_from_rates(tmp_path: Path) -> None:
    text = """\
system: rates
dpus: [{id: 1}, {id: 2}]
buffers: [{id: 1, name: slow, bytes: 8}, {id: 2, name: fast, bytes: 8}]
processes:
  - {id: 1, name: w_slow, dpu: 1, period_us: 20000, compute_us: 100, outputs: [slow]}
  - {id: 2, name: w_fast, dpu: 1, period_us: 2500, compute_us: 100, outputs: [fast]}
  - {id: 3, name: reader, dpu: 2, period_us: 5000, compute_us: 100, inputs: [slow, fast]}
"""
    shares = {i.buffer: (i.new, i.stale, i.dropped) for i in predict(_system(tmp_path, text)).inputs}
    assert shares == {"slow": (0.25, 0.75, 0.0), "fast": (1.0, 0.0, 1.0)}


def test_paced_reader_warns_with_its_rate_and_lockout(tmp_path: Path) -> None:
    pred = predict(_system(tmp_path, LOCKOUT_SYSTEM))
    reader = pred.process("hungry_reader")
    assert reader.paced_by == "slow_writer" and reader.rate_hz == pytest.approx(10)
    assert pred.warnings == ("hungry_reader (sync: data, 200 Hz) is paced by slow_writer: it will run at "
                             "10 Hz, one cycle per 100 ms, at least lockout_cycles (5) periods: it will "
                             "lock out",)
    shares = {i.buffer: (i.new, i.stale) for i in pred.inputs}
    assert shares == {"slow_data": (1.0, 0.0)}  # one cycle per sample


def test_link_traffic_and_bandwidth_warning(tmp_path: Path) -> None:
    text = """\
system: traffic
links: [{name: bus, url: "DEFAULT_URL", bandwidth_mbps: 1}, {name: mem, url: local}]
dpus: [{id: 1}]
buffers: [{id: 1, name: big, bytes: 10000, link: bus}, {id: 2, name: near, bytes: 100, link: mem}]
processes:
  - {id: 1, name: w, dpu: 1, period_us: 10000, compute_us: 100, outputs: [big, near]}
  - {id: 2, name: r, dpu: 1, period_us: 10000, compute_us: 100, inputs: [big, near]}
"""
    pred = predict(_system(tmp_path, text.replace("DEFAULT_URL", contract.DEFAULT_URL)))
    bus, mem = pred.links
    per_message = 40 + 10000 + 8 + len("SKEL_BUF_big") + 1 + 28
    assert (bus.messages_per_s, bus.bytes_per_s) == pytest.approx((100, 100 * per_message))
    assert bus.over and not mem.over and mem.bytes_per_s == pytest.approx(10000)
    assert any(w.startswith("link bus: 8.07 Mbit/s of buffers (100 messages/s) exceeds its bandwidth_mbps 1")
               for w in pred.warnings), pred.warnings


def test_a_link_over_its_bandwidth_with_known_writers_alone_is_flagged_though_its_total_is_unknown(
        tmp_path: Path) -> None:
    """A writer on host-sent events makes the link's traffic unknown, but never less than what
    the others send: 8.07 Mbit/s on a 1 Mbit/s link was shown as "unknown", with no warning."""
    text = """\
system: traffic
links: [{name: bus, url: "DEFAULT_URL", bandwidth_mbps: BW}]
dpus: [{id: 1}]
buffers: [{id: 1, name: big, bytes: 10000}, {id: 2, name: knock, bytes: 8}]
processes:
  - {id: 1, name: w, dpu: 1, period_us: 10000, compute_us: 100, outputs: [big]}
  - {id: 2, name: on_demand, dpu: 1, period_us: 10000, compute_us: 100, sync: event, event: go,
     outputs: [knock]}
  - {id: 3, name: r, dpu: 1, period_us: 10000, compute_us: 100, inputs: [big, knock]}
events: [{name: go, kind: host}]
""".replace("DEFAULT_URL", contract.DEFAULT_URL)
    path = tmp_path / "over.yaml"
    path.write_text(text.replace("BW", "1"))
    pred = predict(load(path))
    bus = pred.links[0]
    assert (bus.messages_per_s, bus.bytes_per_s) == (None, None) and bus.over
    assert bus.known_messages_per_s == 100 and pred.to_json()["links"][0]["over"]
    over, fills = pred.warnings
    assert over == ("link bus: at least 8.07 Mbit/s of buffers (100 messages/s, its writers "
                    "of known rate: those on host-sent events add theirs) exceeds its bandwidth_mbps 1")
    # the transmitter's model takes the event writer at its most, one message a period
    assert fills.startswith("link bus: its transmit queue fills: each message waits about queue_us (100 ms)")
    out = io.StringIO()
    assert check(path, out=out) == 0
    assert "bus      unknown  at least 8.07 of 1" in out.getvalue()
    # within the bandwidth the known part says nothing of the whole: unknown, not held against it
    roomy = predict(_system(tmp_path, text.replace("BW", "100")))
    assert not roomy.links[0].over and roomy.links[0].bytes_per_s is None and roomy.warnings == ()


def test_what_follows_from_a_host_events_rate_is_unknown(tmp_path: Path) -> None:
    path = tmp_path / "host.yaml"
    path.write_text(HOST_EVENTS_SYSTEM)
    pred = predict(load(path))
    assert {p.name: p.rate_hz for p in pred.processes} == {
        "on_demand": None, "ticker": 1000, "listener": 200, "follower": None, "waiter": None}
    assert [d.compute_pct for d in pred.dpus] == [None, pytest.approx(20), None]
    assert [d.load_pct for d in pred.dpus] == pytest.approx([10, 20, 20])  # static: once a period
    # a writer as fast as on_demand can run gives it new data every cycle, however few they are
    assert {(i.reader, i.buffer): (i.new, i.stale, i.dropped) for i in pred.inputs} == {
        ("on_demand", "tick"): (1.0, 0.0, None), ("listener", "knock"): (None, None, None),
        ("waiter", "knock"): (None, None, None)}
    # waiter may be paced by on_demand, so its response may hold the wait: not judged
    assert pred.process("waiter").paced_by == "on_demand"
    assert pred.warnings == ("waiter (sync: data, 200 Hz) waits for on_demand: how often it runs depends on "
                             "events the host sends, and it locks out if on_demand writes less often than "
                             "once every lockout_cycles (10) of its periods",)
    # on_demand reads tick at its next event, whenever the host sends it; waiter waits for knock (its
    # latest start, 0.2 ms after follower) or reads it within its next period and the spread of its
    # start (5 + 0.2 ms), whichever is worse
    assert [c.worst_us for c in pred.chains] == [None, 5200]
    assert (pred.links[0].messages_per_s, pred.links[0].bytes_per_s) == (None, None)
    as_json = pred.to_json()
    assert [d["compute_pct"] for d in as_json["dpus"]] == [None, 20.0, None]
    assert as_json["processes"][0]["rate_hz"] is None and as_json["inputs"][1]["new"] is None
    out = io.StringIO()
    assert check(path, out=out) == 0
    printed = out.getvalue()
    assert "1       cyclic    10.0              unknown" in printed
    assert "listener <- knock (on_demand)  unknown  unknown            unknown" in printed
    # an overloaded cyclic DPU slows all its processes alike, by however much the host asks for
    crowded = HOST_EVENTS_SYSTEM.replace("ticker, dpu: 2", "ticker, dpu: 1").replace(
        "compute_us: 100, sync", "compute_us: 950, sync")
    one = predict(_system(tmp_path, crowded))
    assert one.process("ticker").rate_hz is None and one.process("listener").rate_hz == 200
    # its lockout is a bound: with fewer events than one a period, the DPU may keep up
    assert any(w.startswith("DPU 1: static load 105.0 % exceeds 100 % (host-sent events at their most, "
                            "one a period): it will overrun") for w in one.warnings), one.warnings


PACED_SYSTEM = """\
system: paced
dpus: [{id: 1, compute: sleep}, {id: 2, compute: sleep, executive: EXECUTIVE}]
buffers: [{id: 1, name: buf, bytes: 100}]
processes:
  - {id: 1, name: w, dpu: 1, period_us: 10000, compute_us: 2000, outputs: [buf]}
  - {id: 2, name: rd5, dpu: 2, period_us: 5000, compute_us: 500, sync: data, inputs: [buf]}
chains: [{name: c, processes: [w, rd5]}]
"""


def test_a_paced_reader_waits_for_its_writer_in_its_start_and_response(tmp_path: Path) -> None:
    """A 5 ms data reader of a 10 ms writer (2 ms) elsewhere runs once per value, waiting for it.
    On the cyclic executive the wait holds the DPU: a cycle ends at 2.5 ms past the value's
    release, the next release's turn comes then, 2.5 ms late, and it waits for the next value
    (10 ms on): it computes 12 ms after that release and responds at 12.5 ms, the one between
    skipped (a real run: start p50 12.6, response p99 12.8 ms). It was predicted 0..0 and 0.5 ms,
    as if it had no wait. On the tasking executive the release at the value's time takes it: 2
    and 2.5 ms. The chain's value waits for no turn (it is computed when it comes)."""
    cyclic = predict(_system(tmp_path, PACED_SYSTEM.replace("EXECUTIVE", "cyclic")))
    rd5 = cyclic.process("rd5")
    assert rd5.paced_by == "w" and rd5.rate_hz == pytest.approx(100)
    assert (rd5.start_min_us, rd5.start_max_us, rd5.response_us) == pytest.approx((12000, 12000, 12500))
    assert cyclic.chains[0].worst_us == pytest.approx(0)
    tasking = predict(_system(tmp_path, PACED_SYSTEM.replace("EXECUTIVE", "threads")))
    rd5 = tasking.process("rd5")
    assert (rd5.start_min_us, rd5.start_max_us, rd5.response_us) == pytest.approx((2000, 2000, 2500))
    # Below it, a process whose start its skipped releases move: not the ideal schedule's grid
    # (that said exactly 500, as if rd5 ran at every release), but 0 up to rd5's compute.
    lower = PACED_SYSTEM.replace("EXECUTIVE", "threads").replace(
        "chains:", "  - {id: 3, name: lo, dpu: 2, period_us: 5000, compute_us: 500}\nchains:")
    lo = predict(_system(tmp_path, lower)).process("lo")
    assert (lo.start_min_us, lo.start_max_us) == pytest.approx((0, 500))
    # the same-cycle wait of a reader of its own period is unchanged: 2 ms, 2.5 ms
    same = predict(_system(tmp_path, PACED_SYSTEM.replace("EXECUTIVE", "cyclic").replace("5000", "10000")))
    assert same.process("rd5").paced_by is None
    assert (same.process("rd5").start_max_us, same.process("rd5").response_us) == pytest.approx((2000, 2500))


def _one_process(period_us: int, compute_us: int, lockout_cycles: int) -> System:
    return loads(f"""\
system: one
dpus: [{{id: 1}}]
processes: [{{id: 1, name: hog, dpu: 1, period_us: {period_us}, compute_us: {compute_us}}}]
run: {{warmup_cycles: 0, lockout_cycles: {lockout_cycles}}}
""", "one.yaml")


def test_a_paced_writer_drops_the_sequences_of_the_releases_it_skips(tmp_path: Path) -> None:
    """m (sync: data, 5 ms) is paced by its 10 ms writer to 100 Hz and skips every other
    release, whose sequence its readers see as dropped (unpublished): t at 5 ms finds new data
    in half its cycles, each a sequence past the last, 0.5 dropped a cycle (was predicted 0; an
    audit measured 1.5 for the 4:1 case, predicted 0)."""
    text = """\
system: paced_writer
dpus: [{id: 1}, {id: 2}, {id: 3}]
buffers: [{id: 1, name: x, bytes: 64}, {id: 2, name: y, bytes: 64}]
processes:
  - {id: 1, name: w, dpu: 1, period_us: 10000, compute_us: 1000, outputs: [x]}
  - {id: 2, name: m, dpu: 2, period_us: 5000, compute_us: 500, sync: data, inputs: [x], outputs: [y]}
  - {id: 3, name: t, dpu: 3, period_us: 5000, compute_us: 500, inputs: [y]}
"""
    pred = predict(_system(tmp_path, text))
    assert pred.process("m").paced_by == "w"
    shares = {(i.reader, i.buffer): (i.new, i.stale, i.dropped) for i in pred.inputs}
    assert shares[("t", "y")] == pytest.approx((0.5, 0.5, 0.5))
    assert shares[("m", "x")] == pytest.approx((1.0, 0.0, 0.0))


@pytest.mark.parametrize(("compute_us", "lockout_ms"), [
    (300_000, 100),  # cycle 0 computes past its window (r_0 + 10 x 10 ms): locked out at 100 ms
    (150_000, 100),
    (12_000, 540),   # cycle k ends at 12 (k + 1) ms, past 10 k + 100 from k = 44 (just at it: late)
    (11_000, 990),   # 11 (k + 1) >= 10 k + 100 from k = 89
])
def test_predicted_lockout_when_a_cycle_first_ends_past_its_window(compute_us: int, lockout_ms: int) -> None:
    """The lockout definition, cycle k not completed by r_k + lockout_cycles x period, on the
    cyclic executive running an overloaded DPU back to back (a run measured 100 and 540 ms)."""
    assert predict(_one_process(10_000, compute_us, 10)).dpu(1).lockout_ms == pytest.approx(lockout_ms)


VARYING_CYCLIC = """\
system: varying_cyclic
dpus: [{id: 1}]
buffers: [{id: 1, name: a, bytes: 64}, {id: 2, name: b, bytes: 64}]
processes:
  - {id: 1, name: uni, dpu: 1, period_us: 10000, compute_us: {dist: uniform, min: 1000, max: 3000},
     outputs: [a]}
  - {id: 2, name: expo, dpu: 1, period_us: 10000, compute_us: {dist: exponential, mean: 1000, max: 4000},
     outputs: [b]}
"""

VARYING_TASKING = """\
system: varying_tasking
dpus: [{id: 1, executive: threads}]
buffers: [{id: 1, name: a, bytes: 64}, {id: 2, name: b, bytes: 64}]
processes:
  - {id: 1, name: hi, dpu: 1, period_us: 10000, compute_us: {dist: uniform, min: 1000, max: 5000},
     outputs: [a]}
  - {id: 2, name: lo, dpu: 1, period_us: 20000, compute_us: 6000, outputs: [b]}
"""


def test_cyclic_worst_figures_take_the_largest_draw_and_averages_the_mean() -> None:
    # Cyclic: expo runs after uni in the frame, so it starts when uni's draw ends (1 to 3 ms)
    # and at worst ends 3 + 4 ms after the release; the mean put both at 2 and 2.925 ms.
    pred = predict(loads(VARYING_CYCLIC, Path("s.yaml")))
    uni, expo = pred.process("uni"), pred.process("expo")
    assert (uni.start_min_us, uni.start_max_us, uni.response_us) == (0, 0, pytest.approx(3000))
    assert (expo.start_min_us, expo.start_max_us) == (pytest.approx(1000), pytest.approx(3000))
    assert expo.response_us == pytest.approx(7000)
    assert pred.dpu(1).compute_pct == pytest.approx(29.25)  # 2000 + 925 (the cut exponential's mean)
    assert pred.schedulable and not pred.warnings


def test_tasking_worst_responses_take_the_largest_draw() -> None:
    # lo's exact RTA with hi at its 5 ms: R = 6 + 2 x 5 = 16 ms (the mean gave 9 ms).
    pred = predict(loads(VARYING_TASKING, Path("s.yaml")))
    assert pred.process("hi").response_us == pytest.approx(5000)
    assert pred.process("lo").response_us == pytest.approx(16000)
    # a varying compute moves the schedule: the bound R - C, not one hyperperiod's starts
    assert (pred.process("lo").start_min_us, pred.process("lo").start_max_us) == (0, pytest.approx(10000))
    assert pred.dpu(1).compute_pct == pytest.approx(60) and pred.dpu(1).load_pct == pytest.approx(60)


def test_a_frame_that_overflows_only_at_the_largest_draws_may_overflow() -> None:
    # 4.5 + 0.84 ms on average, 8 + 3 ms at the largest draws: a risk, not a certainty
    text = VARYING_CYCLIC.replace("max: 3000", "max: 8000").replace("max: 4000", "max: 3000")
    pred = predict(loads(text, Path("s.yaml")))
    d = pred.dpu(1)
    assert not d.overflowing and [f.first for f in d.may_overflow] == [0] and not d.schedulable
    assert d.frames[0].worst_demand_us == pytest.approx(11000) and d.lockout_ms is None
    # every draw at its maximum forever falls ever further behind: no bound
    assert pred.process("expo").response_us is None and d.compute_pct == pytest.approx(53.43)
    assert [w for w in pred.warnings if "may overflow the 10 ms minor cycle" in w and "up to 11 ms" in w]

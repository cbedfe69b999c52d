"""Signed control (dpu/seal.c, analysis/read/seal.py), with real sanitizer DPUs on a private port:
a host with another key, or none, cannot push, start, stop, resend or shut down; a replay of a
recorded signed START (lcm-logplayer) is refused; each refusal is counted by kind in the DPUs'
status and logged once; the analysis of a signed run uses only its genuine messages; the key
is nowhere in what a run leaves behind."""

from __future__ import annotations

import json
import re
import subprocess
import time
from pathlib import Path

import pytest
from conftest import EXAMPLES, DpuFarm, skel

import skelmsg
from skeleton.analysis.read.logreader import encode_events, read_log
from skeleton.analysis.read.seal import KeyFileError, Signer, authenticate, load_key, split, write_key
from skeleton.host.live import spawn
from skeleton.host.live.control import Control
from skelmsg import contract

PAIR = EXAMPLES / "pair-10ms-5ms.yaml"


@pytest.fixture
def keys(tmp_path: Path) -> tuple[Path, Path]:
    k1, k2 = tmp_path / "k1", tmp_path / "k2"
    assert skel("keygen", str(k1)).returncode == 0
    write_key(k2)
    return k1, k2


def _refused(control: Control, dpu: int, kind: str, want: int, timeout_s: float = 5.0) -> int:
    """The DPU's count of `kind` refusals once it reaches `want` (or the timeout)."""
    def count() -> int:
        status = control.dpus[dpu].status if dpu in control.dpus else None
        return -1 if status is None else getattr(status, f"rejected_{kind}")
    control.wait_for(lambda: count() >= want, timeout_s)
    time.sleep(0.3)  # more than wanted would show now
    return count()


@pytest.mark.parametrize(("content", "mode", "why"), [
    (None, 0o600, "No such file or directory"),
    (b"x" * 31, 0o600, "must hold exactly 32 bytes"),
    (b"x" * 33, 0o600, "must hold exactly 32 bytes"),
    (b"x" * 32, 0o644, "readable by others (mode 644): chmod 600"),
])
def test_a_bad_key_file_is_one_line_and_exit_2(tmp_path: Path, url: str, content: bytes | None, mode: int,
                                               why: str) -> None:
    path = tmp_path / "key"
    if content is not None:
        path.write_bytes(content)
        path.chmod(mode)
    with pytest.raises(KeyFileError, match=re.escape(why)):
        load_key(path)
    done = skel("status", "--url", url, "--wait", "0", "--key", str(path))
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and why in done.stderr, done.stderr
    dpu = subprocess.run([str(spawn.dpu_binary()), "--id", "1", "--url", url, "--key", str(path)],
                         capture_output=True, text=True, timeout=30)
    assert dpu.returncode == 2 and why in dpu.stderr, dpu.stderr


# --- real DPUs ---------------------------------------------------------------------------
def test_another_key_or_none_cannot_command_the_dpus(dpus: DpuFarm, url: str,
                                                      keys: tuple[Path, Path]) -> None:
    """Every kind of control message from a host with the wrong key (forged) or none (unsigned)
    is refused and counted exactly; the DPUs keep running unconfigured, and log each kind once."""
    k1, k2 = keys
    dpus.start(1, 2, extra=["--key", str(k1)])
    genuine = Control(url, load_key(k1))
    wrong, bare = Control(url, load_key(k2)), Control(url)
    try:
        assert genuine.wait_heard([1, 2], 10) == []
        for intruder in (wrong, bare):
            intruder.publish_config(skelmsg.config_t())
            intruder.command(skelmsg.command_t.START, repeats=1, generation=1, run_id=5,
                             at_utc_ns=time.time_ns())
            intruder.command(skelmsg.command_t.COMMIT, repeats=1, generation=1)
            intruder.command(skelmsg.command_t.STOP, repeats=1)
            intruder.command(skelmsg.command_t.RESEND, repeats=1, run_id=5, batch_from=0, batch_to=3)
            intruder.ping()
            intruder.command(skelmsg.command_t.SHUTDOWN, repeats=1)
        for dpu in (1, 2):
            assert _refused(genuine, dpu, "forged", 7) == 7
            assert _refused(genuine, dpu, "unsigned", 7) == 7
            status = genuine.dpus[dpu].status
            assert (status.rejected_replayed, status.rejected_signed, status.keyed) == (0, 0, 1)
            assert status.state == skelmsg.status_t.STATE_UNCONFIGURED and status.generation == 0
        # each host heard why: the DPUs sign with another key, or sign at all
        assert wrong.key_problems == {1: "its messages fail the MAC: it has another key than this host's",
                                      2: "its messages fail the MAC: it has another key than this host's"}
        assert set(bare.key_problems) == {1, 2} and "it has a key and this host none" in bare.key_problems[1]
        # the genuine host still commands them: shut down by it, they exit 0
        genuine.shutdown()
        for d in dpus.daemons.values():
            d.process.wait(timeout=10)
            assert d.process.returncode == 0
    finally:
        for c in (genuine, wrong, bare):
            c.close()
    for dpu in (1, 2):  # one line per sender and kind, however many messages
        log = dpus.log(dpu)
        assert log.count("refused: its MAC does not match") == 1, log
        assert log.count("refused: it has no seal") == 1, log


def test_a_host_and_dpus_that_disagree_on_the_key_say_so(dpus: DpuFarm, url: str,
                                                          keys: tuple[Path, Path]) -> None:
    k1, k2 = keys
    dpus.start(1, 2, extra=["--key", str(k1)])
    system = ["-s", "run.cycles=20"]
    for key, line in ((None, "it signs its messages: it has a key and this host none"),
                      (k2, "its messages fail the MAC: it has another key than this host's")):
        args = ["--key", str(key)] if key else []
        done = skel("push", str(PAIR), "--url", url, *system, *args, timeout=60)
        assert done.returncode == 1, done.stdout + done.stderr
        assert f"DPU 1: did not answer generation 1: {line}" in done.stderr, done.stderr
    assert skel("push", str(PAIR), "--url", url, *system, "--key", str(k1)).returncode == 0
    assert dpus.stop_all() == {1: 0, 2: 0}
    # the other way round: DPUs without a key, a host with one
    dpus.start(1, 2)
    done = skel("push", str(PAIR), "--url", url, *system, "--key", str(k1), timeout=60)
    assert done.returncode == 1
    assert ("DPU 1: did not answer generation 1: its messages are unsigned: it has no key and this host "
            "has one") in done.stderr, done.stderr
    assert dpus.log(1).count("refused: it is signed: the sender has a key and this DPU none") == 1
    # A run says the same: its DPUs were heard, the key check refused them (not "start them").
    run = skel("run", str(PAIR), "--url", url, *system, "--key", str(k1), "--wait-dpus", "2",
               "--out", str(keys[0].parent / "run"), timeout=60)
    assert run.returncode == 1, run.stdout + run.stderr
    assert "DPU 1, 2 not accepted on" in run.stdout and "the key check refused" in run.stdout, run.stdout
    assert "DPU 1: its messages are unsigned" in run.stdout and "firewall" not in run.stdout, run.stdout


def test_a_replayed_start_is_refused(dpus: DpuFarm, url: str, keys: tuple[Path, Path],
                                     tmp_path: Path) -> None:
    """A real signed run recorded by lcm-logger, then its config and commands played again onto
    the group by lcm-logplayer: every one is refused as a replay, and no run starts."""
    k1, _ = keys
    dpus.start(1, 2, extra=["--key", str(k1)])
    out = tmp_path / "run"
    done = skel("run", str(PAIR), "--url", url, "--out", str(out), "--cycles", "60", "--key", str(k1))
    assert done.returncode == 0, done.stdout + done.stderr
    log = read_log(out / "run.lcm")
    replayed = sum(len(log.indices(c)) for c in (contract.CONFIG_CHANNEL, contract.COMMAND_CHANNEL))
    starts = [skelmsg.command_t.decode(bytes(split(d)[0])) for _, d in log.messages(contract.COMMAND_CHANNEL)]
    assert any(c.kind == skelmsg.command_t.START for c in starts)
    watcher = Control(url, load_key(k1))
    try:
        assert watcher.wait_heard([1, 2], 10) == []
        before = {d: watcher.dpus[d].status.minor_cycles for d in (1, 2)}
        player = Path(spawn.logger_binary()).with_name("lcm-logplayer")
        channels = f"({contract.CONFIG_CHANNEL}|{contract.COMMAND_CHANNEL})"
        subprocess.run([str(player), "-s", "20", "-e", channels, "-l", url, str(out / "run.lcm")],
                       check=True, timeout=60, capture_output=True)
        for dpu in (1, 2):
            assert _refused(watcher, dpu, "replayed", replayed) == replayed
            status = watcher.dpus[dpu].status
            assert status.state == skelmsg.status_t.STATE_READY and status.minor_cycles == before[dpu]
            assert (status.rejected_forged, status.rejected_unsigned) == (0, 0)
    finally:
        watcher.close()


def test_a_signed_runs_analysis_leaves_out_injected_messages(url: str, keys: tuple[Path, Path],
                                                              tmp_path: Path) -> None:
    """Messages injected into a signed run's log (unsigned, forged, replayed) change nothing in
    its tables with the key, are counted in integrity.unauthenticated, and the key is nowhere in
    the run directory or the MCAP export."""
    k1, k2 = keys
    out = tmp_path / "run"
    done = skel("run", str(PAIR), "--spawn", "--url", url, "--out", str(out), "--cycles", "100",
                "--key", str(k1))
    assert done.returncode == 0, done.stdout + done.stderr
    clean = skel("report", str(out), "--json", "--key", str(k1))
    log = read_log(out / "run.lcm")
    events = [(e.utime_us, e.channel, e.data) for e in log.iter_events()]
    status_data = next(d for _, c, d in events if c == contract.STATUS_CHANNEL)
    timing_data = next(d for _, c, d in events if c == contract.TIMING_CHANNEL)
    forged = Signer(load_key(k2), 99).seal(contract.TIMING_CHANNEL, bytes(split(timing_data)[0]))
    injected = [(events[-1][0], contract.TIMING_CHANNEL, bytes(split(timing_data)[0])),  # unsigned
                (events[-1][0], contract.TIMING_CHANNEL, forged),
                (events[-1][0], contract.STATUS_CHANNEL, status_data)]                    # replayed
    tampered = tmp_path / "tampered.lcm"
    tampered.write_bytes(encode_events(events + injected))
    _, found = authenticate(read_log(tampered), load_key(k1))
    assert found.by_verdict == {"unsigned": 1, "forged": 1, "replayed": 1}
    again = skel("report", str(tampered), "--json", "--key", str(k1))
    assert again.returncode == 0, again.stderr
    a, b = json.loads(clean.stdout), json.loads(again.stdout)
    assert b["integrity"]["unauthenticated"] == 3 and b["integrity"]["checked"]
    assert a["dpus"] == b["dpus"] and a["processes"] == b["processes"]
    # without the key the injected batch counts (a duplicate here): the report says it was not checked
    text = skel("report", str(tampered))
    assert "the run was signed, but not checked here" in text.stdout
    # the key never leaves its file
    assert skel("export", str(out), str(tmp_path / "run.mcap"), "--key", str(k1)).returncode == 0
    secret = load_key(k1)
    for path in [*out.rglob("*"), tmp_path / "run.mcap"]:
        if path.is_file():
            data = path.read_bytes()
            assert secret not in data and secret.hex().encode() not in data, path

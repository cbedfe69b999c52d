"""tests/unit/test_control.py's tests that start skel-dpu (it says what they check)."""

from __future__ import annotations

import time
from pathlib import Path

from conftest import DpuFarm, skel
from unit.test_control import INT64_MAX, PAIR, _publish, _stray_config

import skelmsg
from skeleton.host.live.control import Control
from skeleton.host.live.wire import config_message
from skeleton.host.sysfile.link import parse_url, record_url
from skeleton.host.sysfile.system import load, with_url
from skelmsg.contract import CONFIG_CHANNEL


def test_a_stray_config_of_generation_int64_max_stops_neither_push_nor_run(dpus: DpuFarm, url: str,
                                                                          tmp_path: Path) -> None:
    dpus.start(1, 2)
    control = Control(url)
    try:
        assert not control.wait_heard([1, 2], 10.0)
        _publish(url, CONFIG_CHANNEL, _stray_config(url, INT64_MAX, committed=False, valid=False))
        assert control.wait_for(lambda: all(control.dpus[i].status.rejected_generation == INT64_MAX
                                            for i in (1, 2)), 5.0), "the DPUs did not refuse the stray config"
        assert control.next_generation() == 1
        assert INT64_MAX not in control.configs and control.rejected_messages >= 1
    finally:
        control.close()
    pushed = skel("push", str(PAIR), "--url", url)
    assert pushed.returncode == 0, pushed.stdout + pushed.stderr
    assert "generation 1: staged on every DPU" in pushed.stdout, pushed.stdout
    run = skel("run", str(PAIR), "--url", url, "--duration", "1", "-s", "run.warmup_cycles=5",
               "--out", str(tmp_path / "run"))
    assert run.returncode == 0, run.stdout + run.stderr
    assert "Traceback" not in run.stderr and (tmp_path / "run" / "report.json").exists()


def test_a_dpu_that_applied_a_stray_generation_is_named_not_a_crash(dpus: DpuFarm, url: str) -> None:
    dpus.start(1, 2)
    control = Control(url)
    try:
        assert not control.wait_heard([1, 2], 10.0)
        _publish(url, CONFIG_CHANNEL, _stray_config(url, INT64_MAX, committed=True, valid=True))
        assert control.wait_for(lambda: all(control.dpus[i].status.generation == INT64_MAX for i in (1, 2)),
                                5.0), "the DPUs did not apply the stray config"
    finally:
        control.close()
    pushed = skel("push", str(PAIR), "--url", url)
    assert pushed.returncode == 1 and "Traceback" not in pushed.stderr, pushed.stdout + pushed.stderr
    assert f"DPU 1: applied generation {INT64_MAX}, which no host tool makes" in pushed.stderr, pushed.stderr
    assert "nothing was committed" in pushed.stderr, pushed.stderr


def test_a_system_one_port_above_does_not_configure_or_command_ours(dpus: DpuFarm, url: str) -> None:
    """Another system's host sends its log the copies of its configs and commands on its record
    URL, a group and a port below its control URL: with its control port one above ours, that
    is our control port. They must not reach our DPUs: LCM binds each receive socket to its
    group, not to every address, so the kernel hands ours only what is sent to our group."""
    dpus.start(1, 2)
    parsed = parse_url(url)
    above = url.replace(f":{parsed.port}", f":{parsed.port + 1}")
    assert parse_url(record_url(above)).port == parsed.port
    ours, theirs = Control(url), Control(above)
    try:
        assert not ours.wait_heard([1, 2], 10.0)
        generation = theirs.next_generation()
        theirs.publish_config(config_message(with_url(load(PAIR), above), generation, 0, committed=True))
        theirs.command(skelmsg.command_t.SHUTDOWN)
        time.sleep(1.0)
        statuses = {i: ours.dpus[i].status for i in (1, 2)}
        assert all(st.generation == 0 and st.staged_generation == 0 and st.rejected_generation == 0
                   for st in statuses.values()), statuses
        assert all(dpus.daemons[i].alive() for i in (1, 2))
        # What is sent to our control URL still arrives: our host configures them.
        generation = ours.next_generation()
        assert ours.push(config_message(with_url(load(PAIR), url), generation, 0, committed=False), [1, 2]).ok
    finally:
        ours.close()
        theirs.close()

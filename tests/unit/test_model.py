"""host/model.py: the typed System; its lookups, and a System read back from the config_t it
is sent as (what the analysis reads from a run's log)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from conftest import REPO

from skeleton.host.live.wire import config_message
from skeleton.host.model import FROM_CONFIG, RunRules, System, from_config
from skeleton.host.sysfile.system import load

EXAMPLES = sorted((REPO / "examples").glob("*.yaml"))


def _as_sent(system: System) -> System:
    """What of SYSTEM a config carries (from_config's docstring): the rest at its default."""
    return dataclasses.replace(
        system, path=Path("system.yaml"), reference=None, overrides=(),
        links=tuple(dataclasses.replace(link, bandwidth_mbps=None) for link in system.links),
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

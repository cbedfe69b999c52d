"""yamledit.with_overrides: the console's Save writes `-s` overrides into the text and keeps
every comment and the rest as written."""

from __future__ import annotations

import pytest
from conftest import EXAMPLES

from skeleton.host.sysfile import yamledit
from skeleton.host.sysfile.system import load, loads


def test_overrides_are_written_in_place_and_comments_kept() -> None:
    path = EXAMPLES / "servo.yaml"
    text = path.read_text()
    edits = ["process.executor.compute_us=3000", "process.force_control.dpu=1", "buffer.pose.bytes=99",
             "dpu.2.compute=wall", "run.cycles=500"]
    new = yamledit.with_overrides(text, edits)
    changed = [(a, b) for a, b in zip(text.splitlines(), new.splitlines(), strict=True) if a != b]
    assert len(changed) == len(edits)  # one line each, nothing else moved
    assert "# forward kinematics: pose, 7 doubles" in new and "{id: 5, name: pose, bytes: 99}" in new
    expected, saved = load(path, edits), loads(new, path)
    assert (saved.processes, saved.buffers, saved.dpus, saved.run) == (
        expected.processes, expected.buffers, expected.dpus, expected.run)


@pytest.mark.parametrize(("override", "problem"), [
    ("process.nobody.compute_us=1", "spells out no such item"),
    ("process.executor.compute_us=", "removing a key"),
    ("link.bus.bandwidth=", "removing a key"),
])
def test_what_the_text_cannot_say_is_refused(override: str, problem: str) -> None:
    with pytest.raises(ValueError, match=problem):
        yamledit.with_overrides((EXAMPLES / "servo.yaml").read_text(), [override])

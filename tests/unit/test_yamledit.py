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


@pytest.mark.parametrize(("text", "key", "expected"), [
    ("{id: 1, compute: {library: a, function: f}, name: p}", "compute", "{id: 1, name: p}"),
    ("{compute: {library: a}, id: 1}", "compute", "{id: 1}"),
    ("{id: 1,\n   compute: {library: a}, name: p}", "compute", "{id: 1, name: p}"),
    ("id: 1\ncompute: {library: a}  # its code\nname: p\n", "compute", "id: 1\nname: p\n"),
    ("compute: {library: a}\nname: p\n", "compute", "name: p\n"),
    ("{id: 1}", "compute", "{id: 1}"),
])
def test_a_key_is_removed_with_what_joined_it(text: str, key: str, expected: str) -> None:
    """skel calibrate takes `compute:` out of a process, in either style, keeping the rest."""
    edit = yamledit.remove_key(text, yamledit.root(text), key)
    assert yamledit.apply(text, [edit] if edit else []) == expected


def test_a_process_item_is_found_by_name_or_id() -> None:
    text = (EXAMPLES / "servo.yaml").read_text()
    top = yamledit.root(text)
    by_name, by_id = yamledit.process_item(top, "executor"), yamledit.process_item(top, "4")
    assert by_name is by_id and yamledit.value(by_name, "compute_us").value == "3500"
    assert yamledit.process_item(top, "nobody") is None

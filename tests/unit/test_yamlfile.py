"""yamlfile.py: any file, however large, deep, aliased or binary, gets one line `FILE: where:
problem` and exit 2 from the real `skel check`, quickly, with no traceback."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from conftest import EXAMPLES, skel

from skeleton.host.sysfile.system import load
from skeleton.host.sysfile.yamlfile import MAX_BYTES, MAX_DEPTH, MAX_VALUES, SystemFileError

# Generous against the 2 s the user may wait: the machine is shared and noisy. Before the
# limits, the 25 MB file took 149 s and the deep list was a RecursionError traceback.
QUICK_S = 10.0


def _bomb(levels: int = 7) -> str:
    """The billion laughs: each level an alias list of ten of the one before."""
    lines = ["system: bomb", "l0: &l0 [x, x, x, x, x, x, x, x, x, x]"]
    for i in range(1, levels):
        lines.append(f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 10) + "]")
    return "\n".join(lines) + "\n"


SERVO = (EXAMPLES / "servo.yaml").read_text()
CASES = {
    # A 1 KB file: a list nested 500 levels deep.
    "deep list": ("dpus: " + "[" * 500 + "]" * 500 + "\n",
                  rf"line 1 column \d+: nested more than {MAX_DEPTH} levels"),
    "deep mapping": ("".join("  " * i + f"k{i}:\n" for i in range(60)) + "  " * 60 + "v: 1\n",
                     rf"nested more than {MAX_DEPTH} levels"),
    "unclosed deep list": ("processes: " + "[{a: " * 300, rf"nested more than {MAX_DEPTH} levels"),
    "alias bomb": (_bomb(), rf"more than {MAX_VALUES} values once aliases are expanded"),
    "alias nesting": ("a: &a " + "[" * 30 + "]" * 30 + "\nb: [[[[[*a]]]]]\n",
                      rf"alias \*a nests more than {MAX_DEPTH} levels"),
    "NUL in UTF-8": ("system: x\ndpus: \x00\x01\n", r"line 2 column 7: character #x0000 is not allowed"),
    "integer of 5000 digits": ("system: x\nrun: {cycles: " + "9" * 5000 + "}\n",
                               r"YAML: a value cannot be read"),
    "broken YAML past the rewording size": (SERVO * 10 + "processes: [\n", r"line \d+ column 1: "),
}


def _check_one_line(path: Path, pattern: str) -> None:
    import re

    start = time.monotonic()
    done = skel("check", str(path), timeout=120)
    took = time.monotonic() - start
    assert done.returncode == 2, done.stdout + done.stderr
    assert "Traceback" not in done.stderr and done.stdout == "", done.stdout + done.stderr
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{path}: "), done.stderr
    assert re.search(pattern, lines[0]), lines[0]
    assert took < QUICK_S, f"{took:.1f} s: {lines[0]}"


@pytest.mark.parametrize("name", CASES)
def test_bad_yaml_is_one_line_exit_2_quickly(tmp_path: Path, name: str) -> None:
    text, pattern = CASES[name]
    path = tmp_path / "system.yaml"
    path.write_text(text)
    _check_one_line(path, pattern)


def test_a_25_mb_file_is_refused_by_its_size(tmp_path: Path) -> None:
    path = tmp_path / "huge.yaml"
    with path.open("w") as f:
        f.write(SERVO)
        line = "# " + "x" * 98 + "\n"
        f.write(line * (25 * 1024 * 1024 // len(line)))
    _check_one_line(path, rf"size: more than {MAX_BYTES // 1024} KiB")


def test_a_device_that_never_ends_is_refused_by_its_size() -> None:
    _check_one_line(Path("/dev/zero"), r"size: more than")


def test_binary_garbage_is_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "a.out"
    path.write_bytes(b"\x7fELF\x02\x01\x01" + bytes(range(256)) * 64)
    _check_one_line(path, r"cannot read: not UTF-8 text \(invalid start byte at byte \d+\)")


def test_an_override_value_nested_500_deep_is_one_line(tmp_path: Path) -> None:
    done = skel("check", str(EXAMPLES / "servo.yaml"), "-s", "run.stop_on=" + "[" * 500 + "]" * 500)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert len(done.stderr.splitlines()) == 1, done.stderr
    assert f"value is not valid YAML: nested more than {MAX_DEPTH} levels deep" in done.stderr


def test_just_under_the_limit_loads_and_a_late_error_is_found_quickly(tmp_path: Path) -> None:
    """A system file of the largest size allowed is read, and an error at its very end is
    found well within the time a user waits."""
    processes = ["processes:\n"]
    buffers = ["buffers:\n"]
    i = 0
    body = "system: big\ndpus: [" + ", ".join(f"{{id: {d}}}" for d in range(1, 33)) + "]\n"
    while len(body) + sum(map(len, processes + buffers)) < MAX_BYTES - 2000:
        i += 1
        buffers.append(f"  - {{id: {i}, name: b{i}, bytes: 64}}\n")
        processes.append(f"  - {{id: {i}, name: p{i}, dpu: {(i - 1) // 60 + 1}, period_us: 10000, "
                         f"compute_us: 10, outputs: [b{i}]}}\n")
    good = body + "".join(buffers) + "".join(processes)
    path = tmp_path / "big.yaml"
    path.write_text(good)
    assert len(load(path).processes) == i
    path.write_text(good + "  - {id: 32767, name: late, dpu: 1, period_us: -5, compute_us: 1}\n")
    _check_one_line(path, r"processes\.late\.period_us: ")


def test_limits_are_errors_of_the_library_too(tmp_path: Path) -> None:
    path = tmp_path / "deep.yaml"
    path.write_text("a: " + "[" * 100 + "]" * 100)
    with pytest.raises(SystemFileError) as raised:
        load(path)
    # `a:` is the first level, so the 32nd `[` (column 35) is the 33rd.
    assert raised.value.where == "line 1 column 35"

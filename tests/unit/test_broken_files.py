"""51 broken system files (tests/unit/broken/, one problem each; tests/unit/broken/expected.txt holds each
one's line): `skel check` gives exactly that one line `FILE: field.path: problem` on stderr and
exit 2, within 2 s, never a traceback. A 20 MB file is made here rather than kept."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import REPO

from skeleton.host.cli import main

BROKEN = REPO / "tests" / "unit" / "broken"
EXPECTED = {line.split(": ", 1)[0]: line for line in (BROKEN / "expected.txt").read_text().splitlines()}
LIMIT_S = 2.0


def test_there_are_fifty_one_and_each_has_its_line() -> None:
    files = sorted(p.name for p in BROKEN.glob("*.yaml"))
    assert len(files) == 51 and files == sorted(EXPECTED), set(files) ^ set(EXPECTED)


def _check(name: str, capsys: pytest.CaptureFixture[str],
           monkeypatch: pytest.MonkeyPatch) -> tuple[int, str, float]:
    monkeypatch.chdir(BROKEN)  # the file as a user names it: its line starts with that name
    start = time.perf_counter()
    code = main(["check", name])
    took = time.perf_counter() - start
    return code, capsys.readouterr().err, took


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_a_broken_file_gives_one_line_and_exit_2(name: str, capsys: pytest.CaptureFixture[str],
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    code, err, took = _check(name, capsys, monkeypatch)
    assert (code, err) == (2, EXPECTED[name] + "\n")
    assert took < LIMIT_S, took


def test_a_20_mb_file_is_refused_at_once(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    big = tmp_path / "big.yaml"
    row = "  - {id: 1, name: p, dpu: 1, period_us: 5000, compute_us: 1}\n"
    big.write_text("system: big\ndpus: [{id: 1}]\nprocesses:\n" + row * (20 * 2**20 // len(row)))
    assert big.stat().st_size > 20 * 10**6
    monkeypatch.chdir(tmp_path)
    start = time.perf_counter()
    code = main(["check", "big.yaml"])
    took = time.perf_counter() - start
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and err.startswith("big.yaml: size: more than 128 KiB"), err
    assert took < LIMIT_S, took


@pytest.mark.parametrize("name", ["43-alias-bomb.yaml", "44-deep-nesting.yaml", "45-binary-garbage.yaml"])
def test_the_command_line_itself_prints_no_traceback(name: str) -> None:
    done = subprocess.run([sys.executable, "-m", "skeleton.host.cli", "check", name], cwd=BROKEN,
                          capture_output=True, text=True, timeout=30)
    assert (done.returncode, done.stderr, done.stdout) == (2, EXPECTED[name] + "\n", "")

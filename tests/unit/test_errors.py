"""One base for skeleton's errors (analysis/errors.py): every exception class of host/ and
analysis/ derives from SkelError, and `skel` prints any of them as one line, with its exit code."""

from __future__ import annotations

import ast
import importlib

import pytest
from conftest import REPO

from skeleton.analysis.errors import EXIT_BAD_INPUT, EXIT_FAILED, SkelError
from skeleton.analysis.read.messages import LogError
from skeleton.analysis.read.seal import KeyFileError
from skeleton.host.cli import commands as cli
from skeleton.host.live.control import ControlError
from skeleton.host.sysfile.yamlfile import SystemFileError


def _exception_classes() -> list[tuple[str, str]]:
    """(module, class) of every class in host/ and analysis/ whose bases name an Error or Exception."""
    found = []
    for folder, package in (("host", "skeleton.host"), ("analysis", "skeleton.analysis")):
        for path in sorted((REPO / folder).rglob("*.py")):
            parts = path.relative_to(REPO / folder).with_suffix("").parts
            module = ".".join((package, *(p for p in parts if p != "__init__")))
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ClassDef) and any(
                        ast.unparse(b).endswith(("Error", "Exception")) for b in node.bases):
                    found.append((module, node.name))
    return found


def test_every_exception_class_derives_from_skelerror() -> None:
    classes = _exception_classes()
    assert ("skeleton.host.sysfile.yamlfile", "SystemFileError") in classes   # the scan sees them
    apart = [f"{m}.{c}" for m, c in classes
             if not issubclass(getattr(importlib.import_module(m), c), SkelError)]
    assert apart == []


@pytest.mark.parametrize(("error", "line", "code"), [
    (SystemFileError("s.yaml", "processes[0].period_us", "must be > 0"),
     "s.yaml: processes[0].period_us: must be > 0", EXIT_BAD_INPUT),
    (KeyFileError("key: not 32 bytes"), "skel: key: not 32 bytes", EXIT_BAD_INPUT),
    (LogError("empty file"), "skel: empty file", EXIT_BAD_INPUT),
    (ControlError("port taken"), "skel: port taken", EXIT_FAILED)])
def test_the_cli_prints_a_skelerror_as_one_line_with_its_code(
        error: SkelError, line: str, code: int, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    def command(_args: object) -> int:
        raise error
    monkeypatch.setitem(cli.COMMANDS, "check", command)
    assert cli.main(["check", "s.yaml"]) == code
    assert capsys.readouterr().err == line + "\n"

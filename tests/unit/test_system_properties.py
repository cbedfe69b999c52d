"""The system-file loader on any input (Hypothesis): arbitrary text, and the examples mutated
line by line and token by token. Each gives a System or a SystemFileError of one line that
names the file; never another exception. `make fuzz` runs thousands of examples."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from conftest import EXAMPLES
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skeleton.host.sysfile.system import SystemFileError, load

SOURCES = {p.name: p.read_text() for p in sorted(EXAMPLES.glob("*.yaml"))}
TOKEN = re.compile(r"[A-Za-z_]+|-?\d+(?:\.\d+)?|[\[\]{}:,\-#&*!|>'\"]")
WEIRD = st.sampled_from(["", "-1", "0", "1e309", "9" * 30, "null", "~", "[]", "{}", "&a", "*a",
                         "!!python/object", "'", '"', ":", "- ", "\t", "\x00", "é", "yes", ".nan", "0x1F",
                         "<<: *a"])


@pytest.fixture(scope="module")
def where(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("properties")


def _judge(where: Path, text: str) -> None:
    path = where / "system.yaml"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        load(path)
    except SystemFileError as error:
        line = str(error)
        assert "\n" not in line and line.startswith(f"{path}: "), line


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.text(alphabet=st.characters(blacklist_categories=["Cs"]), max_size=400))
def test_any_text_is_a_system_or_one_line(where: Path, text: str) -> None:
    _judge(where, text)


@st.composite
def mutated(draw: st.DrawFn) -> str:
    """An example with a few edits: lines dropped, doubled or cut, tokens replaced."""
    text = SOURCES[draw(st.sampled_from(sorted(SOURCES)))]
    for _ in range(draw(st.integers(1, 4))):
        lines = text.splitlines(keepends=True)
        at = draw(st.integers(0, max(0, len(lines) - 1)))
        how = draw(st.sampled_from(["drop", "double", "cut", "token", "indent"]))
        if how == "drop":
            del lines[at:at + 1]
        elif how == "double":
            lines.insert(at, lines[at] if lines else "")
        elif how == "cut":
            lines = lines[:at] + ([lines[at][: draw(st.integers(0, len(lines[at])))]] if lines else [])
        elif how == "indent" and lines:
            lines[at] = draw(st.sampled_from(["", " ", "    ", "\t"])) + lines[at].lstrip()
        elif lines:
            tokens = list(TOKEN.finditer(lines[at]))
            if tokens:
                m = tokens[draw(st.integers(0, len(tokens) - 1))]
                new = draw(st.one_of(WEIRD, st.integers(-2**70, 2**70).map(str), st.text(max_size=8)))
                lines[at] = lines[at][:m.start()] + new + lines[at][m.end():]
        text = "".join(lines)
    return text


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=mutated())
def test_a_mutated_example_is_a_system_or_one_line(where: Path, text: str) -> None:
    _judge(where, text)

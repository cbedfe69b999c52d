"""dpu/'s files call each other in one direction only: no cycle in the file -> file call graph.

Every function a dpu/ file exports is named after the file (`cycle_record` lives in cycle.c),
so a use of that name elsewhere is a call into that file. The graph is read from the source:
comments and literals blanked, a definition is a top-level name with its parameters and a
body, and a use is that name anywhere but after `.` or `->` (a call, or a function handed on
as a pointer). Two files that call each other are a cycle of two; a longer circle counts too.
"""

from __future__ import annotations

import re
from itertools import pairwise
from pathlib import Path

import graphs
from conftest import REPO

DPU = REPO / "dpu"
_BLANK = re.compile(r"/\*.*?\*/|//[^\n]*|\"(?:\\.|[^\"\\\n])*\"|'(?:\\.|[^'\\\n])*'", re.S)
# At column 0: the return type, the name, the parameters (one level of parentheses), the body.
_DEFINITION = re.compile(
    r"^(static\s+)?[A-Za-z_][\w \t*]*?\b([A-Za-z_]\w*)\s*\((?:[^;{}()]|\([^()]*\))*\)\s*\{", re.M)
_USE = re.compile(r"(?<![\w.>])([A-Za-z_]\w*)\b")


def _source(path: Path) -> str:
    return _BLANK.sub(" ", path.read_text())


def exported(folder: Path) -> dict[str, dict[str, bool]]:
    """Each file's stem -> the functions it defines -> whether it exports them (not static)."""
    return {path.stem: {m.group(2): m.group(1) is None for m in _DEFINITION.finditer(_source(path))}
            for path in sorted(folder.glob("*.c"))}


def call_graph(folder: Path) -> dict[str, dict[str, set[str]]]:
    """file -> file it calls -> the functions of that file it names."""
    owner = {name: stem for stem, names in exported(folder).items()
             for name, public in names.items() if public}
    graph: dict[str, dict[str, set[str]]] = {path.stem: {} for path in folder.glob("*.c")}
    for path in sorted(folder.glob("*.c")):
        for name in _USE.findall(_source(path)):
            target = owner.get(name)
            if target is not None and target != path.stem:
                graph[path.stem].setdefault(target, set()).add(name)
    return graph


def find_cycle(graph: dict[str, dict[str, set[str]]]) -> list[str]:
    """A circle of files, first file repeated at its end ([] when there is none)."""
    return graphs.find_cycle({source: sorted(targets) for source, targets in graph.items()})


def describe(graph: dict[str, dict[str, set[str]]], cycle: list[str]) -> str:
    return "\n".join(f"  {a}.c -> {b}.c: {', '.join(sorted(graph[a][b]))}" for a, b in pairwise(cycle))


def test_every_exported_function_is_named_after_its_file() -> None:
    wrong = [f"{stem}.c: {name}" for stem, names in exported(DPU).items() for name, public in names.items()
             if public and not name.startswith(f"{stem}_") and (stem, name) != ("main", "main")]
    assert not wrong, f"exported functions not named file_verb: {wrong}"


def test_no_two_dpu_files_call_each_other() -> None:
    graph = call_graph(DPU)
    assert sum(len(targets) for targets in graph.values()) > 50, "the graph is read: dpu/ calls across files"
    cycle = find_cycle(graph)
    assert not cycle, "dpu/ files call each other around a circle:\n" + describe(graph, cycle)


def test_the_executives_sit_side_by_side_above_what_they_share() -> None:
    """executive.c chooses one of three executives; none of them calls another, and the file
    they share (cycle.c: accounting, records, the wait, the live switch) calls none of them."""
    graph = call_graph(DPU)
    executives = {"cyclic", "tasking", "threads"}
    assert set(graph["executive"]) >= executives
    for name in executives:
        assert not executives & set(graph[name]), f"{name}.c calls {sorted(executives & set(graph[name]))}"
        assert "cycle" in graph[name]
    assert not (executives | {"executive"}) & set(graph["cycle"]), f"cycle.c calls {sorted(graph['cycle'])}"


def _write(folder: Path, files: dict[str, str]) -> Path:
    folder.mkdir()
    for name, text in files.items():
        (folder / name).write_text(text)
    return folder


def test_a_back_call_is_found(tmp_path: Path) -> None:
    """The check is not vacuous: a lower file calling back up makes a circle it reports, while
    a comment, a string or a member of the same name does not."""
    lower = ("/* low.c: high_run( is only named here */\nint low_add(int a, int b)\n{\n"
             "    const char *s = \"high_run()\";\n    return a + b + (int)s[0] + p->high_run;\n}\n")
    upper = ("#include \"x.h\"\nstatic int high_twice(int a) { return low_add(a, a); }\n"
             "void high_run(void)\n{\n    (void)high_twice(1);\n}\n")
    clean = call_graph(_write(tmp_path / "clean", {"low.c": lower, "high.c": upper}))
    assert clean == {"high": {"low": {"low_add"}}, "low": {}}
    assert find_cycle(clean) == []
    back = lower.replace("return a + b", "high_run();\n    return a + b")
    tied = call_graph(_write(tmp_path / "tied", {"low.c": back, "high.c": upper,
                                                  "mid.c": "void mid_x(void) {}\n"}))
    cycle = find_cycle(tied)
    assert cycle == ["high", "low", "high"], cycle
    assert describe(tied, cycle) == "  high.c -> low.c: low_add\n  low.c -> high.c: high_run"


def test_a_longer_circle_is_found(tmp_path: Path) -> None:
    files = {"a.c": "void a_go(void)\n{\n    b_go();\n}\n", "b.c": "void b_go(void)\n{\n    c_go();\n}\n",
             "c.c": "void c_go(void)\n{\n    a_go();\n}\n"}
    assert find_cycle(call_graph(_write(tmp_path / "abc", files))) == ["a", "b", "c", "a"]

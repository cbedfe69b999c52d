"""The package's import structure: every module imports alone, no import cycle, and the layers hold.

The graph is built from the source with `ast`: every import statement of a module, at its
top level or inside a function (a late import is still a dependency), relative ones resolved.
Imports under `if TYPE_CHECKING:` are never executed, so they do not make a cycle; they still
count for the layer order (an annotation naming an upper layer is a dependency on it).
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import graphs
import pytest

REPO = Path(__file__).resolve().parents[2]
PACKAGES = {"skeleton.host": REPO / "host", "skeleton.analysis": REPO / "analysis"}
ANALYSIS_LAYERS = {"read": 0, "measure": 1, "views": 2}   # imports run only from a higher to a lower one
# host/'s packages: each imports only itself and those before it; analysis/ imports only the model.
# console/ (the web page) and cli/ are the two front ends, side by side at the top: the page serves
# what the command line's views compute (check's summary, watch's tables), the command line starts it.
HOST_LAYERS = {"model": 0, "sysfile": 1, "theory": 2, "live": 3, "console": 4, "cli": 4}
SYSFILE_ORDER = ["schema", "link", "rules", "system"]  # inside sysfile/: each imports only earlier ones


@dataclass(frozen=True)
class Edge:
    source: str
    target: str
    line: int
    typing_only: bool

    def __str__(self) -> str:
        typing = ", TYPE_CHECKING" if self.typing_only else ""
        return f"{self.source} -> {self.target} (line {self.line}{typing})"


def project_modules() -> dict[str, Path]:
    """Every module of skeleton.host and skeleton.analysis (packages by their __init__)."""
    found: dict[str, Path] = {}
    for package, root in PACKAGES.items():
        for path in sorted(root.rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join((package, *parts))] = path
    return found


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.AST, typing_only: bool = False) -> list[tuple[ast.Import | ast.ImportFrom, bool]]:
    """Every import statement under `tree`, wherever it is, and whether only a type checker runs it."""
    out: list[tuple[ast.Import | ast.ImportFrom, bool]] = []
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.Import | ast.ImportFrom):
            out.append((node, typing_only))
        elif isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.body:
                out.extend(_imports(ast.Module(body=[child], type_ignores=[]), True))
            for child in node.orelse:
                out.extend(_imports(ast.Module(body=[child], type_ignores=[]), typing_only))
        else:
            out.extend(_imports(node, typing_only))
    return out


def import_graph(modules: dict[str, Path]) -> list[Edge]:
    edges: list[Edge] = []
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node, typing_only in _imports(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            else:
                if node.level:
                    base = package.split(".")
                    base = base[: len(base) - (node.level - 1)]
                    stem = ".".join(base + ([node.module] if node.module else []))
                else:
                    stem = node.module or ""
                # `from PKG import mod` imports the module PKG.mod; `from mod import name` the module.
                targets = [f"{stem}.{a.name}" if f"{stem}.{a.name}" in modules else stem for a in node.names]
            for target in dict.fromkeys(targets):
                while target and target not in modules and target.startswith("skeleton."):
                    target = target.rpartition(".")[0]   # `import a.b.c` of a name inside a module
                if target in modules and target != name:
                    edges.append(Edge(name, target, node.lineno, typing_only))
    return edges


def find_cycle(edges: list[Edge]) -> list[str] | None:
    """One import cycle among the edges, as the modules around it, or None."""
    graph: dict[str, list[str]] = {}
    for e in edges:
        graph.setdefault(e.source, []).append(e.target)
    return graphs.find_cycle(graph) or None


def _analysis_layer(module: str) -> int | None:
    parts = module.split(".")
    return ANALYSIS_LAYERS.get(parts[2]) if len(parts) > 2 and parts[1] == "analysis" else None


def _host_layer(module: str) -> int | None:
    parts = module.split(".")
    return HOST_LAYERS.get(parts[2]) if len(parts) > 2 and parts[1] == "host" else None


def _sysfile_rank(module: str) -> int | None:
    parts = module.split(".")
    return SYSFILE_ORDER.index(parts[3]) if parts[1:3] == ["host", "sysfile"] and len(parts) == 4 \
        and parts[3] in SYSFILE_ORDER else None


def layer_violations(edges: list[Edge]) -> list[str]:
    bad: list[str] = []
    for e in edges:
        low, high = _analysis_layer(e.target), _analysis_layer(e.source)
        if low is not None and high is not None and low > high:
            bad.append(f"analysis imports upward: {e}")
        if e.source.startswith("skeleton.analysis") and e.target.startswith("skeleton.host") \
                and e.target != "skeleton.host.model":
            bad.append(f"analysis imports host beyond its model: {e}")
        low, high = _host_layer(e.target), _host_layer(e.source)
        if low is not None and high is not None and low > high:
            bad.append(f"host imports upward (model < sysfile < theory < live < console, cli): {e}")
        low, high = _sysfile_rank(e.target), _sysfile_rank(e.source)
        if low is not None and high is not None and low >= high:
            bad.append(f"sysfile imports against schema -> link -> rules -> system: {e}")
    return bad


def test_no_import_cycle() -> None:
    edges = [e for e in import_graph(project_modules()) if not e.typing_only]
    cycle = find_cycle(edges)
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_layers_hold() -> None:
    assert layer_violations(import_graph(project_modules())) == []


def test_the_graph_sees_late_and_relative_imports(tmp_path: Path) -> None:
    """The checks above would pass vacuously if the graph missed imports: it must see a late,
    a relative and a package-relative import, and find the cycle they make."""
    sysfile = "skeleton.host.sysfile"
    modules = {sysfile: tmp_path / "__init__.py", f"{sysfile}.system": tmp_path / "system.py",
               f"{sysfile}.rules": tmp_path / "rules.py", f"{sysfile}.spawn": tmp_path / "spawn.py"}
    modules[sysfile].write_text("")
    modules[f"{sysfile}.system"].write_text("def build():\n    from .rules import resolve\n")
    modules[f"{sysfile}.rules"].write_text("from . import spawn\nfrom .system import Dpu\n")
    modules[f"{sysfile}.spawn"].write_text(f"if TYPE_CHECKING:\n    from {sysfile}.rules import X\n")
    edges = import_graph(modules)
    assert {(e.source, e.target, e.typing_only) for e in edges} == {
        (f"{sysfile}.system", f"{sysfile}.rules", False),
        (f"{sysfile}.rules", f"{sysfile}.spawn", False),
        (f"{sysfile}.rules", f"{sysfile}.system", False),
        (f"{sysfile}.spawn", f"{sysfile}.rules", True)}
    assert find_cycle(edges) is not None
    assert any(f"rules -> {sysfile}.system" in v for v in layer_violations(edges))


def _write(tmp_path: Path, sources: dict[str, str]) -> dict[str, Path]:
    """Synthetic modules in a tree like the project's: a name's dots are folders."""
    modules: dict[str, Path] = {}
    for name, text in sources.items():
        parts = name.split(".")[1:]
        path = tmp_path.joinpath(*parts, "__init__.py") if name.count(".") < 3 else \
            tmp_path.joinpath(*parts[:-1], parts[-1] + ".py")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        modules[name] = path
    return modules


def test_a_back_import_between_host_packages_is_reported(tmp_path: Path) -> None:
    """theory/ importing live/ (a package above it), or analysis/ importing more of host/ than its
    model, is a violation; the same imports downward are not."""
    modules = _write(tmp_path, {
        "skeleton.host": "", "skeleton.host.theory": "", "skeleton.host.live": "",
        "skeleton.host.theory.predict": "from ..live.run import run\nfrom ..model import System\n",
        "skeleton.host.live.run": "from ..theory.predict import predict\n",
        "skeleton.host.model": "",
        "skeleton.analysis": "", "skeleton.analysis.measure": "",
        "skeleton.analysis.measure.run": "from skeleton.host.model import System\n"
                                         "from skeleton.host.live.run import run\n"})
    edges = import_graph(modules)
    assert {(e.source, e.target) for e in edges} >= {
        ("skeleton.host.theory.predict", "skeleton.host.live.run"),
        ("skeleton.host.live.run", "skeleton.host.theory.predict")}
    bad = layer_violations(edges)
    assert [v.split(":")[0] for v in bad] == [
        "host imports upward (model < sysfile < theory < live < console, cli)",
        "analysis imports host beyond its model"], bad
    assert "skeleton.host.theory.predict -> skeleton.host.live.run" in bad[0]
    assert "skeleton.analysis.measure.run -> skeleton.host.live.run" in bad[1]


# A fresh interpreter with the third-party libraries imported forks a child per module: each
# child imports one of ours into an interpreter that holds none of them, as a fresh one would,
# without paying numpy's, pydantic's and rich's imports again each time (a fresh interpreter per
# module took 21-54 s of CI).
_FORK_SERVER = """
import collections, json, os, sys, traceback
import lcm, numpy, pydantic, rich.console, yaml, skelmsg
assert not [m for m in sys.modules if m == "skeleton" or m.startswith("skeleton.")]
def start(module):
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(r)
        try:
            __import__(module)
            os._exit(0)
        except BaseException:
            os.write(w, traceback.format_exc().strip().splitlines()[-1].encode())
            os._exit(1)
    os.close(w)
    return module, pid, r
def finish(module, pid, r):
    with os.fdopen(r, "rb") as out:
        error = out.read().decode(errors="replace")
    _, status = os.waitpid(pid, 0)
    print(json.dumps([module, os.waitstatus_to_exitcode(status), error]), flush=True)
running = collections.deque()  # two children at a time, one per core, answered in order
for module in json.loads(sys.stdin.read()):
    running.append(start(module))
    if len(running) == 2:
        finish(*running.popleft())
while running:
    finish(*running.popleft())
"""


def _import_each_alone(modules: list[str]) -> dict[str, str]:
    """Per module whose import fails when it is the first of ours imported: its error."""
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    done = subprocess.run([sys.executable, "-c", _FORK_SERVER], cwd=REPO, env=env, input=json.dumps(modules),
                          capture_output=True, text=True, timeout=500)
    assert done.returncode == 0, done.stderr
    results = [json.loads(line) for line in done.stdout.splitlines()]
    assert [m for m, _, _ in results] == modules, done.stderr
    return {m: error or f"exit {code}" for m, code, error in results if code != 0}


@pytest.mark.timeout(600)
def test_every_module_imports_alone() -> None:
    """Each module first of ours in its interpreter: an import that works only after another module
    was imported first (a cycle held apart by import order) fails here."""
    assert _import_each_alone(sorted(project_modules())) == {}
    # and the check sees a failure
    assert _import_each_alone(["skeleton.host.cli", "skeleton.no_such_module"]) == {
        "skeleton.no_such_module": "ModuleNotFoundError: No module named 'skeleton.no_such_module'"}


def _badly_named(name: str, path: Path, node: ast.Import | ast.ImportFrom) -> bool:
    """host/ names host/ relatively and analysis/ absolutely: is this import the other way round?"""
    if isinstance(node, ast.ImportFrom) and node.level:
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        base = package.split(".")
        return not ".".join(base[: len(base) - (node.level - 1)]).startswith("skeleton.host")
    names = [node.module or ""] if isinstance(node, ast.ImportFrom) else [a.name for a in node.names]
    return any(n.split(".")[0] == "skeleton" and not n.startswith("skeleton.analysis") for n in names)


def test_host_imports_host_relatively_and_analysis_absolutely() -> None:
    """Inside host/ a sibling is `from .control`, another package of host/ `from ..sysfile.system`;
    the analysis, another folder, is `from skeleton.analysis.measure.run` (no `...analysis`)."""
    bad = [f"{path.relative_to(REPO)}:{node.lineno}" for name, path in project_modules().items()
           if name.startswith("skeleton.host")
           for node, _ in _imports(ast.parse(path.read_text())) if _badly_named(name, path, node)]
    assert bad == []

"""The fuzzers' seed corpus in the repository is what tests/fuzz/seeds.py makes today: a
change to a message, an example or the host's encoding must regenerate it, or libFuzzer
would start from bytes no host sends any more."""

from __future__ import annotations

import importlib.util
import sys
from types import ModuleType

from conftest import REPO

FUZZ = REPO / "tests" / "fuzz"


def _seeds() -> ModuleType:
    spec = importlib.util.spec_from_file_location("seeds", FUZZ / "seeds.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_the_committed_seeds_are_what_seeds_py_makes() -> None:
    made: dict[str, bytes] = _seeds().seeds()
    committed = {f"{p.parent.name}/{p.name}": p.read_bytes() for p in (FUZZ / "corpus").glob("*/*")}
    fix = "run `.venv/bin/python tests/fuzz/seeds.py` and commit tests/fuzz/corpus"
    assert sorted(committed) == sorted(made), fix
    assert [name for name in made if made[name] != committed[name]] == [], fix


def test_every_harness_has_seeds_and_every_seed_folder_a_harness() -> None:
    harnesses = {p.stem.removeprefix("fuzz_") for p in FUZZ.glob("fuzz_*.c")}
    assert harnesses == {"buffer", "event", "config", "command", "seal"}
    # Every harness is one `make fuzz` and the CI smoke run.
    listed = next(line for line in (REPO / "Makefile").read_text().splitlines()
                  if line.startswith("FUZZ_HARNESSES"))
    assert set(listed.split(":=")[1].split()) == harnesses
    assert {p.name for p in (FUZZ / "corpus").iterdir()} == harnesses
    regressions = FUZZ / "regressions"
    assert {p.name for p in regressions.iterdir()} <= harnesses

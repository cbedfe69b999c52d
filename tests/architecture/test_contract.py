"""The wire contract's names and limits: one source (lcmtypes/contract.txt), the same in C and in
Python, and written down nowhere else.

A small C program, built as the DPU is (its dpu.h, the generated headers, -Werror), prints every
constant as the DPU's code sees it; skelmsg.contract must hold the same names and values. A value
hand-written again in dpu.h, or a generated file edited or stale, fails here.
"""

from __future__ import annotations

import functools
import importlib.util
import re
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import lcm
import pytest
from conftest import REPO

import skelmsg.contract as contract

SOURCE = REPO / "lcmtypes" / "contract.txt"
LCM_PREFIX = Path(lcm.__file__).resolve().parent.parent


@functools.cache
def _contractgen() -> ModuleType:
    spec = importlib.util.spec_from_file_location("contractgen", REPO / "lcmtypes" / "contractgen.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def _source() -> dict[str, str | int | float]:
    return {c.name: c.value for c in _contractgen().parse(SOURCE)}


def _c_values(tmp_path: Path, names: list[str]) -> dict[str, str | int | float]:
    """Each SKEL_<name> as a C file that includes dpu.h sees it."""
    prints = "\n".join(f'    P("{name}", SKEL_{name});' for name in names)
    program = tmp_path / "contract.c"
    program.write_text(f"""\
#include <stdio.h>
#include "dpu.h"

static void p_text(const char *name, const char *v) {{ printf("%s s %s\\n", name, v); }}
static void p_int(const char *name, long long v) {{ printf("%s i %lld\\n", name, v); }}
static void p_real(const char *name, double v) {{ printf("%s f %.17g\\n", name, v); }}
#define P(name, v) \\
    _Generic((v), char *: p_text, const char *: p_text, double: p_real, default: p_int)(name, v)

int main(void)
{{
{prints}
    return 0;
}}
""")
    binary = tmp_path / "contract"
    subprocess.run(["make", "--no-print-directory", "-s", "build/gen/c/skelmsg_contract.h"], cwd=REPO,
                   check=True, capture_output=True)
    built = subprocess.run(["cc", "-std=c11", "-D_GNU_SOURCE", "-Wall", "-Wextra", "-Werror",
                            f"-I{REPO / 'build' / 'gen' / 'c'}", f"-I{REPO / 'dpu'}", f"-I{REPO / 'include'}",
                            f"-I{LCM_PREFIX / 'include'}", "-o", str(binary), str(program)],
                           capture_output=True, text=True)
    assert built.returncode == 0, built.stderr
    out = subprocess.run([str(binary)], capture_output=True, text=True, check=True).stdout
    values: dict[str, str | int | float] = {}
    for line in out.splitlines():
        name, kind, value = line.split(" ", 2)
        values[name] = value if kind == "s" else float(value) if kind == "f" else int(value)
    return values


def test_python_holds_every_constant_of_the_source_and_no_other() -> None:
    source = _source()
    assert source, "lcmtypes/contract.txt defines nothing"
    python = {name: value for name, value in vars(contract).items() if name.isupper()}
    assert python == source


def test_c_and_python_agree_on_every_constant(tmp_path: Path) -> None:
    source = _source()
    assert _c_values(tmp_path, sorted(source)) == {name: getattr(contract, name) for name in source}


def test_the_c_check_sees_a_value_written_again(tmp_path: Path) -> None:
    """The comparison above can fail: a C file that defines a contract name again does not build."""
    (tmp_path / "dpu.h").write_text('#include "skelmsg_contract.h"\n#define SKEL_MAX_IO 17\n')
    program = tmp_path / "drift.c"
    program.write_text('#include "dpu.h"\nint main(void) { return SKEL_MAX_IO; }\n')
    built = subprocess.run(["cc", "-std=c11", "-Wall", "-Werror", f"-I{tmp_path}",
                            f"-I{REPO / 'build' / 'gen' / 'c'}", "-o", str(tmp_path / "drift"), str(program)],
                           capture_output=True, text=True)
    assert built.returncode != 0 and "SKEL_MAX_IO" in built.stderr, built.stderr


# Quoted channel names and the default URL: the values only the generated files may spell out.
CODE = [*(REPO / "dpu").glob("*.[ch]"), *(REPO / "tests" / "c").glob("*.[ch]")] + [
    path for folder in ("host", "analysis", "bench", "tests") for path in (REPO / folder).rglob("*.py")
    if path.name != "test_contract.py"]


@pytest.mark.parametrize("name", [n for n, v in _source().items() if isinstance(v, str)])
def test_no_code_writes_a_contract_text_by_hand(name: str) -> None:
    value = str(getattr(contract, name))
    quoted = re.compile(rf"""["']{re.escape(value)}["']""")
    copies = [f"{path.relative_to(REPO)}:{number}" for path in CODE
              for number, line in enumerate(path.read_text().splitlines(), 1) if quoted.search(line)]
    assert not copies, f"{name} ({value!r}) written by hand; use skelmsg.contract / SKEL_{name}: {copies}"


def test_sizes_on_the_wire_are_lcm_gens_encodings() -> None:
    """contract.txt's sizeof()/offsetof() are computed from the .lcm files: they must be what
    lcm-gen's encoder writes (an empty payload and an empty name are the fixed parts alone)."""
    import skelmsg
    assert contract.BUFFER_HEADER_BYTES == len(skelmsg.buffer_t().encode())
    name = skelmsg.event_t()
    name.name = ""
    assert contract.EVENT_HEADER_BYTES == len(name.encode()) - 4 - 1  # a string: int32 length, bytes, NUL
    seal = skelmsg.seal_t()
    seal.mac = bytes(32)   # the encoder writes what it holds: a whole mac, as every seal has
    assert contract.SEAL_BYTES == len(seal.encode())
    assert contract.SEAL_SIGNED_BYTES == contract.SEAL_BYTES - len(seal.mac)


@pytest.mark.parametrize(("written", "problem"), [
    ("offsetof(config_t, source)", "has no fixed size"),   # a string and arrays come before it
    ("offsetof(seal_t, nothing)", "has no field nothing"),
    ("sizeof(buffer_t)", "has no fixed size"),
    ("sizeof(seal_t, mac)", "sizeof(message) or offsetof(message, field)")])
def test_a_size_that_cannot_be_computed_is_refused(written: str, problem: str, tmp_path: Path) -> None:
    source = tmp_path / "contract.txt"
    source.write_text(f"X = {written}\n")
    for lcm_file in (REPO / "lcmtypes").glob("*.lcm"):
        (tmp_path / lcm_file.name).write_text(lcm_file.read_text())
    with pytest.raises(SystemExit, match=re.escape(problem)):
        _contractgen().parse(source)

"""The system file loaded: load() reads, overrides (`-s`) and validates one into a System
(host/model.py), which the rest of the host uses.

The schema (what each field may be) is schema.py's, the checks across sections
rules.py's; wire.py turns a System into the config_t every DPU configures itself from.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from skelmsg import contract

from ..model import Reference, ReferenceDpu, RunRules, System
from .link import writer_ports, writer_url
from .overrides import OverrideError, apply_overrides
from .rules import Invalid, resolve
from .schema import (
    DEFAULT_LINK,
    DEFAULT_RUN_CYCLES,
    BufferSpec,
    DpuSpec,
    EventSpec,
    LinkSpec,
    ProcessSpec,
    Run,
    SystemSpec,
)
from .schema import Reference as ReferenceSpec
from .yamlfile import SystemFileError, describe, field_path, parse_yaml, read_yaml

__all__ = ["SystemFileError", "load", "loads", "with_url"]


# --- loading -------------------------------------------------------------------------------

def load(path: str | Path, overrides: Sequence[str] = ()) -> System:
    """Read, override (`-s TARGET=VALUE`) and validate a system file."""
    text, doc = read_yaml(path)
    if overrides:
        return _build(path, doc, tuple(overrides))
    return _build(path, doc, (), text)


def loads(text: str, path: str | Path) -> System:
    """A system file's TEXT, validated as if it were the file at PATH (a `samples:` file is
    looked for beside it): `skel allocate`'s candidates before they are written."""
    return _build(path, parse_yaml(path, text), (), text)


def with_url(system: System, url: str) -> System:
    """A copy whose default link uses `url` (tests give each run its own port)."""
    if url == system.default_link.url:
        return system  # keeps source_text exactly as written
    return _build(system.path, system.document,
                  (*system.overrides, f"link.{system.default_link.name}.url={url}"))


def _build(path: str | Path, doc: Any, overrides: tuple[str, ...], text: str | None = None) -> System:
    if doc is None:
        raise SystemFileError(path, "top level", "the file is empty; a system file needs at least "
                              "system, dpus and processes")
    origin: dict[str, str] = {}
    if overrides:
        fields = {"processes": ProcessSpec.model_fields.keys(), "dpus": DpuSpec.model_fields.keys(),
                  "buffers": BufferSpec.model_fields.keys(), "links": LinkSpec.model_fields.keys(),
                  "events": EventSpec.model_fields.keys(),
                  "run": Run.model_fields.keys()}
        try:
            default_links = [{"name": DEFAULT_LINK, "url": contract.DEFAULT_URL}]
            doc, origin = apply_overrides(doc, overrides, fields, default_links)
        except OverrideError as e:
            raise SystemFileError(path, f"-s {e.override}", str(e)) from None
        header = "".join(f"# -s {o}\n" for o in overrides)
        text = f"# {path} with overrides:\n{header}" + yaml.safe_dump(doc, sort_keys=False)
    try:
        spec = SystemSpec.model_validate(doc)
        parts = resolve(spec, Path(path).parent)
    except ValidationError as e:
        error = _first(e.errors())
        where = field_path(tuple(error["loc"]), doc)
        raise SystemFileError(path, where, describe(error, SystemSpec) + _blame(where, origin)) from None
    except Invalid as e:
        raise SystemFileError(path, e.path, e.problem + _blame(e.path, origin)) from None
    run = spec.run
    if run.cycles is None and run.duration_s is None:
        run = run.model_copy(update={"cycles": DEFAULT_RUN_CYCLES})
    links = {link.id: link for link in parts.links}
    ports = writer_ports(parts.links, ((b.link, b.writer) for b in parts.buffers))
    urls = {b.id: "" if links[b.link].local else writer_url(links[b.link].url, ports[b.link, b.writer])
            for b in parts.buffers}
    return System(
        name=spec.system, path=Path(path), source_text=text or "", links=parts.links, dpus=parts.dpus,
        buffers=parts.buffers, processes=parts.processes, run=_run_rules(run), chains=parts.chains,
        reference=_reference(spec.reference), events=parts.events, overrides=overrides, document=doc,
        writer_ports=ports, buffer_urls=urls,
    )


def _run_rules(run: Run) -> RunRules:
    return RunRules(cycles=run.cycles, duration_s=run.duration_s, warmup_cycles=run.warmup_cycles,
                    lockout_cycles=run.lockout_cycles, stop_on=tuple(run.stop_on), late_pct=run.late_pct,
                    too_late_pct=run.too_late_pct, seed=run.seed, network=run.network)


def _reference(spec: ReferenceSpec | None) -> Reference | None:
    if spec is None:
        return None
    return Reference(spec.source, {i: ReferenceDpu(**row.model_dump()) for i, row in spec.dpus.items()})


def _first(errors: Sequence[Any]) -> Any:
    """The first error, except that a typo beats the missing key it causes (`period:` for `period_us:`)."""
    first = errors[0]
    if first["type"] == "missing":
        parent = tuple(first["loc"][:-1])
        for error in errors:
            if error["type"] == "extra_forbidden" and tuple(error["loc"][:-1]) == parent:
                return error
    return first


def _blame(where: str, origin: dict[str, str]) -> str:
    for target, override in origin.items():
        if where == target or where.startswith((target + ".", target + "[")):
            return f" (set by -s {override})"
    return ""

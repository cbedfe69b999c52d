"""The system file loaded: load() reads, overrides (`-s`) and validates one into a System,
which the rest of the host uses.

The schema (what each field may be) is schema.py's, the checks across sections
rules.py's; wire.py turns a System into the config_t every DPU configures itself from.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from skelmsg import contract

from .link import control_link, writer_ports, writer_url
from .overrides import OverrideError, apply_overrides
from .rules import Invalid, resolve
from .schema import (
    DEFAULT_LINK,
    DEFAULT_RUN_CYCLES,
    Buffer,
    BufferSpec,
    Chain,
    Dpu,
    DpuSpec,
    Event,
    EventSpec,
    Link,
    LinkSpec,
    Process,
    ProcessSpec,
    Reference,
    Run,
    SystemSpec,
)
from .yamlfile import SystemFileError, describe, field_path, parse_yaml, read_yaml

__all__ = ["System", "SystemFileError", "load", "loads"]


@dataclass(frozen=True)
class System:
    """A validated system file: what the host broadcasts, runs and reports on."""
    name: str
    path: Path
    source_text: str                # the YAML used: the file, or its re-dump after overrides
    links: tuple[Link, ...]
    dpus: tuple[Dpu, ...]
    buffers: tuple[Buffer, ...]
    processes: tuple[Process, ...]
    run: Run
    chains: tuple[Chain, ...]
    reference: Reference | None
    events: tuple[Event, ...] = ()
    overrides: tuple[str, ...] = ()
    document: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    # Lookups raise KeyError: after validation a missing id is the caller's bug.
    def link(self, key: int | str) -> Link:
        return _lookup(self.links, key, "link")

    def dpu(self, dpu_id: int) -> Dpu:
        return _lookup(self.dpus, dpu_id, "DPU")

    def buffer(self, key: int | str) -> Buffer:
        return _lookup(self.buffers, key, "buffer")

    def process(self, key: int | str) -> Process:
        return _lookup(self.processes, key, "process")

    def processes_on(self, dpu_id: int) -> list[Process]:
        """The DPU's processes in the order its minor cycle runs them."""
        return sorted((p for p in self.processes if p.dpu == dpu_id), key=lambda p: p.order)

    def readers(self, buffer_id: int) -> list[Process]:
        return [p for p in self.processes if buffer_id in p.inputs]

    @functools.cached_property
    def writer_ports(self) -> dict[tuple[int, int], int]:
        """(link id, writer process id) -> the port its buffers travel on (host/sysfile/link.py)."""
        return writer_ports(self.links, ((b.link, b.writer) for b in self.buffers))

    def buffer_url(self, key: int | str) -> str:
        """The URL a buffer travels on: its writer's group and port on its link; "" on a local link."""
        b = self.buffer(key)
        link = self.link(b.link)
        return "" if link.local else writer_url(link.url, self.writer_ports[b.link, b.writer])

    @property
    def default_link(self) -> Link:
        """The first udpm link: buffers without a `link:` use it, and so does control traffic."""
        found = control_link(self.links)
        assert found is not None, "rules._links refuses a system without a udpm link"
        return found

    @property
    def critical_period_us(self) -> int:
        """The shortest period of the clock-driven processes (`run.cycles` counts these): an
        event process's period only bounds how often it may run."""
        clocked = [p.period_us for p in self.processes if p.sync != "event"]
        return min(clocked or [p.period_us for p in self.processes])

    def static_load(self, worst: bool = False) -> dict[int, float]:
        """Per DPU, the fraction of its time its processes compute: Σ compute/period / speed,
        with each varying compute at its mean, or at its maximum when `worst`."""
        def compute(p: Process) -> float:
            return p.worst_compute_us if worst else p.compute_us
        return {
            d.id: sum(compute(p) / p.period_us for p in self.processes if p.dpu == d.id) / d.speed
            for d in self.dpus
        }

    def run_duration_ns(self, cycles: int | None = None, duration_s: float | None = None) -> int:
        """The run's length; arguments (the command line) beat the file's `run:` section.
        Cycles count the critical (shortest) period and include the warm-up."""
        if cycles is not None and duration_s is not None:
            raise ValueError("give cycles or a duration, not both")
        if cycles is None and duration_s is None:
            cycles, duration_s = self.run.cycles, self.run.duration_s
        if cycles is not None:
            if cycles < 1:
                raise ValueError(f"cycles must be at least 1, got {cycles}")
            return cycles * self.critical_period_us * 1000
        if duration_s is None or not duration_s > 0:
            raise ValueError(f"duration must be positive, got {duration_s}")
        return round(duration_s * 1e9)

    def with_url(self, url: str) -> System:
        """A copy whose default link uses `url` (tests give each run its own port)."""
        if url == self.default_link.url:
            return self  # keeps source_text exactly as written
        return _build(self.path, self.document, (*self.overrides, f"link.{self.default_link.name}.url={url}"))


def _lookup(items: Sequence[Any], key: int | str, noun: str) -> Any:
    for item in items:
        if (item.id if isinstance(key, int) else item.name) == key:
            return item
    raise KeyError(f"no {noun} {key!r}")


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
    return System(
        name=spec.system, path=Path(path), source_text=text or "", links=parts.links, dpus=parts.dpus,
        buffers=parts.buffers, processes=parts.processes, run=run, chains=parts.chains,
        reference=spec.reference, events=parts.events, overrides=overrides, document=doc,
    )


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

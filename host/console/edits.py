"""What the page may send, checked before anything uses it, and what an edit comes to.

An edit is a set of `-s TARGET=VALUE` overrides (host/sysfile/overrides.py), the paper's
"interactively available" descriptors: validated by the same load() and predicted by the same
predict() as `skel check -s`, so an invalid edit gets `skel check`'s one line.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from skeleton.analysis.errors import EXIT_BAD_INPUT, SkelError

from ..cli.check import summarize
from ..model import System
from ..sysfile import yamledit
from ..sysfile.system import SystemFileError, load, loads, with_url
from ..theory.predict import predict

MAX_BODY_BYTES = 64 * 1024  # a request body beyond this is refused (413) before it is parsed
MAX_EDITS = 256
TARGET = re.compile(r"^[A-Za-z0-9_]+(\.[A-Za-z0-9_-]+){0,2}$")
Scalar = str | int | float | bool
# A descriptor's value, as the system file writes it: a scalar, a list, or one mapping (a link's, a
# compute distribution's `varying:`); deeper nesting is no descriptor.
Value = Scalar | list[Scalar] | dict[str, Scalar | list[Scalar]] | None


class BadRequest(SkelError):
    """A request refused: its HTTP status and one line (the page shows it; nothing is sent)."""

    exit_code = EXIT_BAD_INPUT

    def __init__(self, status: int, line: str) -> None:
        super().__init__(line)
        self.status = status


class EditRequest(BaseModel):
    """{"set": {"process.executor.compute_us": 3000, ...}}: the descriptors changed."""

    model_config = ConfigDict(extra="forbid", strict=True)
    set: dict[str, Value] = Field(default_factory=dict, max_length=MAX_EDITS)


class DiffRequest(BaseModel):
    """{"a": RUN, "b": RUN}: two runs of the notebook, by their directory."""

    model_config = ConfigDict(extra="forbid", strict=True)
    a: str = Field(max_length=4096)
    b: str = Field(max_length=4096)


class PlotsRequest(BaseModel):
    """{"run": RUN}: a run of the notebook whose plots to draw."""

    model_config = ConfigDict(extra="forbid", strict=True)
    run: str = Field(max_length=4096)


def parse(body: bytes, model: type[BaseModel]) -> Any:
    """The body as `model`, or BadRequest(400) saying in one line what is wrong with it."""
    try:
        doc = json.loads(body)
    except (ValueError, RecursionError) as e:
        raise BadRequest(400, f"the body is not JSON: {e}") from None
    try:
        return model.model_validate(doc)
    except ValidationError as e:
        error = e.errors()[0]
        where = ".".join(str(part) for part in error["loc"]) or "the body"
        raise BadRequest(400, f"{where}: {error['msg']}") from None


def overrides(request: EditRequest) -> list[str]:
    """The edits as `-s` overrides, each value written as JSON (which YAML reads back as such)."""
    out = []
    for target, value in sorted(request.set.items()):
        if not TARGET.match(target):
            raise BadRequest(400, f"set: '{target[:80]}' is no descriptor (process.NAME.FIELD, "
                                  "dpu.ID.FIELD, buffer.NAME.FIELD, ...)")
        out.append(f"{target}={json.dumps(value)}" if value is not None else f"{target}=")
    return out


@dataclass(frozen=True)
class Evaluated:
    system: System | None
    summary: dict[str, Any] | None  # `skel check --json`'s
    error: str | None  # `skel check`'s one line

    def to_json(self) -> dict[str, Any]:
        if self.system is None or self.summary is None:
            return {"ok": False, "error": self.error}
        return {"ok": True, "summary": self.summary, "graph": graph(self.system)}


def evaluate(path: Path, edits: list[str], url: str | None = None) -> Evaluated:
    """`skel check FILE -s EDIT... [--url URL]`: the system and its summary, or the one line it prints."""
    try:
        system = load(path, edits)
        system = with_url(system, url) if url else system
    except SystemFileError as e:
        return Evaluated(None, None, str(e))
    prediction = predict(system)
    if prediction.errors:
        first = prediction.errors[0]
        return Evaluated(None, None, str(SystemFileError(system.path, first.path, first.problem)))
    return Evaluated(system, summarize(system, prediction), None)


def saved_text(path: Path, edits: list[str], system: System) -> str:
    """The file's text with the edits written in, comments kept (yamledit): refused unless it
    loads to the very system that was predicted."""
    try:
        text = yamledit.with_overrides(path.read_text(), edits)
        again = loads(text, path)
    except (ValueError, SystemFileError) as e:
        raise BadRequest(422, f"cannot save: {e}") from None
    if (again.dpus, again.processes, again.buffers, again.links, again.events, again.run) != (
            system.dpus, system.processes, system.buffers, system.links, system.events, system.run):
        raise BadRequest(422, "cannot save: the edited text would not load as the system predicted")
    return text


def graph(system: System) -> dict[str, Any]:
    """The system as the page draws it (Figure 8): hosts holding DPUs holding processes, buffers
    from their writer to their readers, events from their source to their awaiters, chains."""
    names = {p.id: p.name for p in system.processes}
    rates = {p.id: 1e6 / p.period_us for p in system.processes}
    readers: dict[int, list[tuple[str, bool]]] = {}
    for p in system.processes:
        for b in p.inputs:
            readers.setdefault(b, []).append((p.name, p.sync == "data" and b in p.required))
    hosts: dict[str, list[int]] = {}
    for d in system.dpus:
        hosts.setdefault(d.host, []).append(d.id)
    return {
        "hosts": [{"name": h, "dpus": ids} for h, ids in hosts.items()],
        "dpus": [{"id": d.id, "host": d.host, "compute": d.compute, "executive": d.executive,
                  "minor_cycle_us": d.minor_cycle_us} for d in system.dpus],
        "processes": [{"id": p.id, "name": p.name, "dpu": p.dpu, "period_us": p.period_us,
                       "compute_us": p.compute_us, "sync": p.sync, "event": p.event,
                       "varying": p.varying.kind if p.varying else None} for p in system.processes],
        "buffers": [{"id": b.id, "name": b.name, "bytes": b.bytes, "writer": names[b.writer],
                     "rate_hz": round(rates[b.writer], 3),
                     "readers": [{"process": r, "waits": w} for r, w in readers.get(b.id, [])]}
                    for b in system.buffers],
        "events": [{"name": n, "from": [p.name for p in system.processes if n in p.emits]
                    or [f"DPU {e.dpu}" if e.dpu else "host" for e in system.events if e.name == n],
                    "to": [p.name for p in system.processes if p.event == n]}
                   for n in sorted({p.event for p in system.processes if p.event})],
        "chains": [{"name": c.name, "processes": [names[i] for i in c.processes]} for c in system.chains],
        "run": {"cycles": system.run.cycles, "duration_s": system.run.duration_s},
    }

"""host/schema, rules, system and wire: the system-file schema, its rules, overrides and config_t."""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pytest
import yaml

import skelmsg
from skeleton.host.live.wire import config_message, dump_yaml
from skeleton.host.model import Code, System, from_config
from skeleton.host.sysfile.system import SystemFileError, load, with_url
from skelmsg.contract import DEFAULT_URL

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
SERVO = EXAMPLES / "servo.yaml"

Doc = dict[str, Any]




def base() -> Doc:
    """A small valid system: a (DPU 1) -> b (DPU 2, data-synchronised) -> c (DPU 2)."""
    return {
        "system": "t",
        "dpus": [{"id": 1}, {"id": 2}],
        "buffers": [{"id": 1, "name": "a_out", "bytes": 48}, {"id": 2, "name": "b_out", "bytes": 48}],
        "processes": [
            {"id": 1, "name": "a", "dpu": 1, "period_us": 5000, "compute_us": 1000, "outputs": ["a_out"]},
            {"id": 2, "name": "b", "dpu": 2, "period_us": 5000, "compute_us": 1000, "sync": "data",
             "inputs": ["a_out"], "outputs": ["b_out"]},
            {"id": 3, "name": "c", "dpu": 2, "period_us": 10000, "compute_us": 1000, "inputs": ["a_out", 2]},
        ],
    }


def write(tmp_path: Path, doc: Doc | str) -> Path:
    path = tmp_path / "sys.yaml"
    path.write_text(doc if isinstance(doc, str) else yaml.safe_dump(doc, sort_keys=False))
    return path


def error_of(tmp_path: Path, doc: Doc | str, overrides: Sequence[str] = ()) -> str:
    path = write(tmp_path, doc)
    with pytest.raises(SystemFileError) as caught:
        load(path, overrides)
    text = str(caught.value)
    assert "\n" not in text and "Traceback" not in text
    assert text.startswith(f"{path}: ")
    return text.removeprefix(f"{path}: ")


def proc(doc: Doc, name: str) -> dict[str, Any]:
    return next(p for p in doc["processes"] if p["name"] == name)


def _many(n: int) -> Callable[[Doc], None]:
    def edit(d: Doc) -> None:
        d["buffers"] = [{"id": i, "name": f"x{i}", "bytes": 8} for i in range(1, n + 1)]
        d["processes"] = [{"id": i, "name": f"p{i}", "dpu": 1, "period_us": 5000, "compute_us": 10,
                           "outputs": [i]} for i in range(1, n + 1)]
    return edit


def _set(path: str, value: Any) -> Callable[[Doc], None]:
    """An edit of `section.key.field` (process/buffer by name, DPU by id) or `key`."""
    def edit(d: Doc) -> None:
        parts = path.split(".")
        if len(parts) == 1:
            d[parts[0]] = value
            return
        if parts[0] == "run":
            d.setdefault("run", {})[parts[1]] = value
            return
        items = d[parts[0]]
        key = "id" if parts[0] == "dpus" else "name"
        item = next(i for i in items if str(i[key]) == parts[1])
        item[parts[2]] = value
    return edit


def _links(*links: dict[str, str]) -> Callable[[Doc], None]:
    return _set("links", list(links))


def _both(*edits: Callable[[Doc], None]) -> Callable[[Doc], None]:
    def edit(d: Doc) -> None:
        for e in edits:
            e(d)
    return edit


BUS = {"name": "bus", "url": DEFAULT_URL}
MEM = {"name": "mem", "url": "local"}
ROW = {"compute_pct": 1.0, "communicate_pct": 1.0, "wait_pct": 1.0}

ERRORS: list[tuple[str, Callable[[Doc], None], str]] = [
    # unknown keys (typos)
    ("top-level typo", _set("proceses", []), "proceses: unknown key; did you mean 'processes'?"),
    ("process typo", _set("processes.a.period", 5),
     "processes.a.period: unknown key; did you mean 'period_us'?"),
    ("typo of a required key", lambda d: proc(d, "a").update(period=proc(d, "a").pop("period_us")),
     "processes.a.period: unknown key; did you mean 'period_us'?"),
    ("dpu typo", _set("dpus.1.speeed", 1.0), "dpus.1.speeed: unknown key; did you mean 'speed'?"),
    ("run typo", _set("run.cycle", 5), "run.cycle: unknown key; did you mean 'cycles'?"),
    ("missing key", lambda d: d.pop("system"), "system: required key is missing"),
    # values
    ("negative period", _set("processes.a.period_us", -5),
     "processes.a.period_us: must be a positive number of microseconds, got -5"),
    ("negative compute", _set("processes.a.compute_us", -1),
     "processes.a.compute_us: must be 0 or more microseconds, got -1"),
    ("zero bytes", _set("buffers.a_out.bytes", 0),
     "buffers.a_out.bytes: must be a positive number of bytes, got 0"),
    ("absurd bytes", _set("buffers.a_out.bytes", 5 * 2**20),
     "buffers.a_out.bytes: 5242880 bytes is absurd for one buffer (limit 4 MiB = 4194304)"),
    ("quoted number", _set("processes.a.period_us", "5000"),
     "processes.a.period_us: must be an integer, got '5000'"),
    ("bool as number", _set("processes.a.period_us", True),
     "processes.a.period_us: must be an integer, got true"),
    ("compute mode", _set("dpus.1.compute", "fast"),
     "dpus.1.compute: must be one of 'sleep', 'wall', 'cpu' or 'work', got 'fast'"),
    ("speed", _set("dpus.1.speed", 0), "dpus.1.speed: must be a positive number, got 0"),
    # the wire contract's limits (MIN_SPEED..MAX_SPEED, MAX_NAME, MIN_RATE_HZ..MAX_RATE_HZ): DPUs refuse more
    ("speed too small", _set("dpus.1.speed", 1e-300), "dpus.1.speed: must be from 0.001 to 1000, got 1e-300"),
    ("speed too large", _set("dpus.1.speed", 1e6), "dpus.1.speed: must be from 0.001 to 1000, got 1e+06"),
    ("name too long", _set("processes.a.name", "n" * 53),
     f"processes.{'n' * 53}.name: must be at most 52 characters (it names an LCM channel), got 53: "
     f"'{'n' * 53}'"),
    ("dpu id range", _set("dpus.2.id", 40000), "dpus.40000.id: must be an id from 1 to 32767, got 40000"),
    ("bad name", _set("processes.a.name", "a.b"),
     "processes.a.b.name: must be a name of letters, digits and _ not starting with a digit, got 'a.b'"),
    ("stop_on", _set("run.stop_on", ["crash"]),
     "run.stop_on[0]: must be one of 'lockout', 'jam', 'behind', 'stall' or 'dpu_lost', got 'crash'"),
    ("lockout_cycles", _set("run.lockout_cycles", 0), "run.lockout_cycles: must be at least 1 cycle, got 0"),
    ("cycles and duration", _both(_set("run.cycles", 10), _set("run.duration_s", 1.0)),
     "run: give cycles or duration_s, not both"),
    ("late pcts", _both(_set("run.late_pct", 50), _set("run.too_late_pct", 20)),
     "run: too_late_pct (20) must be at least late_pct (50)"),
    ("link url", _links({"name": "bus", "url": "tcp://x"}),
     "links.bus.url: must be `local` or an udpm:// URL, got 'tcp://x'"),
    ("unicast group", _links({"name": "bus", "url": "udpm://10.0.0.1:7667"}),
     "links.bus.url: udpm://10.0.0.1:7667: 10.0.0.1 is not a multicast group (224.0.0.0 to 239.255.255.255)"),
    ("cpu beyond the wire", _set("dpus.1.cpu", 40000), "dpus.1.cpu: must be at most 32767, got 40000"),
    ("only local links", _links(MEM),
     "links: needs at least one udpm:// link: the host reaches the DPUs over it"),
    ("no processes", _set("processes", []), "processes: needs at least 1 item(s)"),
    # duplicates
    ("duplicate dpu", _set("dpus", [{"id": 1}, {"id": 1}]), "dpus[1].id: duplicate id 1 (also dpus[0])"),
    ("duplicate process name", _set("processes.c.name", "a"),
     "processes[2].name: duplicate name 'a' (also processes[0])"),
    ("duplicate buffer id", _set("buffers.b_out.id", 1), "buffers[1].id: duplicate id 1 (also buffers[0])"),
    ("duplicate link", _links(BUS, BUS), "links[1].name: duplicate name 'bus' (also links[0])"),
    # references
    ("unknown dpu", _set("processes.a.dpu", 9), "processes.a.dpu: no DPU with id 9; DPUs: 1, 2"),
    ("unknown buffer id", _set("processes.c.inputs", ["a_out", 99]),
     "processes.c.inputs[1]: no buffer with id 99"),
    ("unknown buffer name", _set("processes.c.inputs", ["nope"]),
     "processes.c.inputs[0]: no buffer named 'nope'; buffers: a_out, b_out"),
    ("misspelt buffer name", _set("processes.c.inputs", ["a_ot"]),
     "processes.c.inputs[0]: no buffer named 'a_ot'; did you mean 'a_out'?"),
    ("input twice", _set("processes.c.inputs", ["a_out", 1]),
     "processes.c.inputs[1]: buffer 'a_out' is listed twice"),
    ("unknown buffer link", _set("buffers.a_out.link", "can"),
     "buffers.a_out.link: no link named 'can'; links: bus"),
    ("unknown dpu link", _set("dpus.2.links", ["can"]), "dpus.2.links[0]: no link named 'can'; links: bus"),
    ("no writer", lambda d: d["buffers"].append({"id": 3, "name": "c_out", "bytes": 8}),
     "buffers.c_out: no process writes it; list it in one process's outputs"),
    ("two writers", _both(_set("processes.c.inputs", ["b_out"]), _set("processes.c.outputs", ["a_out"])),
     "buffers.a_out: written by both 'a' and 'c'; a buffer has exactly one writer"),
    ("own output", _set("processes.b.inputs", ["a_out", "b_out"]),
     "processes.b.inputs[1]: reads its own output buffer 'b_out'"),
    ("required not an input", _set("processes.b.required", [2]),
     "processes.b.required[0]: 2 is not one of the process's inputs"),
    ("required with periodic", _set("processes.c.required", ["a_out"]),
     "processes.c.required: only a `sync: data` process waits for required inputs; "
     "remove `required` or set `sync: data`"),
    ("data sync without inputs", _set("processes.a.sync", "data"),
     "processes.a.sync: a `sync: data` process needs at least one required input; "
     "give it inputs or use `sync: periodic`"),
    ("too many inputs", _set("processes.c.inputs", list(range(1, 18))),
     "processes.c.inputs: 17 inputs; at most 16 per process"),
    ("too many outputs", _set("processes.a.outputs", list(range(1, 18))),
     "processes.a.outputs: 17 outputs; at most 16 per process"),
    # links and reach
    ("unreachable link", _both(_links(BUS, {"name": "can", "url": "udpm://239.255.76.67:7668?ttl=0"}),
                               _set("dpus.2.links", ["can"])),
     "processes.b.inputs[0]: DPU 2 cannot reach link 'bus' of buffer 'a_out'; add it to dpus.2.links"),
    ("local across DPUs", _both(_links(BUS, MEM), _set("buffers.a_out.link", "mem")),
     "processes.b.inputs[0]: buffer 'a_out' is on local link 'mem' inside DPU 1 (its writer 'a') "
     "but 'b' runs on DPU 2; a local link reaches only inside one DPU"),
    # timing
    ("absurd compute", _set("processes.a.compute_us", 600_000),
     "processes.a.compute_us: 600000 us is more than 100 periods (5000 us): absurd; "
     "both are in microseconds"),
    # compute times that vary
    ("empty bounds", _set("processes.a.compute_us", {"dist": "uniform", "min": 300, "max": 100}),
     "processes.a.compute_us: the bounds are empty: min 300 us > max 100 us"),
    ("distribution without a max", _set("processes.a.compute_us", {"dist": "normal", "mean": 900, "sd": 50}),
     "processes.a.compute_us: normal needs max (max bounds the worst case)"),
    ("unknown distribution", _set("processes.a.compute_us", {"dist": "gamma", "mean": 900, "max": 2000}),
     "processes.a.compute_us.dist: must be one of 'uniform', 'normal', 'lognormal' or 'exponential', "
     "got 'gamma'"),
    ("bounds holding nothing",
     _set("processes.a.compute_us", {"dist": "normal", "mean": 1000, "sd": 10, "min": 3000, "max": 4000}),
     "processes.a.compute_us.max: the bounds 3000..4000 us hold 0.0e+00 of this normal distribution: "
     "nothing to draw from; widen them or fix mean/sd"),
    ("missing samples file", _set("processes.a.compute_us", {"samples": "measured.csv"}),
     "processes.a.compute_us.samples: cannot read measured.csv: No such file or directory"),
    ("samples with bounds", _set("processes.a.compute_us", {"samples": "measured.csv", "max": 9}),
     "processes.a.compute_us: samples takes no max; the samples are used as measured"),
    ("absurd worst case", _set("processes.a.compute_us", {"dist": "uniform", "min": 100, "max": 600_000}),
     "processes.a.compute_us.max: 600000 us is more than 100 periods (5000 us): absurd; "
     "both are in microseconds"),
    ("not a multiple of the minor cycle", _set("dpus.2.minor_cycle_us", 3000),
     "processes.b.period_us: 5000 us is not a multiple of DPU 2's minor cycle (3000 us)"),
    ("minor cycle too short", _set("dpus.2.minor_cycle_us", 50),
     "dpus.2.minor_cycle_us: must be at least 100 us, got 50"),
    ("gcd too short", _set("processes.c.period_us", 5050),
     "dpus.2: minor cycle 50 us (the gcd of its periods 5000, 5050 us) is below 100 us; "
     "give the periods a larger common divisor or set minor_cycle_us"),
    ("too many processes", _many(65), "dpus.1: 65 processes; at most 64 per DPU"),
    ("duplicate order", _both(_set("processes.b.order", 1), _set("processes.c.order", 1)),
     "processes.c.order: order 1 is already taken on DPU 2 by 'b'"),
    # chains and reference
    ("chain unknown process", _set("chains", [["a", "zz"]]),
     "chains[0][1]: no process named 'zz'; processes: a, b, c"),
    ("chain not connected", _set("chains", [["b", "a"]]),
     "chains[0][1]: 'a' reads no buffer that 'b' writes"),
    ("named chain", _set("chains", [{"name": "main", "processes": ["a"]}]),
     "chains.main: a chain needs at least 2 processes"),
    ("chain typo", _set("chains", [{"name": "main", "proceses": ["a"]}]),
     "chains.main.proceses: unknown key; did you mean 'processes'?"),
    ("reference dpu", _set("reference", {"source": "x", "dpus": {7: ROW}}),
     "reference.dpus.7: no DPU with id 7"),
    # events (sync: event)
    ("event nobody emits", _both(_set("processes.a.sync", "event"), _set("processes.a.event", "tick")),
     "processes.a.event: event 'tick' is emitted by no process and generated by no `events:` entry; "
     "add one (kind: host to send it with `skel event`)"),
    ("event process without its event", _set("processes.a.sync", "event"),
     "processes.a.event: a `sync: event` process names the event it awaits"),
    ("queue without sync event", _set("processes.a.queue", 4),
     "processes.a.queue: only a `sync: event` process has queue; set `sync: event` or remove it"),
    ("queue too long", _both(_set("processes.a.sync", "event"), _set("processes.a.event", "tick"),
                             _set("processes.a.queue", 65),
                             _set("events", [{"name": "tick", "kind": "host"}])),
     "processes.a.queue: must be at most 64, got 65"),
    ("awaits what it emits", _both(_set("processes.a.sync", "event"), _set("processes.a.event", "tick"),
                                   _set("processes.a.emits", ["tick"])),
     "processes.a.emits: it emits the event 'tick' it awaits: it would run for ever on its own events"),
    ("event jitter", _set("events", [{"name": "t", "kind": "periodic", "dpu": 1, "period_us": 1000,
                                      "jitter_us": 500}]),
     "events.t: jitter_us 500 must be below half the period (1000 us): events would change order"),
    ("burst too long", _set("events", [{"name": "t", "kind": "bursts", "dpu": 1, "period_us": 1000,
                                        "count": 5, "spacing_us": 300}]),
     "events.t: a burst of 5 events 300 us apart does not fit in its period of 1000 us"),
    ("poisson without rate", _set("events", [{"name": "t", "kind": "poisson", "dpu": 1}]),
     "events.t: poisson needs rate_hz"),
    ("poisson rate too small", _set("events", [{"name": "t", "kind": "poisson", "dpu": 1, "rate_hz": 1e-9}]),
     "events.t.rate_hz: must be from 1e-06 to 1e+06, got 1e-09"),
    ("host event on a DPU", _set("events", [{"name": "t", "kind": "host", "dpu": 1}]),
     "events.t: host takes no dpu; the host sends it with `skel event`"),
    ("event generator DPU", _set("events", [{"name": "t", "kind": "poisson", "dpu": 9, "rate_hz": 5.0}]),
     "events.t.dpu: no DPU with id 9; DPUs: 1, 2"),
    ("event kind", _set("events", [{"name": "t", "kind": "often"}]),
     "events.t.kind: must be one of 'host', 'periodic', 'poisson' or 'bursts', got 'often'"),
    ("duplicate event", _set("events", [{"name": "t", "kind": "host"}, {"name": "t", "kind": "host"}]),
     "events[1].name: duplicate name 't' (also events[0])"),
    # a link's CPU costs (issue 44)
    ("negative link cost", _set("links", [{**BUS, "per_message_us": -1}]),
     "links.bus.per_message_us: must be a cost from 0 to 1e+06, got -1"),
    ("link cost not a number", _set("links", [{**BUS, "per_byte_ns": float("nan")}]),
     "links.bus.per_byte_ns: must be a cost from 0 to 1e+06, got nan"),
    ("link cost a units mistake", _set("links", [{**BUS, "push_byte_ns": 2e6}]),
     "links.bus.push_byte_ns: must be a cost from 0 to 1e+06, got 2e+06"),
    ("unknown link preset", _set("links", [{**BUS, "preset": "vme2"}]),
     "links.bus.preset: no preset 'vme2'; presets: vme, can-1m, ethernet-100m"),
    ("cost on a local link", _set("links", [BUS, {**MEM, "remote_read_us": 5}]),
     "links.mem: a `local` link is memory inside one DPU and charges no cost: give the cost to an "
     "udpm:// link"),
    ("link cost on a tasking DPU", _both(_set("links", [{**BUS, "remote_read_us": 5}]),
                                         _set("dpus.2.executive", "threads")),
     "dpus.2.executive: the tasking executive charges no link costs yet (process b would pay its links' "
     "per_message_us, per_byte_ns, push_byte_ns or remote_read_us): use `cyclic`, or links without costs"),
    ("code library a path", _set("processes.b.compute", {"library": "../lib/sum", "function": "sum_bytes"}),
     "processes.b.compute.library: must name a library (NAME for libNAME.so in the DPU's --lib-dir), not a "
     "path: got '../lib/sum'"),
    ("code library a file", _set("processes.b.compute", {"library": "libsum.so", "function": "sum_bytes"}),
     "processes.b.compute.library: must name a library (NAME for libNAME.so in the DPU's --lib-dir), not a "
     "path: got 'libsum.so'"),
    ("code without function", _set("processes.b.compute", {"library": "sum"}),
     "processes.b.compute.function: required key is missing"),
    ("code reading through an emulated latency",
     _both(_set("links", [{**BUS, "latency_us": 2000}]),
           _set("processes.b.compute", {"library": "sum", "function": "sum_bytes"})),
     "processes.b.compute: real code cannot read a_out through link bus's emulated latency or bandwidth yet"),
    ("code on threads", _both(_set("dpus.2.executive", "threads"),
                              _set("processes.b.compute", {"library": "sum", "function": "sum_bytes"})),
     "processes.b.compute: DPU 2 runs executive: threads; real code runs on the cyclic executive only"),
]


@pytest.mark.parametrize(("edit", "expected"), [(e, x) for _, e, x in ERRORS], ids=[n for n, _, _ in ERRORS])
def test_validation_error(tmp_path: Path, edit: Callable[[Doc], None], expected: str) -> None:
    doc = base()
    edit(doc)
    assert error_of(tmp_path, doc) == expected


def test_real_code_is_carried_beside_the_declared_compute(tmp_path: Path) -> None:
    """compute: names real code; compute_us stays the schedule's and the prediction's figure; the
    config carries both, and the dumped file reads back the same."""
    doc = base()
    proc(doc, "b")["compute"] = {"library": "sum", "function": "sum_bytes"}
    system = load(write(tmp_path, doc))
    b = system.process("b")
    assert b.code == Code("sum", "sum_bytes") and b.compute_us == 1000
    assert system.process("a").code is None
    sent = config_message(system, generation=1, run_id=0, committed=False)
    assert [(p.library, p.function) for p in sent.processes] == [("", ""), ("sum", "sum_bytes"), ("", "")]
    assert from_config(sent).process("b").code == b.code
    again = load(write(tmp_path, dump_yaml(system)))
    assert again.process("b").code == b.code


def test_base_is_valid(tmp_path: Path) -> None:
    system = load(write(tmp_path, base()))
    assert [d.minor_cycle_us for d in system.dpus] == [5000, 5000]
    assert system.process("b").required == (1,)
    assert system.process("c").inputs == (1, 2)
    assert system.buffer("b_out").writer == 2
    assert system.default_link.url == DEFAULT_URL
    assert system.run.cycles == 2000  # neither cycles nor duration_s: the default


def test_local_link_inside_one_dpu(tmp_path: Path) -> None:
    doc = base()
    doc["links"] = [BUS, {"name": "mem", "url": "local"}]
    doc["buffers"][1]["link"] = "mem"          # b_out: b -> c, both on DPU 2
    system = load(write(tmp_path, doc))
    assert system.buffer("b_out").link == system.link("mem").id
    assert system.link("mem").local
    config = config_message(system, 1, 0, committed=False)
    assert [link.url for link in config.links] == [DEFAULT_URL, ""]


def test_explicit_order_and_default_order(tmp_path: Path) -> None:
    doc = base()
    proc(doc, "c")["order"] = 1
    system = load(write(tmp_path, doc))
    assert [p.name for p in system.processes_on(2)] == ["c", "b"]
    assert load(write(tmp_path, base())).process("b").order == 1


@pytest.mark.parametrize(("text", "expected"), [
    ("system: x\ndpus: [\n", "line 3 column 1: expected the node content, but found '<stream end>' "
                             "(while parsing a flow node)"),
    ("system: x\n  dpus: 1\n", "line 2 column 7: mapping values are not allowed here"),
    ("system: x\ndpus:\n  - id: 1\n    id: 2\n", "line 4 column 5: duplicate key 'id'"),
    ("", "top level: the file is empty; a system file needs at least system, dpus and processes"),
    ("- 1\n", "top level: must be a mapping, got a list"),
])
def test_yaml_errors(tmp_path: Path, text: str, expected: str) -> None:
    assert error_of(tmp_path, text) == expected


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(SystemFileError, match=r"^.*nope\.yaml: cannot read: No such file or directory$"):
        load(tmp_path / "nope.yaml")


# --- overrides -------------------------------------------------------------------------------

def test_overrides_apply_before_validation(tmp_path: Path) -> None:
    path = write(tmp_path, base())
    system = load(path, ["process.a.compute_us=3000", "processes.b.compute_us=200", "dpu.2.compute=wall",
                         "buffer.a_out.bytes=96", "run.cycles=400", "run.lockout_cycles=5",
                         "process.3.period_us=20000", "link.bus.url=udpm://239.255.76.67:7701?ttl=0",
                         "system=renamed"])
    assert system.process("a").compute_us == 3000
    assert system.process("b").compute_us == 200
    assert system.process("c").period_us == 20000
    assert system.dpu(2).compute == "wall"
    assert system.buffer("a_out").bytes == 96
    assert (system.run.cycles, system.run.lockout_cycles) == (400, 5)
    assert system.default_link.url == "udpm://239.255.76.67:7701?ttl=0"
    assert system.name == "renamed"
    # The log must hold the exact configuration used: the re-dump loads to the same system.
    assert "# -s process.a.compute_us=3000" in system.source_text
    again = load(write(tmp_path, system.source_text))
    assert again.processes == system.processes and again.links == system.links and again.run == system.run


def test_override_duration_replaces_cycles(tmp_path: Path) -> None:
    doc = base()
    doc["run"] = {"cycles": 10}
    system = load(write(tmp_path, doc), ["run.duration_s=2.5"])
    assert (system.run.cycles, system.run.duration_s) == (None, 2.5)
    assert system.run_duration_ns() == 2_500_000_000


def test_override_empty_value_restores_default(tmp_path: Path) -> None:
    doc = base()
    doc["dpus"][1]["minor_cycle_us"] = 1000
    assert load(write(tmp_path, doc), ["dpu.2.minor_cycle_us="]).dpu(2).minor_cycle_us == 5000


@pytest.mark.parametrize(("override", "expected"), [
    ("process.nope.compute_us=1", "-s process.nope.compute_us=1: no process named 'nope'"),
    ("dpu.9.compute=wall", "-s dpu.9.compute=wall: no DPU with id 9"),
    ("buffer.x.bytes=1", "-s buffer.x.bytes=1: no buffer named 'x'"),
    ("link.can.url=local", "-s link.can.url=local: no link named 'can'"),
    ("process.a.compute_ms=1",
     "-s process.a.compute_ms=1: a process has no field 'compute_ms'; did you mean 'compute_us'?"),
    ("run.cycle=1", "-s run.cycle=1: run has no field 'cycle'; did you mean 'cycles'?"),
    ("dpu.1.xyz=1", "-s dpu.1.xyz=1: a DPU has no field 'xyz'; fields: compute, cpu, executive, host, id, "
                    "links, minor_cycle_us, speed"),
    ("foo.bar=1", "-s foo.bar=1: unknown target 'foo.bar'; use process.NAME.FIELD, dpu.ID.FIELD, "
                  "buffer.NAME.FIELD, link.NAME.FIELD, event.NAME.FIELD, run.FIELD or system"),
    ("run.cycles", "-s run.cycles: expected TARGET=VALUE"),
    ("run.cycles=[1",
     "-s run.cycles=[1: value is not valid YAML: expected ',' or ']', but got '<stream end>'"),
    ("process.a.period_us=-5", "processes.a.period_us: must be a positive number of microseconds, got -5 "
                               "(set by -s process.a.period_us=-5)"),
])
def test_override_errors(tmp_path: Path, override: str, expected: str) -> None:
    assert error_of(tmp_path, base(), [override]) == expected


# --- the SERVO example -----------------------------------------------------------------------

def test_servo_static_load_matches_table_1() -> None:
    system = load(SERVO)
    loads = system.static_load()
    assert system.reference is not None
    for dpu, row in system.reference.dpus.items():
        assert 100 * loads[dpu] == pytest.approx(row.compute_pct, abs=0.1)
    assert 100 * loads[1] == pytest.approx(90.3, abs=0.1)
    assert 100 * loads[4] == pytest.approx(96.5, abs=0.1)


def test_servo_executor_is_figure_9() -> None:
    system = load(SERVO)
    executor = system.process("executor")
    assert (executor.id, executor.dpu, executor.compute_us) == (4, 2, 3500)
    assert executor.inputs == (3, 5, 6, 7, 8) and executor.outputs == (4,)
    assert executor.sync == "periodic"
    assert all(b.writer == b.id for b in system.buffers)
    assert [d.minor_cycle_us for d in system.dpus] == [5000, 5000, 5000, 23800]
    assert system.critical_period_us == 5000
    assert system.run_duration_ns() == 10 * 10**9
    assert system.source_text == SERVO.read_text()


def test_servo_at_2_5_ms_overloads_dpus_1_to_3() -> None:
    loads = load(EXAMPLES / "servo-2.5ms.yaml").static_load()
    assert all(loads[d] > 1.0 for d in (1, 2, 3))
    assert loads[4] == pytest.approx(load(SERVO).static_load()[4])


def test_pair_example() -> None:
    system = load(EXAMPLES / "pair-10ms-5ms.yaml")
    assert system.readers(system.buffer("slow").id)[0].period_us == 5000
    assert system.readers(system.buffer("fast").id)[0].period_us == 10000
    assert {p.dpu for p in system.processes if p.outputs} == {1}


def test_run_duration() -> None:
    system = load(SERVO)
    assert system.run_duration_ns(cycles=10) == 50_000_000
    assert system.run_duration_ns(duration_s=1.5) == 1_500_000_000
    with pytest.raises(ValueError):
        system.run_duration_ns(cycles=10, duration_s=1.0)


def test_command_line_beats_the_run_section(tmp_path: Path) -> None:
    doc = base()
    doc["run"] = {"duration_s": 3.0}
    system = load(write(tmp_path, doc))
    assert system.run_duration_ns() == 3 * 10**9
    assert system.run_duration_ns(cycles=4) == 4 * 5000 * 1000


def test_with_url() -> None:
    system = load(SERVO)
    url = "udpm://239.255.76.67:7711?ttl=0"
    moved = with_url(system, url)
    assert moved.default_link.url == url and system.default_link.url != url
    assert url in moved.source_text and moved.processes == system.processes
    assert config_message(moved, 1, 0, committed=False).links[0].url == url
    assert with_url(system, system.default_link.url) is system


def test_to_config_round_trip() -> None:
    system = load(SERVO)
    sent = config_message(system, generation=7, run_id=42, committed=True)
    got = skelmsg.config_t.decode(sent.encode())
    assert (got.generation, got.run_id, got.committed, got.system) == (7, 42, 1, "servo")
    assert got.sent_utc_ns > 0 and got.source == system.source_text
    assert (got.warmup_cycles, got.lockout_cycles, got.late_pct, got.too_late_pct) == (100, 10, 20, 100)
    assert [(link.id, link.name, link.url) for link in got.links] == [(1, "bus", DEFAULT_URL)]
    sleep, cyclic = skelmsg.dpu_t.COMPUTE_SLEEP, skelmsg.dpu_t.EXECUTIVE_CYCLIC
    assert [(d.id, d.host, d.cpu, d.compute, d.executive, d.speed, d.minor_cycle_us, list(d.links))
            for d in got.dpus] == [(d.id, "localhost", -1, sleep, cyclic, 1.0, d.minor_cycle_us, [1])
                                   for d in system.dpus]
    assert [(b.id, b.name, b.bytes, b.link, b.writer, b.channel) for b in got.buffers] == [
        (b.id, b.name, b.bytes, 1, b.id, f"SKEL_BUF_{b.name}") for b in system.buffers]
    for p, m in zip(system.processes, got.processes, strict=True):
        assert (m.id, m.name, m.dpu, m.order, m.period_us, m.compute_us) == (
            p.id, p.name, p.dpu, p.order, p.period_us, p.compute_us)
        assert list(m.inputs) == list(p.inputs) and list(m.outputs) == list(p.outputs)
        assert m.ninputs == len(p.inputs) and m.noutputs == len(p.outputs)
        assert list(m.required) == [int(b in p.required) for b in p.inputs]
        data = p.sync == "data"
        assert m.sync == (skelmsg.process_t.SYNC_DATA if data else skelmsg.process_t.SYNC_PERIODIC)
    jt = got.processes[[p.name for p in system.processes].index("jacobian_transpose")]
    assert list(jt.required) == [1, 0, 0, 0]
    assert [(c.name, list(c.processes)) for c in got.chains] == [
        ("joint_sensors->jacobian_transpose->executor", [2, 3, 4]),
        ("joint_sensors->jacobian_transpose->force_control->executor", [2, 3, 6, 4])]


def test_dump_yaml_round_trip(tmp_path: Path) -> None:
    system = load(SERVO)
    again: System = load(write(tmp_path, dump_yaml(system)))
    for part in ("name", "links", "dpus", "buffers", "processes", "run", "chains", "reference"):
        assert getattr(again, part) == getattr(system, part), part


def test_loading_does_not_touch_the_document(tmp_path: Path) -> None:
    doc = base()
    before = copy.deepcopy(doc)
    load(write(tmp_path, doc), ["process.a.compute_us=10"])
    assert doc == before


def test_a_preset_gives_its_figures_and_a_field_beside_it_overrides(tmp_path: Path) -> None:
    doc = base()
    doc["links"] = [{**BUS, "preset": "vme", "push_byte_ns": 10}]
    link = load(write(tmp_path, doc)).link("bus")
    assert (link.push_byte_ns, link.remote_read_us, link.per_message_us, link.bandwidth_mbps) == (
        10, 58.8, 0, None)
    doc["links"] = [{**BUS, "preset": "can-1m"}]
    assert load(write(tmp_path, doc)).link("bus").bandwidth_mbps == 1


def test_servo_vme_is_servo_with_the_vme_preset(tmp_path: Path) -> None:
    vme = load(EXAMPLES / "servo-vme.yaml")
    doc = yaml.safe_load((EXAMPLES / "servo-vme.yaml").read_text())
    doc["links"] = [{"name": "bus", "url": doc["links"][0]["url"], "preset": "vme"}]
    assert load(write(tmp_path, doc)).links == vme.links

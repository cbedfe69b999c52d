"""The fuzzers' seed corpus: real messages, encoded by the generated skelmsg types and
host/live/wire.py as the host tool sends them, one folder per harness (tests/fuzz/fuzz_*.c).

    .venv/bin/python tests/fuzz/seeds.py    # (re)writes tests/fuzz/corpus/<harness>/

The files are committed; tests/unit/test_fuzz_seeds.py checks they are what this script
makes, so a change to a message, an example or the host's encoding regenerates them
instead of leaving libFuzzer to start from stale bytes.

What the harnesses expect (tests/fuzz/fuzz.h, tests/c/fixture.h) is repeated here: the
buffer and event harnesses' plan is the fixture's DPU 2 in run FUZZ_RUN_ID, reading
buffer 1 written by process 1 and, for events, awaiting the event "go"; the command
harness is `skel-dpu --id 1` and is handed only configs whose plan opens no socket.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
CORPUS = HERE / "corpus"
if str(REPO) not in sys.path:  # run as a script from anywhere
    sys.path.insert(0, str(REPO))

import skelmsg  # noqa: E402
from skeleton.analysis.read.seal import Signer  # noqa: E402
from skeleton.host.live.wire import config_message  # noqa: E402
from skeleton.host.model import System  # noqa: E402
from skeleton.host.sysfile.system import load, loads  # noqa: E402
from skelmsg import contract  # noqa: E402

FUZZ_RUN_ID = 1             # fuzz.h
FIXTURE_BUFFER = 1          # fixture.h: buffer 1, written by process 1, read on DPU 2
FIXTURE_WRITER = 1
FIXTURE_EVENT = "go"        # fuzz_fixture_plan(1): DPU 2's processes 2 and 3 await it
SESSION = 42                # the host tool that starts the command seeds' runs
OTHER_SESSION = 43
SENT_UTC_NS = 1_700_000_000_000_000_000  # fixed, so the seeds do not change at every run
FAR_UTC_NS = 4_102_444_800 * 10**9       # 2100-01-01: a START or COMMIT long ahead

# One DPU (1), every buffer on a local link: the command harness may apply it (no socket).
LOCAL_SYSTEM = f"""\
system: fuzz_local
links:
  - {{name: bus, url: "{contract.DEFAULT_URL}"}}
  - {{name: mem, url: local}}
dpus: [{{id: 1, links: [mem]}}]
buffers:
  - {{id: 1, name: state, bytes: 64, link: mem}}
  - {{id: 2, name: command, bytes: 32, link: mem}}
processes:
  - {{id: 1, name: sensor, dpu: 1, period_us: 5000, compute_us: 500, outputs: [state]}}
  - {{id: 2, name: control, dpu: 1, period_us: 10000, compute_us: 1000, sync: data,
     inputs: [state], outputs: [command]}}
  - {{id: 3, name: actuator, dpu: 1, period_us: 10000, compute_us: 200, inputs: [command]}}
run: {{cycles: 100}}
"""

# The same on the tasking executive, its compute varying: what a live switch between the two refuses.
LOCAL_TASKING = LOCAL_SYSTEM.replace("dpus: [{id: 1, links: [mem]}]",
                                     "dpus: [{id: 1, links: [mem], executive: threads}]").replace(
    "compute_us: 1000,", "compute_us: {dist: uniform, min: 800, max: 1200},")


def _config(system: System, generation: int, committed: bool, source: bool = True,
            session: int = 0, force: bool = False) -> bytes:
    msg = config_message(system, generation, run_id=0, committed=committed)
    msg.sent_utc_ns = SENT_UTC_NS
    msg.session, msg.force, msg.sender = session, int(force), "seeds pid 1" if session else ""
    if not source:
        msg.source = ""
    return bytes(msg.encode())


def _command(kind: int, seq: int, session: int = SESSION, force: bool = False, **fields: int) -> bytes:
    cmd = skelmsg.command_t()
    cmd.seq, cmd.kind, cmd.dpu = seq, kind, -1
    cmd.session, cmd.force, cmd.sender = session, int(force), f"seeds pid {session}"
    for name, value in fields.items():
        setattr(cmd, name, value)
    return bytes(cmd.encode())


def _frames(*messages: tuple[str, bytes]) -> bytes:
    """fuzz_command's input: per message [tag: 0 config, 1 command][length, 2 bytes][bytes]."""
    out = b""
    for channel, data in messages:
        assert len(data) < 1 << 16, "a frame holds at most 65535 bytes"
        out += bytes([0 if channel == "config" else 1]) + len(data).to_bytes(2, "big") + data
    return out


def _buffers() -> Iterator[tuple[str, bytes]]:
    for name, nbytes, run_id, buffer, seq in (
            ("accepted", 64, FUZZ_RUN_ID, FIXTURE_BUFFER, 0), ("empty", 0, FUZZ_RUN_ID, FIXTURE_BUFFER, 3),
            ("large", 1000, FUZZ_RUN_ID, FIXTURE_BUFFER, 12), ("other-run", 64, 77, FIXTURE_BUFFER, 1),
            ("other-buffer", 64, FUZZ_RUN_ID, 2, 1)):
        msg = skelmsg.buffer_t()
        msg.run_id, msg.writer, msg.buffer, msg.seq = run_id, FIXTURE_WRITER, buffer, seq
        msg.send_ns, msg.nbytes = 5_000_000 * seq, nbytes
        # dpu/plan.c's dummy payload pattern, as a DPU publishes it
        msg.payload = bytes(0xA5 ^ (i & 0xFF) for i in range(nbytes))
        yield name, bytes(msg.encode())


def _events() -> Iterator[tuple[str, bytes]]:
    for name, run_id, dpu, process, seq in (
            ("host", 0, 0, 0, 0), ("generated", FUZZ_RUN_ID, 2, 0, 5), ("emitted", FUZZ_RUN_ID, 1, 5, 9),
            ("other-run", 77, 1, 5, 2)):
        msg = skelmsg.event_t()
        msg.run_id, msg.dpu, msg.process, msg.seq = run_id, dpu, process, seq
        msg.sent_ns, msg.name = 1_000_000 * (seq + 1), FIXTURE_EVENT
        yield name, bytes(msg.encode())


def _configs() -> Iterator[tuple[str, bytes]]:
    for path in sorted((REPO / "examples").glob("*.yaml")):
        system = load(path)
        yield path.stem, _config(system, 1, committed=True)
        yield f"{path.stem}-nosource", _config(system, 2, committed=False, source=False)
    yield "local", _config(loads(LOCAL_SYSTEM, HERE / "local.yaml"), 1, committed=True)
    yield "local-tasking", _config(loads(LOCAL_TASKING, HERE / "local.yaml"), 1, committed=True)


def _commands() -> Iterator[tuple[str, bytes]]:
    local = loads(LOCAL_SYSTEM, HERE / "local.yaml")
    tasking = loads(LOCAL_TASKING, HERE / "local.yaml")
    c = skelmsg.command_t
    g1 = ("config", _config(local, 1, committed=True, session=SESSION))
    start = ("command", _command(c.START, 10, generation=1, run_id=7, duration_ns=10**9))
    stop = ("command", _command(c.STOP, 11))
    yield "apply", _frames(g1)
    yield "stage-commit", _frames(("config", _config(local, 1, committed=False, session=SESSION)),
                                  ("command", _command(c.COMMIT, 3, generation=1)))
    yield "start-stop", _frames(g1, start, ("command", _command(c.PING, 12, ping_t1_ns=123)), stop)
    yield "start-later", _frames(g1, ("command", _command(c.START, 10, generation=1, run_id=8,
                                                          at_utc_ns=FAR_UTC_NS)))
    g2 = ("config", _config(local, 2, committed=False, session=SESSION))
    commit_later = ("command", _command(c.COMMIT, 13, generation=2, at_utc_ns=FAR_UTC_NS))
    yield "live-commit", _frames(g1, start, g2, commit_later, stop)
    tasking_g2 = ("config", _config(tasking, 2, committed=False, session=SESSION))
    yield "live-tasking", _frames(g1, start, tasking_g2, ("command", _command(c.COMMIT, 13, generation=2)))
    foreign_start = _command(c.START, 20, OTHER_SESSION, generation=1, run_id=9)
    yield "foreign", _frames(g1, start, ("command", foreign_start),
                             ("config", _config(local, 3, committed=True, session=OTHER_SESSION)),
                             ("command", _command(c.STOP, 21, OTHER_SESSION, force=True)))
    yield "resend", _frames(g1, start, ("command", _command(c.RESEND, 30, run_id=7, batch_from=0, batch_to=3,
                                                            with_report=1)))
    yield "repeated", _frames(g1, start, start, ("command", _command(c.START, 10, generation=1, run_id=7)))
    yield "ping", _frames(("command", _command(c.PING, 1, ping_t1_ns=5)))
    yield "shutdown", _frames(g1, ("command", _command(c.SHUTDOWN, 2)))
    yield "unknown-kind", _frames(("command", _command(99, 3)))
    yield "tasking", _frames(("config", _config(tasking, 1, committed=True, session=SESSION)), start, stop)


def _seals() -> Iterator[tuple[str, bytes]]:
    """Control messages as a keyed DPU meets them: bare, and sealed with fuzz_seal.c's key."""
    command = bytes(_command(skelmsg.command_t.STOP, 40))
    yield "empty", b""
    yield "unsigned", command
    signer = Signer(bytes([0x5A]) * contract.KEY_BYTES, sender=7, clock=lambda: SENT_UTC_NS)
    yield "sealed", signer.seal(contract.COMMAND_CHANNEL, command)
    yield "seal-alone", signer.seal(contract.COMMAND_CHANNEL, b"")


def seeds() -> dict[str, bytes]:
    """Every seed by its path under corpus/: `<harness>/<name>`."""
    out: dict[str, bytes] = {}
    for harness, made in (("buffer", _buffers()), ("event", _events()), ("config", _configs()),
                          ("command", _commands()), ("seal", _seals())):
        for name, data in made:
            out[f"{harness}/{name}"] = data
    return out


def main() -> None:
    made = seeds()
    for old in CORPUS.glob("*/*"):
        if f"{old.parent.name}/{old.name}" not in made:
            old.unlink()
    for rel, data in made.items():
        path = CORPUS / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    print(f"{len(made)} seeds in {CORPUS.relative_to(REPO)}")


if __name__ == "__main__":
    main()

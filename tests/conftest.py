"""Shared fixtures: real skel-dpu daemons (under ASan/UBSan) on a private multicast port.

Every test gets its own LCM port with ttl=0, so multicast never leaves the host
and tests never hear each other's DPUs. The sanitizer build is made (by make) when
missing or older than dpu/, so `pytest` works after a plain `make`.

The folders of tests/ (test_X.py in unit/ tests module X; no two test files share a name):
  unit/          no DPU started: modules run on files and synthetic logs (broken/: bad system files)
  e2e/           real skel-dpu daemons started (the timing harness, tests/steal.py, judges them)
  netns/         multi-host tests on network-namespace hosts, beside their harness (root only)
  architecture/  the code's structure: layers, layout, the wire contract, the Makefile
  c/             unit tests of dpu/ in C (`make test-c`); fuzz/: libFuzzer harnesses; flood/: build/flood
Here beside this file: the shared helpers (steal.py, randsys.py, analysis_synth.py), which
tests import as `from conftest import REPO` does (pytest puts tests/ on sys.path).
"""

from __future__ import annotations

import itertools
import os
import random
import re
import resource
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import lcm
import pytest
from hypothesis import settings

import skelmsg
from skeleton.host.live import spawn
from skeleton.host.sysfile.link import record_url
from skelmsg.contract import DEFAULT_URL, TIMING_CHANNEL

SANITIZER_ERROR = re.compile(rb"ERROR: AddressSanitizer|runtime error:|ERROR: LeakSanitizer")
# Timing tests get another attempt only when steal or the harness's probe saw the platform
# take the time, never on a DPU's own figures (tests/steal.py).
pytest_plugins = ["steal"]

# A suite started in the background (`make test &`: the shell ignores SIGINT for it) would
# hand that on to every skel it starts, which then rightly ignores Ctrl-C (host/cli/commands.py): the
# tests of Ctrl-C need it as a terminal gives it. A handler here is reset to the default in
# the children.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

REPO = Path(__file__).resolve().parent.parent
ASAN_DPU = REPO / "build" / "asan" / "skel-dpu"
EXAMPLES = REPO / "examples"
LOGPLAYER = Path(lcm.__file__).parent.parent / "bin" / "lcm-logplayer"  # LCM's, from the venv
# Property-based tests (Hypothesis): a hundred examples each in `make test`, thousands in
# `make fuzz` (SKEL_HYPOTHESIS=fuzz). No deadline: a shared machine's pauses are not failures.
settings.register_profile("test", max_examples=100, deadline=None)
settings.register_profile("fuzz", max_examples=5000, deadline=None)
settings.load_profile(os.environ.get("SKEL_HYPOTHESIS", "test"))

# Each test gets a private port. A session takes a block of PORT_BLOCK ports of its own, drawn at
# random: two test sessions on one machine (a CI clone and a developer's checkout) whose blocks
# overlapped heard each other's DPUs and failed at random.
# The blocks lie below the kernel's ephemeral ports (ip_local_port_range), where any program's
# sockets, LCM's own senders among them, may hold a port: a test's host tool that could not bind its port
# (an ephemeral one, taken) failed with "bind: Address already in use".
PORT_BLOCK = 600
_EPHEMERAL_LOW = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
_ports = itertools.count(
    10000 + random.SystemRandom().randrange((_EPHEMERAL_LOW - 10000) // PORT_BLOCK) * PORT_BLOCK)


@pytest.fixture(scope="session", autouse=True)
def _asan_dpu_built() -> None:
    """`make` builds build/skel-dpu only; the tests run the sanitizer build. Asking make for it
    costs nothing when `make test` just built it and rebuilds it when dpu/ changed since."""
    done = subprocess.run(["make", "--no-print-directory", "-s", str(ASAN_DPU.relative_to(REPO))],
                          cwd=REPO, capture_output=True, text=True)
    if done.returncode != 0:
        pytest.exit(f"`make {ASAN_DPU.relative_to(REPO)}` failed:\n{done.stdout}{done.stderr}", returncode=1)


@pytest.fixture(autouse=True)
def _asan_dpu(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every daemon a test starts is the sanitizer build (`make test` builds it first)."""
    monkeypatch.setenv("SKEL_DPU", str(ASAN_DPU))
    monkeypatch.setenv("ASAN_OPTIONS", "detect_leaks=1:abort_on_error=0:exitcode=66")
    monkeypatch.setenv("UBSAN_OPTIONS", "print_stacktrace=1:halt_on_error=1:exitcode=67")


def fresh_url() -> str:
    """A private ttl=0 URL: the next port of this session's block, heard by no other test."""
    return f"udpm://239.255.76.67:{next(_ports)}?ttl=0"


@pytest.fixture
def url() -> str:
    return fresh_url()


@pytest.fixture
def state_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    path = tmp_path / "state"
    monkeypatch.setenv("SKEL_STATE_DIR", str(path))
    return path


class DpuFarm:
    """Starts DPUs for a test and checks, at the end, that each exited cleanly."""

    def __init__(self, url: str, log_dir: Path) -> None:
        self.url = url
        self.log_dir = log_dir
        self.daemons: dict[int, spawn.Daemon] = {}

    def start(self, *ids: int, extra: list[str] | None = None) -> None:
        for dpu_id in ids:
            self.daemons[dpu_id] = spawn.start_dpu(dpu_id, self.url, self.log_dir, extra)

    def kill(self, dpu_id: int) -> None:
        self.daemons[dpu_id].process.kill()
        self.daemons[dpu_id].process.wait()

    def log(self, dpu_id: int) -> str:
        return self.daemons[dpu_id].log_path.read_text(errors="replace")

    def logs(self, *dpu_ids: int) -> list[Path]:
        return [self.daemons[d].log_path for d in dpu_ids]

    def stop_all(self) -> dict[int, int | None]:
        return {i: spawn.stop(d) for i, d in self.daemons.items()}


@pytest.fixture
def dpus(url: str, tmp_path: Path) -> Iterator[DpuFarm]:
    """DPUs the test starts; stopped at its end, and judged by _dpus_ended_clean."""
    assert ASAN_DPU.exists(), f"{ASAN_DPU} missing: run `make test` (it builds it)"
    farm = DpuFarm(url, tmp_path / "dpu-logs")
    yield farm
    farm.stop_all()


def dpu_log_problems(root: Path) -> list[str]:
    """Every DPU log under ROOT (DpuFarm's dpu-logs/, `skel run --spawn`'s logs/): sanitizer
    reports, and how each DPU stopped when not cleanly (spawn.stop's note: a DPU stuck on
    exit and killed, or a status other than 0). A DPU the test killed itself has no note."""
    problems = []
    for log in sorted([*root.rglob("dpu*.log"), *root.rglob("simulate.log")]):
        text = log.read_bytes().decode(errors="replace")
        if SANITIZER_ERROR.search(text.encode()):
            problems.append(f"{log}: sanitizer report:\n{text[-6000:]}")
        problems += [f"{log}: {line}\n{text[-3000:]}" for line in text.splitlines()
                     if line.startswith(spawn.ENDED_NOTE) and not line.endswith("exited with status 0")]
    return problems


@pytest.fixture(autouse=True)
def _dpus_ended_clean(tmp_path: Path) -> Iterator[None]:
    """Every test that starts DPUs, itself or through `skel run --spawn`, fails on a
    sanitizer report or a DPU that did not exit cleanly when stopped."""
    yield
    problems = dpu_log_problems(tmp_path)
    if problems:
        pytest.fail("\n".join(problems), pytrace=False)


def user_env(tmp_path: Path) -> dict[str, str]:
    """The environment of a user's shell: the shipped daemon (no test's SKEL_DPU or sanitizer
    options), and daemon state of the test's own."""
    env = {k: v for k, v in os.environ.items() if k not in ("SKEL_DPU", "ASAN_OPTIONS", "UBSAN_OPTIONS")}
    env["SKEL_STATE_DIR"] = str(tmp_path / "state")
    return env


def released_compute_pct(report: dict, dpu_id: int) -> float:
    """A DPU's % compute unstalled, with what its processes' skipped releases would have computed
    added back. Each run's stalls are its own draw of the platform, and a data reader whose writer
    the platform stalled skips releases (SERVO's prediction skips none): a CI's one-machine run had
    jacobian_transpose skip 44 of 580 while DPU 1 ran 149 ms behind (81.8 % unstalled; 86.05 with
    them added back), the lab run 9 (85.2; 86.07)."""
    dpu = next(d for d in report["dpus"] if d["id"] == dpu_id)
    skipped = sum(100.0 * p["releases_skipped"] * p["compute_mean_us"]
                  / ((p["cycles"] + p["releases_skipped"]) * p["period_us"])
                  for p in report["processes"] if p["dpu"] == dpu_id and p["cycles"])
    return dpu["compute_unstalled_pct"] + skipped


def faults_but_stalls(report: dict) -> list[dict]:
    """The report's faults less the stalls and the overruns every one of which a stall
    explains: those are the test machine's (a neighbour, the hypervisor), which a test of the
    design cannot rule out on a shared machine: the harness's probe (tests/probe/probe.c), with
    nothing of the tests running, wakes 1 ms or more late about twice a second and up to 11 ms
    late within a minute (2026-12-02), and a stall fault is one of 1 ms or more."""
    stalled = {(p["name"], p["dpu"]) for p in report["processes"] if p["overruns"] == p["overruns_stalled"]}
    return [f for f in report["faults"] if f["kind"] != "stall"
            and not (f["kind"] == "overrun" and (f["process"], f["dpu"]) in stalled)]


def mapped_kib(path: Path) -> int:
    """Resident KiB of this process's maps of `path` (/proc/self/smaps)."""
    total, inside = 0, False
    for line in Path("/proc/self/smaps").read_text().splitlines():
        if re.match(r"[0-9a-f]+-[0-9a-f]+ ", line):
            inside = line.rstrip().endswith(str(path))
        elif inside and line.startswith("Rss:"):
            total += int(line.split()[1])
    return total


def bound_udp_ports(pid: int) -> set[int]:
    """The UDP ports the process's sockets are bound to (its fds' inodes in /proc/net/udp)."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = fd.readlink().as_posix()
        except OSError:
            continue  # closed meanwhile
        if (m := re.fullmatch(r"socket:\[(\d+)\]", target)) is not None:
            inodes.add(m.group(1))
    ports = set()
    for line in Path(f"/proc/{pid}/net/udp").read_text().splitlines()[1:]:
        fields = line.split()
        if fields[9] in inodes:
            ports.add(int(fields[1].split(":")[1], 16))
    return ports


def threads_cpus(pid: int) -> dict[int, set[int]]:
    """Per thread of process `pid`, the CPUs it may run on (its Cpus_allowed_list); a thread
    that ended meanwhile (a thread pool's) is left out."""
    out = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            status = (task / "status").read_text()
        except (FileNotFoundError, ProcessLookupError):
            continue
        listed = re.search(r"^Cpus_allowed_list:\s*(\S+)", status, re.MULTILINE)
        assert listed, task
        cpus: set[int] = set()
        for part in listed.group(1).split(","):
            first, _, last = part.partition("-")
            cpus.update(range(int(first), int(last or first) + 1))
        out[int(task.name)] = cpus
    return out


def skel(*args: str, timeout: float = 120, file_limit: int | None = None) -> subprocess.CompletedProcess[str]:
    """Run the real `skel` command line, as a user would; with `file_limit`, as a user whose
    files may not grow past that many bytes (RLIMIT_FSIZE: a write past it fails as on a full
    disk, Python ignoring the SIGXFSZ that comes with it)."""
    assert ASAN_DPU.exists(), f"{ASAN_DPU} missing: run `make test` (it builds it)"

    def limited() -> None:
        _, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
        resource.setrlimit(resource.RLIMIT_FSIZE, (file_limit, hard))

    return subprocess.run([sys.executable, "-m", "skeleton.host.cli", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO, env={**os.environ, "COLUMNS": "160"},
                          preexec_fn=limited if file_limit is not None else None)  # fmt: skip


class Background:
    """A process running in the background: its output lines, each with the time it arrived."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.proc = proc
        self.lines: list[tuple[float, str]] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append((time.monotonic(), line))

    def wait(self, timeout: float = 60) -> int:
        code = self.proc.wait(timeout)
        self._reader.join(5)
        return code

    @property
    def output(self) -> str:
        return "".join(line for _, line in self.lines)

    def wait_started(self, logs: Callable[[], Iterable[Path]], count: int, timeout_s: float = 30) -> None:
        """Until `count` of the DPU logs `logs()` say a run started, while this process runs: on a
        loaded machine the spawn, the clock estimate and the START lead may take seconds."""
        deadline = time.monotonic() + timeout_s
        while sum(bool(re.search(r"run \d+ started", log.read_text(errors="replace")))
                  for log in logs() if log.exists()) < count:
            assert time.monotonic() < deadline and self.proc.poll() is None, self.output
            time.sleep(0.05)

    def first(self, pattern: str) -> tuple[float, re.Match[str]] | None:
        """When the first line matching `pattern` arrived, and the match."""
        for when, line in self.lines:
            match = re.search(pattern, line)
            if match:
                return when, match
        return None


class TimingTap:
    """Every timing record of one run, decoded from SKEL_TIMING as the logger would see it:
    a subclass's `_add(msg)` turns each timing_t of the run into its `records` (under the
    lock); `close()` returns them by release."""

    def __init__(self, url: str, run_id: int) -> None:
        self.run_id = run_id
        self.records: list = []  # of the subclass's record type
        self._lock = threading.Lock()
        self._lcm = lcm.LCM(record_url(url))  # where the DPUs send timing (host/sysfile/link.py)
        self._lcm.subscribe(TIMING_CHANNEL, self._handle).set_queue_capacity(0)
        self._running = True
        self._thread = threading.Thread(target=self._drain, daemon=True)
        self._thread.start()

    def _drain(self) -> None:
        while self._running:
            self._lcm.handle_timeout(50)

    def _handle(self, _channel: str, data: bytes) -> None:
        msg = skelmsg.timing_t.decode(data)
        if msg.run_id != self.run_id:
            return
        with self._lock:
            self._add(msg)

    def _add(self, msg: skelmsg.timing_t) -> None:
        raise NotImplementedError

    def close(self) -> list:
        self._running = False
        self._thread.join(timeout=1.0)
        with self._lock:
            return sorted(self.records, key=lambda r: (r.release_ns, r.process))


def skel_background(*args: str, new_session: bool = False) -> Background:
    """The real `skel` command line, running in the background."""
    return Background(subprocess.Popen(
        [sys.executable, "-m", "skeleton.host.cli", *args], cwd=REPO, text=True,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=new_session,
        env={**os.environ, "COLUMNS": "160"}))


# A data-synchronised reader of a writer twenty times slower: it locks out.
LOCKOUT_SYSTEM = f"""\
system: lockout
links: [{{name: bus, url: "{DEFAULT_URL}"}}]
dpus: [{{id: 1}}, {{id: 2}}]
buffers: [{{id: 1, name: slow_data, bytes: 64}}]
processes:
  - {{id: 1, name: slow_writer, dpu: 1, period_us: 100000, compute_us: 1000, outputs: [1]}}
  - {{id: 2, name: hungry_reader, dpu: 2, period_us: 5000, compute_us: 500, sync: data, inputs: [1]}}
run: {{duration_s: 3, warmup_cycles: 0, lockout_cycles: 5, stop_on: [lockout]}}
"""


# Processes on events the host sends (`skel event`), whose rate no file says: on_demand on
# them, follower on the event on_demand emits, waiter on on_demand's data; ticker and
# listener on DPU 2 run once a period whatever the host does.
HOST_EVENTS_SYSTEM = """\
system: host_driven
dpus: [{id: 1}, {id: 2}, {id: 3}]
buffers: [{id: 1, name: knock, bytes: 8}, {id: 2, name: tick, bytes: 8}]
processes:
  - {id: 1, name: on_demand, dpu: 1, period_us: 1000, compute_us: 100, sync: event, event: go, queue: 64,
     inputs: [tick], outputs: [knock], emits: [knocked]}
  - {id: 2, name: ticker, dpu: 2, period_us: 1000, compute_us: 100, outputs: [tick]}
  - {id: 3, name: listener, dpu: 2, period_us: 5000, compute_us: 500, inputs: [knock]}
  - {id: 4, name: follower, dpu: 3, period_us: 2000, compute_us: 200, sync: event, event: knocked, queue: 8}
  - {id: 5, name: waiter, dpu: 3, period_us: 5000, compute_us: 500, sync: data, inputs: [knock]}
events: [{name: go, kind: host}]
chains: [[ticker, on_demand, listener], [on_demand, waiter]]
"""

def short_servo_run(out: Path, speed: int = 3) -> subprocess.CompletedProcess[str]:
    """A real SERVO run of 300 cycles (sanitizer DPUs, a private port) into `out`. Speed 3
    (~30 % load) keeps a busy shared machine from locking it out."""
    assert ASAN_DPU.exists(), f"{ASAN_DPU} missing: run `make test` (it builds it)"
    url = fresh_url()
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SKEL_DPU", str(ASAN_DPU))
        fast = [arg for d in (1, 2, 3, 4) for arg in ("-s", f"dpu.{d}.speed={speed}")]
        run = skel("run", str(EXAMPLES / "servo.yaml"), "--spawn", "--url", url, "--cycles", "300",
                   "-s", "run.warmup_cycles=20", *fast, "--out", str(out))  # fmt: skip
    assert run.returncode in (0, 3), run.stderr  # 3: a fault was measured; the log is as good
    return run


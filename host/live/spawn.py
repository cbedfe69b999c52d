"""Local daemons: the skel-dpu processes of this machine and the lcm-logger.

`skel up` leaves DPUs running between runs (their pids go to a small state
file so `skel down` finds them); `skel run --spawn` starts and stops them
around one run. The logger is always ours for the length of a run.

Given a deadline, a daemon runs under coreutils `timeout`, which forwards our
SIGINT to it and ends it by itself at the deadline: what `skel run` started
cannot outlive a killed host tool by more than that. The logger also gets its
own session, so a signal to the host tool's process group does not reach it.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import lcm

from skeleton.analysis.errors import SkelError
from skelmsg import contract

REPO = Path(__file__).resolve().parents[2]   # host/live/spawn.py -> the checkout
LOCAL_HOSTS = {"", "localhost", "127.0.0.1", "::1"}
# What the logger records by default: everything but the dummy buffers themselves, events
# included (a regular expression; LCM anchors it at both ends, so the alternatives are grouped).
_CONTROL_CHANNELS = (contract.CONFIG_CHANNEL, contract.COMMAND_CHANNEL, contract.STATUS_CHANNEL,
                     contract.TIMING_CHANNEL, contract.REPORT_CHANNEL, contract.CLOCK_CHANNEL,
                     contract.EVENT_CHANNEL_PREFIX + ".*")
LOGGED_CHANNELS = f"({'|'.join(_CONTROL_CHANNELS)})"


class SpawnError(SkelError, RuntimeError):
    """A local daemon could not be started; the message says what to do."""


def is_local(host: str) -> bool:
    return host in LOCAL_HOSTS or host == socket.gethostname()


def keep_off(pinned: set[int], allowed: set[int], threads: list[int] | None = None) -> set[int]:
    """Keep the host tool's own work (live tables, the search for faults: milliseconds at each
    refresh) off `pinned`, the CPUs this machine's DPUs are pinned to, when `allowed` has
    others: under SCHED_OTHER a DPU waking on a CPU where that work runs waits out the
    scheduler's slice (4.4 ms; `make bench` part wakeup, `wall` mode: a wake-up p99 of 1.6 ms
    against cyclictest's 0.1 ms). Sets the affinity of `threads` (native ids; None: the
    calling thread), and so of the threads they start from now on, and returns it."""
    cpus = allowed - pinned if pinned & allowed and allowed - pinned else allowed
    for tid in [0] if threads is None else threads:
        with contextlib.suppress(ProcessLookupError):  # a thread that ended meanwhile (a pool's)
            os.sched_setaffinity(tid, cpus)
    return cpus


def own_threads() -> list[int]:
    """The native ids of every thread of this process now (the control drain, numpy's and
    pyarrow's pools): keep_off moves them all."""
    return [int(t) for t in os.listdir("/proc/self/task")]


def dpu_binary() -> Path:
    """$SKEL_DPU, else the build in this checkout, else skel-dpu on PATH."""
    candidates = [os.environ.get("SKEL_DPU"), str(REPO / "build" / "skel-dpu"), shutil.which("skel-dpu")]
    for candidate in candidates:
        if candidate and os.access(candidate, os.X_OK):
            return Path(candidate)
    raise SpawnError("skel-dpu not found: run `make` in the skeleton checkout or set SKEL_DPU")


def logger_binary() -> Path:
    # The venv's lcm-logger is a Python wrapper: a signal to it leaves the real
    # logger running, so start the wheel's binary directly.
    path = Path(lcm.__file__).resolve().parent.parent / "bin" / "lcm-logger"
    if not os.access(path, os.X_OK):
        raise SpawnError(f"lcm-logger not found at {path}: reinstall the lcm wheel (make)")
    return path


def state_dir() -> Path:
    base = os.environ.get("SKEL_STATE_DIR") or os.environ.get("XDG_RUNTIME_DIR")
    path = Path(base) / "skeleton" if base else Path(f"/tmp/skeleton-{os.getuid()}")
    path.mkdir(parents=True, exist_ok=True)
    return path


def _state_file(url: str) -> Path:
    return state_dir() / f"up-{hashlib.sha1(url.encode()).hexdigest()[:10]}.json"


# The line stop() appends to a daemon's log: how it ended.
ENDED_NOTE = "skel: "


@dataclass
class Daemon:
    name: str
    process: subprocess.Popen[bytes]
    log_path: Path

    def alive(self) -> bool:
        return self.process.poll() is None


def _with_deadline(argv: list[str], deadline_s: float | None, signal_name: str) -> list[str]:
    if deadline_s is None:
        return argv
    wrapper = shutil.which("timeout")
    if wrapper is None:
        raise SpawnError("`timeout` (GNU coreutils) not found: install coreutils")
    return [wrapper, f"--signal={signal_name}", "--kill-after=5", f"{deadline_s:.1f}", *argv]


def start_dpu(dpu_id: int, url: str, log_dir: Path, extra: list[str] | None = None,
              detach: bool = False, deadline_s: float | None = None, key_file: Path | None = None) -> Daemon:
    """Start one skel-dpu; with `key_file`, it signs and checks control with that key (the
    path goes on its command line, never the key)."""
    log_dir.mkdir(parents=True, exist_ok=True)
    log_path = log_dir / f"dpu{dpu_id}.log"
    keyed = ["--key", str(key_file.resolve())] if key_file is not None else []
    argv = [str(dpu_binary()), "--id", str(dpu_id), "--url", url, *keyed, *(extra or [])]
    with open(log_path, "ab") as log:
        process = subprocess.Popen(
            _with_deadline(argv, deadline_s, "TERM"),
            stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
            start_new_session=detach)
    return Daemon(f"dpu {dpu_id}", process, log_path)


def start_logger(url: str, path: Path, channels: str = LOGGED_CHANNELS,
                 deadline_s: float | None = None, append: bool = False) -> Daemon:
    """Start lcm-logger on `url` writing `path` (or appending to it), and wait until it has
    opened the file. With `deadline_s`, it stops by itself (SIGINT: it flushes) that long
    after its start."""
    path.parent.mkdir(parents=True, exist_ok=True)
    log_path = path.with_suffix(".logger.txt")
    argv = [str(logger_binary()), "-a" if append else "-f", "-q", "-l", url, "-c", channels,
            "--flush-interval=50", str(path)]
    with open(log_path, "ab") as log:
        process = subprocess.Popen(
            _with_deadline(argv, deadline_s, "INT"),
            stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    deadline = time.monotonic() + 5.0
    while not path.exists():
        if process.poll() is not None or time.monotonic() > deadline:
            stop(Daemon("lcm-logger", process, log_path))
            raise SpawnError(f"lcm-logger did not start: see {log_path}")
        time.sleep(0.02)
    return Daemon("lcm-logger", process, log_path)


def stop(daemon: Daemon, timeout_s: float = 3.0) -> int | None:
    """SIGINT (the logger flushes on it, the DPU exits cleanly), then SIGKILL to its whole
    process group: under `timeout` (which leads a group of its own) killing the wrapper
    alone would orphan a daemon stuck on its way out, e.g. a sanitizer's exit-time check.
    How it ended goes at the end of its log (ENDED_NOTE), so a run's logs say it."""
    if daemon.alive():
        daemon.process.send_signal(signal.SIGINT)
        killed = False
        try:
            daemon.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            killed = True
            pid = daemon.process.pid
            try:
                leads_group = os.getpgid(pid) == pid
            except ProcessLookupError:
                leads_group = False
            if leads_group:
                os.killpg(pid, signal.SIGKILL)
            else:
                daemon.process.kill()
            daemon.process.wait()
        how = (f"did not exit within {timeout_s:g} s of SIGINT: killed" if killed
               else f"exited with status {daemon.process.returncode}")
        with open(daemon.log_path, "a") as log:
            log.write(f"{ENDED_NOTE}{daemon.name} {how}\n")
    return daemon.process.returncode


def bad_exit(daemon: Daemon) -> str | None:
    """What was wrong with how a stopped daemon ended (None: it exited cleanly on SIGINT)."""
    code = daemon.process.returncode
    if code == 0:
        return None
    return "did not exit on SIGINT: killed" if code == -signal.SIGKILL else f"exited with status {code}"


# --- skel up / skel down -------------------------------------------------------------
def up(dpu_ids: list[int], url: str, key_file: Path | None = None,
       extra: list[str] | None = None) -> list[int]:
    """Start detached DPUs for `dpu_ids` unless already up (with `extra` arguments, e.g. --lib-dir);
    return the ids started."""
    state = _read_state(url)
    running = {int(k): v for k, v in state.items() if _is_dpu_pid(v)}
    started = []
    for dpu_id in dpu_ids:
        if dpu_id in running:
            continue
        daemon = start_dpu(dpu_id, url, state_dir() / "logs", extra, detach=True, key_file=key_file)
        running[dpu_id] = daemon.process.pid
        started.append(dpu_id)
    _state_file(url).write_text(json.dumps({"url": url, "dpus": running}))
    return started


def down(url: str | None) -> list[int]:
    """Stop the DPUs `skel up` started (for `url`, or for every URL); return their ids."""
    files = [_state_file(url)] if url else sorted(state_dir().glob("up-*.json"))
    stopped = []
    for path in files:
        if not path.exists():
            continue
        pids = json.loads(path.read_text()).get("dpus", {})
        for dpu_id, pid in pids.items():
            if _is_dpu_pid(pid):
                os.kill(pid, signal.SIGTERM)
                stopped.append(int(dpu_id))
        for pid in pids.values():
            _wait_gone(pid)
        path.unlink()
    return sorted(stopped)


def remember_push(url: str, source_text: str, generation: int) -> None:
    """Keep what `skel push` applied, so `skel run` without a file runs exactly that."""
    stem = _state_file(url).stem.replace("up-", "pushed-")
    (state_dir() / f"{stem}.yaml").write_text(source_text)
    (state_dir() / f"{stem}.json").write_text(json.dumps({"url": url, "generation": generation}))


def last_push(url: str) -> tuple[Path, int] | None:
    stem = _state_file(url).stem.replace("up-", "pushed-")
    meta = state_dir() / f"{stem}.json"
    if not meta.exists():
        return None
    return state_dir() / f"{stem}.yaml", int(json.loads(meta.read_text())["generation"])


def _read_state(url: str) -> dict[str, int]:
    path = _state_file(url)
    return json.loads(path.read_text()).get("dpus", {}) if path.exists() else {}


def argv_of(pid: int) -> list[bytes]:
    """The command line of process `pid` ([] once it is gone)."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return []


def running(program: str) -> dict[int, list[bytes]]:
    """Every running process whose executable's name ends with `program`: pid -> argv."""
    found = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and (argv := argv_of(int(entry.name))) and argv[0].endswith(program.encode()):
            found[int(entry.name)] = argv
    return found


def _is_dpu_pid(pid: int) -> bool:
    """True when pid is still a skel-dpu (pids are reused)."""
    argv = argv_of(pid)
    return bool(argv) and b"skel-dpu" in argv[0]


def _wait_gone(pid: int, timeout_s: float = 3.0) -> None:
    deadline = time.monotonic() + timeout_s
    while _is_dpu_pid(pid):
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            return
        time.sleep(0.02)

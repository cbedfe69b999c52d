"""`skel console` in a real browser: Debian's headless Chromium driven by Selenium, on SERVO.

What an operator does on the page: sees the system drawn (9 processes in 4 DPUs, 9 buffers),
is refused without the token, edits `executor`'s compute and reads the prediction (DPU 2 at
63.4 %, as `skel check` says), pushes it to running DPUs (no restart: same pid, a new
generation), and gets `skel check`'s one line for an invalid edit, with nothing sent (the
DPUs' generation unchanged); bad HTTP input from the page's origin is a 4xx, nothing sent;
runs from the page (Table 1 reached live, its progress counted), pushes executor at 3000 us into
that run, runs again (63.4 % measured) and compares the two; follows `lcm-logplayer` replaying a
log, its faults drawn as chains back to their root cause; and the layout stays readable from SERVO
to the 64-DPU scale system (measured: boxes, nesting, texts). `make test` installs chromium and
chromium-driver as root (Makefile: test-tools); without them these tests skip and say so. Cost:
about 73 s (one browser for the module, a console per test; four DPUs for the push test, 7 s; a
2400-cycle and a 600-cycle run, a push and a diff, 31 s; three layouts, 12 s; a simulation and
its replay, 8 s).
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import EXAMPLES, LOGPLAYER, Background, DpuFarm, skel, skel_background

from skeleton.analysis.errors import EXIT_FATAL_FLAW, EXIT_INTERRUPTED
from skeleton.host.console.app import LIVE_PERIOD_S
from skeleton.host.console.live import FAULTS_SHOWN
from skeleton.host.live.control import Control
from skeleton.host.sysfile.link import record_url
from skeleton.host.sysfile.system import load

CHROMIUM, DRIVER = shutil.which("chromium"), shutil.which("chromedriver")
pytestmark = pytest.mark.skipif(
    not (CHROMIUM and DRIVER),
    reason="needs Debian's chromium and chromium-driver (`make test` as root installs them)")
SERVO = EXAMPLES / "servo.yaml"
WAIT_S = 20.0
RUN_WAIT_S = 60.0  # a 600-cycle run with its spawn, clock estimate and report, on a loaded machine
REFERENCE = load(SERVO).reference
assert REFERENCE is not None
TABLE_1 = {d: row.compute_pct for d, row in REFERENCE.dpus.items()}  # the paper's % compute
PERIOD_0_LINE = (f"{SERVO}: processes.executor.period_us: must be a positive number of microseconds, got 0 "
                 "(set by -s process.executor.period_us=0)")


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1600,1000"):
        options.add_argument(arg)
    options.binary_location = CHROMIUM
    driver = webdriver.Chrome(options=options, service=Service(DRIVER))
    yield driver
    driver.quit()


class Console:
    """`skel console` running in the background, and the URL it printed."""

    def __init__(self, url: str, runs: Path, *extra: str, file: Path = SERVO) -> None:
        self.proc: Background = skel_background("console", str(file), "--url", url, "--port", "0",
                                                "--runs-dir", str(runs), *extra)
        deadline = time.monotonic() + WAIT_S
        while not (found := re.search(r"at (http://127\.0\.0\.1:\d+/)\?token=(\S+)", self.proc.output)):
            assert time.monotonic() < deadline and self.proc.proc.poll() is None, self.proc.output
            time.sleep(0.05)
        self.base, self.token = found.group(1), found.group(2)

    @property
    def url(self) -> str:
        return f"{self.base}?token={self.token}"

    def stop(self) -> None:
        """SIGTERM ends it at once, open page or not, as every command: 130, no traceback."""
        self.proc.proc.terminate()
        code = self.proc.wait(10)
        assert code == EXIT_INTERRUPTED and "Traceback" not in self.proc.output, self.proc.output


@pytest.fixture
def console(url: str, tmp_path: Path) -> Iterator[Console]:
    c = Console(url, tmp_path / "runs")
    yield c
    c.stop()


@pytest.fixture
def spawning_console(url: str, tmp_path: Path) -> Iterator[Console]:
    """A console whose Run spawns the run's DPUs (skel run --spawn), into the test's tmp_path."""
    c = Console(url, tmp_path / "runs", "--spawn")
    yield c
    c.stop()


def until(browser: Any, script: str, timeout_s: float = WAIT_S) -> Any:
    """The value of `script` (JavaScript returning something) once it is truthy."""
    deadline = time.monotonic() + timeout_s
    while not (value := browser.execute_script(script)):
        assert time.monotonic() < deadline, f"never true: {script}"
        time.sleep(0.05)
    return value


def open_page(browser: Any, console: Console) -> None:
    browser.get(console.url)
    until(browser, "return document.body.dataset.ready")


def edit(browser: Any, target: str, value: str) -> None:
    """Type a descriptor's new value, as the operator does, and wait for its prediction."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    settled = browser.execute_script("return document.body.dataset.settled || '0'")
    field = browser.find_element(By.ID, "edit-" + target.replace(".", "-"))
    field.send_keys(Keys.CONTROL, "a")
    field.send_keys(value, Keys.TAB)
    until(browser, f"return (document.body.dataset.settled || '0') !== '{settled}' || "
                   "!document.getElementById('error').hidden")


def drag(browser: Any, process: str, dpu: int) -> None:
    """Drag a process's box onto a DPU's title on the graph, and wait for the prediction."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    settled = browser.execute_script("return document.body.dataset.settled || '0'")
    box = browser.find_element(By.CSS_SELECTOR, f'#graph .process[data-process="{process}"] rect')
    title = browser.find_element(By.CSS_SELECTOR, f'#graph .dpu[data-dpu="{dpu}"] .title')
    ActionChains(browser).drag_and_drop(box, title).perform()
    until(browser, f"return (document.body.dataset.settled || '0') !== '{settled}'")


def loads(browser: Any) -> dict[str, str]:
    return browser.execute_script(
        "return Object.fromEntries([...document.querySelectorAll('#prediction tr[data-dpu]')]"
        ".map(tr => [tr.dataset.dpu, tr.querySelector('.load').textContent]))")


def post(browser: Any, path: str, body: str) -> tuple[int, str]:
    """A request from the page's own origin (its cookie sent): the status and the error line."""
    return tuple(browser.execute_async_script(
        "const done = arguments[arguments.length - 1];"
        "fetch(arguments[0], {method: 'POST', headers: {'Content-Type': 'application/json'},"
        " body: arguments[1]})"
        ".then(r => r.json().then(j => done([r.status, j.error || ''])))", path, body))


def dpu_views(url: str) -> dict[int, tuple[int, int]]:
    """Each DPU heard on `url`: (pid, generation)."""
    control = Control(url)
    try:
        control.listen(1.0)
        return {v.status.dpu: (v.status.pid, v.status.generation) for v in control.daemons()}
    finally:
        control.close()


def test_the_page_draws_servo_and_predicts_an_edit(browser: Any, console: Console) -> None:
    browser.get(console.base)  # no token: refused
    assert "refused" in browser.find_element("tag name", "body").text
    open_page(browser, console)
    counts = browser.execute_script(
        "return [document.querySelectorAll('#graph .process').length,"
        " document.querySelectorAll('#graph .dpu').length,"
        " new Set([...document.querySelectorAll('#graph .buffer')].map(g => g.dataset.buffer)).size,"
        " document.querySelectorAll('#graph .buffer path.wait').length,"
        " document.querySelectorAll('#graph .buffer path.chain').length]")
    assert counts[:3] == [9, 4, 9]
    assert counts[3] == 1 and counts[4] >= 3  # jacobian_transpose's data wait; the chains drawn apart
    assert loads(browser) == {"1": "90.3", "2": "73.4", "3": "86.0", "4": "96.5"}
    edit(browser, "process.executor.compute_us", "3000")
    assert loads(browser)["2"] == "63.4"
    title = "return document.querySelector('#graph .dpu[data-dpu=\"2\"] .title').textContent"
    assert browser.execute_script(title) == "DPU 2 · 63.4 %"  # drawn on the graph too
    drag(browser, "force_control", 1)  # onto DPU 1, as choosing it in its row
    assert loads(browser) == {"1": "120.3", "2": "63.4", "3": "56.0", "4": "96.5"}
    row = "return document.getElementById('edit-process-force_control-dpu').value"
    assert browser.execute_script(row) == "1"
    edit(browser, "process.executor.period_us", "0")
    assert browser.execute_script("return document.getElementById('error').textContent") == PERIOD_0_LINE
    assert browser.execute_script("return document.getElementById('push').disabled")


def start_run(browser: Any) -> str:
    """Click Run: the new run's directory, once the page shows its `skel run` running."""
    from selenium.webdriver.common.by import By

    before = browser.execute_script(
        "return [...document.querySelectorAll('#runs tbody tr')].map(tr => tr.dataset.out)")
    browser.find_element(By.ID, "run").click()
    return until(browser, "const j = [...document.querySelectorAll('#job .job[data-kind=\"run\"]')]"
                          f".find(j => !{before!r}.includes(j.dataset.out)); return j && j.dataset.out")


def job_ended(browser: Any, selector: str, timeout_s: float = WAIT_S) -> str:
    """The output of the command `selector` picks in the page's job view, once it has ended."""
    return until(browser, f"const j = document.querySelector('#job .job{selector}');"
                          "return j && j.dataset.running === 'false' && j.textContent", timeout_s)


def end_of_run(browser: Any, out: str) -> dict[int, float | None]:
    """Wait for the run to end (exit 0) and the live tables to have its last figures."""
    text = job_ended(browser, f'[data-kind="run"][data-out="{out}"]', RUN_WAIT_S)
    assert "(exit 0)" in text, text
    until(browser, "return [...document.querySelectorAll('#runs tbody tr')]"
                   f".some(tr => tr.dataset.out === '{out}')")
    time.sleep(2 * LIVE_PERIOD_S)  # the stream's snapshot after the run's last records
    return live_compute(browser)


def live_compute(browser: Any) -> dict[int, float | None]:
    """Each DPU's live % compute, as the page shows it beside the prediction (None: not yet)."""
    cells = browser.execute_script(
        "return Object.fromEntries([...document.querySelectorAll('#prediction tr[data-dpu]')]"
        ".map(tr => [tr.dataset.dpu, tr.querySelector('.live').textContent.split(' / ')[0]]))")
    return {int(d): None if cell == "-" else float(cell) for d, cell in cells.items()}


def reaches(browser: Any, expected: dict[int, float], out: str) -> dict[int, float | None]:
    """The live % compute once it is within 1 point of `expected` for every DPU, or as it is
    when the run `out` has ended without getting there."""
    ended = f"return !!document.querySelector('#job .job[data-out=\"{out}\"][data-running=\"false\"]')"
    deadline = time.monotonic() + RUN_WAIT_S
    while True:
        done = browser.execute_script(ended)
        shown = live_compute(browser)
        if all((s := shown.get(d)) is not None and abs(s - v) <= 1.0 for d, v in expected.items()):
            return shown
        if done or time.monotonic() > deadline:
            return shown
        time.sleep(LIVE_PERIOD_S)


def progress(browser: Any) -> tuple[int, int]:
    """The run's planned cycles and the cycle it has reached, as the page shows them."""
    shown = browser.execute_script("return {...document.getElementById('progress').dataset}")
    return int(shown["cycles"]), int(shown["cycle"])


HEARTBEAT_CYCLES = 2 * 40  # SERVO's 5 ms cycles in two of a DPU's heartbeats (5 Hz): the last running one
FIRST_CYCLES = 2400


@pytest.mark.timing
def test_run_push_into_it_run_again_and_compare(browser: Any, spawning_console: Console) -> None:
    """The operator's loop on the page, with spawned DPUs. A run of the file: its live table
    reaches the paper's Table 1 within 1 point, and its progress counts its cycles to the end.
    Executor edited to 3000 us (63.4 % predicted) and pushed into that run, live (`skel push`,
    mid-run). The next run measures what was predicted, within 1 point. Both runs are in the
    notebook, and Compare prints `skel diff` of them."""
    from selenium.webdriver.common.by import By

    open_page(browser, spawning_console)
    # 12 s: room for the push to land mid-run after the live table reached Table 1. In 6 s (1200
    # cycles) it landed 3.5 s after the run's end on a fresh-clone CI that the platform left alone.
    edit(browser, "run.cycles", str(FIRST_CYCLES))
    first = start_run(browser)
    reached = reaches(browser, TABLE_1, first)
    assert reached == pytest.approx(TABLE_1, abs=1.0), reached
    cycles, midway = progress(browser)
    assert cycles == FIRST_CYCLES and 0 < midway < FIRST_CYCLES, midway  # cycles of 5 ms, warm-up included
    edit(browser, "process.executor.compute_us", "3000")
    assert loads(browser)["2"] == "63.4"
    browser.find_element(By.ID, "push").click()
    pushed = job_ended(browser, '[data-kind="push"]')
    assert "(exit 0)" in pushed and "mid-run" in pushed, pushed
    end_of_run(browser, first)
    cycles, last = progress(browser)
    assert cycles == FIRST_CYCLES and midway <= last <= FIRST_CYCLES, last
    assert last >= FIRST_CYCLES - HEARTBEAT_CYCLES, last
    edit(browser, "run.cycles", "600")
    second = end_of_run(browser, start_run(browser))
    assert second == pytest.approx({**TABLE_1, 2: 63.4}, abs=1.0), second
    verdicts = browser.execute_script("return [...document.querySelectorAll('#runs tbody tr')]"
                                      ".map(tr => tr.cells[3].textContent)")
    assert len(verdicts) == 2 and all("no fatal flaw" in v for v in verdicts), verdicts
    for tick in browser.find_elements(By.CSS_SELECTOR, "#runs tbody input[type=checkbox]"):
        tick.click()
    browser.find_element(By.ID, "compare").click()
    text = job_ended(browser, '[data-kind="diff"]')
    assert "(exit 0)" in text and "per DPU: B - A" in text, text


def test_push_from_the_page_and_nothing_sent_on_bad_input(browser: Any, console: Console,
                                                          dpus: DpuFarm) -> None:
    from selenium.webdriver.common.by import By

    dpus.start(1, 2, 3, 4)
    before = dpu_views(dpus.url)
    assert sorted(before) == [1, 2, 3, 4], before
    open_page(browser, console)
    edit(browser, "process.executor.compute_us", "3000")
    browser.find_element(By.ID, "push").click()
    text = job_ended(browser, '[data-kind="push"]')
    assert "(exit 0)" in text and "committed" in text, text
    pushed = dpu_views(dpus.url)
    pids = {d: pid for d, (pid, _) in before.items()}
    assert {d: pid for d, (pid, _) in pushed.items()} == pids  # nothing restarted
    generation = {g for _, g in pushed.values()}
    assert len(generation) == 1 and generation.pop() > max(g for _, g in before.values())

    edit(browser, "process.executor.period_us", "0")
    assert browser.execute_script("return document.getElementById('error').textContent") == PERIOD_0_LINE
    assert post(browser, "/api/push", '{"set": {"process.executor.period_us": 0}}') == (422, PERIOD_0_LINE)
    for body, status in (("{not json", 400), ('{"set": {}, "dpu": 2}', 400),
                         ('{"set": {"a": [{}]}}', 400), ('{"set": {"x": "' + "a" * 70_000 + '"}}', 413)):
        assert post(browser, "/api/push", body)[0] == status, body
    assert dpu_views(dpus.url) == pushed  # the same pids, the same generation: nothing was sent


# Each system's page measured in the browser, in the SVG's own units: the process boxes that
# overlap, those outside their DPU's box, the DPU boxes outside their host's, the texts that
# overlap, run out of their box or have an arrow across them, the buffer labels over a process
# box, and how long ELK's layout and the drawing took.
READABILITY = """
const rect = (g) => { const r = g.querySelector(':scope > rect'); const a = (k) => +r.getAttribute(k);
  return {x: a('x'), y: a('y'), w: a('width'), h: a('height')}; };
const text = (t) => { const b = t.getBBox(); return {x: b.x, y: b.y, w: b.width, h: b.height}; };
const meet = (a, b) => a.x < b.x + b.w - 0.5 && b.x < a.x + a.w - 0.5
  && a.y < b.y + b.h - 0.5 && b.y < a.y + a.h - 0.5;
const inside = (a, b) => a.x >= b.x - 0.5 && a.y >= b.y - 0.5
  && a.x + a.w <= b.x + b.w + 0.5 && a.y + a.h <= b.y + b.h + 0.5;
const pairs = (items, name, test) => { const out = [];
  for (let i = 0; i < items.length; i++) for (let j = i + 1; j < items.length; j++)
    if (test(items[i].box, items[j].box)) out.push(name(items[i]) + ' / ' + name(items[j]));
  return out; };
const all = (selector) => [...document.querySelectorAll('#graph ' + selector)];
const hosts = Object.fromEntries(all('.host').map((g) => [g.dataset.host, rect(g)]));
const dpus = Object.fromEntries(all('.dpu').map((g) => [g.dataset.dpu, rect(g)]));
const procs = all('.process').map((g) => ({g, name: g.dataset.process, box: rect(g)}));
const texts = all('text').map((t) => ({name: t.textContent, box: text(t)}));
const boxed = [...all('.host'), ...all('.dpu'), ...all('.process')];
// Every straight piece of every arrow (ELK routes them orthogonally: each piece's box is itself).
const segments = all('path[d]').flatMap((path) => path.getAttribute('d').split('M').filter((p) => p.trim())
  .flatMap((part) => { const pts = part.split('L').map((pt) => pt.trim().split(',').map(Number));
    return pts.slice(1).map((b, i) => ({x: Math.min(pts[i][0], b[0]), y: Math.min(pts[i][1], b[1]),
                                        w: Math.abs(pts[i][0] - b[0]), h: Math.abs(pts[i][1] - b[1])})); }));
const across = (s, b) => s.x < b.x + b.w - 1 && b.x + 1 < s.x + s.w + 0.01
  && s.y < b.y + b.h - 1 && b.y + 1 < s.y + s.h + 0.01;
return {
  processes: procs.length, dpus: Object.keys(dpus).length, hosts: Object.keys(hosts).length,
  overlapping: pairs(procs, (p) => p.name, meet),
  outside_dpu: procs.filter((p) => !inside(p.box, dpus[p.g.dataset.dpu])).map((p) => p.name),
  outside_host: all('.dpu').filter((g) => !inside(rect(g), hosts[g.dataset.host])).map((g) => g.dataset.dpu),
  texts: texts.length,
  texts_overlapping: pairs(texts, (t) => t.name, meet),
  texts_out_of_box: boxed.flatMap((g) => [...g.querySelectorAll(':scope > text')]
    .filter((t) => !inside(text(t), rect(g))).map((t) => t.textContent)),
  labels_on_a_process: all('.buffer .label').filter((t) => procs.some((p) => meet(text(t), p.box)))
    .map((t) => t.textContent),
  texts_crossed: texts.filter((t) => segments.some((s) => across(s, t.box))).map((t) => t.name),
  layout_ms: Number(document.body.dataset.layoutMs)};
"""
# Measured here: 0.4, 0.7 and 4 s (past the column, two layouts); a loaded machine takes longer.
LAYOUT_MS = {"servo": 2000, "autoware-22": 3000, "scale-32x2": 15000}
READABLE = ((SERVO, 9, 4, 1), (EXAMPLES / "autoware-22.yaml", 22, 6, 1),  # (file, processes, DPUs, hosts)
            (EXAMPLES / "scale-32x2.yaml", 128, 64, 32))


def test_the_layout_stays_readable_from_servo_to_64_dpus(browser: Any, url: str, tmp_path: Path) -> None:
    """The paper's Figure 8 for SERVO, an Autoware-sized graph (22 processes) and the 64-DPU scale
    system, each measured on its page: no process box over another, each inside its DPU's box,
    each DPU's inside its host's, no text over another, out of its box or crossed by an arrow, no
    buffer label over a process, and the layout drawn within LAYOUT_MS. The Autoware graph, too
    long for the column left to right, is drawn top to bottom."""
    for file, processes, dpus, hosts in READABLE:
        console = Console(url, tmp_path / "runs", file=file)
        try:
            open_page(browser, console)
            found = browser.execute_script(READABILITY)
            direction = browser.execute_script("return document.getElementById('graph').dataset.direction")
        finally:
            console.stop()
        took = found.pop("layout_ms")
        assert found.pop("texts") > 2 * processes + dpus, found
        assert found == {"processes": processes, "dpus": dpus, "hosts": hosts, "overlapping": [],
                         "outside_dpu": [], "outside_host": [], "texts_overlapping": [],
                         "texts_out_of_box": [], "labels_on_a_process": [], "texts_crossed": []}, file.name
        assert 0 < took < LAYOUT_MS[file.stem], (file.name, took)
        assert direction == ("DOWN" if file.stem == "autoware-22" else "RIGHT"), file.name


JAMMED = EXAMPLES / "servo-2.5ms.yaml"  # the paper's design flaw: lockouts within half a second


def struck(fault: dict[str, Any]) -> list[str]:
    """A fatal fault's chain as the graph draws it: a jam's, or a lockout's process back to the
    writer it waits on (host/console/live.py)."""
    return fault["chain"] or [fault["process"], *([fault["writer"]] if fault.get("writer") else [])]


def test_the_page_follows_a_replayed_log_and_draws_its_faults(browser: Any, url: str, tmp_path: Path) -> None:
    """`lcm-logplayer` replaying a run's log on the console's URL: the page follows it as it
    would the run. SERVO at 2.5 ms, simulated (virtual time, a second), recorded its log; replayed,
    the live table shows that run, its processes' cycles as its report counts them, its progress
    (the planned 400 cycles, stopped early), and each fatal fault drawn on the graph as its chain
    back to the root cause (a DPU that ran behind, its box)."""
    out = tmp_path / "jammed"
    done = skel("simulate", str(JAMMED), "--out", str(out))
    assert done.returncode == EXIT_FATAL_FLAW, done.stdout + done.stderr
    report = json.loads((out / "report.json").read_text())
    chains = [struck(f) for f in report["faults"] if f["fatal"] and f["process"]]
    behind = sorted(str(f["dpu"]) for f in report["faults"] if f["fatal"] and not f["process"])
    assert chains and any(len(c) > 1 for c in chains), report["faults"]  # a jam among them
    console = Console(url, tmp_path / "runs", file=JAMMED)
    try:
        open_page(browser, console)
        until(browser, "return document.getElementById('live-head').textContent.startsWith('waiting')")
        player = subprocess.run([str(LOGPLAYER), "-s", "1", "-l", record_url(url), str(out / "run.lcm")],
                                capture_output=True, text=True, timeout=60)
        assert player.returncode == 0, player.stderr
        # The faults are searched for in a thread of their own, as often as their cost allows: the
        # page is read once it shows as many as the report has, and after the stream's next snapshot.
        expected = min(len(report['faults']), FAULTS_SHOWN)
        until(browser, f"return document.querySelectorAll('#faults li').length >= {expected}")
        time.sleep(2 * LIVE_PERIOD_S)
        shown = browser.execute_script(
            "const faulty = (s) => [...document.querySelectorAll(s)];"
            "return {head: document.getElementById('live-head').textContent,"
            " cycles: Object.fromEntries([...document.querySelectorAll('#live-processes tbody tr')]"
            "   .map(tr => [tr.cells[0].textContent, Number(tr.cells[2].textContent)])),"
            " progress: {...document.getElementById('progress').dataset},"
            " faulty: faulty('#graph .process.faulty').map(g => g.dataset.process).sort(),"
            " roots: faulty('#graph .process.root-cause').map(g => g.dataset.process).sort(),"
            " dpus: faulty('#graph .dpu.faulty').map(g => g.dataset.dpu).sort(),"
            " steps: faulty('#graph .buffer path.faulty')"
            "   .map(p => p.dataset.writer + '>' + p.dataset.reader).sort()}")
    finally:
        console.stop()
    assert shown["head"].startswith(f"run {report['run_id']} of servo-2.5ms"), shown["head"]
    assert shown["cycles"] == {p["name"]: p["cycles"] for p in report["processes"]}, shown["cycles"]
    progress = shown["progress"]
    assert progress["cycles"] == "400" and 0 < int(progress["cycle"]) < 400, progress  # stopped early
    assert shown["faulty"] == sorted({p for c in chains for p in c})
    assert shown["roots"] == sorted({c[-1] for c in chains})
    assert shown["steps"] == sorted({f"{c[i + 1]}>{c[i]}" for c in chains for i in range(len(c) - 1)})
    assert shown["dpus"] == behind  # each DPU that ran behind its schedule

"""skel console's web application without a browser (Starlette's test client): the token
refuses every request without it, an edit is predicted as `skel check -s` predicts it and an
invalid one gets its one line, bad HTTP input is a clear 4xx and starts nothing, Save keeps
the comments. The page itself, in Chromium: tests/e2e/test_console_browser.py."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import EXAMPLES, fresh_url
from starlette.testclient import TestClient

from skeleton.host.cli.check import check
from skeleton.host.console.app import COOKIE, STATIC, Settings, build_app
from skeleton.host.console.edits import MAX_BODY_BYTES
from skeleton.host.console.jobs import Busy, Job, Jobs
from skelmsg.contract import DEFAULT_URL

TOKEN = "t0ken-for-the-tests"


@pytest.fixture
def servo(tmp_path: Path) -> Path:
    path = tmp_path / "servo.yaml"
    shutil.copy(EXAMPLES / "servo.yaml", path)
    return path


def client(file: Path, tmp_path: Path) -> TestClient:
    settings = Settings(file=file, url=None, key_file=None, spawn=False, runs_dir=tmp_path / "runs",
                        token=TOKEN)
    return TestClient(build_app(settings, None, DEFAULT_URL))  # no test here opens the live stream


@pytest.fixture
def console(servo: Path, tmp_path: Path) -> TestClient:
    c = client(servo, tmp_path)
    assert c.get(f"/?token={TOKEN}").status_code == 200  # the printed URL: sets the cookie
    return c


@pytest.mark.parametrize("path", ["/", "/api/system", "/api/job", "/static/console.js",
                                  "/static/elk/elk.bundled.js", "/nowhere"])
@pytest.mark.parametrize("token", [None, "", "wrong", TOKEN + "x"])
def test_no_token_is_refused(servo: Path, tmp_path: Path, path: str, token: str | None) -> None:
    c = client(servo, tmp_path)
    if token is not None:
        c.cookies.set(COOKIE, token)
    response = c.get(path if token is None else f"{path}?token={token}")
    assert response.status_code == 403 and "token" in response.text
    assert c.post("/api/push", json={"set": {}}).status_code == 403


def test_the_token_once_then_its_cookie(servo: Path, tmp_path: Path) -> None:
    c = client(servo, tmp_path)
    first = c.get(f"/?token={TOKEN}")
    assert first.status_code == 200 and "HttpOnly" in first.headers["set-cookie"]
    assert "SameSite=Strict" in first.headers["set-cookie"]
    assert c.get("/api/system").status_code == 200
    assert c.get("/static/elk/elk.bundled.js").status_code == 200  # served by the package, not a CDN


def test_the_system_as_check_sees_it(console: TestClient) -> None:
    data = console.get("/api/system").json()
    graph = data["graph"]
    assert data["ok"] and data["summary"]["system"] == "servo"
    assert (len(graph["processes"]), len(graph["dpus"]), len(graph["buffers"])) == (9, 4, 9)
    assert [h["dpus"] for h in graph["hosts"]] == [[1, 2, 3, 4]]
    joint_state = next(b for b in graph["buffers"] if b["name"] == "joint_state")
    assert joint_state["writer"] == "joint_sensors" and joint_state["rate_hz"] == 200
    assert {"process": "jacobian_transpose", "waits": True} in joint_state["readers"]  # sync: data
    assert len(graph["chains"]) == 2


def test_an_edit_is_predicted_as_skel_check_predicts_it(console: TestClient) -> None:
    response = console.post("/api/predict", json={"set": {"process.executor.compute_us": 3000}})
    loads = {d["id"]: d["load_pct"] for d in response.json()["summary"]["prediction"]["dpus"]}
    assert response.status_code == 200 and loads == {1: 90.3, 2: 63.4, 3: 86.0, 4: 96.5}


def test_an_invalid_edit_gets_skel_checks_line_and_starts_nothing(
        console: TestClient, servo: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert check(servo, ["process.executor.period_us=0"]) == 2
    line = capsys.readouterr().err.strip()
    for path in ("/api/predict", "/api/push", "/api/run", "/api/save"):
        response = console.post(path, json={"set": {"process.executor.period_us": 0}})
        assert response.status_code == 422 and response.json() == {"ok": False, "error": line}
    assert console.get("/api/job").json() == [] and console.get("/api/runs").json() == []
    assert servo.read_text() == (EXAMPLES / "servo.yaml").read_text()


@pytest.mark.parametrize(("body", "status", "says"), [
    (b"{not json", 400, "not JSON"),
    (b'{"set": {}, "also": 1}', 400, "also: Extra inputs are not permitted"),
    (b'{"sett": {}}', 400, "sett"),
    (b'{"set": {"process.executor.compute_us": {"a": {"b": 1}}}}', 400, "process.executor.compute_us"),
    (b'{"set": {"process.executor.compute_us": {"a": 1}}}', 422, "unknown key"),
    (b'{"set": {"process.executor.compute_us=3000": 1}}', 400, "is no descriptor"),
    (b'{"set": ["process.executor.compute_us"]}', 400, "set"),
    (b"[" * 100_000, 413, "larger than"),
    (b'{"set": {"x": "' + b"a" * MAX_BODY_BYTES + b'"}}', 413, "larger than"),
])
def test_bad_http_input_is_a_clear_4xx_and_sends_nothing(console: TestClient, body: bytes, status: int,
                                                         says: str) -> None:
    for path in ("/api/predict", "/api/push", "/api/run"):
        response = console.post(path, content=body, headers={"content-type": "application/json"})
        assert response.status_code == status and says in response.json()["error"], response.text
        assert "\n" not in response.json()["error"]
    assert console.get("/api/job").json() == []


def test_a_huge_body_without_a_length_is_cut_off(console: TestClient) -> None:
    def chunks() -> Iterator[bytes]:  # a generator body: sent chunked, no content-length
        for _ in range(100):
            yield b" " * 4096
    response = console.post("/api/push", content=chunks(), headers={"content-type": "application/json"})
    assert response.status_code == 413


def test_save_writes_the_edits_and_keeps_the_comments(console: TestClient, servo: Path) -> None:
    response = console.post("/api/save", json={"set": {"process.executor.compute_us": 3000,
                                                       "process.force_control.dpu": 1}})
    assert response.status_code == 200, response.text
    text = servo.read_text()
    assert "{id: 4, name: executor, dpu: 2, period_us: 5000, compute_us: 3000," in text
    assert "# The Executor (process 4) is the paper's Figure 9" in text
    assert len(text.splitlines()) == len((EXAMPLES / "servo.yaml").read_text().splitlines())
    dpus = console.get("/api/system").json()["summary"]["prediction"]["dpus"]
    assert {d["id"]: d["load_pct"] for d in dpus}[2] == 63.4


def test_compare_takes_only_the_sessions_runs(console: TestClient) -> None:
    response = console.post("/api/diff", json={"a": "/etc", "b": "/tmp"})
    assert response.status_code == 404 and console.get("/api/job").json() == []


def test_the_notebook_opens_earlier_runs_and_serves_only_their_plots(servo: Path, tmp_path: Path) -> None:
    run = tmp_path / "runs" / "servo-earlier"
    (run / "plots").mkdir(parents=True)
    (run / "report.json").write_text(json.dumps({"system": "servo", "run_id": 7, "fatal": False, "faults": [],
                                                 "dpus": [{"id": 2, "compute_pct": 73.4}]}))
    (run / "plots" / "utilization.png").write_bytes(b"\x89PNG\r\n")
    (tmp_path / "runs" / "not-a-run").mkdir()
    c = client(servo, tmp_path)
    c.get(f"/?token={TOKEN}")
    [listed] = c.get("/api/runs").json()
    assert listed["out"] == str(run) and listed["verdict"] == "servo, run 7: no fatal flaw, 0 fault(s)"
    assert listed["dpus"] == [{"id": 2, "compute_pct": 73.4, "communicate_pct": None, "wait_pct": None,
                               "measured_cycle_ms": None, "overruns": None}]
    assert c.get("/api/plots", params={"run": str(run)}).json() == ["utilization.png"]
    assert c.get("/api/plots", params={"run": str(run), "name": "utilization.png"}).content == b"\x89PNG\r\n"
    for params in ({"run": str(run), "name": "../report.json"}, {"run": str(run), "name": "nothing.png"},
                   {"run": str(tmp_path / "runs" / "not-a-run")}, {"run": "/etc", "name": "passwd"}):
        assert c.get("/api/plots", params=params).status_code == 404, params
    assert c.post("/api/plots", json={"run": "/etc"}).status_code == 404
    assert c.post("/api/plots", json={"run": str(run), "also": 1}).status_code == 400
    assert c.get("/api/job").json() == []


def test_any_descriptor_even_a_distribution_is_an_edit(console: TestClient) -> None:
    """The page's `-s` field: a compute distribution (a mapping) is predicted as `skel check` does."""
    varying = {"process.dynamics.compute_us": {"dist": "uniform", "min": 9000, "max": 19000}}
    summary = console.post("/api/predict", json={"set": varying}).json()["summary"]
    assert summary["varying_compute"] == [{"process": "dynamics", "kind": "uniform", "min_us": 9000.0,
                                           "mean_us": 14000.0, "max_us": 19000.0}]
    assert any("117.5 % when its varying computations draw their maximum" in w for w in summary["warnings"])
    deeper = {"process.dynamics.compute_us": {"dist": {"nested": 1}}}
    assert console.post("/api/predict", json={"set": deeper}).status_code == 400


def test_the_layout_library_is_the_pinned_one_with_its_licence(console: TestClient) -> None:
    """elkjs is vendored, not fetched: the file served is the one its VERSION note pins, and its
    licence travels with it; the page loads scripts from the package alone."""
    elk = STATIC / "elk"
    digest = re.search(r"^sha256 ([0-9a-f]{64})  elk.bundled.js$", (elk / "VERSION").read_text(), re.M)
    served = console.get("/static/elk/elk.bundled.js").content
    assert digest and hashlib.sha256(served).hexdigest() == digest.group(1)
    assert "Eclipse Public License - v 2.0" in (elk / "LICENSE.md").read_text()
    page = console.get("/").text
    assert re.findall(r'src="([^"]+)"', page) == ["/static/elk/elk.bundled.js", "/static/console.js"]
    assert "http" not in " ".join(re.findall(r'(?:src|href)="([^"]+)"', page))


def test_one_command_at_a_time_but_a_push_into_the_pages_run(tmp_path: Path) -> None:
    """As at a terminal, a command waits for the one before, except a push into the run the page
    started (live reconfiguration). Stand-ins: `skel watch --once` waiting for a run,
    `skel keygen` for the push."""
    jobs = Jobs(tmp_path / "runs")
    waiting = ["watch", "--url", fresh_url(), "--once", "--duration", "30"]
    run = jobs.start(Job("run", waiting, out=tmp_path / "run"))
    try:
        push = jobs.start(Job("push", ["keygen", str(tmp_path / "key")]))
        for kind in ("run", "diff", "report"):
            with pytest.raises(Busy, match=r"skel watch .* is still running"):
                jobs.start(Job(kind, ["keygen", str(tmp_path / kind)]))
        deadline = time.monotonic() + 30
        while push.returncode is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert push.returncode == 0 and jobs.shown() == [run, push] and jobs.runs == [run]
    finally:
        jobs.stop()  # as when the console stops: the run is ended as Ctrl-C ends it
    assert run.returncode is not None and jobs.running() == []
    assert jobs.shown() == [run, push]  # the run and its push, ended, until the next command
    later = jobs.start(Job("diff", ["keygen", str(tmp_path / "later")]))
    assert jobs.shown() == [later]


def test_every_page_shares_one_live_listener(servo: Path, tmp_path: Path) -> None:
    """The live stream sends snapshots until the server stops (here after one each): however many
    pages open it, one listener hears the run."""
    asked: list[bool] = []

    def closing() -> bool:  # each stream: one snapshot, then the server is stopping
        asked.append(True)
        return len(asked) % 2 == 0

    settings = Settings(file=servo, url=None, key_file=None, spawn=False, runs_dir=tmp_path / "runs",
                        token=TOKEN)
    with TestClient(build_app(settings, None, fresh_url(), closing)) as c:
        c.get(f"/?token={TOKEN}")
        for _ in range(3):
            stream = c.get("/api/live")
            assert stream.headers["content-type"].startswith("text/event-stream")
            [event] = [line for line in stream.text.splitlines() if line.startswith("data: ")]
            assert json.loads(event[len("data: "):])["run_id"] is None
        assert [t.name for t in threading.enumerate()].count("skel-console-live") == 1
    assert "skel-console-live" not in [t.name for t in threading.enumerate()]  # stopped with the server

"""The console's web application (Starlette): the page, its script, the vendored layout
library, and JSON endpoints that return what the layers below compute. Every request carries
the token `skel console` printed (as a query parameter once, then a cookie), or is refused."""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
import secrets
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, PlainTextResponse, Response, StreamingResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles
from starlette.types import ASGIApp, Receive, Scope, Send

from ..model import System
from .edits import (
    MAX_BODY_BYTES,
    BadRequest,
    DiffRequest,
    EditRequest,
    PlotsRequest,
    evaluate,
    overrides,
    parse,
    saved_text,
)
from .jobs import Busy, Job, Jobs
from .live import LiveView

STATIC = Path(__file__).parent / "static"
COOKIE = "skel_console_token"
LIVE_PERIOD_S = 0.5  # how often the live stream sends a snapshot
PLOTS = "plots"  # a run's folder of `skel report --plots`
PLOT_NAME = re.compile(r"^[a-z0-9_]+\.png$")
REFUSED = "refused: open the URL `skel console` printed (it carries the token)\n"


@dataclass
class Settings:
    file: Path
    url: str | None  # --url: the system's default link, as for every command
    key_file: Path | None
    spawn: bool  # the Run button starts local DPUs for the run (skel run --spawn)
    runs_dir: Path
    token: str


class TokenGate:
    """Refuses (403) every HTTP request and WebSocket without the token: in the query
    (`?token=`, the printed URL) or in the cookie the first such request sets."""

    def __init__(self, app: ASGIApp, token: str) -> None:
        self.app = app
        self.token = token

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        request = Request(scope)
        given = request.query_params.get("token") or request.cookies.get(COOKIE) or ""
        if not secrets.compare_digest(given.encode(), self.token.encode()):
            response: Response = PlainTextResponse(REFUSED, status_code=403)
            return await response(scope, receive, send)

        async def send_with_cookie(message: Any) -> None:
            if message["type"] == "http.response.start" and "token" in request.query_params:
                cookie = f"{COOKIE}={self.token}; Path=/; HttpOnly; SameSite=Strict"
                message["headers"] = [*message.get("headers", []), (b"set-cookie", cookie.encode())]
            await send(message)

        await self.app(scope, receive, send_with_cookie)


async def _body(request: Request) -> bytes:
    """The request's body, refused (413) past MAX_BODY_BYTES before more of it is read."""
    declared = request.headers.get("content-length")
    if declared is not None and (not declared.isdigit() or int(declared) > MAX_BODY_BYTES):
        raise BadRequest(413, f"the body is larger than {MAX_BODY_BYTES} bytes")
    body = b""
    async for chunk in request.stream():
        body += chunk
        if len(body) > MAX_BODY_BYTES:
            raise BadRequest(413, f"the body is larger than {MAX_BODY_BYTES} bytes")
    return body


def _error(status: int, line: str) -> JSONResponse:
    return JSONResponse({"ok": False, "error": line}, status_code=status)


def build_app(settings: Settings, key: bytes | None, live_url: str,
              closing: Callable[[], bool] = lambda: False) -> ASGIApp:
    """The application; `closing()` turns true when the server is asked to stop (its live
    streams then end, or an open page would hold the server up). Validating and predicting run
    in a worker thread: a large system's prediction holds up no live stream."""
    jobs = Jobs(settings.runs_dir)
    live: dict[str, LiveView] = {}

    def command_args(edits: list[str]) -> list[str]:
        out = [str(settings.file)]
        for edit in edits:
            out += ["-s", edit]
        out += ["--url", settings.url] if settings.url else []
        out += ["--key", str(settings.key_file)] if settings.key_file else []
        return out

    async def edited(request: Request) -> tuple[list[str], System]:
        """The request's edits and the system they make, or BadRequest: 4xx, nothing sent."""
        edits = overrides(parse(await _body(request), EditRequest))
        found = await run_in_threadpool(evaluate, settings.file, edits, settings.url)
        if found.system is None:
            raise BadRequest(422, found.error or "invalid")
        return edits, found.system

    async def index(request: Request) -> Response:
        return FileResponse(STATIC / "index.html")

    async def system(request: Request) -> Response:
        found = await run_in_threadpool(evaluate, settings.file, [], settings.url)
        return JSONResponse({**found.to_json(), "file": str(settings.file), "spawn": settings.spawn,
                             "url": live_url})

    async def predict(request: Request) -> Response:
        edits = overrides(parse(await _body(request), EditRequest))
        found = await run_in_threadpool(evaluate, settings.file, edits, settings.url)
        return JSONResponse(found.to_json(), status_code=200 if found.system else 422)

    async def push(request: Request) -> Response:
        edits, _ = await edited(request)
        # Into the run the page started (its DPUs switch at one shared cycle boundary): that run
        # is another session's to `skel push`, so this one says it means it.
        into_run = ["--force"] if any(j.kind == "run" for j in jobs.running()) else []
        argv = ["push", *command_args(edits), *into_run]
        return JSONResponse(jobs.start(Job("push", argv, edits=edits)).to_json())

    async def run(request: Request) -> Response:
        edits, found = await edited(request)
        out = jobs.run_dir(found.name)
        argv = ["run", *command_args(edits), "--out", str(out)] + (["--spawn"] if settings.spawn else [])
        return JSONResponse(jobs.start(Job("run", argv, out=out, edits=edits)).to_json())

    async def save(request: Request) -> Response:
        edits, found = await edited(request)
        if settings.url:  # the file keeps its own link URL: --url is this session's
            raise BadRequest(409, "cannot save under --url: the file would keep the session's URL unsaid")
        settings.file.write_text(saved_text(settings.file, edits, found))
        return JSONResponse({"ok": True, "saved": str(settings.file), "edits": edits})

    async def job(request: Request) -> Response:
        return JSONResponse([j.to_json() for j in jobs.shown()])

    async def runs(request: Request) -> Response:
        return JSONResponse(jobs.notebook())

    key_args = ["--key", str(settings.key_file)] if settings.key_file else []

    async def diff(request: Request) -> Response:
        asked = parse(await _body(request), DiffRequest)
        a, b = jobs.run_of(asked.a), jobs.run_of(asked.b)
        if a is None or b is None:
            raise BadRequest(404, "compare two runs of the notebook")
        return JSONResponse(jobs.start(Job("diff", ["diff", str(a), str(b), *key_args])).to_json())

    async def draw_plots(request: Request) -> Response:
        run = jobs.run_of(parse(await _body(request), PlotsRequest).run)
        if run is None:
            raise BadRequest(404, "plot a run of the notebook")
        argv = ["report", str(run), "--plots", str(run / PLOTS), *key_args]
        return JSONResponse(jobs.start(Job("report", argv, out=run)).to_json())

    async def plots(request: Request) -> Response:
        """The plots `skel report --plots` drew for a run of the notebook: their names, or one."""
        run = jobs.run_of(request.query_params.get("run", ""))
        if run is None:
            raise BadRequest(404, "a run of the notebook")
        name = request.query_params.get("name")
        if name is None:
            return JSONResponse(sorted(p.name for p in (run / PLOTS).glob("*.png")))
        if not PLOT_NAME.match(name) or not (run / PLOTS / name).is_file():
            raise BadRequest(404, f"no plot {name[:80]} for this run")
        return FileResponse(run / PLOTS / name)

    async def stream(request: Request) -> Response:
        if "view" not in live:  # one listener for every page open, started by the first
            live["view"] = LiveView(live_url, key)
        view = live["view"]

        async def events() -> Any:
            while not closing() and not await request.is_disconnected():
                yield f"data: {json.dumps(view.snapshot())}\n\n"
                await asyncio.sleep(LIVE_PERIOD_S)

        return StreamingResponse(events(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store"})

    async def refused(request: Request, exc: Exception) -> Response:
        assert isinstance(exc, BadRequest)
        return _error(exc.status, str(exc))

    async def busy(request: Request, exc: Exception) -> Response:
        return _error(409, str(exc))

    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette) -> AsyncIterator[None]:
        yield
        jobs.stop()
        for view in live.values():
            view.stop()

    routes = [
        Route("/", index), Route("/api/system", system), Route("/api/predict", predict, methods=["POST"]),
        Route("/api/push", push, methods=["POST"]), Route("/api/run", run, methods=["POST"]),
        Route("/api/save", save, methods=["POST"]), Route("/api/job", job), Route("/api/runs", runs),
        Route("/api/diff", diff, methods=["POST"]), Route("/api/live", stream),
        Route("/api/plots", draw_plots, methods=["POST"]), Route("/api/plots", plots, methods=["GET"]),
        Mount("/static", StaticFiles(directory=STATIC)),
    ]
    app = Starlette(routes=routes, exception_handlers={BadRequest: refused, Busy: busy},
                    lifespan=lifespan)
    return TokenGate(app, settings.token)

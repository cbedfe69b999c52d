"""`skel console [FILE] [--url URL] [--host ADDR] [--port N] [--key FILE] [--spawn]`: serve
the page on ADDR (127.0.0.1 unless told) and print one URL carrying a fresh random token, as
Jupyter does: another user of the machine cannot drive the lab through it."""

from __future__ import annotations

import argparse
import secrets
import socket
import sys
from pathlib import Path

import uvicorn

from skeleton.analysis.errors import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK
from skelmsg.contract import DEFAULT_URL

from ..live import spawn
from ..live.run import control_url
from .app import Settings, build_app
from .edits import evaluate

TOKEN_BYTES = 24
SHUTDOWN_S = 1.0


def console_command(args: argparse.Namespace) -> int:
    file = args.file
    if file is None:
        remembered = spawn.last_push(args.url or DEFAULT_URL)
        if remembered is None:
            print(f"skel console: no system file given and nothing pushed on {args.url or DEFAULT_URL} yet",
                  file=sys.stderr)
            return EXIT_BAD_INPUT
        file = remembered[0]
    found = evaluate(file, [], args.url)
    if found.system is None:
        print(found.error, file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        sock = socket.create_server((args.host, args.port), family=_family(args.host))
    except OSError as e:
        print(f"skel console: cannot listen on {args.host} port {args.port}: {e.strerror}", file=sys.stderr)
        return EXIT_FAILED
    token = secrets.token_urlsafe(TOKEN_BYTES)
    settings = Settings(file=Path(file), url=args.url, key_file=args.key_file, spawn=args.spawn,
                        runs_dir=args.runs_dir, token=token)
    server: uvicorn.Server | None = None
    app = build_app(settings, args.key, control_url(found.system),
                    closing=lambda: server is not None and server.should_exit)
    host, port = sock.getsockname()[:2]
    shown = f"[{host}]" if ":" in host else host
    print(f"skel console: {found.system.name} ({file}) at http://{shown}:{port}/?token={token}", flush=True)
    # A live stream ends when the server is asked to stop; a request under way has this long.
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", lifespan="on",
                                           timeout_graceful_shutdown=SHUTDOWN_S))
    server.run(sockets=[sock])
    return EXIT_OK  # after Ctrl-C or SIGTERM, uvicorn raises it again: skel exits 130, as every command


def _family(host: str) -> socket.AddressFamily:
    return socket.AF_INET6 if ":" in host else socket.AF_INET

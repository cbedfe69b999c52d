"""The `skel` commands: main.py parses and dispatches, one module per command beside it."""

from .main import build_parser, main

__all__ = ["build_parser", "main"]

"""The `skel` commands: commands.py parses and dispatches, one module per command beside it."""

from .commands import build_parser, main

__all__ = ["build_parser", "main"]

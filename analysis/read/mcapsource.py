"""An MCAP written by `skel export`, served back as the LCM log it came from.

The export attaches its source log whole (mcapformat.SOURCE_LOG): byte for byte, with
its seals, its damage and every run in it, so the analysis of the MCAP is the analysis
of the log, at the log's speed. The topics are for Foxglove; nothing is rebuilt from them.
"""

from __future__ import annotations

import os

from mcap.exceptions import McapError
from mcap.reader import make_reader

from .logreader import Log, read_bytes
from .mcapformat import METADATA, SOURCE_LOG


class McapSourceError(OSError):
    """The file is not an MCAP written by `skel export` (an OSError, so callers that
    report unreadable files need no new case)."""


def read_as_log(path: str | os.PathLike[str]) -> Log:
    """The LCM log an export came from (see the module comment). Raises OSError."""
    name = os.fspath(path)
    try:
        with open(path, "rb") as stream:
            reader = make_reader(stream)
            if METADATA not in {m.name for m in reader.iter_metadata()}:
                raise McapSourceError(f"{name}: not an MCAP written by `skel export`")
            source = next((a.data for a in reader.iter_attachments() if a.name == SOURCE_LOG), None)
    except McapError as e:
        raise McapSourceError(f"{name}: not a readable MCAP file ({e})") from e
    except (ValueError, KeyError) as e:
        raise McapSourceError(f"{name}: unexpected content ({e})") from e
    if source is None:
        raise McapSourceError(f"{name}: no {SOURCE_LOG} attached: exported by an older skel, export it again")
    return read_bytes(source, name)

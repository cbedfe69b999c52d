"""An MCAP written by `skel export`, served back as the LCM log it came from.

The export attaches its source log whole (mcapformat.SOURCE_LOG): byte for byte, with
its seals, its damage and every run in it, so the analysis of the MCAP is the analysis
of the log, at the log's speed; the run exported (the "skeleton" metadata's run_id) is
the one analysed unless another is asked for. The topics are for Foxglove; nothing is
rebuilt from them.
"""

from __future__ import annotations

import dataclasses
import os
import struct

from mcap.exceptions import McapError
from mcap.reader import make_reader

from ..errors import EXIT_BAD_INPUT, SkelError
from .logreader import Log, read_bytes
from .mcapformat import METADATA, SOURCE_LOG


class McapSourceError(SkelError, OSError):
    """The file is not an MCAP written by `skel export` (an OSError, so callers that
    report unreadable files need no new case)."""

    exit_code = EXIT_BAD_INPUT


def read_as_log(path: str | os.PathLike[str]) -> Log:
    """The LCM log an export came from (see the module comment). Raises OSError."""
    name = os.fspath(path)
    try:
        with open(path, "rb") as stream:
            reader = make_reader(stream)
            meta = next((m.metadata for m in reader.iter_metadata() if m.name == METADATA), None)
            if meta is None:
                raise McapSourceError(f"{name}: not an MCAP written by `skel export`")
            summary = reader.get_summary()
            index = next((a for a in summary.attachment_indexes if a.name == SOURCE_LOG), None) \
                if summary is not None else None  # fmt: skip
            if index is None:
                raise McapSourceError(f"{name}: no {SOURCE_LOG} attached: exported by an older skel, "
                                      "export it again")  # fmt: skip
            # The attachment's data, read straight from its record (the mcap reader would
            # refuse a record over 4 GiB): opcode, length, two times, name, media type, size.
            stream.seek(index.offset + 1 + 8 + 8 + 8)
            for _ in range(2):
                (length,) = struct.unpack("<I", stream.read(4))
                stream.seek(length, os.SEEK_CUR)
            (size,) = struct.unpack("<Q", stream.read(8))
            source = stream.read(size)
            if size != index.data_size or len(source) != size:
                raise McapSourceError(f"{name}: its {SOURCE_LOG} attachment is cut short")
    except McapError as e:
        raise McapSourceError(f"{name}: not a readable MCAP file ({e})") from e
    except (ValueError, KeyError, struct.error) as e:
        raise McapSourceError(f"{name}: unexpected content ({e})") from e
    run_id = meta.get("run_id", "")
    return dataclasses.replace(read_bytes(source, name), run_id=int(run_id) if run_id.isdigit() else None)

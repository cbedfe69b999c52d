"""The files the views write: whole or not at all (`replaced`), and a large one without
keeping it in the page cache (`DropBehindFile`).

`skel export` writes gigabytes (an MCAP holds its source log whole). Written plainly,
every page of it first lands in the page cache, and on a virtual machine whose host
takes back memory the guest left free (this project's: the memory a process had freed
came back at 2-3.6 s per GiB a second later) that costs more than the disk: a plain
2.4 GiB write here ran at 250-270 MB/s, the same write dropping what the disk already
holds at 1.8-1.95 GB/s (O_DIRECT: 1.6-1.7 GB/s, which tmpfs refuses). On a real machine
the output goes at the disk's speed instead of filling memory that other programs use,
as `dd oflag=nocache` does.

So, every STEP bytes: the kernel starts writing the step just filled, waits for the one
before it and forgets its pages. At most three steps of the file are in memory.
"""

from __future__ import annotations

import ctypes
import errno
import io
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

STEP = 64 << 20
# linux/fs.h: start writing; wait for what was started, start the rest, wait for it all
START, FLUSH = 2, 1 | 2 | 4
# The file systems that cannot (a pipe, some FUSE ones) say so with these: the file is
# then written plainly.
UNSUPPORTED = (errno.EINVAL, errno.ESPIPE, errno.ENOSYS, errno.EOPNOTSUPP)

_libc = ctypes.CDLL(None, use_errno=True)
_sync_file_range = getattr(_libc, "sync_file_range", None)  # Linux only
if _sync_file_range is not None:
    _sync_file_range.argtypes = [ctypes.c_int, ctypes.c_int64, ctypes.c_int64, ctypes.c_uint]


@contextmanager
def replaced(path: str | os.PathLike[str]) -> Iterator[Path]:
    """The path to write `path` through: PATH.part, renamed to PATH once written whole (a
    reader never sees half a file under its name), removed if the writing fails (a full
    disk is not left full of it)."""
    part = Path(f"{os.fspath(path)}.part")
    try:
        yield part
        part.replace(path)
    except BaseException:
        part.unlink(missing_ok=True)
        raise


class DropBehindFile(io.FileIO):
    """A file opened for writing ("wb") whose written pages leave the page cache as soon
    as they are on disk. A write error the kernel meets on the way is raised by the write
    that waits for it."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        super().__init__(path, "wb")
        self._dropped = 0  # bytes from the start forgotten (a multiple of STEP): the writer only appends
        self._dropping = _sync_file_range is not None and hasattr(os, "posix_fadvise")

    def write(self, data: Any) -> int:  # any buffer, as FileIO's
        view = memoryview(data).cast("B")
        done = 0
        while done < len(view):
            # A write to a regular file is whole unless interrupted: carry on from where it stopped.
            done += super().write(view[done : done + STEP]) or 0
            while self._dropping and self.tell() - self._dropped >= 2 * STEP:
                self._drop_step()
        return done

    def _drop_step(self) -> None:
        """Start writing the newer of the two steps not yet forgotten; forget the older."""
        oldest = self._dropped
        if self._sync(oldest + STEP, START) and self._sync(oldest, FLUSH):
            os.posix_fadvise(self.fileno(), oldest, STEP, os.POSIX_FADV_DONTNEED)
            self._dropped += STEP

    def _sync(self, offset: int, flags: int) -> bool:
        """sync_file_range; False (and no more dropping) where the file system cannot."""
        if _sync_file_range is None or _sync_file_range(self.fileno(), offset, STEP, flags) == 0:
            return True
        code = ctypes.get_errno()
        if code not in UNSUPPORTED:
            raise OSError(code, os.strerror(code), self.name)
        self._dropping = False
        return False

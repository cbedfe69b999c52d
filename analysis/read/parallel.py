"""Memory-bound numpy work spread over the machine's cores.

The log reader's big steps (scanning for sync words, copying columns out of the
memory map) are numpy calls that release the GIL: run side by side in threads
they use the second core of a small machine, where the analysis would otherwise
wait on one core's memory bandwidth.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

T = TypeVar("T")
R = TypeVar("R")

WORKERS = min(4, os.cpu_count() or 1)
WORTH_BYTES = 4 << 20  # below this much work a thread costs more than it saves
M_ARENA_MAX = -8  # glibc's malloc.h


def table_bytes(*tables: Any) -> int:
    """About how many bytes of columns some tables (numpy or ColumnTable) hold: map_threads'
    `work_bytes` for work that reads them."""
    return sum(len(t) * t.dtype.itemsize for t in tables)


def one_heap() -> None:
    """Have the threads started from now on allocate from glibc's one main arena (call it
    before the analysis starts its workers). A worker's numpy arrays otherwise come from an
    arena of its own, whose freed memory the other threads do not reuse: they ask the kernel
    for fresh pages, which a virtual machine's host may back only when first written. The
    report of 10^7 records faulted 460-490 k pages instead of 550-620 k, in 10.3-11.2 s
    instead of 11.4-12.6 s (seven runs each, taken in turn). Python's threads allocate under
    the GIL anyway, so one arena's lock makes them wait for nothing. A C library without
    mallopt: nothing to do."""
    mallopt = getattr(ctypes.CDLL(None), "mallopt", None)
    if mallopt is not None:
        mallopt(M_ARENA_MAX, 1)  # 0 (refused) leaves the arenas as they were: only slower


def map_threads(fn: Callable[[T], R], items: Iterable[T], work_bytes: int) -> list[R]:
    """[fn(item) for item in items], on WORKERS threads when `work_bytes` makes it worth it."""
    items = list(items)
    if WORKERS < 2 or len(items) < 2 or work_bytes < WORTH_BYTES:
        return [fn(item) for item in items]
    pool = ThreadPoolExecutor(min(WORKERS, len(items)))
    try:
        return list(pool.map(fn, items))
    finally:
        # After Ctrl-C or an error, what has not started does not (a with-block would run it all first).
        pool.shutdown(cancel_futures=True)

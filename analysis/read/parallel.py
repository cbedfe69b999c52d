"""Memory-bound numpy work spread over the machine's cores.

The log reader's big steps (scanning for sync words, copying columns out of the
memory map) are numpy calls that release the GIL: run side by side in threads
they use the second core of a small machine, where the analysis would otherwise
wait on one core's memory bandwidth.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")

WORKERS = min(4, os.cpu_count() or 1)
WORTH_BYTES = 4 << 20  # below this much work a thread costs more than it saves


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

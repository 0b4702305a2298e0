"""Index ranges of a serial kernel run on a few Python threads.

The engine's loops over rows or points are serial ``@njit(cache=True, nogil=True)`` kernels that
take an index range ``[lo, hi)``; ``split_range`` calls them on contiguous ranges from a thread
pool (the kernels release the GIL, so the ranges run at the same time). numba's
``parallel=True`` gives the same speed-up but costs a second or more of compilation per kernel
(first run). Each index is processed by exactly one call, so results equal one whole-range call.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

from ..cores import usable_threads

#: ranges per thread: small enough pieces that unequal rows (e.g. spans) balance
_PIECES_PER_THREAD = 4


def ranges(n: int, pieces: int, min_size: int = 1) -> list[tuple[int, int]]:
    """[lo, hi) ranges covering [0, n) in order: ``pieces`` of them at most, none smaller than
    ``min_size`` (except when n itself is), sizes differing by one at most."""
    n = max(int(n), 0)
    if n == 0:
        return []
    k = max(1, min(int(pieces), n // max(int(min_size), 1)))
    bounds = [n * i // k for i in range(k + 1)]
    return [(bounds[i], bounds[i + 1]) for i in range(k)]


def split_range(kernel: Callable[[int, int], object], n: int, *, threads: int | None = None,
                min_size: int = 1, pieces_per_thread: int = _PIECES_PER_THREAD) -> None:
    """Call ``kernel(lo, hi)`` on ranges covering [0, n) exactly once each, on up to ``threads``
    threads (default ``cores.usable_threads()``); ranges of at least ``min_size`` indices,
    ``pieces_per_thread`` of them a thread. One thread or one range: a single direct call.
    Exceptions of the kernel are raised here."""
    threads = usable_threads() if threads is None else max(int(threads), 1)
    parts = ranges(n, threads * pieces_per_thread if threads > 1 else 1, min_size)
    if not parts:
        return
    if threads == 1 or len(parts) == 1 or threading.current_thread().name.startswith(_PREFIX):
        for lo, hi in parts:  # (inside a range already: no nested waiting on the pool)
            kernel(lo, hi)
        return
    pool = _pool(threads)
    for f in [pool.submit(kernel, lo, hi) for lo, hi in parts]:
        f.result()


_PREFIX = "engine-range"
_POOLS: dict[int, ThreadPoolExecutor] = {}
_LOCK = threading.Lock()
os.register_at_fork(after_in_child=_POOLS.clear)  # a forked child has none of the threads


def _pool(threads: int) -> ThreadPoolExecutor:
    """One pool of ``threads`` workers per process, kept (starting threads for every call would
    cost 0.1 s over the 15 bands of a map)."""
    with _LOCK:
        if threads not in _POOLS:
            _POOLS[threads] = ThreadPoolExecutor(max_workers=threads,
                                                 thread_name_prefix=_PREFIX)
        return _POOLS[threads]

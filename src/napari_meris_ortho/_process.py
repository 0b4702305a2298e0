"""Process tuning for a process this package owns (the ``meris-ortho`` command and the
background compiler of ``warmup``), in one place, with one switch.

Set ``MERIS_ORTHO_NO_TUNING=1`` to turn all of it off (the process then runs as any Python
process; only speed changes). A library user's process is never tuned: only ``cli.console_main``
and ``python -m napari_meris_ortho.warmup --late`` call ``tune_process``. A dask worker that runs
the synthesis' tile tasks gets its malloc thresholds back (``keep_task_arrays``).

What it does (the figures are those of a fr-alps map):

- glibc's malloc keeps the memory the run frees (``mallopt``): band-sized arrays come back from
  the heap instead of fresh, kernel-zeroed ``mmap`` pages (0.3 s of a 3.9 s map);
- numpy arrays on ordinary pages (``NUMPY_MADVISE_HUGEPAGE=0``, read by numpy when first
  imported: transparent huge pages cost 0.4-0.6 s of compaction and zeroing);
- one OpenBLAS thread (no linear algebra here: its server threads spin at start-up);
- Python's cyclic garbage collector run rarely, and not at all on the way out;
- numba's CPU target started without importing scipy.linalg (0.13-0.2 s saved).

In a napari session (the plugin's reader and widget): glibc's malloc handing big blocks back
when they are freed (``return_freed_memory``) but for the length of a synthesis run
(``task_arrays_kept``), the viewer's heap trimmed after layer removals (``schedule_trim``), and
pint's unit registry loaded from pint's own disk cache while no one has used it yet
(``unit_registry_from_disk``).

numba offers no public interface for two things this package needs; both private hooks are
here and only here (``numba_cache_index``, ``_refresh_cpu_target``), and ``check_numba_hooks``
(run by the tests) fails loudly when a numba release changes them.
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import os
import sys
import threading
from collections.abc import Callable, Iterator
from typing import Any

#: the one switch: any non-empty value turns the tuning off
SWITCH = "MERIS_ORTHO_NO_TUNING"
#: glibc ``mallopt`` parameters
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3


def enabled() -> bool:
    """False when ``MERIS_ORTHO_NO_TUNING`` is set."""
    return not os.environ.get(SWITCH)


def tune_process() -> None:
    """Before numpy is imported: ordinary pages for numpy arrays, one OpenBLAS thread (a
    user's own settings win), glibc keeping freed memory (module docstring)."""
    if not enabled():
        return
    os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    _keep_freed_memory()


def _malloc_thresholds(mmap_threshold: int, trim_threshold: int) -> bool:
    """glibc's ``mallopt``: blocks from ``mmap_threshold`` up mapped on their own, a heap
    trimmed past ``trim_threshold`` free at its top (both set: glibc then leaves them where
    they are). False off glibc or when glibc refuses a value."""
    with contextlib.suppress(OSError, AttributeError, ValueError):
        if not (os.confstr("CS_GNU_LIBC_VERSION") or "").startswith("glibc"):
            return False
        libc = ctypes.CDLL(None)
        return bool(libc.mallopt(_M_MMAP_THRESHOLD, mmap_threshold)
                    and libc.mallopt(_M_TRIM_THRESHOLD, trim_threshold))
    return False


def _keep_freed_memory() -> None:
    """glibc's malloc: arrays up to 1 GiB from the heap, no trimming; no-op off glibc."""
    _malloc_thresholds(2 ** 30, 2 ** 31 - 1)


#: a long-lived process (the viewer): blocks from this size up are mapped on their own, heaps are
#: trimmed past twice it (``return_freed_memory``); with 1 MiB, smaller blocks (tiles, small
#: levels) can keep 21-37 MB resident
VIEWER_MMAP_THRESHOLD = 2**18


def return_freed_memory() -> bool:
    """glibc's malloc in a long-lived process (the viewer): a block of ``VIEWER_MMAP_THRESHOLD``
    or more mapped on its own, so that freeing it hands it back whichever thread made it, and
    every heap trimmed past twice that. glibc's default raises both thresholds as big blocks are
    freed (up to 32 and 64 MiB); a run's arrays then come from its worker thread's heap, whose
    free top ``malloc_trim`` leaves alone: after four fr-alps runs with every layer removed, a
    session can hold 57 MB (13 %) more resident, against 3-4 % with this. The
    cost: a run's arrays come from fresh pages each time (the job of a 3-band fr-alps run, in
    the worker: 0.2-0.36 s more of 2.5 s). False off glibc or with the tuning off. The opposite of
    ``_keep_freed_memory`` (the command's short process). A synthesis run in the process
    keeps its arrays for its length (``task_arrays_kept``)."""
    if not enabled():
        return False
    with _runs_lock:
        _runs["viewer"] = True
        if _runs["kept"]:  # a run is keeping its arrays: its end sets them
            return True
        return _viewer_thresholds()


def _viewer_thresholds() -> bool:
    """glibc's thresholds of a long-lived process: ``VIEWER_MMAP_THRESHOLD``, trimmed past
    twice it."""
    return _malloc_thresholds(VIEWER_MMAP_THRESHOLD, 2 * VIEWER_MMAP_THRESHOLD)


#: a process whose malloc hands big blocks back (``return_freed_memory`` called), and how many
#: synthesis runs are keeping their arrays in it (``task_arrays_kept``)
_runs = {"viewer": False, "kept": 0}
_runs_lock = threading.Lock()


@contextlib.contextmanager
def task_arrays_kept() -> Iterator[None]:
    """A synthesis run's tile tasks in a process whose malloc hands big blocks back (the
    viewer's: ``return_freed_memory``): for the run's length, its arrays come from the heap as
    in a worker (``keep_task_arrays``); the viewer's thresholds come back after the last run,
    and the heap is trimmed (``malloc_trim``). The run's arrays are its own (its result is in
    the store), so none outlives it. In the Orthorectify widget, this takes about a fifth off
    ``synthesize`` for 4 fr-alps products of 15 bands (``bench_napari.py --synthesis 4``), with
    the same memory left once the layers are removed. Elsewhere (a command, a library user's
    process): nothing."""
    with _runs_lock:
        viewer = _runs["viewer"]
        if viewer:
            if not _runs["kept"]:
                keep_task_arrays()
            _runs["kept"] += 1
    try:
        yield
    finally:
        if viewer:
            with _runs_lock:
                _runs["kept"] -= 1
                last = not _runs["kept"]
                if last:
                    _viewer_thresholds()
            if last:
                malloc_trim()


#: a dask worker of the synthesis: blocks from this size up are mapped on their own, its heap is
#: trimmed past twice it (the ceilings of glibc's own moving thresholds, ``keep_task_arrays``)
WORKER_MMAP_THRESHOLD = 32 * 2**20


def keep_task_arrays() -> bool:
    """glibc's malloc in a dask worker that runs the synthesis' tasks, one tile after another:
    blocks under ``WORKER_MMAP_THRESHOLD`` come from the heap, and a heap is trimmed past twice
    it free at its top, where glibc's default thresholds would have moved up to. A dask nanny
    starts its workers with ``MALLOC_TRIM_THRESHOLD_=65536`` (``distributed.nanny.pre-spawn-
    environ``), which fixes both at 128 KiB: every array of a tile is then fresh, kernel-zeroed
    pages, freed again at once: one worker (held to a core) merging 4 fr-alps products of 15
    bands makes about a million page faults and spends 4 s of system time in a 15 s run; with
    this, 50 thousand faults in an 11 s run, for a peak resident memory of 670 MB instead of
    450 MB. False off glibc or with the tuning off."""
    return enabled() and _malloc_thresholds(WORKER_MMAP_THRESHOLD, 2 * WORKER_MMAP_THRESHOLD)


def malloc_trim() -> bool:
    """Return the C heap's free memory to the system (glibc ``malloc_trim(0)``); False off
    glibc. The opposite of ``_keep_freed_memory``, for a long-lived process (the viewer) once
    what it freed will not be needed again soon."""
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return False
    trim(0)
    return True


#: seconds after the last request (napari's deferred deletions done) before trimming
TRIM_DELAY_S = 1.0
_trim_lock = threading.Lock()
_pending: dict[str, threading.Timer] = {}


def schedule_trim(delay_s: float = TRIM_DELAY_S) -> threading.Timer:
    """``malloc_trim`` in a background thread ``delay_s`` after the last call (debounced; ctypes
    releases the GIL, so the caller never waits for it)."""
    with _trim_lock:
        old = _pending.pop("timer", None)
        if old is not None:
            old.cancel()
        timer = threading.Timer(delay_s, malloc_trim)
        timer.daemon = True
        timer.name = "meris-ortho-trim"
        _pending["timer"] = timer
        timer.start()
        return timer


@contextlib.contextmanager
def few_collections(last: bool) -> Iterator[None]:
    """Python's cyclic garbage collector run rarely (imports and numba's cache loading make
    hundreds of thousands of objects: 0.3 s of collections in a 3.5 s map); restored after,
    or, when the process ends with this run (``last``), turned off: the collections that
    restoring and leaving would start walk every object the run made for nothing."""
    if not enabled():
        yield
        return
    previous = gc.get_threshold()
    gc.set_threshold(200_000, 50, 100)
    try:
        yield
    finally:
        if last:  # Python collects at exit even when disabled: frozen objects it skips
            gc.disable()
            gc.freeze()
        else:
            gc.set_threshold(*previous)


def unit_registry_from_disk() -> bool:
    """pint's application registry (the units napari gives every layer) loaded from pint's own
    disk cache (``cache_folder`` in the user's cache directory, written by the first session)
    instead of parsed from pint's definition files in every session: the first layer of a
    session then spends 0.015 s on it, not 0.15 s. Only while the registry is pint's untouched
    lazy default: a registry in use is never replaced. A cache that cannot be written or read
    leaves pint as it was (napari then builds its registry as usual). False when nothing was
    done."""
    if not enabled():
        return False
    import pint

    if type(pint.get_application_registry().get()) is not pint.LazyRegistry:
        return False
    try:
        import platformdirs

        folder = platformdirs.user_cache_path("pint", appauthor=False)
        folder.mkdir(parents=True, exist_ok=True)
        # pint's lazy default raises on a redefinition: the same here
        registry: Any = pint.UnitRegistry(cache_folder=folder, on_redefinition="raise")
    except Exception:  # any failure (a broken cache, no folder): pint as it was
        return False
    pint.set_application_registry(registry)
    return True


def start_numba_without_blas() -> None:
    """Start numba's CPU target without importing scipy.linalg. numba's first compilation or
    cache load imports its array implementations, and one of them imports scipy.linalg only to
    learn whether BLAS is there (without it, compiled ``np.correlate`` / ``np.convolve`` use a
    plain loop). No kernel of this package calls BLAS, and a kernel with ``np.dot`` still gets
    it: numba imports scipy.linalg again when it compiles one. Before the process's first
    kernel and before it starts other threads; no-op once scipy.linalg or numba's array
    implementations are imported, or with the tuning off."""
    for piece in numba_start_pieces():
        piece()


#: the implementation modules numba's CPU target imports at the process's first compilation or
#: cache load (``BaseContext.refresh``), heaviest first; ``numba_start_pieces`` imports them
#: one at a time
NUMBA_TARGET_MODULES = (
    "numba.cpython.charseq", "numba.cpython.unicode", "numba.np.arrayobj", "numba.np.linalg",
    "numba.np.arraymath", "numba.np.npyimpl", "numba.cpython.builtins",
    "numba.cpython.enumimpl", "numba.cpython.hashing", "numba.cpython.heapq",
    "numba.cpython.iterators", "numba.cpython.listobj", "numba.cpython.numbers",
    "numba.cpython.rangeobj", "numba.cpython.setobj", "numba.cpython.slicing",
    "numba.cpython.tupleobj", "numba.core.optional", "numba.core.inline_closurecall",
    "numba.misc.gdb_hook", "numba.misc.literal", "numba.np.random.generator_core",
    "numba.np.random.generator_methods", "numba.np.random.legacy",
    "numba.np.polynomial.polynomial_core", "numba.np.polynomial.polynomial_functions",
    "numba.typed.typeddict", "numba.typed.dictimpl", "numba.typed.typedlist",
    "numba.typed.listobject", "numba.typed.typedset", "numba.typed.setobject",
    "numba.experimental.jitclass", "numba.experimental.function_type",
    "numba.np.types.datetime_registry", "numba.np.npdatetime", "numba.cpython.cmathimpl",
    "numba.cpython.mathimpl", "numba.cpython.printimpl", "numba.cpython.randomimpl",
    "numba.misc.cffiimpl", "numba.experimental.jitclass.base",
)


def numba_start_pieces() -> list[Callable[[], None]]:
    """``start_numba_without_blas`` in pieces of a few tens of milliseconds each (for a
    process that must stay responsive while numba starts: the napari dock's warm-up): numba's
    implementation modules imported one per piece (``numba.np.arraymath`` without
    scipy.linalg), then the CPU target refreshed with them in memory. Empty when numba's array
    implementations are imported already or the tuning is off (numba then starts as usual)."""
    if not enabled() or "scipy.linalg" in sys.modules or "numba.np.arraymath" in sys.modules:
        return []

    def load(name: str) -> Callable[[], None]:
        def piece() -> None:
            if name == "numba.np.arraymath" and "scipy.linalg" not in sys.modules:
                sys.modules["scipy.linalg"] = None  # type: ignore[assignment]
                try:
                    __import__(name)  # (the import statement's way: -X importtime sees it)
                finally:
                    del sys.modules["scipy.linalg"]
            else:
                __import__(name)
        piece.__qualname__ = piece.__name__ = f"import {name}"
        return piece

    return [*(load(name) for name in NUMBA_TARGET_MODULES), _refresh_cpu_target]


# --------------------------------------------------------------------------- numba's privates


def _refresh_cpu_target() -> None:
    """numba private: load the CPU target's implementations now (``refresh``)."""
    from numba.core.registry import cpu_target

    cpu_target.target_context.refresh()


def numba_cache_index(dispatcher: Any) -> str | None:
    """numba private: the path of a ``cache=True`` kernel's cache index file (``.nbi``; it
    exists once the kernel was compiled for this installation), None when numba does not say."""
    cache_file = getattr(getattr(dispatcher, "_cache", None), "_cache_file", None)
    index = getattr(cache_file, "_index_path", None)  # numba's IndexDataCacheFile
    return None if index is None else str(index)


def check_numba_hooks(dispatcher: Any) -> None:
    """RuntimeError naming what changed when numba's private interfaces used here are gone
    (``dispatcher``: a ``cache=True`` kernel)."""
    import numba
    from numba.core.registry import cpu_target

    missing = []
    if not callable(getattr(getattr(cpu_target, "target_context", None), "refresh", None)):
        missing.append("numba.core.registry.cpu_target.target_context.refresh()")
    index = numba_cache_index(dispatcher)
    if index is None or not index.endswith(".nbi"):
        missing.append("Dispatcher._cache._cache_file._index_path (the .nbi cache index)")
    if missing:
        raise RuntimeError(f"numba {numba.__version__} changed private interfaces that "
                           f"napari_meris_ortho._process uses: {', '.join(missing)}")

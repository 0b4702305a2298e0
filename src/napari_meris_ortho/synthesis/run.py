"""One ``synthesize`` run: plan one task per output tile (``tile_job``: the (product, tile)
pieces orthorectified and merged in it), run them in this process or on dask workers, merge the
Icechunk forks and commit (see :mod:`napari_meris_ortho.synthesis`).

Task functions are module-level (dask ships them by reference); the products they open and the
grids they build are cached per worker process, so a product is opened once per worker, not once
per tile.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
import sys
import uuid
import warnings
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from .._process import keep_task_arrays, task_arrays_kept
from ..engine.synthesis import NDVI_NIR_BAND, NDVI_RED_BAND, TileState, WinnerBands
from ..errors import DemError, MerisOrthoError, OptionsError, OutputError
from ..options import OrthoOptions, Sampling, StoreCodec
from ..progress import ProgressCallback
from . import store as st
from .reading import SynthesisStore
from .reports import (
    RADIANCE_NOTE,
    STATUS_ALREADY,
    STATUS_FAILED,
    STATUS_OUTSIDE,
    ProductReport,
    SynthesisResult,
    message_of,
)
from .store import Window
from .tiling import (
    ALL_BANDS,
    check_new_grid_size,
    check_write_size,
    footprint_window,
    grid_from_dict,
    grid_to_dict,
    terrain_margin_px,
    tile_of,
    tiles,
)

if TYPE_CHECKING:
    from ..ortho.antecedents import Antecedents

log = logging.getLogger("napari_meris_ortho.synthesis")

#: seconds to wait for a dask scheduler before giving up (bad address: exit 2 quickly)
CONNECT_TIMEOUT_S = 8
#: products / grids kept open per process
CACHE_SIZE = 16
#: environment of embedded worker processes: one thread each (the workers are the parallelism)
WORKER_ENV = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
              "MKL_NUM_THREADS": "1"}

#: a segment task: product index, path, its piece of the grid, the product's whole window
Job = tuple[int, str, Window, Window]
#: the fixed cost of a piece (its segment window, lines read, merge call) in output pixels of
#: work: about 0.04 s against 0.28 s per million pixels inside a product (fr-alps tile tasks)
PIECE_WORK_PX = 1 << 17


# --------------------------------------------------------------------------- runners


class _Lazy:
    """A task of the in-process runner: computed when its turn comes (submission order)."""

    def __init__(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        self.fn, self.args = fn, args
        self.value: Any = None
        self.done = False

    def compute(self) -> Any:
        if not self.done:
            self.value = self.fn(*self.args)
            self.done, self.args = True, ()
        return self.value


class InProcess:
    """Runs the tasks one after the other in this process, in submission order; a tile's
    writes go out on a writer thread (``TileWriter``) while the next tile is computed."""

    def __init__(self) -> None:
        self.writer = TileWriter()

    def submit(self, fn: Callable[..., Any], *args: Any, **_: Any) -> _Lazy:
        return _Lazy(fn, args)

    def completed(self, futures: Sequence[_Lazy]) -> Iterator[_Lazy]:
        for f in futures:
            f.compute()
            yield f

    def result(self, future: _Lazy) -> Any:
        return future.value

    def release(self, futures: Sequence[Any]) -> None:
        pass

    def cancel(self, futures: Sequence[Any]) -> None:
        pass


class Dask:
    """Runs tasks on a dask.distributed cluster."""

    def __init__(self, client: Any) -> None:
        self.client = client

    def submit(self, fn: Callable[..., Any], *args: Any, key: str, priority: int = 0) -> Any:
        return self.client.submit(fn, *args, key=key, priority=priority, pure=False)

    def completed(self, futures: Sequence[Any]) -> Iterator[Any]:
        from distributed import as_completed

        yield from as_completed(futures, loop=self.client.loop)

    def result(self, future: Any) -> Any:
        return future.result()

    def release(self, futures: Sequence[Any]) -> None:
        for f in futures:
            f.release()

    def cancel(self, futures: Sequence[Any]) -> None:
        with contextlib.suppress(Exception):
            self.client.cancel(list(futures))


class TileWriter:
    """One thread that writes the merged tiles of the in-process runner: the chunks of tile
    N are compressed (zstd releases the GIL) and written into its fork while tile N + 1 is
    orthorectified and merged. At most one write is pending: ``submit`` first waits for the
    previous one (one merged tile in memory besides the one being computed)."""

    def __init__(self) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="synthesis-writer")
        self._last: Any = None

    def submit(self, fn: Callable[[], int]) -> Any:
        """Run ``fn`` (a tile's writes, returning the chunks written) on the thread; the
        future gives its result or raises its error."""
        if self._last is not None:
            self._last.exception()  # wait; the error, if any, is raised by its owner
        self._last = self._pool.submit(fn)
        return self._last

    def close(self) -> None:
        """Wait for the pending write (a failed run's fork is dropped, not committed)."""
        self._pool.shutdown(wait=True)


def hold_to_core(core: int) -> None:
    """Hold every thread of this process to ``core`` (the threads it starts later inherit it
    from the thread that starts them)."""
    for tid in os.listdir("/proc/self/task"):
        with contextlib.suppress(OSError):  # a thread that has just ended
            os.sched_setaffinity(int(tid), {core})


def hold_workers_to_cores(client: Any, every: bool = False) -> dict[str, int]:
    """Hold each worker of ``client``'s cluster (processes on this machine) to a core of its
    own when there are as many workers as cores this process may use, or with ``every`` (as
    many workers as cores at most); returns {worker address: core}, empty when not held.

    A worker runs its task on one thread, but its writes (Icechunk's I/O threads, zstd) run
    beside it: left free, the workers' threads move between the cores and meet on the same
    one. Held, two workers on 2 cores merge 6 fr-alps products in about 11.1 s, left free in
    about 12 s (``benchmarks/bench_synthesis.py``)."""
    if not (hasattr(os, "sched_setaffinity") and os.path.isdir("/proc/self/task")):
        return {}
    cores = sorted(os.sched_getaffinity(0))
    workers = sorted(client.scheduler_info()["workers"])
    if not workers or len(workers) > len(cores) or (len(workers) < len(cores) and not every):
        return {}
    held = {}
    for core, worker in zip(cores[:len(workers)], workers, strict=True):
        client.run(hold_to_core, core, workers=[worker])
        held[worker] = core
    return held


@contextlib.contextmanager
def engine(workers: int, scheduler: str | None) -> Iterator[InProcess | Dask]:
    """The runner: this process, an embedded LocalCluster or an existing scheduler."""
    if scheduler is None and workers == 0:
        runner = InProcess()
        with task_arrays_kept():  # in a viewer: its arrays from the heap, as in a worker
            try:
                yield runner
            finally:
                runner.writer.close()
                _release_decoded_bands()
        return
    import distributed

    with contextlib.ExitStack() as stack:
        quiet = logging.getLogger("distributed")  # its INFO lines are not ours to print
        stack.callback(quiet.setLevel, quiet.level)
        quiet.setLevel(logging.ERROR)
        if scheduler is not None:
            try:
                client = distributed.Client(scheduler, timeout=CONNECT_TIMEOUT_S,
                                            set_as_default=False)
            except (OSError, TimeoutError, ValueError, TypeError) as exc:
                raise OptionsError(f"cannot reach the dask scheduler at {scheduler} "
                                   f"({message_of(exc).splitlines()[0]})") from None
        else:
            with warnings.catch_warnings():  # "port 8787 in use": no dashboard is served
                warnings.simplefilter("ignore", UserWarning)
                cluster = stack.enter_context(distributed.LocalCluster(
                    n_workers=workers, threads_per_worker=1, processes=True,
                    dashboard_address=None, env=WORKER_ENV,
                    silence_logs=logging.CRITICAL))  # a failed task: the client reports it
            client = distributed.Client(cluster, set_as_default=False)
            hold_workers_to_cores(client)  # our own processes: one core each, if they fit
        stack.callback(client.close)
        stack.callback(_release_on_workers, client)  # before the close: on every worker
        yield Dask(client)


def _release_on_workers(client: Any) -> None:
    """The decoded ``.SEN3`` bands the run's tasks kept, freed on every worker (an external
    cluster's workers outlive the run)."""
    with contextlib.suppress(Exception):  # a worker gone, a closing cluster: nothing to free
        client.run(_release_decoded_bands)


def _release_decoded_bands() -> None:
    """The end of a run in this process: bands read ahead and not begun are called off, the
    bands kept are freed."""
    from ..products.sen3.kept import release_decoded_bands

    for product in list(_PRODUCTS.values()):
        cancel = getattr(product, "cancel_read_ahead", None)
        if callable(cancel):
            cancel()
    release_decoded_bands()


# --------------------------------------------------------------------------- worker side


@dataclass(frozen=True)
class Spec:
    """What every task needs to know of the run (small, picklable)."""

    grid: tuple[tuple[str, Any], ...]
    bands: tuple[int, ...]
    algorithm: str
    dems: tuple[str, ...]
    #: the options of ``orthorectify`` (its bands: those the merge rule needs)
    options: OrthoOptions
    reject_bright: bool
    tile: int
    names: tuple[str, ...]
    overviews: tuple[int, ...]
    #: band layers stored as uint16 counts (store versions 3, 4): every product's radiances are
    #: quantized to them before the merge, so the merge compares what the store holds
    compact: bool = True
    #: the snapshot the tile tasks' forks start from (``Run._session``: no uncommitted
    #: changes): its arrays' metadata is read once per process (``store._open_array``)
    layout: str = ""

    @property
    def needed(self) -> tuple[int, ...]:
        return _needed(self.bands, self.algorithm)


def _needed(bands: Sequence[int], algorithm: str) -> tuple[int, ...]:
    """The bands a product is sampled in: the synthesis's and the NDVI's (max-NDVI rule)."""
    ndvi = {NDVI_RED_BAND, NDVI_NIR_BAND} if algorithm == "max-ndvi" else set()
    return tuple(sorted(set(bands) | ndvi))


@dataclass
class Piece:
    """One product's contribution to one tile (``state`` covers ``window``; None: nothing).
    In a compact store (``Spec.compact``) the state's bands are the store's uint16 counts: the
    product's own at the nearest pixel (``counts_as_stored``), else ``engine.synthesis.count_of``
    of radiances already quantized to them (exact); merged as counts by ``tile_task``
    (``_state_of``)."""

    index: int
    window: Window
    state: TileState | None
    processed: int = 0
    validated: int = 0
    error: str | None = None
    dem_error: str | None = None
    #: the state's bands, read where it wins at its merge (``gathers_winners``), or None
    source: WinnerBands | None = None


@dataclass
class TileDone:
    """A written tile: its fork of the session and the pixels each product holds there."""

    fork: Any
    window: Window
    winners: dict[int, int] = field(default_factory=dict)
    #: chunks written (every layer and overview level)
    chunks: int = 0
    pieces: list[Piece] = field(default_factory=list)  # without their states
    #: the writes still under way on the in-process ``TileWriter`` (None: done)
    writing: Any = None

    def wait(self) -> None:
        """Wait for the tile's writes (in-process writer thread); their error is raised."""
        if self.writing is not None:
            self.chunks, self.writing = self.writing.result(), None


_PRODUCTS: OrderedDict[str, Any] = OrderedDict()
_GRIDS: OrderedDict[tuple[Any, ...], Any] = OrderedDict()
_SEGMENTS: OrderedDict[tuple[Any, ...], Any] = OrderedDict()


def _cached(cache: OrderedDict[Any, Any], key: Any, make: Callable[[], Any]) -> Any:
    if key in cache:
        cache.move_to_end(key)
        return cache[key]
    value = cache[key] = make()
    while len(cache) > CACHE_SIZE:
        cache.popitem(last=False)
    return value


def _product(path: str) -> Any:
    from ..products.open import read_product

    return _cached(_PRODUCTS, path, lambda: read_product(path))


def _grid(spec: Spec) -> Any:
    return _cached(_GRIDS, spec.grid, lambda: grid_from_dict(dict(spec.grid)))


def _segment(spec: Spec, path: str, extent: Window) -> Any:
    """The product's ``ortho.Segment`` (tie points, segment boundary, DEMs read under its
    whole ``extent`` of the grid), built once per worker process and product."""
    from ..ortho import open_segment

    def make() -> Any:
        segment = open_segment(_product(path), list(spec.dems), spec.options)
        segment.prepare_dems(_grid(spec).window(*extent))
        return segment

    key = (path, extent, spec.grid, spec.dems, spec.options)
    return _cached(_SEGMENTS, key, make)


def segment_task(spec: Spec, index: int, path: str, window: Window,
                 extent: Window | None = None) -> Piece:
    """Orthorectify product ``path`` on ``window`` of the grid: its contribution (cropped to
    its validated pixels); ``extent``: the product's whole window of the grid (default
    ``window``). Errors come back as text (exceptions may not survive pickling)."""
    from ..engine.synthesis import segment_counts_state, segment_state, winner_state

    _keep_bands(spec)
    try:
        segment = _segment(spec, path, window if extent is None else extent)
        _prepare_bands(segment.prod, spec.needed)  # the workers of a host decode them together
        antecedents = segment.precompute(_grid(spec).window(*window), allow_empty=True,
                                         hold_bands=True)
        gathering = gathers_winners(spec, segment.prod)
        # (first: the NDVI bands are then gathered from the windows it copies)
        source = antecedents.nearest_source(spec.needed) if gathering else None
        sampled = _Sampled.of(antecedents, spec, _NDVI_BANDS if gathering else None)
        _release_pages(segment.prod)
    except DemError as exc:
        return Piece(index, window, None, dem_error=message_of(exc))
    except (MerisOrthoError, OSError, ValueError) as exc:
        return Piece(index, window, None, error=message_of(exc))
    valid = sampled.validated(spec)
    piece = Piece(index, window, None, int(sampled.inside.sum()), int(valid.sum()))
    rows, cols = np.flatnonzero(valid.any(axis=1)), np.flatnonzero(valid.any(axis=0))
    if rows.size == 0:
        return piece
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    red = nir = None
    if spec.algorithm == "max-ndvi":
        red = sampled.radiance(NDVI_RED_BAND, (r0, r1, c0, c1))
        nir = sampled.radiance(NDVI_NIR_BAND, (r0, r1, c0, c1))
    if source is not None and red is not None and nir is not None:  # bands read at the merge
        piece.state = winner_state(valid[r0:r1, c0:c1], index, red, nir)
        piece.source = _winner_bands(segment.prod, spec, source, sampled, (r0, r1, c0, c1))
        piece.window = (window[0] + r0, window[0] + r1, window[2] + c0, window[2] + c1)
        return piece
    planes = [sampled.bands[b] for b in spec.bands]
    if spec.compact:  # the store's counts: half the bytes to ship and hold until the merge
        divisors = (None if sampled.counts  # already the store's counts: copied where valid
                    else [st.count_divisor(st.BAND_SCALES[b]) for b in spec.bands])
        piece.state = segment_counts_state(planes, (r0, c0), divisors, valid[r0:r1, c0:c1],
                                           index, red, nir)
    else:
        segment = np.stack([p[r0:r1, c0:c1] for p in planes])
        piece.state = segment_state(segment, valid[r0:r1, c0:c1], index, red, nir)
    piece.window = (window[0] + r0, window[0] + r1, window[2] + c0, window[2] + c1)
    return piece


_NDVI_BANDS = (NDVI_RED_BAND, NDVI_NIR_BAND)


def gathers_winners(spec: Spec, product: Any) -> bool:
    """Whether a piece of ``product`` reads its bands where it wins only, at its merge
    (``engine.synthesis.WinnerBands``): under the maximum-NDVI rule (a pixel's bands follow
    its NDVI) when its counts at the nearest pixel are the store's (``counts_as_stored``)."""
    scales = {b: float(product.scaling.radiance[b - 1]) for b in spec.needed}
    return spec.algorithm == "max-ndvi" and counts_as_stored(spec, scales)


def _winner_bands(product: Any, spec: Spec, source: tuple[np.ndarray, np.ndarray, Window],
                  sampled: _Sampled, box: Window) -> WinnerBands:
    """The ``WinnerBands`` of a piece cropped to ``box`` of its tile (rows r0:r1, columns
    c0:c1; inside the extent of ``Antecedents.nearest_source`` of ``spec.needed``): the
    windows of the stored bands, its index and saturation bits there, each band's fill and
    bit."""
    pixels, index, extent = source
    if spec.needed != spec.bands:  # the NDVI bands were copied for the NDVI only
        pixels = pixels[[spec.needed.index(b) for b in spec.bands]]
    r0, r1, c0, c1 = box
    rows, cols = slice(r0 - extent[0], r1 - extent[0]), slice(c0 - extent[2], c1 - extent[2])
    fills = [product.no_data_count(b) for b in spec.bands]
    return WinnerBands(
        pixels, index[rows, cols], np.array([-1 if f is None else f for f in fills], np.int64),
        (np.zeros((0, 0), np.uint16) if sampled.saturated is None
         else sampled.saturated[r0:r1, c0:c1]),
        np.array([1 << (b - 1) for b in spec.bands], np.uint16))


@dataclass
class _Sampled:
    """A product sampled at the antecedents of a tile: ``bands`` (the bands the merge needs) as
    float32 radiances, or, with ``counts``, as the product's own uint16 counts when those are
    already the store's (``counts_as_stored``); ``inside``: points with an antecedent."""

    bands: dict[int, np.ndarray]
    counts: bool
    inside: np.ndarray
    flags: np.ndarray
    saturated: np.ndarray | None
    scales: dict[int, float]

    @classmethod
    def of(cls, antecedents: Antecedents, spec: Spec,
           only: Sequence[int] | None = None) -> _Sampled:
        """``only``: these bands only (the product's counts are the store's)."""
        prod = antecedents.prod
        scales = {b: float(prod.scaling.radiance[b - 1]) for b in spec.needed}
        counts = counts_as_stored(spec, scales)
        if counts:
            needed = spec.needed if only is None else tuple(only)
            values = antecedents.counts(needed)
            bands = {b: values[k] for k, b in enumerate(needed)}
        else:
            result = antecedents.result()
            bands = result.bands
            if spec.compact:
                _quantize(bands, spec)
        return cls(bands, counts, np.ascontiguousarray(antecedents.valid, dtype=np.bool_),
                   np.ascontiguousarray(antecedents.flags(), dtype=np.uint8),
                   antecedents.saturated(), scales)

    def validated(self, spec: Spec) -> np.ndarray:
        """The pixels the merge takes (``validated_pixels``); saturated pixels of a band
        (``saturated_Mnn``, .SEN3) are no data (0) for that band; the maximum-NDVI rule takes
        only pixels with both NDVI bands (a fill there is no data)."""
        from ..engine.synthesis import validated_pixels

        valid = validated_pixels(self.inside, self.flags, spec.reject_bright)
        if self.saturated is not None:
            for b in set(spec.needed) & set(self.bands):
                hit = (self.saturated & np.uint16(1 << (b - 1))) != 0
                if hit.any():
                    self.bands[b][hit] = 0
        if spec.algorithm == "max-ndvi":
            valid &= (self.bands[NDVI_RED_BAND] > 0) & (self.bands[NDVI_NIR_BAND] > 0)
        return valid

    def radiance(self, band: int, box: Window) -> np.ndarray:
        """float32 radiances of ``band`` in ``box`` (rows r0:r1, columns c0:c1): counts times
        the product's scale in float32, the numbers of the product's radiances."""
        r0, r1, c0, c1 = box
        values = self.bands[band][r0:r1, c0:c1]
        return st.decode_band(values, self.scales[band]) if self.counts else values


def counts_as_stored(spec: Spec, scales: dict[int, float]) -> bool:
    """Whether a product's counts at the nearest pixel are the compact store's counts: its
    scale of every stored band is the store's (Appendix A factor; both as float32)."""
    return (spec.compact and spec.options.sampling is Sampling.NEAREST
            and all(np.float32(scales[b]) == np.float32(st.BAND_SCALES[b]) for b in spec.bands))


def _keep_bands(spec: Spec) -> None:
    """A .SEN3 band decoded once per process, not per tile, and shared by the run's workers on
    a host; the run frees it (``products.sen3.kept``)."""
    from ..products.sen3.kept import keep_decoded_bands

    keep_decoded_bands(spec.layout if _in_worker() else "")


def _decode_ahead(path: str, bands: Sequence[int]) -> None:
    """Start decoding ``bands`` of the product at ``path`` (not kept yet) in the background, for
    a product that reads its bands whole (``read_ahead`` of a .SEN3); nothing for others or
    when it cannot be opened (its task says why)."""
    try:
        product = _product(path)
    except (MerisOrthoError, OSError, ValueError):
        return
    read_ahead = getattr(product, "read_ahead", None)
    if callable(read_ahead):
        read_ahead(bands)


def _prepare_bands(product: Any, bands: Sequence[int]) -> None:
    """Decode ``bands`` of a product that reads its bands whole, the run's workers on a host
    sharing the work (``prepare_bands`` of a .SEN3); nothing for other products."""
    prepare = getattr(product, "prepare_bands", None)
    if callable(prepare):
        prepare(bands)


def _release_pages(product: Any) -> None:
    """Drop the product's file pages that the task read from this worker's resident memory
    (``release_pages`` of an N1, or the bands a .SEN3 keeps in file maps for the run). A
    worker then holds the lines of the task at hand, not every product it was given (section
    3.1: a tile reads the antecedent lines only)."""
    release = getattr(product, "release_pages", None)
    if callable(release):
        release()


def _quantize(bands: dict[int, np.ndarray], spec: Spec) -> None:
    """The radiances of ``bands`` as a compact store holds them (``store.quantized``)."""
    for b in spec.bands:
        bands[b] = st.quantized(bands[b], st.BAND_SCALES[b])


def tile_work(pixels: dict[int, int], exclude: frozenset[int] = frozenset()) -> int:
    """The work of a tile task, in output pixels: each product's pixels inside the tile plus
    a piece's fixed cost (``PIECE_WORK_PX``), for the products not excluded."""
    return sum(n + PIECE_WORK_PX for index, n in pixels.items() if index not in exclude)


def submission_order(jobs: dict[Window, list[Job]], work: dict[Window, dict[int, int]],
                     exclude: frozenset[int] = frozenset()) -> list[Window]:
    """The tiles in the order their tasks are submitted: the most work first (``tile_work``),
    equal work in grid order. Longest processing time first: on N workers the short tiles
    come last, so that no worker is left with a long one while the others have finished (of
    two workers merging 4 fr-alps products, one idles 0.25-0.33 s at the end in this order,
    0.36-0.67 s with the tiles ordered by their number of products)."""
    return sorted(jobs, key=lambda w: (-tile_work(work.get(w, {}), exclude), w))


def tile_job(fork: Any, spec: Spec, window: Window, jobs: Sequence[Job], rank: np.ndarray,
             exclude: frozenset[int], writer: TileWriter | None = None,
             on_piece: Callable[[], None] | None = None) -> TileDone:
    """One output tile, whole: every product's piece of it orthorectified here
    (``segment_task``, one after the other) and merged as it comes, then written (``tile_task``).
    One task per tile: no piece travels between workers or waits for its merge, a worker holds
    one piece at a time, and tiles stream (each is written as soon as its products are done).
    ``on_piece``: called after each piece (in process: the run's progress, and its Cancel)."""
    _tune_worker()

    todo = [job for job in jobs if job[0] not in exclude]
    if writer is not None:  # in process: the bands of the products after the first decode
        _keep_bands(spec)  # while the first ones are orthorectified, and are kept
        for job in todo:
            _decode_ahead(job[1], spec.needed)

    def pieces() -> Iterator[Piece]:
        for index, path, piece, extent in todo:
            yield segment_task(spec, index, path, piece, extent)
            if on_piece is not None:
                on_piece()

    return tile_task(fork, spec, window, pieces(), rank, writer)


@functools.cache
def _tune_worker() -> bool:
    """Once per process, in a dask worker only (a user's own process is left as it is): glibc's
    malloc reuses a tile's arrays for the next one (``_process.keep_task_arrays``)."""
    return _in_worker() and keep_task_arrays()


def _in_worker() -> bool:
    """Whether this is a dask worker's task."""
    distributed = sys.modules.get("distributed")
    if distributed is None:
        return False
    try:
        distributed.get_worker()
    except ValueError:  # not in a worker's task
        return False
    return True


def tile_task(fork: Any, spec: Spec, window: Window, pieces: Iterable[Piece],
              rank: np.ndarray, writer: TileWriter | None = None) -> TileDone:
    """Merge the pieces, as they come, into the stored tile ``window`` (a whole chunk) and write
    it into ``fork`` (on ``writer``'s thread if given: ``TileDone.wait``). Pieces that failed
    are left out (those of excluded products are not made: ``tile_job``). The merge rule is
    associative and commutative (``engine.synthesis.combine``, ties by ``rank``): any order of
    the pieces gives the same."""
    from ..engine.synthesis import combine

    st.quiet_icechunk()
    done = TileDone(None, window)
    state: TileState | None = None
    stored: dict[str, np.ndarray] = {}
    merged: set[int] = set()
    ahead = _read_ahead(fork.store, spec.names, window, spec.layout)
    try:
        for p in pieces:
            done.pieces.append(Piece(p.index, p.window, None, p.processed, p.validated,
                                     p.error, p.dem_error))
            if p.state is None or p.error is not None or p.dem_error is not None:
                continue
            if state is None:  # the stored tile, once a piece has something to merge
                stored = ahead.result()  # counts (compact)
                state = _state_of(stored, spec)
            r0, r1, c0, c1 = (p.window[0] - window[0], p.window[1] - window[0],
                              p.window[2] - window[2], p.window[3] - window[2])
            combine(state.window(r0, r1, c0, c1), p.state, rank, p.source)
            merged.add(p.index)
            p.state = p.source = None  # merged: its memory goes
    finally:
        # nothing to merge, or an error (a Cancel): the read is dropped, and waited for when
        # it has begun (no read of the fork left running while the run is undone)
        if state is None and not ahead.cancel():
            ahead.exception()
    if state is None:
        return done
    arrays = _arrays_of(state, spec)
    if writer is None:
        done.chunks = st.write_tile(fork.store, window, arrays, stored, spec.overviews,
                                    spec.layout)
    else:
        done.writing = writer.submit(lambda: st.write_tile(fork.store, window, arrays, stored,
                                                           spec.overviews, spec.layout))
    done.winners = winner_counts(state.winner, merged)
    done.fork = fork
    return done


def _read_ahead(store: Any, names: Sequence[str], window: Window, layout: str = "") -> Any:
    """A future of the stored tile (``read_tile``) read on a thread of its own, started before
    the first piece is orthorectified: the chunk fetches and their decompression (Icechunk's
    I/O, zstd: outside the GIL) overlap that work instead of following it."""
    from concurrent.futures import ThreadPoolExecutor

    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="synthesis-reader")
    try:
        return pool.submit(st.read_tile, store, names, window, layout)
    finally:
        pool.shutdown(wait=False)  # the thread ends with its read


def winner_counts(winner: np.ndarray, indices: set[int]) -> dict[int, int]:
    """Pixels of the 2-D ``winner`` layer held by each of ``indices`` that holds any: one
    counting pass over the index range (``engine.synthesis.count_winners``), no sort."""
    from ..engine.synthesis import count_winners

    counts = count_winners(winner, max(indices, default=0) + 1)
    return {i: int(counts[i]) for i in sorted(indices) if counts[i]}


def _state_of(arrays: dict[str, np.ndarray], spec: Spec) -> TileState:
    """The merge state of a stored tile (``read_tile``). Compact band layers stay counts: the
    pieces are counts of the same per-band scale, and ``decode_band`` is strictly increasing
    on [0, MAX_COUNT] (distinct counts differ by at least 1/65535 of the value, far above the
    float32 rounding), so both merge rules (smallest positive radiance, its ties; the NDVI
    codes) pick the same pixels on counts as on radiances, and the counts need no decoding
    nor encoding again."""
    shape = arrays["count"].shape
    dtype = np.uint16 if spec.compact else np.float32
    bands = np.empty((len(spec.bands), *shape), dtype)
    for k, b in enumerate(spec.bands):
        bands[k] = arrays[st.band_layer(b)]
    return TileState(bands, arrays["count"].astype(np.uint16),
                     arrays["product"].astype(np.int32),
                     arrays["ndvi"].astype(np.uint16) if "ndvi" in arrays else None)


def _arrays_of(state: TileState, spec: Spec) -> dict[str, np.ndarray]:
    """The layers of a merged tile as stored (compact band layers: the counts merged)."""
    out = {st.band_layer(b): state.bands[k] for k, b in enumerate(spec.bands)}
    if state.ndvi is not None:
        out["ndvi"] = state.ndvi
    out["count"] = state.count
    out["product"] = state.winner
    return out


# --------------------------------------------------------------------------- client side


@dataclass
class Target:
    """The store a run writes: its repository and current synthesis (None: a new one)."""

    path: Any
    repo: Any
    synthesis: SynthesisStore | None


@dataclass
class _Product:
    report: ProductReport
    product: Any = None
    margin: int = 0
    window: Window | None = None

    @property
    def key(self) -> tuple[str, str]:
        return (self.report.sensing_start, self.report.product_name)


class Synthesis:
    """Plan, run and commit one ``synthesize`` call."""

    def __init__(self, target: Target, paths: list[str], *, algorithm: str | None, grid: Any,
                 crs: Any, pixel_size: float | None, dems: list[str], options: OrthoOptions,
                 bands: Sequence[int] | None, reject_bright: bool, tile: int,
                 progress: ProgressCallback | None, max_pixels: int | None = None,
                 codec: StoreCodec = StoreCodec.ZSTD,
                 merged: ProgressCallback | None = None) -> None:
        self.target = target
        self.paths = paths
        old = target.synthesis
        self.algorithm = old.algorithm if old else (algorithm or "min-radiance")
        self.bands = old.bands if old else tuple(sorted({int(b) for b in bands or ALL_BANDS}))
        self.tile = old.tile if old else int(tile)
        self.grid = old.grid if old else grid
        self.crs, self.pixel_size = crs, pixel_size
        self.dems = dems
        self.options = options
        self.reject_bright = reject_bright
        self.max_pixels = max_pixels
        self.codec = codec
        self.progress = progress
        self.merged = merged  # (products whose every tile is merged, products to merge)
        self.table: list[dict[str, Any]] = old.products if old else []
        self._branch: str | None = None  # run branch of a new synthesis

    # ---------------------------------------------------------------- products
    def _open(self) -> list[_Product]:
        """Read every product's header; report failures and products already merged."""
        from ..products.open import read_product

        seen = {(str(p.get("sensing_start", "")), str(p["product_name"])) for p in self.table}
        out = []
        for path in self.paths:
            item = _Product(ProductReport(path))
            out.append(item)
            try:
                item.product = read_product(path)
            except (MerisOrthoError, OSError, ValueError) as exc:
                item.report.status, item.report.error = STATUS_FAILED, message_of(exc)
                continue
            when = item.product.first_line_time
            item.report.product_name = item.product.product_name or os.path.basename(path)
            item.report.sensing_start = "" if when is None else str(when)
            item.report.sf_rad = {b: float(item.product.scaling.radiance[b - 1])
                                  for b in self.bands}
            if item.key in seen:
                item.report.status = STATUS_ALREADY
                item.product = None
                continue
            seen.add(item.key)
        return out

    def _plan(self, items: list[_Product]) -> list[_Product]:
        """Indices (canonical order: sensing time, then name) and footprints of the products
        to merge."""
        todo = sorted((i for i in items if i.product is not None), key=lambda i: i.key)
        if self.grid is None and todo:
            from ..ortho import product_grid

            self.grid = product_grid(todo[0].product, self.crs or "EPSG:4326", self.pixel_size)
            check_new_grid_size(self.grid, len(self.bands), self.max_pixels)
        for k, item in enumerate(todo):
            item.report.index = len(self.table) + k + 1
            item.margin = terrain_margin_px(item.product, self.grid)
            item.window = footprint_window(item.product, self.grid, item.margin)
        return todo

    def _rank(self, todo: list[_Product]) -> np.ndarray:
        """Tie-break rank of every product index (stored and new): sensing time, then name."""
        keys = {int(p["index"]): (str(p.get("sensing_start", "")), str(p["product_name"]))
                for p in self.table}
        keys.update({i.report.index: i.key for i in todo})
        rank = np.zeros(max(keys, default=0) + 1, np.int64)
        for r, index in enumerate(sorted(keys, key=lambda k: (keys[k], k))):
            rank[index] = r + 1
        return rank

    def _jobs(self, todo: list[_Product]) -> tuple[dict[Window, list[Job]],
                                                   dict[Window, dict[int, int]]]:
        """Output tile -> the (product index, path, piece, product window) tasks it needs, and
        tile -> product index -> output pixels of the tile inside the product (its work)."""
        from ..engine.boundary import row_spans, segment_boundary

        shape = (self.grid.height, self.grid.width)
        jobs: dict[Window, list[Job]] = {}
        work: dict[Window, dict[int, int]] = {}
        for item in todo:
            if item.window is None:
                item.report.status = STATUS_OUTSIDE
                item.product = None
                continue
            tp = item.product.tie_points
            boundary = segment_boundary(tp["latitude"], tp["longitude"])
            touched = False
            for piece in tiles(item.window, self.tile):
                inside = row_spans(boundary, self.grid.window(*piece), margin=item.margin).count
                if inside == 0:
                    continue  # beyond any terrain point of the product
                tile = tile_of(piece, self.tile, shape)
                jobs.setdefault(tile, []).append(
                    (item.report.index, item.report.path, piece, item.window))
                pixels = work.setdefault(tile, {})
                pixels[item.report.index] = pixels.get(item.report.index, 0) + inside
                touched = True
            if not touched:
                item.report.status = STATUS_OUTSIDE
            item.product = None  # the workers open it themselves
        return dict(sorted(jobs.items())), work

    # ---------------------------------------------------------------- run
    def run(self, runner: InProcess | Dask) -> SynthesisResult:
        items = self._open()
        todo = self._plan(items)
        reports = [i.report for i in items]
        result = SynthesisResult(self.target.path, None, self.grid, self.algorithm, self.bands,
                                 reports)
        if not todo:
            return _log(result)
        rank, (jobs, work) = self._rank(todo), self._jobs(todo)
        todo = [i for i in todo if i.report.status != STATUS_OUTSIDE]
        if not todo:  # no product touches the grid: nothing to commit
            return _log(result)
        check_write_size(jobs, len(self.bands), self.target.path, self.max_pixels,
                         2 if self._version >= 3 else 4)
        spec = self._spec()
        session, finish = self._session(spec)
        spec = replace(spec, layout=str(session.snapshot_id))
        try:
            failed: set[int] = set()
            while True:
                done = self._execute(runner, session, spec, jobs, work, rank,
                                     frozenset(failed))
                newly = self._collect(done, todo, failed)
                if not newly:
                    break
                log.warning("%d product(s) failed part-way; merging again without them",
                            len(newly))
            merged = [i for i in todo if i.report.index not in failed]
            if merged:
                session.merge(*[d.fork for d in done if d.fork is not None])
                result.snapshot = finish(session, merged, reports)
        except BaseException:
            self._abandon()
            raise
        return _log(result)

    def _spec(self) -> Spec:
        shape = (self.grid.height, self.grid.width)
        needed = _needed(self.bands, self.algorithm)
        return Spec(tuple(grid_to_dict(self.grid).items()), self.bands, self.algorithm,
                    tuple(self.dems), replace(self.options, bands=needed, diagnostics=False),
                    self.reject_bright,
                    self.tile, tuple(st.layer_names(self.bands, self.algorithm)),
                    tuple(st.overview_factors(shape[1], shape[0], self.tile)),
                    self._version >= 3)

    def _session(self, spec: Spec) -> tuple[Any, Callable[..., str]]:
        """A writable session without uncommitted changes (forks need one) and the function
        that commits it. A new synthesis lays its arrays out in a snapshot of a run branch;
        ``main`` moves to the run's commit only at the end."""
        repo = self.target.repo
        if self.target.synthesis is not None:
            base = self.target.synthesis.snapshot
            session = repo.writable_session(st.BRANCH)
            if session.snapshot_id != base:
                raise OutputError(f"{self.target.path}: the synthesis changed while this run "
                                  "started (another writer without the lock?); run it again")
            return session, lambda s, m, r: self._commit(s, m, r, base)
        st.delete_run_branches(repo)  # left by a killed run
        base = repo.lookup_branch(st.BRANCH)
        layout = repo.writable_session(st.BRANCH)
        st.create_layout(layout.store, self._attributes([]), (self.grid.height, self.grid.width),
                         self.tile, spec.names, spec.overviews, st.CHUNK, self.codec)
        snapshot = layout.flush("synthesis layout: grid, bands, empty arrays")
        self._branch = f"{st.RUN_BRANCH_PREFIX}{uuid.uuid4().hex[:12]}"
        repo.create_branch(self._branch, snapshot)
        return (repo.writable_session(self._branch),
                lambda s, m, r: self._commit(s, m, r, base, move_main=True))

    def _abandon(self) -> None:
        if self._branch is not None:
            with contextlib.suppress(Exception):
                self.target.repo.delete_branch(self._branch)

    @property
    def _version(self) -> int:
        """The store format: an update keeps its store's (2: float32 band layers)."""
        old = self.target.synthesis
        return st.VERSION if old is None else int(old.attrs.get("version", 2))

    def _attributes(self, table: list[dict[str, Any]]) -> dict[str, Any]:
        shape = (self.grid.height, self.grid.width)
        return {"format": st.FORMAT, "version": self._version, "algorithm": self.algorithm,
                "bands": list(self.bands), "grid": grid_to_dict(self.grid), "tile": self.tile,
                "overviews": st.overview_factors(shape[1], shape[0], self.tile),
                "radiance": RADIANCE_NOTE, "products": table}

    def _execute(self, runner: InProcess | Dask, session: Any, spec: Spec,
                 jobs: dict[Window, list[Job]], work: dict[Window, dict[int, int]],
                 rank: np.ndarray, exclude: frozenset[int]) -> list[TileDone]:
        """Submit every task (tile by tile, the most work first), report progress, return the
        written tiles."""
        futures: list[Any] = []
        run = uuid.uuid4().hex[:8]
        steps = {window: sum(1 for job in tasks if job[0] not in exclude) + 1
                 for window, tasks in jobs.items()}  # its pieces and its merge
        total, count = sum(steps.values()), [0]

        def advance(n: int) -> None:
            """Progress: one step per piece and per merged tile (pieces are reported as they
            come in process, with their tile on dask)."""
            count[0] += n
            if self.progress is not None:
                self.progress(count[0], total)

        # the tiles each product is merged into: a product is merged with its last tile
        tiles_left: dict[int, int] = {}
        for tasks in jobs.values():
            for index in {job[0] for job in tasks if job[0] not in exclude}:
                tiles_left[index] = tiles_left.get(index, 0) + 1
        products_done = [0]

        def tile_merged(window: Window) -> None:
            for index in {job[0] for job in jobs[window] if job[0] not in exclude}:
                tiles_left[index] -= 1
                products_done[0] += tiles_left[index] == 0
            if self.merged is not None:
                self.merged(products_done[0], len(tiles_left))

        advance(0)  # the total known before the first piece
        if self.merged is not None:
            self.merged(0, len(tiles_left))
        # in process: the writer thread, and progress (and Cancel) after every piece
        extra: tuple[Any, ...] = ((runner.writer, lambda: advance(1))
                                  if isinstance(runner, InProcess) else ())
        for window in submission_order(jobs, work, exclude):
            futures.append(runner.submit(tile_job, session.fork(), spec, window, jobs[window],
                                         rank, exclude, *extra,
                                         key=f"tile-{run}-{window[0]}-{window[2]}",
                                         priority=tile_work(work.get(window, {}), exclude)))
        written: list[TileDone] = []
        try:
            for future in runner.completed(futures):
                tile = runner.result(future)
                runner.release([future])
                written.append(tile)
                errors = [p.dem_error for p in tile.pieces if p.dem_error is not None]
                if errors:  # not the product's fault: stop the run (exit 2)
                    raise DemError(errors[0])
                tile_merged(tile.window)
                advance(1 if extra else steps[tile.window])  # pieces counted already
            for tile in written:
                tile.wait()
        except BaseException:
            runner.cancel(futures)
            raise
        return written

    def _collect(self, done: list[TileDone], todo: list[_Product], failed: set[int]
                 ) -> set[int]:
        """Statistics of the run; products that failed on some tile (newly)."""
        by_index = {i.report.index: i.report for i in todo}
        for report in by_index.values():
            report.processed = report.validated = report.added = 0
        newly: set[int] = set()
        for tile in done:
            for p in tile.pieces:
                report = by_index[p.index]
                if p.error is not None and p.index not in failed:
                    newly.add(p.index)
                    report.status, report.error = STATUS_FAILED, p.error
                report.processed += p.processed
                report.validated += p.validated
            for index, n in tile.winners.items():
                by_index[index].added += n
        failed |= newly
        return newly

    def _run_facts(self) -> dict[str, Any]:
        """What a commit records of the run: its options, the DEMs used with their vertical
        datums (``ortho.writing``'s names) and the software version."""
        from ..dem.stack import dem_datums
        from ..ortho.description import dem_list, options_tags, software_version

        dems: tuple[dict[str, str], ...] = ()
        if self.options.elevation.value == "dem" and self.dems:
            dems = dem_list(self.dems, dem_datums(self.dems))
        return {"options": options_tags(self.options), "dems": [dict(d) for d in dems],
                "software_version": software_version()}

    def _commit(self, session: Any, merged: list[_Product], reports: list[ProductReport],
                base: str, move_main: bool = False) -> str:
        """One commit: the product table grows by the merged products; the commit metadata
        lists every product of the run with its status."""
        import icechunk

        table = self.table + [i.report.table_entry() for i in merged]
        st.set_attributes(session.store, self._attributes(table))
        names = ", ".join(i.report.product_name for i in merged)
        others = len(reports) - len(merged)
        message = f"synthesize: {len(merged)} product(s) merged ({names})" + (
            f"; {others} skipped or failed" if others else "")
        metadata = {st.COMMIT_KEY: {"products": [r.commit_entry() for r in reports],
                                    "algorithm": self.algorithm, **self._run_facts()}}
        try:
            with st.store_errors(self.target.path, "the commit failed"):
                snapshot = session.commit(message, metadata=metadata)
            if move_main:
                self.target.repo.reset_branch(st.BRANCH, snapshot, from_snapshot_id=base)
                self.target.repo.delete_branch(self._branch)
                self._branch = None
        except icechunk.ConflictError as exc:
            raise OutputError(f"{self.target.path}: another run committed to the synthesis "
                              f"meanwhile; nothing was written by this one ({exc})") from None
        return str(snapshot)


def _log(result: SynthesisResult) -> SynthesisResult:
    """The Appendix B log of every product."""
    pixels = 0 if result.grid is None else result.grid.width * result.grid.height
    for r in result.reports:
        for line in r.lines(pixels):
            (log.warning if r.status == STATUS_FAILED else log.info)(line)
    return result

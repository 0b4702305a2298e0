"""The on-disk synthesis: a Zarr v3 store managed by Icechunk (a transactional repository).

Layout (``STORE`` is an Icechunk repository; branch ``main`` is the synthesis)::

    /                       attributes: format, version, algorithm, bands, grid, tile,
                            overview factors, products (the product table); the band
                            set and band matching (``bandsets``: an OLCI store, OLCI
                            products in a MERIS store)
    /band_07 ...            radiance of each band as uint16 counts, CF ``scale_factor`` =
                            the band's Appendix A factor (``BAND_SCALES``; an OLCI store:
                            ESA's ``scale_factor``, ``OLCI_BAND_SCALES``; 0 = background):
                            standard products' radiances round-trip exactly, others within
                            half a count; stores of version 2 hold float32 radiances (read and
                            updated as they are)
    /ndvi                   uint16 NDVI of the maximum-NDVI rule (Appendix C: [1, 65535], 0 =
                            background); absent for the minimum-radiance rule
    /count                  uint16 number of products that gave a valid pixel
    /product                int32 index (1-based) in the product table of the product that
                            won the pixel (0 = background)
    /overview_2/<layer> ... the same layers decimated by 2, 4, ... (every 2**k-th pixel), for
                            viewers; written with the full-resolution tiles

Every array is compressed by zstd (``ZSTD_LEVEL``); a store made with codec
``StoreCodec.DELTA_ZSTD`` puts a delta filter (``numcodecs.delta``) before it in its
full-resolution bands and NDVI (``DELTA_LAYERS``). Updates keep the store's codecs.

Arrays are chunked inside the output tile: chunks of ``CHUNK`` pixels (version 4; every
overview level: ``level_chunk``), so one tile task writes the chunks of its own tile and tasks
never write the same chunk; an update rewrites only the chunks whose values change (those the
new products touch: ``changed_chunks``), all of a tile's at once. Version 3 stores, chunked by
the tile (overviews by the tile / factor), are read and updated as they are. Each
``synthesize`` call is one Icechunk commit whose metadata lists the products
(``COMMIT_KEY``); a run that dies before its commit leaves the branch at the previous commit.
An advisory lock on ``.STORE.meris-ortho-lock`` next to the store (Icechunk creates
repositories in empty directories only) is held from the
"is there a synthesis" check to the commit.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..bands import Sensor, band_table
from ..errors import OptionsError, OutputError
from ..options import StoreCodec
from ..products.n1.format import ScalingFactors

# the delta filter (``DELTA_LAYERS``) makes zarr warn, at every opening of an array,
# that numcodecs codecs are not in the Zarr v3 specification: said once in the docs instead
warnings.filterwarnings("ignore", message="Numcodecs codecs are not in the Zarr version 3",
                        category=UserWarning)

FORMAT = "napari-meris-ortho synthesis"
VERSION = 4
#: chunk side (pixels) of a version-4 store's full-resolution arrays; tiles are multiples of it
CHUNK = 512
#: zstd level of new stores: radiance counts of simulated (noisy) products compress to 0.74 of
#: their bytes at level 1 and 0.73 at levels 3-15 (11.3 bits of entropy per count), level 1 in
#: about half the time of level 3
ZSTD_LEVEL = 1
#: layers that a store of codec ``StoreCodec.DELTA_ZSTD`` encodes with a delta filter
#: (``numcodecs.delta``: each value minus the previous one of the chunk, in C order, modulo
#: the dtype) before zstd, at full resolution: neighbouring radiances differ by far less than
#: their range, so these chunks of an fr-alps store shrink to 0.84 of their zstd-only size at
#: the same speed (byte or bit shuffles gain less, pcodec a little more at a fifth of the
#: speed). The overviews (every 2**k-th pixel: neighbours further apart), count and product
#: layers gain nothing and keep zstd alone. The filter is not in the Zarr v3 specification:
#: zarr-python (numcodecs, which it depends on) reads it, with a warning that this module
#: silences; readers of the core codecs only (zarrs, without a plugin) refuse it, hence not
#: the default.
DELTA_LAYERS = ("band_", "ndvi")
#: stored radiance of a band count: count x the band's Appendix A factor (Scaling Factor GADS)
BAND_SCALES: dict[int, float] = dict(enumerate(ScalingFactors().radiance, start=1))
#: the same for the bands of an OLCI store: the ``scale_factor`` of ``Oa01_radiance`` ..
#: ``Oa21_radiance`` in ESA's OLCI Level 1B products (Oa01 as stored: 0.013946459628641605;
#: the others as published with 6 digits); a product of other factors is quantized to them
OLCI_BAND_SCALES: dict[int, float] = dict(enumerate((
    0.013946459628641605, 0.0133873, 0.0121481, 0.0115198, 0.0100953, 0.0123538, 0.00879161,
    0.00876539, 0.0095103, 0.00773378, 0.00675523, 0.0071996, 0.00749684, 0.0086512,
    0.00526779, 0.00530267, 0.00493004, 0.00549962, 0.00502847, 0.00326378, 0.00324118),
    start=1))  # fmt: skip
BRANCH = "main"
LOCK_SUFFIX = ".meris-ortho-lock"
COMMIT_KEY = "meris_ortho"
RUN_BRANCH_PREFIX = "meris-ortho-run-"
#: the old (before Icechunk) generation-directory synthesis: recognised to refuse it clearly
OLD_MANIFEST = "synthesis.json"
#: overviews stop when the coarsest level's larger side is below this, or its chunk below
#: ``MIN_OVERVIEW_CHUNK``
OVERVIEW_TARGET = 512
MIN_OVERVIEW_CHUNK = 64

Window = tuple[int, int, int, int]  # row0, row1, col0, col1


def quiet_icechunk() -> None:
    """Icechunk warns on stderr that local storage is not safe for concurrent commits: we take
    the lock (module docstring), so only errors are logged."""
    import icechunk

    icechunk.set_logs_filter("error")


def band_scales(sensor: Sensor | str = Sensor.MERIS) -> dict[int, float]:
    """The scale of each band's counts in a store of the band set ``sensor``."""
    return OLCI_BAND_SCALES if Sensor(sensor) is Sensor.OLCI else BAND_SCALES


def band_layer(band: int) -> str:
    return f"band_{band:02d}"


def layer_names(bands: Sequence[int], algorithm: str) -> list[str]:
    """Arrays of a synthesis: the bands, NDVI (maximum NDVI only), count, product."""
    names = [band_layer(b) for b in bands]
    if algorithm == "max-ndvi":
        names.append("ndvi")
    return [*names, "count", "product"]


def layer_dtype(name: str) -> str:
    """The dtype a reader gets (band layers decoded to float32 radiances)."""
    return {"ndvi": "uint16", "count": "uint16", "product": "int32"}.get(name, "float32")


def _band_number(name: str) -> int | None:
    return int(name[5:]) if name.startswith("band_") else None


def encode_band(values: np.ndarray, scale: float) -> np.ndarray:
    """float32 radiances -> uint16 counts: round(v / scale) on [1, MAX_COUNT] for v > 0, 0 for
    the background (v <= 0 or NaN): ``engine.synthesis.count_of``."""
    from ..engine.synthesis import encode_counts

    v = np.asarray(values)
    if v.dtype not in (np.float32, np.float64):
        v = v.astype(np.float64)
    flat = encode_counts(np.ascontiguousarray(v).reshape(-1), count_divisor(scale))
    return flat.reshape(v.shape)


def count_divisor(scale: float) -> float:
    """The divisor of ``engine.synthesis.count_of`` for a band scale: the scale as float32
    (as the store's ``scale_factor`` and a product's radiances use it), in float64."""
    return float(np.float32(scale))


def decode_band(counts: np.ndarray, scale: float, out: np.ndarray | None = None
                ) -> np.ndarray:
    """uint16 counts -> float32 radiances ``float32(count) x float32(scale)`` (the arithmetic of
    a product's own radiances; into ``out`` if given), 0 stays 0."""
    if out is None:
        out = np.empty(np.shape(counts), np.float32)
    return np.multiply(counts, np.float32(scale), out=out, dtype=np.float32)


def quantized(values: np.ndarray, scale: float) -> np.ndarray:
    """The radiances a compact store holds for ``values`` (decode(encode(values)))."""
    return decode_band(encode_band(values, scale), scale)


def stored_scale(array: Any) -> float | None:
    """The ``scale_factor`` of a compact band array; None for any other layer (only band
    arrays carry one) and for the float32 bands of version-2 stores."""
    if np.dtype(array.dtype) != np.uint16:
        return None
    scale = array.attrs.get("scale_factor")
    return None if scale is None else float(scale)


def overview_factors(width: int, height: int, tile: int) -> list[int]:
    """Decimation factors 2, 4, ... until the larger side is at most ``OVERVIEW_TARGET``."""
    factors: list[int] = []
    f = 2
    while max(width, height) / (f // 2) > OVERVIEW_TARGET and tile // f >= MIN_OVERVIEW_CHUNK:
        factors.append(f)
        f *= 2
    return factors


#: longest wait at interpreter exit for Icechunk's threads to leave Python (``settle_at_exit``)
SETTLE_TIMEOUT_S = 2.0
_SETTLE_REGISTERED: list[bool] = []


def settle_at_exit(timeout: float = SETTLE_TIMEOUT_S) -> None:
    """At exit (``atexit``, before the interpreter finalizes): wait until no thread that Python
    did not start is running Python code. Icechunk resolves each awaited future from one of its
    Rust (tokio) threads through ``loop.call_soon_threadsafe``, which writes to the event
    loop's socket with the GIL released; when the process's main thread ends meanwhile, the
    Rust thread re-takes the GIL during finalization, CPython 3.11-3.13 ``pthread_exit``s it
    and the forced unwind through Rust frames aborts the process (SIGABRT, "Fatal Python
    error: Aborted"; https://github.com/python/cpython/issues/87135). Such a thread shows in
    ``sys._current_frames`` until it has left Python, unlike the threads of ``threading``;
    polled every millisecond, with the GIL released, for at most ``timeout`` seconds."""
    import sys
    import threading
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        known = {t.ident for t in threading.enumerate()}
        if all(ident in known for ident in sys._current_frames()):
            return
        time.sleep(0.001)


def _storage(path: Path) -> Any:
    import icechunk

    quiet_icechunk()
    if not _SETTLE_REGISTERED:  # after zarr's own exit handler: runs before it (LIFO)
        import atexit

        import zarr  # noqa: F401  (its exit handler, which stops its event loop, first)

        atexit.register(settle_at_exit)
        _SETTLE_REGISTERED.append(True)
    return icechunk.local_filesystem_storage(str(path))


def is_repository(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` is an Icechunk repository."""
    import icechunk

    p = Path(path)
    if not (p / "refs").is_dir():
        return False
    try:
        return bool(icechunk.Repository.exists(_storage(p)))
    except Exception:  # any storage failure means "not a repository"
        return False


def open_repository(path: str | os.PathLike[str]) -> Any:
    """The Icechunk repository at ``path`` (OptionsError naming the path if it is none)."""
    import icechunk

    p = Path(path)
    if (p / OLD_MANIFEST).is_file():
        raise OptionsError(f"{p}: a synthesis in the old generation-directory format (before "
                           "the Icechunk store); it cannot be opened any more: synthesize its "
                           "products again into a new store")
    if not is_repository(p):
        raise OptionsError(f"{p}: not a synthesis store (no Icechunk repository there)")
    try:
        return icechunk.Repository.open(_storage(p))
    except Exception as exc:  # icechunk raises its own error types
        raise OptionsError(f"{p}: damaged synthesis store ({exc})") from None


def create_repository(path: Path) -> Any:
    import icechunk

    try:
        return icechunk.Repository.create(_storage(path))
    except Exception as exc:
        raise OutputError(f"{path}: cannot create the synthesis store ({exc})") from None


def read_attributes(store: Any) -> dict[str, Any] | None:
    """Root attributes of a synthesis, or None when the snapshot holds no synthesis."""
    import zarr

    try:
        attrs = dict(zarr.open_group(store, mode="r", zarr_format=3).attrs)
    except (FileNotFoundError, KeyError, ValueError):
        return None
    return attrs if attrs.get("format") == FORMAT else None


def level_chunk(chunk: int, tile: int, factor: int = 1) -> int:
    """Chunk side of overview ``factor`` (1: full resolution): the largest divisor of the tile
    at that level (``tile // factor``) that divides ``chunk``, so a tile's chunks are its own."""
    return math.gcd(int(chunk), int(tile) // int(factor))


def create_layout(store: Any, attrs: dict[str, Any], shape: tuple[int, int], tile: int,
                  names: Sequence[str], factors: Sequence[int], chunk: int = CHUNK,
                  codec: StoreCodec = StoreCodec.ZSTD, sensor: Sensor = Sensor.MERIS) -> None:
    """Empty (fill value 0) arrays of a new synthesis, chunked by ``level_chunk``, and
    overviews, encoded by ``codec`` (``DELTA_LAYERS``); band layers of the band set
    ``sensor`` (``band_scales``); created concurrently on zarr's event
    loop (the 72 arrays of a 15-band fr-alps synthesis in 0.09 s, against 0.13 s one by one,
    while every worker waits: what is left is zarr's own work per array)."""
    import zarr.api.asynchronous as za
    from zarr.codecs import ZstdCodec
    from zarr.codecs.numcodecs import Delta

    scales = band_scales(sensor)

    async def create(group: Any, name: str, shape: tuple[int, int], chunk: int,
                     full: bool) -> None:
        band = _band_number(name)
        attrs = {} if band is None else {"scale_factor": scales[band], "add_offset": 0.0,
                                         "units": "mW m-2 sr-1 nm-1",
                                         "long_name": band_long_name(sensor, band)}
        dtype = np.dtype("uint16" if band is not None else layer_dtype(name))
        delta = codec is StoreCodec.DELTA_ZSTD and full and name.startswith(DELTA_LAYERS)
        filters = [Delta(dtype=dtype.newbyteorder("<").str)] if delta else []
        await group.create_array(name, shape=shape, chunks=(chunk, chunk), dtype=dtype,
                                 fill_value=0, dimension_names=("y", "x"), attributes=attrs,
                                 filters=filters, compressors=ZstdCodec(level=ZSTD_LEVEL))

    async def laid_out() -> None:
        root = await za.open_group(store=store, mode="w", attributes=attrs, zarr_format=3)
        groups = await gather_all(*(root.create_group(f"overview_{f}") for f in factors))
        arrays = [create(root, name, shape, level_chunk(chunk, tile), True) for name in names]
        for f, level in zip(factors, groups, strict=True):
            arrays += [create(level, name, (-(-shape[0] // f), -(-shape[1] // f)),
                              level_chunk(chunk, tile, f), False) for name in names]
        await gather_all(*arrays)

    _sync(laid_out())


def band_long_name(sensor: Sensor | str, band: int) -> str:
    """What a band layer holds: "TOA radiance of MERIS band 7", "... of OLCI band Oa08"."""
    if Sensor(sensor) is Sensor.MERIS:
        return f"TOA radiance of MERIS band {band}"
    return f"TOA radiance of OLCI band {band_table(sensor).name(band)}"


def set_attributes(store: Any, attrs: dict[str, Any]) -> None:
    import zarr

    zarr.open_group(store, mode="r+", zarr_format=3).attrs.update(attrs)


def open_layer(store: Any, name: str, level: int = 1) -> Any:
    """The Zarr array of layer ``name`` (at overview ``level``), read only."""
    import zarr

    return zarr.open_array(store, path=_level_path(name, level), mode="r", zarr_format=3)


def open_layers(store: Any, names: Sequence[str], levels: Sequence[int]) -> dict[
        tuple[str, int], Any]:
    """The Zarr arrays of layers ``names`` at each overview level of ``levels`` (1: full
    resolution), read only, their metadata fetched concurrently (one round trip of zarr's
    event loop: 90 arrays of a Europe-size store in 0.02 s, against 0.18 s one by one)."""
    import asyncio

    import zarr

    keys = [(n, level) for n in names for level in levels]

    async def opened() -> list[Any]:
        return await asyncio.gather(*(_open_array(store, _level_path(n, level), "r")
                                      for n, level in keys))

    return {key: zarr.Array(array) for key, array in zip(keys, _sync(opened()), strict=True)}


def undecodable(what: str, exc: BaseException) -> OutputError:
    """The error of a layer or chunk of the store that does not decode (zarr's codecs or ours:
    "Zstd decompression error"): the store is damaged."""
    return OutputError(f"the synthesis store: {what} does not decode ({exc}): the store is "
                       "damaged")


def read_window(store: Any, names: Sequence[str], window: Window, level: int = 1, *,
                decode: bool = True) -> dict[str, np.ndarray]:
    """Arrays ``names`` over ``window`` (rows/columns of the full grid; at overview ``level``
    the window is in that level's pixels); compact band layers decoded to float32 radiances
    unless ``decode`` is False (their uint16 counts)."""
    r0, r1, c0, c1 = window
    out = {}
    for n in names:
        array = open_layer(store, n, level)
        try:
            with store_errors():
                values = np.asarray(array[r0:r1, c0:c1])
        except (RuntimeError, ValueError) as exc:  # zarr's codecs: "Zstd decompression error"
            raise undecodable(f"layer {n}", exc) from None
        scale = stored_scale(array)
        out[n] = values if scale is None or not decode else decode_band(values, scale)
    return out


def written_window(store: Any, name: str, array: Any, level: int = 1) -> Window | None:
    """Rows and columns, at overview ``level``, of the bounding box of the chunks of layer
    ``name`` (its zarr ``array``) that hold values; None when none does. A synthesis writes
    only the chunks its products touch: on a Europe-size grid the others have no key. Listed
    from the store's manifests, no chunk read."""
    path = _level_path(name, level)
    prefix = f"{path}/c/"

    async def keys() -> list[str]:
        return [k async for k in store.list_prefix(path)]

    found = [k[len(prefix):].partition("/") for k in _sync(keys()) if k.startswith(prefix)]
    if not found:
        return None
    rows, cols = (int(n) for n in array.chunks)
    height, width = (int(n) for n in array.shape)
    i = [int(a) for a, _, _ in found]
    j = [int(b) for _, _, b in found]
    return (min(i) * rows, min((max(i) + 1) * rows, height),
            min(j) * cols, min((max(j) + 1) * cols, width))


def _sync(coroutine: Any) -> Any:
    """Run ``coroutine`` on zarr's event loop (the loop of its synchronous API); the store's
    own errors as one-line ``OutputError`` (:func:`store_errors`)."""
    from zarr.core.sync import sync

    with store_errors():
        return sync(coroutine)


async def gather_all(*awaitables: Any) -> list[Any]:
    """``asyncio.gather`` that lets every awaitable end before it raises the first error: no
    fetch of a failed read is left in flight in Icechunk's runtime (one still running when
    the process ends panics in its Rust thread)."""
    results = await asyncio.gather(*awaitables, return_exceptions=True)
    for r in results:
        if isinstance(r, BaseException):
            raise r
    return list(results)


@contextlib.contextmanager
def store_errors(path: str | os.PathLike[str] | None = None,
                 doing: str = "the synthesis store") -> Iterator[None]:
    """Icechunk's errors (a missing or truncated object of a damaged store, a full disk) and
    a chunk that does not decode, as one ``OutputError`` line naming ``path`` (Icechunk's own
    message is a multi-line report); a commit conflict passes as it is."""
    import icechunk

    try:
        yield
    except icechunk.ConflictError:
        raise
    except icechunk.IcechunkError as exc:
        where = f"{path}: " if path is not None else ""
        raise OutputError(f"{where}{doing}: {brief_store_error(exc)}") from None


def brief_store_error(exc: BaseException) -> str:
    """What an Icechunk error report says, in a few words."""
    text = str(exc)
    if "No space left on device" in text:
        return "no space left on device (nothing was committed)"
    if "not found" in text and "chunks/" in text:
        return "a chunk object is missing: the store is damaged"
    if "range was invalid" in text or "object was only" in text:
        return "a chunk object is truncated: the store is damaged"
    lines = (ln.strip(" x|") for ln in text.splitlines())
    return next((ln for ln in lines if ln), type(exc).__name__)[:200]


def _level_path(name: str, factor: int) -> str:
    return name if factor == 1 else f"overview_{factor}/{name}"


#: array metadata by (layout, array path): ``_open_array``'s, for the tile tasks of a run
_METADATA: dict[tuple[str, str], Any] = {}
#: entries kept at most (then the cache starts again empty)
METADATA_ENTRIES = 4096


async def _open_array(store: Any, path: str, mode: str, layout: str = "") -> Any:
    """The Zarr v3 array ``path`` of ``store`` (``zarr.api.asynchronous.open_array``). With a
    ``layout`` (the id of a snapshot whose array metadata the store shows unchanged: a run's
    forks, which start from a session without uncommitted changes and write chunks only), the
    metadata (``zarr.json``) is read once per layout and process (``_METADATA``), not at every
    tile (an update of the fr-alps Europe-size store would open 1 764 arrays for 90 distinct
    ones, over 18 tile tasks)."""
    import zarr
    import zarr.api.asynchronous as za
    from zarr.storage import StorePath

    meta = _METADATA.get((layout, path)) if layout else None
    if meta is not None:
        return zarr.AsyncArray(meta, StorePath(store, path))
    array = await za.open_array(store=store, path=path, mode=mode, zarr_format=3)
    if layout:
        if len(_METADATA) >= METADATA_ENTRIES:
            _METADATA.clear()
        _METADATA[(layout, path)] = array.metadata
    return array


def read_tile(store: Any, names: Sequence[str], window: Window, layout: str = ""
              ) -> dict[str, np.ndarray]:
    """The stored values (band layers as stored: counts in compact stores) of arrays ``names``
    over ``window`` of the full grid (starting on a chunk corner), every chunk read
    concurrently: fetched from the store and decoded on zarr's thread pool
    (``_chunk_encoder``'s zstd and delta; a missing chunk holds the fill value 0), or by zarr's
    ``getitem`` for arrays of other codecs. ``layout``: see ``_open_array``."""
    from zarr.core.buffer import default_buffer_prototype

    r0, r1, c0, c1 = window
    prototype = default_buffer_prototype()

    async def chunk(array: Any, codec: Any, out: np.ndarray, i: int, j: int) -> None:
        rows, cols = (int(c) for c in array.chunks)
        key = f"{array.store_path.path}/{array.metadata.encode_chunk_key((i // rows, j // cols))}"
        data = await store.get(key, prototype)
        if data is None:  # never written: fill value
            return
        dtype = out.dtype.newbyteorder("<")
        try:
            raw = await asyncio.to_thread(codec.decode, data.to_bytes())
        except (RuntimeError, ValueError) as exc:  # numcodecs: "Zstd decompression error"
            raise undecodable(f"chunk {key}", exc) from None
        block = np.frombuffer(raw, dtype).reshape(rows, cols)
        part = out[i - r0:i - r0 + rows, j - c0:j - c0 + cols]
        part[...] = block[:part.shape[0], :part.shape[1]]

    async def read(name: str) -> np.ndarray:
        array = await _open_array(store, name, "r", layout)
        codec = _chunk_encoder(array)
        if codec is None:
            return np.asarray(await array.getitem((slice(r0, r1), slice(c0, c1))))
        out = np.zeros((r1 - r0, c1 - c0), native_dtype(array))
        rows, cols = (int(c) for c in array.chunks)
        await gather_all(*(chunk(array, codec, out, i, j) for i in range(r0, r1, rows)
                               for j in range(c0, c1, cols)))
        return out

    async def gather() -> list[np.ndarray]:
        return await gather_all(*(read(n) for n in names))

    return dict(zip(names, _sync(gather()), strict=True))


def native_dtype(array: Any) -> np.dtype[Any]:
    """The numpy dtype of a zarr array (zarr 3.1: a ``ZDType`` wrapping it)."""
    dtype = array.dtype
    native = getattr(dtype, "to_native_dtype", None)
    return np.dtype(native() if callable(native) else dtype)


def changed_chunks(new: np.ndarray, old: np.ndarray, chunk: int
                   ) -> Iterator[tuple[int, int, int, int, bool]]:
    """``(row0, row1, col0, col1, filled)`` (relative to the arrays, which start on a chunk
    corner) of every ``chunk`` x ``chunk`` block where ``new`` differs from ``old``; ``filled``:
    the block holds a value other than the fill value 0 (``engine.synthesis.chunk_changes``,
    one pass without the GIL)."""
    from ..engine.synthesis import CHUNK_CHANGED, CHUNK_NOT_EMPTY, chunk_changes

    if new.shape != old.shape:
        raise ValueError(f"new {new.shape} and old {old.shape} values differ in shape")
    marks = chunk_changes(new, old, int(chunk))
    for bi, bj in zip(*np.nonzero(marks & CHUNK_CHANGED), strict=True):
        i, j = int(bi) * chunk, int(bj) * chunk
        yield (i, min(i + chunk, new.shape[0]), j, min(j + chunk, new.shape[1]),
               bool(marks[bi, bj] & CHUNK_NOT_EMPTY))


def layer_codec(array: Any) -> str:
    """The ``StoreCodec`` value of a zarr array's codec pipeline ("zstd": bytes + zstd;
    "delta-zstd": numcodecs.delta + bytes + zstd), else its codec names joined by "+"."""
    names = [str(c["name"]) for c in array.metadata.to_dict().get("codecs", [])]
    known = {("bytes", "zstd"): StoreCodec.ZSTD,
             ("numcodecs.delta", "bytes", "zstd"): StoreCodec.DELTA_ZSTD}
    codec = known.get(tuple(names))
    return str(codec.value) if codec is not None else "+".join(names)


class _DeltaZstd:
    """A chunk's delta filter then zstd, as zarr's pipeline ``numcodecs.delta``, bytes
    (little-endian), zstd encodes it: ``encode`` (C-order little-endian chunk) -> stored
    bytes, ``decode`` the reverse."""

    def __init__(self, delta: Any, zstd: Any) -> None:
        self.delta, self.zstd = delta, zstd

    def encode(self, chunk: np.ndarray) -> bytes:
        return bytes(self.zstd.encode(self.delta.encode(chunk)))

    def decode(self, data: bytes) -> np.ndarray:
        raw = np.frombuffer(self.zstd.decode(data), self.delta.dtype)
        return np.asarray(self.delta.decode(raw))


def _chunk_encoder(array: Any) -> Any:
    """The codec that turns a chunk's little-endian values into what zarr stores for
    ``array`` (``encode``/``decode``: a ``numcodecs.Zstd`` of its codec's level and checksum,
    after a ``numcodecs.Delta`` of the array's dtype when the pipeline starts with one), when
    its codec pipeline is exactly [delta,] bytes (little-endian), zstd and its fill value is
    0, as ``create_layout`` makes them; None otherwise (zarr's own ``getitem``/``setitem``)."""
    import numcodecs
    from zarr.codecs import BytesCodec, ZstdCodec
    from zarr.codecs.numcodecs import Delta

    meta = array.metadata
    codecs: tuple[Any, ...] = tuple(getattr(meta, "codecs", ()))
    delta = None
    if codecs and isinstance(codecs[0], Delta):
        config = {k: v for k, v in codecs[0].codec_config.items() if k != "id"}
        dtype = np.dtype(str(config.pop("dtype"))) if "dtype" in config else None
        if config or dtype is None or dtype != native_dtype(array).newbyteorder("<"):
            return None  # an astype, or another dtype: zarr's own pipeline
        delta = numcodecs.Delta(dtype=dtype.str)
        codecs = codecs[1:]
    if (getattr(meta, "zarr_format", None) != 3 or len(codecs) != 2
            or not isinstance(codecs[0], BytesCodec) or not isinstance(codecs[1], ZstdCodec)
            or (codecs[0].endian is not None and codecs[0].endian.value != "little")
            or meta.fill_value != 0 or array.order != "C"):
        return None
    zstd = numcodecs.Zstd(level=codecs[1].level, checksum=codecs[1].checksum)
    return zstd if delta is None else _DeltaZstd(delta, zstd)


def write_tile(store: Any, window: Window, arrays: dict[str, np.ndarray],
               stored: dict[str, np.ndarray], factors: Sequence[int], layout: str = "") -> int:
    """Write one tile (``window`` starts on a tile corner) of ``arrays`` (values as stored)
    and its overview chunks (every ``factor``-th pixel), only the chunks whose values differ
    from ``stored`` (what ``read_tile`` gave; overviews hold the decimated full-resolution
    values, so their old values are ``stored`` decimated too), all concurrently. Returns the
    number of chunks written. ``layout``: see ``_open_array``.

    A chunk is encoded here as zarr encodes it (``_chunk_encoder``: C-order little-endian
    values of the chunk, padded with the fill value 0 past the array's edge, delta, zstd; a chunk of
    fill values only is deleted, zarr's ``write_empty_chunks=False``) on zarr's thread pool
    (zstd releases the GIL) and put into the store: the same bytes as ``setitem`` at a
    third of its per-chunk cost."""
    from zarr.core.buffer import default_buffer_prototype

    r0, _, c0, _ = window
    prototype = default_buffer_prototype()

    async def put(array: Any, encoder: Any, index: tuple[int, int], block: np.ndarray,
                  filled: bool) -> None:
        key = f"{array.store_path.path}/{array.metadata.encode_chunk_key(index)}"
        if not filled:  # fill values only: no chunk, as zarr writes it
            await store.delete(key)
            return
        shape = tuple(int(c) for c in array.chunks)
        full = np.zeros(shape, block.dtype.newbyteorder("<"))
        full[:block.shape[0], :block.shape[1]] = block
        data = await asyncio.to_thread(encoder.encode, full)
        await store.set(key, prototype.buffer.from_bytes(data))

    async def write(name: str, factor: int) -> int:
        array = await _open_array(store, _level_path(name, factor), "r+", layout)
        new = arrays[name][::factor, ::factor]
        old = stored[name][::factor, ::factor]
        top, left = r0 // factor, c0 // factor  # tile corners are multiples of every factor
        chunk = int(array.chunks[0])
        blocks = list(changed_chunks(new, old, chunk))
        encoder = _chunk_encoder(array)
        if encoder is None:
            writes = [array.setitem((slice(top + i0, top + i1), slice(left + j0, left + j1)),
                                    new[i0:i1, j0:j1]) for i0, i1, j0, j1, _ in blocks]
        else:
            writes = [put(array, encoder, ((top + i0) // chunk, (left + j0) // chunk),
                          new[i0:i1, j0:j1], filled) for i0, i1, j0, j1, filled in blocks]
        await gather_all(*writes)
        return len(writes)

    async def gather() -> list[int]:
        return await gather_all(*(write(n, f) for n in arrays for f in (1, *factors)))

    return sum(_sync(gather()))


def lock_path(directory: Path) -> Path:
    """The lock file of the store ``directory``: a hidden file next to it."""
    directory = Path(os.path.abspath(directory))
    return directory.parent / f".{directory.name}{LOCK_SUFFIX}"


@contextlib.contextmanager
def locked(directory: Path) -> Iterator[None]:
    """Exclusive advisory lock of the store ``directory`` (released by the OS if the run
    dies). On release, when ``directory`` holds no repository (the run made none, or removed
    what it made), the lock file is removed too, still under the lock; a run that locked a
    lock file removed meanwhile (another inode at the path) is refused as a concurrent one."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - no advisory locks (Windows): unguarded
        yield
        return
    path = lock_path(directory)
    try:
        fh = open(path, "a+b")  # held for the whole run
    except OSError as exc:
        raise OutputError(f"{directory}: cannot write in the synthesis store ({exc})") from exc
    held = False
    try:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            if os.fstat(fh.fileno()).st_ino != os.stat(path).st_ino:
                raise OSError("lock file replaced")
        except OSError:
            raise OptionsError(f"{directory}: another synthesis run is using it") from None
        held = True
        yield
    finally:
        if held and not is_repository(directory):
            remove_lock(directory)
        fh.close()


def remove_lock(directory: Path) -> None:
    """Remove the lock file of ``directory`` (none: nothing)."""
    with contextlib.suppress(OSError):
        lock_path(directory).unlink()


@dataclass
class Commit:
    """One ``synthesize`` commit of the history."""

    snapshot: str
    written_at: Any
    message: str
    products: list[dict[str, Any]]
    #: the run's options, DEMs (path, name, vertical datum) and software version, as
    #: ``ortho.writing`` names them (empty for commits that did not record them)
    run: dict[str, Any] = field(default_factory=dict)


def history(repo: Any, branch: str = BRANCH, snapshot: str | None = None) -> list[Commit]:
    """The synthesis commits reachable from ``branch`` (or ``snapshot``), newest first."""
    kwargs = {"snapshot_id": snapshot} if snapshot else {"branch": branch}
    out = []
    for info in repo.ancestry(**kwargs):
        meta = (info.metadata or {}).get(COMMIT_KEY)
        if meta is not None:
            out.append(Commit(info.id, info.written_at, info.message,
                              list(meta.get("products", [])),
                              {k: meta[k] for k in ("options", "dems", "software_version")
                               if k in meta}))
    return out


def delete_run_branches(repo: Any) -> int:
    """Delete the run branches a killed run left (``RUN_BRANCH_PREFIX``; nothing else holds
    them: a live run holds the lock); their number."""
    runs = [b for b in repo.list_branches() if b.startswith(RUN_BRANCH_PREFIX)]
    for branch in runs:
        repo.delete_branch(branch)
    return len(runs)


@dataclass
class Pruned:
    """What ``prune`` did: synthesis commits kept and expired, run branches of killed
    runs deleted, objects the garbage collection deleted."""

    kept: int
    expired: int
    run_branches: int
    bytes_deleted: int
    chunks_deleted: int
    files_deleted: int


def prune(repo: Any, keep: int) -> Pruned:
    """Keep the newest ``keep`` synthesis commits of ``main`` and delete what only older ones
    held: the run branches of killed runs, then Icechunk's ``expire_snapshots`` (older than the
    oldest commit kept) and ``garbage_collect`` of every object nothing references any more
    (chunk versions an update replaced, their manifests). The commits kept keep their snapshot
    ids; the product table (in the attributes) keeps every product, so "already in the
    synthesis" still holds. The caller holds the lock (:func:`locked`): the collection would
    take the chunks of a run in flight. Other branches and tags are left as they are."""
    import datetime

    runs = delete_run_branches(repo)
    commits = history(repo)
    expired = set()
    if 0 < keep < len(commits):
        expired = repo.expire_snapshots(commits[keep - 1].written_at)
    summary = repo.garbage_collect(datetime.datetime.now(datetime.UTC))
    return Pruned(kept=min(keep, len(commits)),
                  expired=sum(1 for c in commits[keep:] if c.snapshot in expired),
                  run_branches=runs, bytes_deleted=int(summary.bytes_deleted),
                  chunks_deleted=int(summary.chunks_deleted),
                  files_deleted=int(summary.chunks_deleted + summary.manifests_deleted
                                    + summary.snapshots_deleted
                                    + summary.transaction_logs_deleted
                                    + summary.attributes_deleted))

"""Multiscale layer data for the napari front end (no Qt, no napari import): napari loads the
level that fits the canvas and reads only the window on screen.

A ``LazyArray`` is a full-resolution raster read on demand: indexing with integers and slices
composes without reading, ``np.asarray`` reads the selection through the raster's ``read``
function (an N1 band reads only the product lines of the selection from its memory map, a COG
the window of the overview whose factor matches the selection's step). Its decimated levels
are strided views of it, factors 1, 2, 4, ... until the longer side is at most
``MAX_LEVEL_SIDE`` (``level_factors``); in-memory results get levels averaged like the COG's
overviews (``memory_levels``, ``engine.resample.overview_level``). A GeoTIFF's levels are its
own overviews, read window by window (``geotiff_levels``; a colour composite's as one RGB(A)
stack, ``geotiff_rgb_levels``); one that is not north-up is warped by GDAL first (``north_up``).
"""

from __future__ import annotations

import contextlib
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .products.protocol import radiance_of_counts

#: longer side (pixels) of the coarsest level; a raster this small is one level
MAX_LEVEL_SIDE = 1024

#: a selection: per axis of the full-resolution raster an index or a range of indices
Selection = tuple[int | range, ...]


def level_factors(rows: int, cols: int) -> list[int]:
    """Decimation factors 1, 2, 4, ... until the level's longer side (``ceil(n / f)``, as the
    COG's overviews) is at most ``MAX_LEVEL_SIDE``."""
    factors = [1]
    while max(-(-rows // factors[-1]), -(-cols // factors[-1])) > MAX_LEVEL_SIDE:
        factors.append(2 * factors[-1])
    return factors


def as_slice(r: range) -> slice:
    """The slice of a range of positive step (an empty range: an empty slice)."""
    return slice(r.start, r.start + len(r) * r.step, r.step)


class LazyArray:
    """A raster of ``shape`` read on demand by ``read(selection)`` (module doc).

    ``read`` gets one entry per full-resolution axis, an ``int`` or a ``range`` of positive
    step, and returns the array of the ranges' axes (in order), never larger than asked.
    """

    def __init__(self, read: Callable[[Selection], np.ndarray], shape: Sequence[int],
                 dtype: Any, selection: Selection | None = None) -> None:
        self._read = read
        self.dtype = np.dtype(dtype)
        self._sel: Selection = (selection if selection is not None
                                else tuple(range(int(n)) for n in shape))

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(s) for s in self._sel if isinstance(s, range))

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    def __len__(self) -> int:
        return self.shape[0]

    def __repr__(self) -> str:
        return f"<LazyArray {self.shape} {self.dtype}>"

    def __getitem__(self, key: Any) -> Any:
        """Integers and slices of positive step compose lazily; anything else reads first."""
        keys = key if isinstance(key, tuple) else (key,)
        free = [axis for axis, s in enumerate(self._sel) if isinstance(s, range)]
        if any(k is Ellipsis for k in keys):
            at = keys.index(Ellipsis)
            keys = (*keys[:at], *(slice(None),) * (len(free) - len(keys) + 1), *keys[at + 1:])
        basic = all(isinstance(k, slice) and (k.step is None or k.step > 0)
                    or isinstance(k, int | np.integer) and not isinstance(k, bool)
                    for k in keys)
        if not basic or len(keys) > len(free):
            return np.asarray(self)[key]
        sel = list(self._sel)
        for axis, k in zip(free, keys, strict=False):
            r = sel[axis]
            assert isinstance(r, range)
            sel[axis] = r[k] if isinstance(k, slice) else r[int(k)]
        view = LazyArray(self._read, (), self.dtype, tuple(sel))
        return view if view.ndim else np.asarray(view)[()]

    def __array__(self, dtype: Any = None, copy: bool | None = None) -> np.ndarray:
        if self.size == 0:
            out = np.empty(self.shape, self.dtype)
        else:
            out = np.asarray(self._read(self._sel), self.dtype).reshape(self.shape)
        return out if dtype is None else out.astype(dtype)

    def levels(self, spatial: tuple[int, int] = (-2, -1)) -> list[LazyArray]:
        """Level 0 and its decimated views (``level_factors`` of the ``spatial`` axes)."""
        rows, cols = (self.shape[a] for a in spatial)
        out = [self]
        for f in level_factors(rows, cols)[1:]:
            key = [slice(None)] * self.ndim
            for a in spatial:
                key[a] = slice(None, None, f)
            out.append(self[tuple(key)])
        return out


def memory_levels(data: np.ndarray, nodata: float | None = 0.0, resampling: str = "average",
                  rgb: bool = False) -> list[np.ndarray]:
    """An in-memory raster (H, W) or RGB (H, W, 3) and its overview levels, each from the
    previous (``engine.resample.overview_level``: GDAL ``AVERAGE`` ignoring ``nodata``, or
    "nearest"), down to ``MAX_LEVEL_SIDE``; one level for a small raster."""
    from .engine.resample import overview_level

    levels = [data]
    rows, cols = data.shape[:2]
    for _ in level_factors(rows, cols)[1:]:
        last = levels[-1]
        if rgb:
            levels.append(np.stack([overview_level(last[..., c], nodata, resampling)
                                    for c in range(last.shape[-1])], axis=-1))
        else:
            levels.append(overview_level(last, nodata, resampling))
    return levels


def full_resolution(data: Any) -> Any:
    """Level 0 of a layer's data (napari's multiscale data and a list of levels are sequences,
    arrays are not), else the data itself."""
    return data[0] if isinstance(data, Sequence) else data


#: radiance bands a product read whole (a ``.SEN3``) keeps read (``WholeBands``): the three of
#: the RGB quick-look and the last three the band slider showed
CACHED_BANDS = 6

class WholeBands:
    """The bands of a product read whole (a ``.SEN3``: its netCDF variables are chunked and
    compressed, so a band's lines, or a strided read, cost the whole band's decompression):
    the uint16 ``counts`` of the last ``size`` bands used (least recently used dropped), the
    radiances of a selection computed from them as ``MerisProduct`` defines them
    (``products.protocol.radiance_of_counts``), elementwise: the values
    of ``product.radiance(b)`` at the selection (a ``MerisProduct``: ``counts``, ``scaling``,
    ``no_data_count``)."""

    def __init__(self, product: Any, size: int = CACHED_BANDS) -> None:
        self.product, self.size = product, size
        self._counts: OrderedDict[int, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()  # napari may read in worker threads
        #: bands read so far (each read once while it stays in the cache)
        self.reads: list[int] = []

    def counts(self, band: int) -> np.ndarray:
        """The stored counts of ``band`` (1..15), read whole when not kept."""
        with self._lock:
            if band in self._counts:
                self._counts.move_to_end(band)
                return self._counts[band]
            counts = self.product.counts(band)
            self.reads.append(band)
            self._counts[band] = counts
            while len(self._counts) > self.size:
                self._counts.popitem(last=False)
            return counts

    def radiance(self, band: int, rows: int | range, cols: int | range) -> np.ndarray:
        return selection_radiance(self.product, self.counts(band), band, rows, cols)


def selection_radiance(product: Any, counts: np.ndarray, band: int, rows: int | range,
                       cols: int | range) -> np.ndarray:
    """The radiances of a selection (an index or a range per axis) of ``band``'s stored
    ``counts`` (whole, or an N1's memory map): the selection first, then only its pixels
    converted (``products.protocol.radiance_of_counts``)."""
    return radiance_of_counts(counts[as_index(rows), as_index(cols)],
                              product.scaling.radiance[band - 1], product.no_data_count(band))


def as_index(r: int | range) -> int | slice:
    """An index as it is, a range as its slice (``as_slice``)."""
    return r if isinstance(r, int) else as_slice(r)


# --------------------------------------------------------------------------- GeoTIFFs


def geotiff_levels(path: Path, ds: Any) -> list[list[LazyArray]]:
    """Per band the levels of a big GeoTIFF with overviews (a COG), read on demand
    (``pyramid``): full resolution and the file's own overviews (without any, every level's
    read would be the whole band's: such a file is read whole, ``physical_bands``); bands with
    a scale as physical values."""
    factors = [1, *ds.overviews(1)]
    physical = has_scale(ds)
    dtype = np.float32 if physical else np.dtype(ds.dtypes[0])
    out = []
    for k in range(ds.count):
        scale = (ds.scales[k], ds.offsets[k]) if physical else None
        read = _GeoTiffWindows(path, k + 1, factors, scale)
        band = LazyArray(read, (ds.height, ds.width), dtype)
        out.append([band[::f, ::f] for f in factors])
    return out


def gcps_only(ds: Any) -> bool:
    """True for a raster georeferenced by ground control points (in a CRS) and no geotransform,
    as ``gdal_translate -gcp`` writes it."""
    gcps, gcp_crs = ds.gcps
    return ds.crs is None and bool(gcps) and gcp_crs is not None


@contextlib.contextmanager
def north_up(ds: Any) -> Iterator[Any]:
    """The dataset itself when it is north-up; a south-up or rotated one, or one georeferenced
    by ground control points only, warped by GDAL onto a north-up grid (``WarpedVRT``,
    nearest: a south-up raster's pixels exactly, flipped)."""
    from rasterio.enums import Resampling
    from rasterio.vrt import WarpedVRT

    t = ds.transform
    if gcps_only(ds):
        with WarpedVRT(ds, src_crs=ds.gcps[1], resampling=Resampling.nearest) as vrt:
            yield vrt
    elif ds.crs is not None and (t.b != 0.0 or t.d != 0.0 or t.e > 0.0):
        with WarpedVRT(ds, resampling=Resampling.nearest) as vrt:
            yield vrt
    else:
        yield ds


def geotiff_rgb_levels(path: Path, ds: Any) -> list[LazyArray]:
    """The levels of a big RGB(A) GeoTIFF (``is_rgb``) with overviews as (rows, columns,
    channels) arrays read on demand, like ``geotiff_levels``."""
    factors = [1, *ds.overviews(1)]
    read = _GeoTiffWindows(path, list(range(1, ds.count + 1)), factors, None)
    rgb = LazyArray(read, (ds.height, ds.width, ds.count), np.uint8)
    return [rgb[::f, ::f] for f in factors]


def is_rgb(ds: Any) -> bool:
    """True for a colour composite: 3 or 4 bytes bands that GDAL says are red, green, blue
    (and alpha), as GDAL, QGIS or a satellite's true-colour image (TCI) write it."""
    from rasterio.enums import ColorInterp

    ci = tuple(ds.colorinterp)
    return (ds.count in (3, 4) and all(d == "uint8" for d in ds.dtypes)
            and ci[:3] == (ColorInterp.red, ColorInterp.green, ColorInterp.blue)
            and (ds.count == 3 or ci[3] == ColorInterp.alpha))


class _GeoTiffWindows:
    """``read`` of a GeoTIFF band (``LazyArray``): a selection whose step is an overview's
    factor reads that overview's window, any other reads the full-resolution window; with
    ``scale`` (the band's GDAL scale and offset) physical values (``_to_physical``). With a
    list of bands (an RGB composite), selections are (rows, columns, channels)."""

    def __init__(self, path: Path, band: int | list[int], factors: list[int],
                 scale: tuple[float, float] | None) -> None:
        self.path, self.band, self.factors, self.scale = path, band, factors, scale

    def __call__(self, sel: Selection) -> np.ndarray:
        import rasterio
        from rasterio.windows import Window

        rows, cols = (range(s, s + 1) if isinstance(s, int) else s for s in sel[:2])
        f = rows.step if rows.step == cols.step else 1
        if f not in self.factors or rows.start % f or cols.start % f:
            f = 1
        level = self.factors.index(f) - 1
        opened = rasterio.open(self.path, overview_level=level) if level >= 0 else (
            rasterio.open(self.path))
        with opened as ds:
            window = Window(cols.start // f, rows.start // f,
                            (cols[-1] - cols.start) // f + 1, (rows[-1] - rows.start) // f + 1)
            data = _read_within(ds.read, self.band, window, ds.height, ds.width)[None]
            if self.scale is not None:  # an overview does not carry the band's scale
                mask = _read_within(ds.read_masks, self.band, window, ds.height,
                                    ds.width)[None] == 0
                data = _to_physical(data, mask, [self.scale[0]], [self.scale[1]])
        step = rows.step // f, cols.step // f
        spatial = tuple(0 if isinstance(x, int) else slice(None) for x in sel[:2])
        if isinstance(self.band, int):
            return data[0, ::step[0], ::step[1]][spatial]
        channels = sel[2] if isinstance(sel[2], int) else as_slice(sel[2])
        return np.moveaxis(data[0, :, ::step[0], ::step[1]], 0, -1)[..., channels][spatial]


def _read_within(read: Any, band: int | list[int], window: Any, height: int, width: int
                 ) -> np.ndarray:
    """``read(band, window=window)`` with the window's shape where it runs past the raster by
    a line or a column, the last ones repeated: the pyramid's levels are ``ceil(n / f)`` long,
    GDAL's COG driver rounds an overview's size down (627 lines: 313, 156)."""
    from rasterio.windows import Window

    row, col = min(window.row_off, height - 1), min(window.col_off, width - 1)
    inside = Window(col, row, min(window.width, width - col), min(window.height, height - row))
    data = read(band, window=inside)
    short = (window.height - data.shape[-2], window.width - data.shape[-1])
    if not any(short):
        return data
    return np.pad(data, [(0, 0)] * (data.ndim - 2) + [(0, short[0]), (0, short[1])], mode="edge")


def has_scale(ds: Any) -> bool:
    """True when a band of the GeoTIFF has a GDAL scale or offset (read as physical values)."""
    return not (all(s == 1.0 for s in ds.scales) and all(o == 0.0 for o in ds.offsets))


def physical_bands(ds: Any) -> np.ndarray:
    """All bands; bands with a GDAL scale/offset (our uint16 counts) as float32 physical
    values (counts x scale + offset, nodata stays 0)."""
    data = ds.read()
    if not has_scale(ds):
        return data
    return _to_physical(data, ds.read_masks() == 0, ds.scales, ds.offsets)


def _to_physical(data: np.ndarray, nodata: np.ndarray, scales: Any, offsets: Any
                 ) -> np.ndarray:
    """(bands, rows, cols) counts x scale + offset as float32, ``nodata`` pixels 0."""
    out = data.astype(np.float32) * np.asarray(scales, np.float32)[:, None, None]
    out += np.asarray(offsets, np.float32)[:, None, None]
    out[nodata] = 0
    return out

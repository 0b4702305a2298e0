"""Orthorectified mapping of a MERIS L1b product (MERSYN use case 3, handbook sections 3.1-3.4).

``orthorectify`` is the only glue between the readers (``products.n1``, ``dem``) and the engine:
segment boundary and output grid, the heights of the output points (none / tie points / DEMs
tried in order), the prediction/correction of every antecedent, then the resampling of the
bands and flags. Everything is checked before any heavy work starts.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import pyproj
from affine import Affine

from .engine import pixelgeo, predcorr, terrain
from .engine.boundary import RowSpans, row_spans, segment_boundary
from .errors import DemError, OptionsError
from .geometry.grid import (
    OutputGrid,
    check_grid_size,
    default_grid,
    parse_crs,
    terrain_margin_px,
)
from .geometry.tiepoints import ProductGeometry, TiePointGrid
from .options import Elevation, Geolocation, OrthoOptions, Sampling, SearchMethod
from .progress import ProgressCallback

if TYPE_CHECKING:
    from .dem.base import DemSource, LatticeWindow
    from .dem.stack import DemStack

log = logging.getLogger(__name__)


class MerisProduct(ProductGeometry, Protocol):
    """What ``orthorectify`` reads of a product (``products.n1.MerisL1bProduct``): the geometry, the
    counts of each band, the flags and the radiance scaling factors (Appendix A)."""

    def counts(self, band: int) -> np.ndarray: ...
    @property
    def flags(self) -> np.ndarray: ...
    @property
    def scaling(self) -> Any: ...

#: elevation source codes of the diagnostics (0..n-1: index of the DEM in the list)
SOURCE_TIEPOINTS = -1
SOURCE_NONE = -2
_BLOCK_ROWS = 256
#: unit of the radiances of the output bands (counts x sf_rad, Scaling Factor GADS)
RADIANCE_UNITS = "W m-2 sr-1 um-1"


@dataclass
class OrthoResult:
    """Output of ``orthorectify``: bands (radiance float32, 0 = background) on ``grid``.

    ``valid``: points whose antecedent is inside the product; ``flags``: L1b flags (nearest);
    ``diagnostics`` (on request): line, col, elevation, elevation_source, iterations,
    shift_east_m, shift_north_m; ``stats``: what the Appendix B log prints.
    """

    bands: dict[int, np.ndarray]
    grid: OutputGrid
    valid: np.ndarray
    flags: np.ndarray
    stats: dict[str, Any] = field(default_factory=dict)
    diagnostics: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def crs(self) -> pyproj.CRS:
        return self.grid.crs

    @property
    def transform(self) -> Affine:
        return self.grid.transform

    def band_metadata(self) -> list[dict[str, Any]]:
        """Per output band (sorted band numbers), ``band_metadata``; the band values are
        already radiances."""
        return band_metadata(self.stats, list(self.bands))


def band_metadata(stats: dict[str, Any], bands: Sequence[int]) -> list[dict[str, Any]]:
    """Per band (sorted band numbers): MERIS band number, central wavelength and bandwidth
    (nm), radiance unit and ``sf_rad``, the source product's counts-to-radiance factor
    (Scaling Factor GADS, Appendix A)."""
    out = []
    for b in sorted(bands):
        meta: dict[str, Any] = {"meris_band": b, "units": RADIANCE_UNITS}
        for key, name in (("wavelengths", "wavelength_nm"), ("bandwidths", "bandwidth_nm"),
                          ("scale_factors", "sf_rad")):
            value = stats.get(key, {}).get(b)
            if value is not None:
                meta[name] = value
        out.append(meta)
    return out


def _open_product(product: str | os.PathLike[str] | MerisProduct) -> MerisProduct:
    from .products.open import read_product

    if isinstance(product, (str, os.PathLike)):
        return read_product(product)
    if not hasattr(product, "tie_points"):
        raise OptionsError(f"not a MERIS L1b product: {product!r}")
    return product


def _open_dems(dems: Sequence[DemSource | str | os.PathLike[str]]) -> DemStack | None:
    if not dems:
        return None
    from .dem.stack import DemStack

    try:
        return DemStack(list(dems))
    except DemError:
        raise
    except (OSError, ValueError) as exc:
        raise DemError(f"cannot open DEM: {exc}") from exc


def _check_dem_coverage(stack: Any, boundary: Any) -> None:
    """A tile directory none of whose tiles meets the footprint is a DemError (a wrong
    directory, not a DEM gap): DEM entries with ``check_covers`` are asked."""
    pad = 0.2  # degrees: terrain seen beyond the zero-height boundary
    bounds = (float(np.nanmin(boundary.lon)) - pad, float(np.nanmin(boundary.lat)) - pad,
              float(np.nanmax(boundary.lon)) + pad, float(np.nanmax(boundary.lat)) + pad)
    for src in stack.sources:
        check = getattr(src, "check_covers", None)
        if check is not None:
            check(bounds)


def _margin_px(tp: TiePointGrid, grid: OutputGrid, terrain: bool = True,
               pixel_m: float = 260.0) -> int:
    """Output pixels beyond the zero-height boundary that an antecedent inside the product
    may reach: the outer half product pixel (the boundary joins the border tie points, which
    sit on pixel centres; ``pixel_m``: the product's column spacing, taken twice for the
    oblique pixels) plus, with ``terrain``, the parallax of the highest terrain."""
    lat = float(np.nanmax(np.abs(tp.latitude)))
    half_pixel = terrain_margin_px(grid, 45.0, lat, max_terrain_m=pixel_m)  # tan 45 deg = 1
    if not terrain:
        return half_pixel
    return half_pixel + terrain_margin_px(grid, float(np.nanmax(tp.view_zenith)), lat)


def lonlat_bounds(grid: OutputGrid, n: int = 65) -> tuple[float, float, float, float] | None:
    """WGS84 (lon_min, lat_min, lon_max, lat_max) of the grid's outline (``n`` points a side,
    longitudes unwrapped around the first corner); None when the outline circles a pole."""
    import pyproj

    h, w = grid.shape
    t = np.linspace(0.0, 1.0, n)
    rows = np.concatenate([t * h, np.full(n, h), (1 - t) * h, np.zeros(n)]) - 0.5
    cols = np.concatenate([np.zeros(n), t * w, np.full(n, w), (1 - t) * w]) - 0.5
    x, y = grid.xy(rows, cols)
    tr = pyproj.Transformer.from_crs(grid.crs, "EPSG:4326", always_xy=True)
    lon, lat = (np.asarray(v, np.float64) for v in tr.transform(x, y, errcheck=False))
    ok = np.isfinite(lon) & np.isfinite(lat)
    if not ok.any():
        return None
    lon, lat = lon[ok], lat[ok]
    lon = lon[0] + (lon - lon[0] + 180.0) % 360.0 - 180.0
    if np.ptp(lon) > 300.0:
        return None
    return float(lon.min()), float(lat.min()), float(lon.max()), float(lat.max())


def _heights(stack: DemStack, lon: np.ndarray, lat: np.ndarray, mask: np.ndarray,
             method: str = "bilinear") -> tuple[np.ndarray, np.ndarray]:
    """DEM heights at the output points in ``mask`` (NaN elsewhere or without data: tie points),
    the DEMs tried in order (``DemStack.sample``): each lattice of a DEM with a prepared window
    in memory by the compiled lookup (``engine.terrain``), anything else by the DEM's
    ``sample``."""
    h = np.full(lon.shape, np.nan, np.float32)
    src = np.full(lon.shape, SOURCE_TIEPOINTS, np.int8)
    fh, fsrc = h.reshape(-1), src.reshape(-1)
    flon = np.ascontiguousarray(lon, dtype=np.float64).reshape(-1)
    flat = np.ascontiguousarray(lat, dtype=np.float64).reshape(-1)
    todo = np.array(mask, dtype=bool, copy=True).reshape(-1)
    geoid: dict[str, np.ndarray] = {}  # N by datum, once: the points left only ever shrink
    for i, dem in enumerate(stack.sources):
        if not todo.any():
            break
        # each lattice of the DEM in its order (``DemSource.parts``) in its prepared window;
        # a point whose posts lie beyond a window, or every point left when a lattice has no
        # window, is read by the DEM itself (which tries its lattices in the same order)
        deferred = np.zeros(todo.size, bool)
        for part, datum in dem.parts():
            window = part.lattice_window()
            if window is None:
                deferred |= todo
                break
            miss = np.zeros(todo.size, bool)
            if _window_heights(replace(window, datum=datum), i, method, flon, flat, todo, fh,
                               fsrc, miss, geoid):
                deferred |= miss
                todo &= ~miss
        if deferred.any():
            todo |= deferred
            _sample_into(dem, i, method, np.flatnonzero(deferred), flon, flat, todo, fh, fsrc)
    return h, src


def _window_heights(window: LatticeWindow, index: int, method: str, lon: np.ndarray,
                    lat: np.ndarray, todo: np.ndarray, h: np.ndarray, src: np.ndarray,
                    miss: np.ndarray, geoid: dict[str, np.ndarray]) -> int:
    """``engine.terrain.window_heights`` at the ``todo`` points (flat arrays): DEM x/y by the
    window's transformation (projected DEMs), geoid N for EGM96 heights (``dem.geoid``; kept
    in ``geoid`` by datum for the DEMs and lattices after this one)."""
    x, y = lon, lat
    sel: np.ndarray | None = None
    if window.transform is not None:
        sel = np.flatnonzero(todo)
        x, y = np.empty_like(lon), np.empty_like(lat)
        x[sel], y[sel] = window.transform(lon[sel], lat[sel])
    undulation = np.empty(0)
    if window.datum not in (None, "ellipsoid"):
        if window.datum not in geoid:
            geoid[window.datum] = _undulation(window.datum, lon, lat, todo)
        undulation = geoid[window.datum]
    return int(terrain.window_heights(
        window.data, window.inv, window.lattice, window.wrap_centre,
        terrain.METHOD_CODES[method], x, y, todo, undulation, index, h, src, miss))


def _undulation(datum: str, lon: np.ndarray, lat: np.ndarray, todo: np.ndarray) -> np.ndarray:
    """Geoid undulation N of ``datum`` at the ``todo`` points (flat arrays): EGM96 by the
    compiled bilinear between the grid nodes under them (``dem.geoid.nodes_between``,
    ``engine.terrain.geoid_bilinear``: ``dem.geoid.geoid_undulation``'s numbers)."""
    from .dem.geoid import EGM96, GRID_STEP_DEG, node_indices, nodes_between, to_ellipsoid

    out = np.full(lon.shape, np.nan)
    sel = np.flatnonzero(todo)
    if sel.size == 0:
        return out
    if datum != EGM96:  # (no other geoid: one message for an unknown datum)
        out[sel] = to_ellipsoid(np.zeros(sel.size), lon[sel], lat[sel], datum)
        return out
    # the nodes under every point with a position (a few more than under the todo ones: no
    # copies of the points); points without one (NaN, |lat| > 90) get NaN from the kernel
    la0 = np.fmax(np.fmin.reduce(lat), -90.0)  # fmin/fmax: NaN skipped (all NaN: NaN)
    la1 = np.fmin(np.fmax.reduce(lat), 90.0)
    lo0, lo1 = np.fmin.reduce(lon), np.fmax.reduce(lon)
    if not (np.isfinite(lo0) and la0 <= la1):
        return out
    if lo0 < -180.0 or lo1 >= 180.0:
        lon = (lon + 180.0) % 360.0 - 180.0
        lo0, lo1 = np.fmin.reduce(lon), np.fmax.reduce(lon)
    i, j = node_indices(np.array([lo0, lo1]), np.array([la0, la1]))
    nodes = nodes_between(int(i[0]), int(i[1]) + 1, int(j[0]), int(j[1]) + 1)
    terrain.geoid_bilinear(nodes, int(i[0]), int(j[0]), GRID_STEP_DEG, lon, lat, todo, out)
    return out


def _sample_into(dem: DemSource, index: int, method: str, sel: np.ndarray, lon: np.ndarray,
                 lat: np.ndarray, todo: np.ndarray, h: np.ndarray, src: np.ndarray) -> None:
    """Heights of DEM ``index`` at the flat points ``sel`` by its ``sample``: where it has
    data, written to ``h``/``src`` and cleared from ``todo``."""
    if sel.size == 0:
        return
    v = dem.sample(lon[sel], lat[sel], method)
    got = np.isfinite(v)
    sel = sel[got]
    h[sel] = v[got]
    src[sel] = index
    todo[sel] = False


def orthorectify(product: str | os.PathLike[str] | MerisProduct,
                 grid: OutputGrid | None = None,
                 dems: Sequence[DemSource | str | os.PathLike[str]] = (),
                 elevation: str = "dem", sampling: str = "nearest",
                 bands: Sequence[int] | None = None, tolerance: float = 0.01,
                 parallax: str = "handbook", diagnostics: bool = False,
                 progress: ProgressCallback | None = None, *, method: str = "primary",
                 crs: Any = "EPSG:4326", pixel_size: float | None = None,
                 geolocation: str | None = None, allow_empty: bool = False,
                 max_pixels: int | None = None) -> OrthoResult:
    """Map a MERIS L1b product onto ``grid`` with terrain correction (sections 3.1-3.4).

    ``product``: path or ``MerisL1bProduct``; ``grid``: ``OutputGrid`` (default: the smallest
    rectangle holding the segment boundary in ``crs``, ``pixel_size`` in CRS units or FR 260 m /
    RR 1040 m pixels);
    ``elevation``: "none" (MERSYN ``-ort NO``), "tiepoints" (dem_alt at the antecedent) or "dem"
    (the DEMs at the output point, tried in order, then the tie points; without DEMs: the tie
    points); ``tolerance``: prediction/correction tolerance in product pixels; ``parallax``:
    "handbook" (sphere) or "ellipsoid" (WGS84 radii); ``geolocation``: "bilinear" lon/lat
    (eq. 4a-4b) or "ecef" (default: bilinear with the handbook parallax, ecef with the
    ellipsoid one) tie points, or "pixel": the per-pixel terrain-corrected geolocation of
    MER_FRG_1P/MER_FSG_1P and .SEN3 products (``engine.pixelgeo``; no parallax, no DEM, the
    elevation is ignored); ``method``: "primary" (primary grid + Newton) or "handbook" (MERSYN's
    facet search in the loop); ``allow_empty``: a ``grid`` holding no pixel centre inside the
    zero-height segment boundary gives an all-background result instead of an OptionsError
    (synthesis tiles: terrain points may still lie there, section 3.1); ``max_pixels``: largest
    output grid (default: what fits in 80 % of the available memory at
    :func:`bytes_per_output_pixel`; a larger grid is an OptionsError before any allocation).
    Equals ``precompute(...).result()``.
    """
    return precompute(product, grid, dems, elevation, sampling, bands, tolerance, parallax,
                      diagnostics, progress, method=method, crs=crs, pixel_size=pixel_size,
                      geolocation=geolocation, allow_empty=allow_empty,
                      max_pixels=max_pixels).result()


def precompute(product: str | os.PathLike[str] | MerisProduct,
               grid: OutputGrid | None = None,
               dems: Sequence[DemSource | str | os.PathLike[str]] = (),
               elevation: str = "dem", sampling: str = "nearest",
               bands: Sequence[int] | None = None, tolerance: float = 0.01,
               parallax: str = "handbook", diagnostics: bool = False,
               progress: ProgressCallback | None = None, *, method: str = "primary",
               crs: Any = "EPSG:4326", pixel_size: float | None = None,
               geolocation: str | None = None, allow_empty: bool = False,
               max_pixels: int | None = None) -> Antecedents:
    """The antecedent of every output point, once (arguments as ``orthorectify``); then
    ``Antecedents.counts/radiance/flags`` sample any band at them (as pyresample's
    ``get_neighbour_info`` / ``get_sample_from_neighbour_info``)."""
    t_start = time.perf_counter()
    opts = OrthoOptions.parse(elevation=elevation, sampling=sampling, parallax=parallax,
                              geolocation=geolocation, method=method, tolerance=tolerance,
                              bands=bands, diagnostics=diagnostics, n_dems=len(dems))
    if grid is None:
        crs = parse_crs(crs)
        if pixel_size is not None and not (math.isfinite(pixel_size) and pixel_size > 0):
            raise OptionsError(f"pixel size must be > 0, got {pixel_size}")
    segment = open_segment(product, dems, opts)
    try:
        return segment.precompute(grid, progress, crs=crs, pixel_size=pixel_size,
                                  allow_empty=allow_empty, max_pixels=max_pixels,
                                  t_start=t_start)
    finally:
        segment.close()


@dataclass
class Segment:
    """What a product needs before any output grid, built once and shared by every grid
    (synthesis tiles): tie-point grid, zero-height segment boundary (section 3.1), the opened
    DEM stack and the per-pixel geolocation grids. ``precompute`` then maps one grid."""

    prod: MerisProduct
    tp: TiePointGrid
    boundary: Any
    stack: DemStack | None
    options: OrthoOptions
    dems: list[str]
    pixel: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    #: the DEM stack was read under a grid holding every later one (``prepare_dems``)
    dems_prepared: bool = False

    def prepare_dems(self, extent: OutputGrid) -> None:
        """Read the DEM window under ``extent`` once; the grids of later ``precompute`` calls
        must lie inside it (points beyond are read lazily, same heights)."""
        if self.stack is not None:
            bounds = lonlat_bounds(extent)
            if bounds is not None:
                self.stack.prepare(*bounds)
        self.dems_prepared = True

    def precompute(self, grid: OutputGrid | None = None,
                   progress: ProgressCallback | None = None, *, crs: Any = "EPSG:4326",
                   pixel_size: float | None = None, allow_empty: bool = False,
                   max_pixels: int | None = None, t_start: float | None = None
                   ) -> Antecedents:
        """The antecedents of ``grid`` (arguments as ``precompute``)."""
        t0 = time.perf_counter() if t_start is None else t_start
        job = _prepare(self, grid, crs, pixel_size, t0, max_pixels)
        job.stats["dems"] = list(self.dems)
        if job.stats["points_in_boundary"] == 0 and not allow_empty:
            raise OptionsError(
                f"the output extent {job.grid.bounds} misses the product footprint")
        if job.spans.count == 0:  # nothing to search: every point is background
            return _empty_antecedents(job)
        return _run(job, progress)

    def close(self) -> None:
        if self.stack is not None:
            self.stack.close()


def open_segment(product: str | os.PathLike[str] | MerisProduct,
                 dems: Sequence[DemSource | str | os.PathLike[str]],
                 opts: OrthoOptions) -> Segment:
    """The ``Segment`` of a product (tie points, boundary, DEMs checked against it)."""
    prod = _open_product(product)
    stack = _open_dems(dems) if opts.elevation is Elevation.DEM else None
    try:
        tp = TiePointGrid.from_product(prod)
        boundary = segment_boundary(tp.latitude, tp.longitude)
        if stack is not None:
            _check_dem_coverage(stack, boundary)
        pixel = _pixel_grids(prod) if opts.geolocation is Geolocation.PIXEL else None
    except BaseException:
        if stack is not None:
            stack.close()
        raise
    return Segment(prod, tp, boundary, stack, opts, [str(d) for d in dems], pixel)


@dataclass
class Antecedents:
    """Antecedent (line, col) of every output point of ``grid`` (float32, NaN: background)
    and the product lines ``window`` = [first, stop) they read; ``counts``, ``radiance`` and
    ``flags`` sample the product there (nearest: one fused gather of all bands)."""

    prod: MerisProduct
    grid: OutputGrid
    line: np.ndarray
    col: np.ndarray
    iterations: np.ndarray
    sampling: Sampling
    bands: list[int]
    stats: dict[str, Any]
    diagnostics: dict[str, np.ndarray]
    progress: ProgressCallback | None = None
    t_start: float = field(default_factory=time.perf_counter)
    _index: np.ndarray | None = field(default=None, repr=False)

    @property
    def valid(self) -> np.ndarray:
        """Points whose antecedent is inside the product."""
        return self.iterations >= 0

    @property
    def window(self) -> tuple[int, int]:
        first, stop = self.stats["product_lines_read"]
        return int(first), int(stop)

    def _rows(self) -> slice:
        first, stop = self.window
        return slice(first, stop)

    def _nearest_index(self) -> np.ndarray:
        """Flat pixel index (relative to the window) of each point's nearest pixel, once."""
        from .engine.resample import nearest_pixel

        if self._index is None:
            first, stop = self.window
            self._index = nearest_pixel(self.line, self.col, stop - first,
                                        int(self.prod.width), line_offset=first)
        return self._index

    def _timed(self, key: str, t0: float) -> None:
        sec = self.stats["seconds"]
        sec[key] += time.perf_counter() - t0

    def _gather(self, images: Sequence[Any], dtype: Any, out: np.ndarray,
                scales: np.ndarray | None = None) -> None:
        """The nearest pixel of every point from ``images`` (their window, as ``dtype``) into
        ``out`` (images, points): as they are (``gather``), or times ``scales`` as float32
        (``gather_scaled``)."""
        from .engine.resample import gather, gather_scaled

        stack = self._stack(images, dtype)
        index = self._nearest_index()
        t0 = time.perf_counter()
        if scales is None:
            gather(stack, index, out)
        else:
            gather_scaled(stack, index, scales, out)
        self._timed("resample", t0)

    def _stack(self, images: Sequence[Any], dtype: Any) -> np.ndarray:
        """(n, window lines, W) native copy of the window of each image (memmaps read here)."""
        t0 = time.perf_counter()
        rows = self._rows()
        out = np.empty((len(images), rows.stop - rows.start, int(self.prod.width)), dtype)
        for k, im in enumerate(images):
            out[k] = im[rows]
        self._timed("read_bands", t0)
        return out

    def _interpolated(self, bands: Sequence[int]) -> list[np.ndarray]:
        """Bilinear/bicubic counts (float32) of ``bands`` at the antecedents."""
        from .engine.resample import resample_bands

        stack = self._stack([self.prod.counts(b) for b in bands], np.uint16)
        t0 = time.perf_counter()
        out = resample_bands(list(stack), self.line.astype(np.float64) - self.window[0],
                             self.col, self.sampling.value)
        self._timed("resample", t0)
        return out

    def counts(self, bands: Sequence[int] | None = None) -> np.ndarray:
        """uint16 counts (len(bands), rows, cols) at the antecedents, 0 = background; nearest:
        the product's counts; bilinear/bicubic: interpolated counts rounded half up."""
        bands = self.bands if bands is None else [int(b) for b in bands]
        nr, nc = self.grid.shape
        first, stop = self.window
        if stop <= first or not bands:
            return np.zeros((len(bands), nr, nc), np.uint16)
        out = np.empty((len(bands), nr * nc), np.uint16)  # every point is written below
        if self.sampling is Sampling.NEAREST:
            self._gather([self.prod.counts(b) for b in bands], np.uint16, out)
            return out.reshape(len(bands), nr, nc)
        for k, v in enumerate(self._interpolated(bands)):
            out[k] = np.clip(np.floor(v.reshape(-1) + np.float32(0.5)), 0, 65535)
        return out.reshape(len(bands), nr, nc)

    def radiance(self, bands: Sequence[int] | None = None) -> dict[int, np.ndarray]:
        """float32 radiances (counts x sf_rad, Scaling Factor GADS) of ``bands``, 0 = background;
        bilinear/bicubic: the interpolated counts, not rounded."""
        bands = self.bands if bands is None else [int(b) for b in bands]
        sf = self.prod.scaling.radiance
        nr, nc = self.grid.shape
        if self.window[1] <= self.window[0]:
            return {b: np.zeros((nr, nc), np.float32) for b in bands}
        if self.sampling is Sampling.NEAREST:  # counts x sf_rad in one pass, no uint16 copy
            values = np.empty((len(bands), nr * nc), np.float32)
            self._gather([self.prod.counts(b) for b in bands], np.uint16, values,
                         scales=np.array([sf[b - 1] for b in bands]))
            return {b: values[k].reshape(nr, nc) for k, b in enumerate(bands)}
        out = {}
        for b, v in zip(bands, self._interpolated(bands), strict=True):
            v *= np.float32(sf[b - 1])
            out[b] = v.reshape(nr, nc)
        return out

    def flags(self) -> np.ndarray:
        """L1b flags (uint8) of the nearest pixel, 0 = background (any sampling)."""
        nr, nc = self.grid.shape
        out = np.zeros((1, nr * nc), np.uint8)
        first, stop = self.window
        if stop > first:
            self._gather([self.prod.flags], np.uint8, out)
        return out.reshape(nr, nc)

    def finish(self) -> dict[str, Any]:
        """Statistics with the engine and total times up to now (Appendix B log)."""
        sec = self.stats["seconds"]
        sec["engine"] = sec["prediction_correction"] + sec["resample"]
        sec["total"] = time.perf_counter() - self.t_start
        return self.stats

    def result(self) -> OrthoResult:
        """All bands and flags as an ``OrthoResult`` (what ``orthorectify`` returns)."""
        radiance = self.radiance()
        flags = self.flags()
        if self.progress is not None:
            total = self.grid.height + len(self.bands)
            self.progress(total, total)
        return OrthoResult(radiance, self.grid, self.valid, flags, self.finish(),
                           self.diagnostics)


@dataclass
class _Job:
    """One orthorectification, everything checked: product, tie points, grid, the CSR spans of
    the output points to search, the DEM stack, the kernel height mode and the options."""

    prod: MerisProduct
    tp: TiePointGrid
    grid: OutputGrid
    spans: RowSpans
    stack: DemStack | None
    hmode: int
    options: OrthoOptions
    stats: dict[str, Any]
    t_start: float
    #: per-pixel (lon, lat, altitude) grids of the pixel geolocation model, else None
    pixel: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None


def _height_mode(elevation: Elevation, has_dems: bool) -> int:
    """Kernel height mode (``engine.predcorr``) of an elevation source."""
    if elevation is Elevation.NONE:
        return predcorr.HEIGHT_NONE
    if elevation is Elevation.DEM and has_dems:
        return predcorr.HEIGHT_GIVEN
    return predcorr.HEIGHT_TIEPOINTS


def bytes_per_output_pixel(opts: OrthoOptions) -> int:
    """Memory an output pixel costs in :func:`_run`: antecedent line/column (float32) and
    iterations, each band and its resampling buffer (float32), the diagnostics layers and
    their float32 copies for writing."""
    return 16 + 8 * len(opts.bands) + (48 if opts.diagnostics else 0)


def _prepare(seg: Segment, grid: OutputGrid | None, crs: Any, pixel_size: float | None,
             t_start: float, max_pixels: int | None = None) -> _Job:
    """Default grid (its size checked) and the spans of ``grid`` to search (3.1)."""
    prod, tp, boundary, stack, opts, pixel = (seg.prod, seg.tp, seg.boundary, seg.stack,
                                              seg.options, seg.pixel)
    res_m = float(getattr(getattr(prod, "resolution", None), "column_spacing_m", 260.0))
    if grid is None:
        grid = default_grid(boundary, res_m, crs, pixel_size=pixel_size)
    check_grid_size(grid.width, grid.height, (grid.dx, grid.dy), bytes_per_output_pixel(opts),
                    max_pixels)
    if stack is not None and not seg.dems_prepared:  # the DEM window under the grid, once
        bounds = lonlat_bounds(grid)
        if bounds is not None:
            stack.prepare(*bounds)
    # MERSYN processes the points inside the segment boundary; the primary-grid path also tries
    # a margin: the outer half pixel of the product and terrain seen obliquely beyond it (the
    # pixel geolocation always: its terrain points may lie outside the zero-height boundary)
    margin = (_margin_px(tp, grid, pixel is not None or opts.elevation is not Elevation.NONE,
                         res_m)
              if pixel is not None or opts.method is SearchMethod.PRIMARY else 0)
    inner = row_spans(boundary, grid)
    spans = row_spans(boundary, grid, margin=margin) if margin else inner
    stats = dict(elevation=opts.elevation.value, parallax=opts.parallax.value,
                 sampling=opts.sampling.value, geolocation=opts.geolocation.value,
                 tolerance=opts.tolerance, method=opts.method.value, margin_px=margin,
                 points_in_boundary=inner.count)
    hmode = (predcorr.HEIGHT_NONE if pixel is not None
             else _height_mode(opts.elevation, stack is not None))
    return _Job(prod, tp, grid, spans, stack, hmode, opts, stats, t_start, pixel)


def _pixel_grids(prod: MerisProduct) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The product's per-pixel (lon, lat, altitude), or OptionsError when it has none."""
    if not getattr(prod, "has_pixel_geolocation", False):
        raise OptionsError(
            f"{getattr(prod, 'path', prod)}: geolocation 'pixel' needs a product with a "
            "per-pixel geolocation (MER_FRG_1P / MER_FSG_1P N1 or a .SEN3 directory)")
    geolocated: Any = prod  # FRG/FSG N1 or SEN3 (products.open): the per-pixel accessors
    return (geolocated.pixel_longitude(), geolocated.pixel_latitude(),
            geolocated.pixel_altitude())


def _solve(job: _Job, lon: np.ndarray, lat: np.ndarray, h: np.ndarray | None,
           spans: tuple[np.ndarray, np.ndarray, np.ndarray], r0: int,
           out: tuple[np.ndarray, np.ndarray, np.ndarray]) -> dict:
    """Antecedents of one block of output rows: tie-point model (``predcorr``; primary search
    straight into ``out``, the block's rows of the whole grid) or the product's pixel
    geolocation (``pixelgeo``)."""
    opts = job.options
    if job.pixel is not None:
        return pixelgeo.solve_pixel(job.pixel[0], job.pixel[1], job.grid, lon, lat, spans,
                                    row_start=r0, tolerance=opts.tolerance,
                                    altitude=job.pixel[2], diagnostics=opts.diagnostics)
    return predcorr.solve(job.tp, job.grid, lon, lat, h, job.hmode, spans, row_start=r0,
                          tolerance=opts.tolerance, model=opts.parallax.code,
                          geo=opts.geolocation.code, method=opts.method.value,
                          diagnostics=opts.diagnostics,
                          out=out if opts.method is SearchMethod.PRIMARY else None)


@dataclass
class _Blocks:
    """What the blocks of output rows accumulate: antecedents, iterations, diagnostics, the
    facet-search counts and the points per elevation source."""

    line: np.ndarray
    col: np.ndarray
    iters: np.ndarray
    diag: dict[str, np.ndarray]
    sources: np.ndarray
    search: dict[str, int] = field(default_factory=dict)

    @classmethod
    def empty(cls, shape: tuple[int, int], diagnostics: bool, n_dems: int) -> _Blocks:
        diag: dict[str, np.ndarray] = {}
        if diagnostics:
            diag = {"elevation": np.full(shape, np.nan, np.float32),
                    "elevation_source": np.full(shape, SOURCE_NONE, np.int8),
                    "shift_east_m": np.full(shape, np.nan, np.float32),
                    "shift_north_m": np.full(shape, np.nan, np.float32)}
        # line, col, iterations: every row is written by ``add`` (blocks cover the grid)
        return cls(np.empty(shape, np.float32), np.empty(shape, np.float32),
                   np.empty(shape, np.int8), diag, np.zeros(n_dems + 1, np.int64))

    def add(self, r0: int, r1: int, res: dict[str, Any], src: np.ndarray | None,
            hmode: int) -> None:
        """Store the solution of rows [r0, r1) (``src``: elevation source per point, None
        when the heights are not the DEMs')."""
        for whole, part in ((self.line, res["line"]), (self.col, res["col"]),
                            (self.iters, res["iterations"])):
            if not np.may_share_memory(whole[r0:r1], part):  # (solved in place: nothing to do)
                whole[r0:r1] = part
        for k, v in res["search"].items():
            self.search[k] = self.search.get(k, 0) + v
        if src is not None:  # DEM k counted at k + 1; tie points (-1) at 0
            self.sources += predcorr.solved_counts(src, res["iterations"], -1,
                                                   self.sources.size)
        else:
            self.sources[0] += int(np.count_nonzero(res["iterations"] >= 0))
        if not self.diag:
            return
        ok = res["iterations"] >= 0
        if "elevation" in res:
            for name in ("elevation", "shift_east_m", "shift_north_m"):
                self.diag[name][r0:r1] = np.where(ok, res[name], np.nan)
        code = (src if src is not None else np.full(ok.shape, SOURCE_TIEPOINTS
                if hmode == predcorr.HEIGHT_TIEPOINTS else SOURCE_NONE, np.int8))
        self.diag["elevation_source"][r0:r1] = np.where(ok, code, SOURCE_NONE)


def _run(job: _Job, progress: ProgressCallback | None) -> Antecedents:
    """Prediction/correction by blocks of output rows (section 3.2); the bands are sampled
    later by the returned ``Antecedents``."""
    grid, spans, stack, hmode, opts = job.grid, job.spans, job.stack, job.hmode, job.options
    nr = grid.shape[0]
    blocks = _Blocks.empty(grid.shape, opts.diagnostics,
                           len(stack.sources) if stack is not None else 0)
    t_dem = t_lonlat = t_engine = 0.0
    total = nr + len(opts.bands)
    for r0 in range(0, nr, _BLOCK_ROWS):
        r1 = min(r0 + _BLOCK_ROWS, nr)
        t0 = time.perf_counter()
        lon, lat = grid.lonlat(r0, r1)
        t_lonlat += time.perf_counter() - t0
        p0, p1 = spans.ptr[r0 - spans.row_start], spans.ptr[r1 - spans.row_start]
        ptr = spans.ptr[r0 - spans.row_start: r1 - spans.row_start + 1] - p0
        start, stop = spans.start[p0:p1], spans.stop[p0:p1]
        h = src = None
        if hmode == predcorr.HEIGHT_GIVEN:
            t0 = time.perf_counter()
            mask = np.zeros(lon.shape, bool)
            _mark(mask, ptr, start, stop)
            assert stack is not None
            h, src = _heights(stack, lon, lat, mask)
            t_dem += time.perf_counter() - t0
        t0 = time.perf_counter()
        res = _solve(job, lon, lat, h, (ptr, start, stop), r0,
                     (blocks.line[r0:r1], blocks.col[r0:r1], blocks.iters[r0:r1]))
        t_engine += time.perf_counter() - t0
        blocks.add(r0, r1, res, src, hmode)
        if progress is not None:
            progress(r1, total)
    seconds = {"lonlat": t_lonlat, "dem": t_dem, "prediction_correction": t_engine,
               "read_bands": 0.0, "resample": 0.0, "engine": t_engine}
    return _antecedents(job, blocks, seconds, progress)


def _antecedents(job: _Job, blocks: _Blocks, seconds: dict[str, float],
                 progress: ProgressCallback | None) -> Antecedents:
    """The ``Antecedents`` of a run: diagnostics completed, the Appendix B statistics."""
    prod, opts, hmode = job.prod, job.options, job.hmode
    line, col, iters, diag = blocks.line, blocks.col, blocks.iters, blocks.diag
    window = antecedent_line_window(line, col, int(prod.height), int(prod.width),
                                    opts.sampling)
    valid = iters >= 0
    hist = predcorr.iteration_histogram(
        iters, pixelgeo.MAX_PIXEL_ITERATIONS if job.pixel is not None else predcorr.MAX_ITERATIONS)
    if opts.diagnostics:
        diag.update(line=line, col=col, iterations=iters)
        if hmode == predcorr.HEIGHT_NONE and job.pixel is None:
            diag["elevation"] = np.where(valid, np.float32(0), np.float32(np.nan))
            diag["shift_east_m"] = diag["elevation"].copy()
            diag["shift_north_m"] = diag["elevation"].copy()
    seconds = {**seconds, "total": time.perf_counter() - job.t_start}
    stats = _stats(job, search=blocks.search, hist=hist, processed=int(valid.sum()),
                   window=window, sources=_source_counts(blocks.sources, job.stack, hmode),
                   seconds=seconds)
    return Antecedents(prod, job.grid, line, col, iters, opts.sampling, list(opts.bands), stats,
                       diag, progress, job.t_start)


def _stats(job: _Job, *, search: dict[str, int], hist: np.ndarray, processed: int,
           window: tuple[int, int], sources: dict[str, int], seconds: dict[str, float]
           ) -> dict[str, Any]:
    """What the Appendix B log prints, plus the options and timings of the run."""
    prod, grid, band_list = job.prod, job.grid, list(job.options.bands)
    nr, nc = grid.shape
    return {
        "product": str(getattr(prod, "path", "")),
        "product_name": str(getattr(prod, "product_name", "")),
        "output_lines": nr, "output_columns": nc,
        "crs": grid.crs.to_string(), "ul_x": grid.x0, "ul_y": grid.y0,
        "lr_x": grid.x0 + nc * grid.dx, "lr_y": grid.y0 - nr * grid.dy,
        "pixel_width": grid.dx, "pixel_height": grid.dy,
        "orthorectification": job.hmode != predcorr.HEIGHT_NONE or job.pixel is not None,
        "facet_search": search,
        "iterations_histogram": [int(v) for v in hist],
        "processed_points": processed,
        "product_lines_read": list(window),
        "output_points": nr * nc,
        "elevation_sources": sources,
        "seconds": seconds,
        "bands": band_list, "wavelengths": _per_band(prod, "wavelengths", band_list),
        "bandwidths": _per_band(prod, "bandwidths", band_list),
        "scale_factors": _per_band(getattr(prod, "scaling", None), "radiance", band_list),
        **job.stats,
    }


def _empty_antecedents(job: _Job) -> Antecedents:
    """No antecedent search can reach the grid (``allow_empty``): all background."""
    grid, stack = job.grid, job.stack
    nr, nc = grid.shape
    nan = np.full((nr, nc), np.nan, np.float32)
    iters = np.full((nr, nc), -1, np.int8)
    diag: dict[str, np.ndarray] = {}
    if job.options.diagnostics:
        diag = {"line": nan, "col": nan.copy(), "elevation": nan.copy(),
                "elevation_source": np.full((nr, nc), SOURCE_NONE, np.int8),
                "iterations": iters, "shift_east_m": nan.copy(), "shift_north_m": nan.copy()}
    hist = np.zeros(predcorr.MAX_ITERATIONS + 1, np.int64)
    sources = np.zeros(len(stack.sources) + 1 if stack is not None else 1, np.int64)
    seconds = {"lonlat": 0.0, "dem": 0.0, "prediction_correction": 0.0, "read_bands": 0.0,
               "resample": 0.0, "engine": 0.0, "total": time.perf_counter() - job.t_start}
    stats = _stats(job, search={}, hist=hist, processed=0, window=(0, 0),
                   sources=_source_counts(sources, stack, job.hmode), seconds=seconds)
    return Antecedents(job.prod, grid, nan, nan, iters, job.options.sampling,
                       list(job.options.bands), stats, diag, None, job.t_start)


def antecedent_line_window(line: np.ndarray, col: np.ndarray, n_lines: int, n_cols: int,
                           sampling: str = "nearest") -> tuple[int, int]:
    """Product lines ``[first, stop)`` holding every pixel the resampling of the antecedents
    inside the product reads (section 3.1 "Retrieve the antecedent"): min..max antecedent line
    plus the kernel margin (nearest/bilinear: 0 and +1 line, bicubic: -1 and +2); (0, 0) when
    no antecedent is inside."""
    from .engine.resample import inside_line_range

    span = inside_line_range(line, col, n_lines, n_cols)
    if span is None:
        return 0, 0
    before, after = Sampling(sampling).margin
    first = int(math.floor(span[0])) - before
    stop = int(math.floor(span[1])) + 1 + after
    return max(first, 0), min(stop, n_lines)


def _per_band(source: Any, name: str, band_list: list[int]) -> dict[int, float]:
    """``{band: source.<name>[band - 1]}`` (wavelengths, bandwidths, radiance factors)."""
    try:
        values = list(getattr(source, name))
        return {b: float(values[b - 1]) for b in band_list}
    except (AttributeError, IndexError, TypeError, ValueError):
        return {}


def _source_counts(sources: np.ndarray, stack: DemStack | None, hmode: int) -> dict[str, int]:
    if hmode == predcorr.HEIGHT_NONE:
        return {}
    if stack is None:
        return {"tiepoints": int(sources.sum())}
    out = {"tiepoints": int(sources[0])}
    for i, s in enumerate(stack.sources):
        name = str(getattr(s, "name", None) or getattr(s, "path", f"dem{i}"))
        out[f"{i}:{Path(name).name}"] = int(sources[i + 1])
    return out


def _mark(mask: np.ndarray, ptr: np.ndarray, start: np.ndarray, stop: np.ndarray) -> None:
    for i in range(mask.shape[0]):
        for k in range(ptr[i], ptr[i + 1]):
            mask[i, start[k]:stop[k]] = True


def histogram_lines(hist: Sequence[int]) -> list[str]:
    """The prediction/correction statistics lines of the Appendix B log."""
    total = sum(hist)
    lines = [f"PREDICTION/CORRECTION LOOP STATISTICS (total processed points = {total})"]
    for k, v in enumerate(hist):
        pct = 100.0 * v / total if total else 0.0
        lines.append(f". ITERATION [{k:2d}] = {v:8d} ({pct:5.1f} %)")
    return lines

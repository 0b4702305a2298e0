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
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from ..bands import MAX_BANDS, MERIS
from ..engine import pixeldem, pixelgeo, predcorr
from ..engine.boundary import RowSpans, row_spans, segment_boundary
from ..errors import DemError, OptionsError
from ..geometry.grid import (
    OutputGrid,
    check_grid_size,
    default_grid,
    is_footprint_utm,
    parse_crs,
    product_crs,
    terrain_margin_px,
)
from ..geometry.tiepoints import TiePointGrid
from ..options import Elevation, Geolocation, Hidden, OrthoOptions, SearchMethod
from ..products.protocol import MerisProduct
from ..progress import ProgressCallback
from . import occlusion
from .antecedents import (
    BACKGROUND,
    Antecedents,
    OrthoResult,
    antecedent_window,
    bytes_per_output_pixel,
    on_whole_grid,
)
from .heights import dem_heights
from .stats import SOURCE_NONE, SOURCE_TIEPOINTS, TIMINGS, RunStats, per_band, source_counts

if TYPE_CHECKING:
    from ..dem.base import DemSource
    from ..dem.stack import DemStack

log = logging.getLogger(__name__)
T = TypeVar("T")
_BLOCK_ROWS = 256
#: the product argument of ``orthorectify``/``precompute``: a path or an opened product
ProductLike = str | os.PathLike[str] | MerisProduct


def _open_product(product: str | os.PathLike[str] | MerisProduct) -> MerisProduct:
    from ..products.open import read_product

    if isinstance(product, (str, os.PathLike)):
        return read_product(product)
    if not hasattr(product, "tie_points"):
        raise OptionsError(f"not a MERIS L1b product: {product!r}")
    return product


def band_count(product: MerisProduct) -> int:
    """The bands of a product (``n_bands``: 15 MERIS, 21 OLCI; 15 for one without)."""
    return int(getattr(product, "n_bands", MERIS.n_bands))


def _open_dems(dems: Sequence[DemSource | str | os.PathLike[str]]) -> DemStack | None:
    if not dems:
        return None
    from ..dem.stack import DemStack

    try:
        return DemStack(list(dems))
    except DemError:
        raise
    except (OSError, ValueError) as exc:
        raise DemError(f"cannot open DEM: {exc}") from exc


def _check_dem_coverage(stack: Any, boundary: Any) -> dict[str, list[str]]:
    """A tile directory none of whose tiles meets the footprint is a DemError (a wrong
    directory, not a DEM gap): DEM entries with ``check_covers`` are asked. Returns the tiles
    each DEM lacks under the footprint (``missing_tiles``; its points go to the next source)."""
    pad = 0.2  # degrees: terrain seen beyond the zero-height boundary
    lon = np.asarray(boundary.lon, np.float64)
    if np.nanmax(lon) - np.nanmin(lon) > 180.0:  # across the antimeridian: unwrapped past 180
        lon = np.where(lon < 0.0, lon + 360.0, lon)
    bounds = (float(np.nanmin(lon)) - pad, float(np.nanmin(boundary.lat)) - pad,
              float(np.nanmax(lon)) + pad, float(np.nanmax(boundary.lat)) + pad)
    gaps = {}
    for k, src in enumerate(stack.sources):
        check = getattr(src, "check_covers", None)
        if check is not None:
            check(bounds)
        missing = src.missing_tiles(bounds)
        if missing:
            gaps[str(getattr(src, "name", None) or getattr(src, "path", f"dem{k}"))] = missing
    return gaps


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


def orthorectify(product: ProductLike, grid: OutputGrid | None = None,
                 dems: Sequence[DemSource | str | os.PathLike[str]] = (), *,
                 options: OrthoOptions | None = None,
                 progress: ProgressCallback | None = None, crs: Any = "EPSG:4326",
                 pixel_size: float | None = None, allow_empty: bool = False,
                 max_pixels: int | None = None, **modes: Any) -> OrthoResult:
    """Map a MERIS L1b product onto ``grid`` with terrain correction (sections 3.1-3.4).

    ``product``: path or opened product (``read_product``); ``grid``: ``OutputGrid`` (default:
    :func:`product_grid`, the smallest rectangle holding the segment boundary in ``crs`` (the
    word "utm": the UTM zone of the product's footprint), ``pixel_size`` in CRS units or FR
    260 m / RR 1040 m pixels); ``dems``: DEM entries or sources, tried in order. The options:
    ``options`` (an ``OrthoOptions``) and/or its fields as keywords (``modes``, which replace
    those of ``options``; all checked by ``OrthoOptions.of``):
    ``elevation``: "none" (MERSYN ``-ort NO``), "tiepoints" (dem_alt at the antecedent) or "dem"
    (the DEMs at the output point, tried in order, then the tie points; without DEMs: the tie
    points); ``sampling``: "nearest", "bilinear", "bicubic"; ``bands`` (default all 15);
    ``tolerance``: prediction/correction tolerance in product pixels; ``parallax``:
    "handbook" (sphere) or "ellipsoid" (WGS84 radii); ``geolocation``: "bilinear" lon/lat
    (eq. 4a-4b) or "ecef" (default: bilinear with the handbook parallax, ecef with the
    ellipsoid one) tie points, or "pixel": the per-pixel terrain-corrected geolocation of
    MER_FRG_1P/MER_FSG_1P and .SEN3 products (``engine.pixelgeo``: bilinear between terrain
    points, no parallax; with DEMs, ``engine.pixeldem``: the terrain points moved back to the
    ellipsoid, then the parallax of the DEM height at the output point); ``method``: "primary"
    (primary grid + Newton) or "handbook" (MERSYN's facet search in the loop);
    ``diagnostics``: the per-point layers of ``OrthoResult``.
    ``allow_empty``: a ``grid`` holding no pixel centre inside the
    zero-height segment boundary gives an all-background result instead of an OptionsError
    (synthesis tiles: terrain points may still lie there, section 3.1); ``max_pixels``: largest
    output grid (default: what fits in 80 % of the available memory at
    :func:`bytes_per_output_pixel`, every band held; a larger grid is an OptionsError before
    any allocation). Equals ``precompute(..., hold_bands=True).result()``.
    """
    return precompute(product, grid, dems, options=options, progress=progress, crs=crs,
                      pixel_size=pixel_size, allow_empty=allow_empty, max_pixels=max_pixels,
                      hold_bands=True, **modes).result()


def precompute(product: ProductLike, grid: OutputGrid | None = None,
               dems: Sequence[DemSource | str | os.PathLike[str]] = (), *,
               options: OrthoOptions | None = None,
               progress: ProgressCallback | None = None, crs: Any = "EPSG:4326",
               pixel_size: float | None = None, allow_empty: bool = False,
               max_pixels: int | None = None, hold_bands: bool = False,
               **modes: Any) -> Antecedents:
    """The antecedent of every output point, once (arguments as ``orthorectify``); then
    ``Antecedents.counts/radiance/flags`` sample any band at them (as pyresample's
    ``get_neighbour_info`` / ``get_sample_from_neighbour_info``). The grid's size is checked
    for bands streamed a few at a time (``writing.write_map``); ``hold_bands``: for every band
    held in memory (``result()``; without ``hold_bands``, ``result()`` checks them before it
    allocates them)."""
    t_start = time.perf_counter()
    # every option checked before the product is read; the bands' range then with its bands
    OrthoOptions.of(options, n_dems=len(dems), n_bands=MAX_BANDS, **modes)
    if grid is None:
        crs = crs if is_footprint_utm(crs) else parse_crs(crs)  # "utm": from the tie points
        check_pixel_size(pixel_size)
    prod = _open_product(product)
    opts = OrthoOptions.of(options, n_dems=len(dems), n_bands=band_count(prod), **modes)
    segment = open_segment(prod, dems, opts)
    read_ahead = getattr(segment.prod, "read_ahead", None)  # products that read bands whole
    if read_ahead is not None:
        read_ahead(opts.bands)  # while the antecedents are computed (a .SEN3: 0.05 s a band)
    try:
        return segment.precompute(grid, progress, crs=crs, pixel_size=pixel_size,
                                  allow_empty=allow_empty, max_pixels=max_pixels,
                                  hold_bands=hold_bands,
                                  t_start=t_start)
    finally:
        segment.close()


def check_pixel_size(pixel_size: float | None) -> None:
    """OptionsError unless ``pixel_size`` is None or a finite size > 0."""
    if pixel_size is not None and not (math.isfinite(pixel_size) and pixel_size > 0):
        raise OptionsError(f"pixel size must be > 0, got {pixel_size}")


def product_grid(product: ProductLike, crs: Any = "EPSG:4326",
                 pixel_size: float | None = None) -> OutputGrid:
    """The default output grid of a product: the smallest rectangle of ``crs`` holding its
    segment boundary (section 3.1; ``crs`` "utm": the UTM zone of its footprint),
    ``pixel_size`` in CRS units (default: the product's column spacing, FR 260 m / RR 1040 m,
    in CRS units). The one default grid of the package (``orthorectify``, a new synthesis,
    the widget)."""
    prod = _open_product(product)
    tp = prod.tie_points
    boundary = segment_boundary(tp["latitude"], tp["longitude"])
    check_pixel_size(pixel_size)
    return default_grid(boundary, _column_spacing_m(prod),
                        product_crs(crs, tp["latitude"], tp["longitude"]), pixel_size=pixel_size)


def _column_spacing_m(prod: MerisProduct) -> float:
    """On-ground column spacing at nadir (m) of a product (FR 260 m when it does not say)."""
    return float(getattr(getattr(prod, "resolution", None), "column_spacing_m", 260.0))


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
    #: per-pixel ellipsoid points (lon, lat) of the pixel geolocation with DEMs, else None
    ellipsoid: tuple[np.ndarray, np.ndarray] | None = None
    #: DEM name -> the tiles of its tiling under the footprint it lacks (``missing_tiles``)
    dem_gaps: dict[str, list[str]] = field(default_factory=dict)

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
                   max_pixels: int | None = None, t_start: float | None = None,
                   hold_bands: bool = False) -> Antecedents:
        """The antecedents of ``grid`` (arguments as ``precompute``)."""
        t0 = time.perf_counter() if t_start is None else t_start
        job = _prepare(self, grid, crs, pixel_size, t0, max_pixels, hold_bands)
        if job.points_in_boundary == 0 and not allow_empty:
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
        gaps = _check_dem_coverage(stack, boundary) if stack is not None else {}
        pixel = _pixel_grids(prod) if opts.geolocation is Geolocation.PIXEL else None
        ellipsoid = (_ellipsoid_grid(pixel, tp, opts)
                     if pixel is not None and stack is not None else None)
    except BaseException:
        if stack is not None:
            stack.close()
        raise
    return Segment(prod, tp, boundary, stack, opts, [str(d) for d in dems], pixel,
                   ellipsoid=ellipsoid, dem_gaps=gaps)


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
    #: output pixels searched beyond the zero-height boundary; output pixel centres inside it
    margin_px: int
    points_in_boundary: int
    dems: list[str]
    t_start: float
    #: per-pixel (lon, lat, altitude) grids of the pixel geolocation model, else None
    pixel: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    #: their ellipsoid points (lon, lat) with DEMs (``engine.pixeldem``), else None
    ellipsoid: tuple[np.ndarray, np.ndarray] | None = None
    #: the caller's limit of output pixels (None: from the available memory)
    max_pixels: int | None = None
    #: rows [r0, r1) and columns [c0, c1) of the grid the search reaches (``_search_area``)
    area: tuple[int, int, int, int] = (0, 0, 0, 0)
    #: the size check counted every band held in memory (``precompute(hold_bands=True)``)
    hold_bands: bool = False
    #: DEM name -> tiles it lacks under the footprint (``Segment.dem_gaps``)
    dem_gaps: dict[str, list[str]] = field(default_factory=dict)
    #: the lines of sight of the hidden ground (DEM heights), prepared in a thread
    sightlines: Future[occlusion.Sightlines] | None = None


def _height_mode(elevation: Elevation, has_dems: bool) -> int:
    """Kernel height mode (``engine.predcorr``) of an elevation source."""
    if elevation is Elevation.NONE:
        return predcorr.HEIGHT_NONE
    if elevation is Elevation.DEM and has_dems:
        return predcorr.HEIGHT_GIVEN
    return predcorr.HEIGHT_TIEPOINTS


def _prepare(seg: Segment, grid: OutputGrid | None, crs: Any, pixel_size: float | None,
             t_start: float, max_pixels: int | None = None,
             hold_bands: bool = False) -> _Job:
    """Default grid, the spans of ``grid`` to search (3.1) and the area they reach; the grid's
    size is checked (``bytes_per_output_pixel``) before the spans for what the whole grid
    costs, then with the area, before any allocation of the grid's or the area's size."""
    prod, tp, boundary, stack, opts, pixel = (seg.prod, seg.tp, seg.boundary, seg.stack,
                                              seg.options, seg.pixel)
    res_m = _column_spacing_m(prod)
    if grid is None:
        grid = default_grid(boundary, res_m, product_crs(crs, tp.latitude, tp.longitude),
                            pixel_size=pixel_size)
    size = (grid.width, grid.height, (grid.dx, grid.dy))
    # what the whole grid costs whatever the segment, before the spans (one a row or so)
    check_grid_size(*size, bytes_per_output_pixel(opts, hold_bands=hold_bands, area_share=0.0),
                    max_pixels, lower_bound=True)
    # MERSYN processes the points inside the segment boundary; the primary-grid path also tries
    # a margin: the outer half pixel of the product and terrain seen obliquely beyond it (the
    # pixel geolocation always: its terrain points may lie outside the zero-height boundary)
    margin = (_margin_px(tp, grid, pixel is not None or opts.elevation is not Elevation.NONE,
                         res_m)
              if pixel is not None or opts.method is SearchMethod.PRIMARY else 0)
    if pixel is not None:  # the DEMs' heights with the ellipsoid grid, else none
        hmode = predcorr.HEIGHT_NONE if seg.ellipsoid is None else predcorr.HEIGHT_GIVEN
    else:
        hmode = _height_mode(opts.elevation, stack is not None)
    sightlines = None
    if hmode == predcorr.HEIGHT_GIVEN and stack is not None:
        # the DEM window read and the lines of sight prepared while the spans are found
        bounds = lonlat_bounds(grid)
        if not seg.dems_prepared and bounds is not None:
            stack.prepare(*bounds)
        sightlines = _in_background(
            occlusion.Sightlines.of, stack,
            0.5 * (bounds[1] + bounds[3]) if bounds is not None else 0.0,
            view=(tp.latitude, tp.longitude, tp.view_zenith, tp.view_azimuth,
                  float(tp.kernel_args()[4])))
    inner = row_spans(boundary, grid)
    spans = row_spans(boundary, grid, margin=margin) if margin else inner
    job = _Job(prod, tp, grid, spans, stack, hmode, opts, margin, inner.count, list(seg.dems),
               t_start, pixel, seg.ellipsoid, max_pixels, sightlines=sightlines)
    job.area, job.hold_bands = _search_area(job), hold_bands
    job.dem_gaps = dict(seg.dem_gaps)
    r0, r1, c0, c1 = job.area
    share = (r1 - r0) * (c1 - c0) / max(grid.width * grid.height, 1)
    check_grid_size(*size, bytes_per_output_pixel(opts, hold_bands=hold_bands, area_share=share),
                    max_pixels)
    if stack is not None and not seg.dems_prepared and sightlines is None:
        # the DEM window under the grid, once
        bounds = lonlat_bounds(grid)
        if bounds is not None:
            stack.prepare(*bounds)
    return job


def _in_background(fn: Callable[..., T], *args: Any, **kwargs: Any) -> Future[T]:
    """``fn(*args, **kwargs)`` run in a thread of its own; its result (or exception) from the
    returned future."""
    future: Future[T] = Future()

    def work() -> None:
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # raised where the result is taken
            future.set_exception(exc)

    threading.Thread(target=work, name="meris-ortho-background", daemon=True).start()
    return future


def _pixel_grids(prod: MerisProduct) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The product's per-pixel (lon, lat, altitude), or OptionsError when it has none."""
    if not getattr(prod, "has_pixel_geolocation", False):
        raise OptionsError(
            f"{getattr(prod, 'path', prod)}: geolocation 'pixel' needs a product with a "
            "per-pixel geolocation (MER_FRG_1P / MER_FSG_1P / MER_RRG_1P N1 or a .SEN3 "
            "directory)")
    geolocated: Any = prod  # FRG/FSG N1 or SEN3 (products.open): the per-pixel accessors
    return (geolocated.pixel_longitude(), geolocated.pixel_latitude(),
            geolocated.pixel_altitude())


def _ellipsoid_grid(pixel: tuple[np.ndarray, np.ndarray, np.ndarray], tp: TiePointGrid,
                    opts: OrthoOptions) -> tuple[np.ndarray, np.ndarray]:
    """The per-pixel terrain points moved back to the ellipsoid (``pixeldem.ellipsoid_grid``)
    with the run's parallax model."""
    _, _, coef, df, dj = tp.kernel_args()
    return pixeldem.ellipsoid_grid(pixel[0], pixel[1], pixel[2], coef, df, dj,
                                   opts.parallax.code)


def _span_columns(job: _Job, start: np.ndarray, stop: np.ndarray) -> tuple[int, int]:
    """Columns [c0, c1) of a block of rows that hold its spans: from a multiple of the
    primary-grid step (the nodes of the whole rows) for the tie-point model; the whole rows for
    the pixel geolocation."""
    if job.pixel is not None:
        return 0, job.grid.width
    step = predcorr.PRIMARY_STEP
    return int(start.min()) // step * step, int(stop.max())


def _solve(job: _Job, lon: np.ndarray, lat: np.ndarray, h: np.ndarray | None,
           spans: tuple[np.ndarray, np.ndarray, np.ndarray], origin: tuple[int, int],
           out: tuple[np.ndarray, np.ndarray, np.ndarray] | None) -> dict:
    """Antecedents of one block of output rows from grid pixel ``origin`` (row, column; the
    spans count from that column): tie-point model (``predcorr``; primary search straight into
    ``out`` when it is given, the block's rows of the whole grid) or the product's pixel
    geolocation (``pixelgeo``; with DEMs, on its ellipsoid points: ``pixeldem``; whole rows)."""
    opts = job.options
    r0, c0 = origin
    if job.pixel is not None and job.ellipsoid is not None:
        assert h is not None
        return pixeldem.solve_pixel_dem(job.pixel[0], job.pixel[1], job.ellipsoid,
                                        job.pixel[2], job.tp, opts.parallax.code, job.grid, lon,
                                        lat, h, spans, row_start=r0, tolerance=opts.tolerance,
                                        max_iter=pixelgeo.MAX_PIXEL_ITERATIONS,
                                        diagnostics=opts.diagnostics)
    if job.pixel is not None:
        return pixelgeo.solve_pixel(job.pixel[0], job.pixel[1], job.grid, lon, lat, spans,
                                    row_start=r0, tolerance=opts.tolerance,
                                    altitude=job.pixel[2], diagnostics=opts.diagnostics)
    return predcorr.solve(job.tp, job.grid, lon, lat, h, job.hmode, spans, row_start=r0,
                          tolerance=opts.tolerance, model=opts.parallax.code,
                          geo=opts.geolocation.code, method=opts.method.value,
                          diagnostics=opts.diagnostics,
                          out=out if opts.method is SearchMethod.PRIMARY else None,
                          col_start=c0)


def _search_area(job: _Job) -> tuple[int, int, int, int]:
    """Rows [r0, r1) and columns [c0, c1) of the grid the search reaches: the blocks of
    ``_BLOCK_ROWS`` rows holding spans, whole, and the columns ``_span_columns`` gives their
    spans; (0, 0, 0, 0) when there is no span."""
    spans = job.spans
    rows = np.flatnonzero(np.diff(spans.ptr)) + spans.row_start
    if rows.size == 0:
        return 0, 0, 0, 0
    r0 = int(rows[0]) // _BLOCK_ROWS * _BLOCK_ROWS
    r1 = min(-(-(int(rows[-1]) + 1) // _BLOCK_ROWS) * _BLOCK_ROWS, job.grid.height)
    c0, c1 = _span_columns(job, spans.start, spans.stop)
    return r0, r1, c0, c1


@dataclass
class _Blocks:
    """What the blocks of output rows accumulate over the search ``area`` (rows [r0, r1),
    columns [c0, c1) of the grid): antecedents, iterations, diagnostics, the facet-search
    counts and the points per elevation source."""

    area: tuple[int, int, int, int]
    line: np.ndarray
    col: np.ndarray
    iters: np.ndarray
    diag: dict[str, np.ndarray]
    sources: np.ndarray
    search: dict[str, int] = field(default_factory=dict)
    #: ground hidden by the relief (the lines of sight marched over the DEMs), else None
    hidden: np.ndarray | None = None

    @classmethod
    def empty(cls, area: tuple[int, int, int, int], diagnostics: bool, n_dems: int,
              hidden: bool = False) -> _Blocks:
        shape = (area[1] - area[0], area[3] - area[2])
        diag: dict[str, np.ndarray] = {}
        if diagnostics:
            diag = {name: _background(name, shape) for name in _LAYERS
                    if name not in BACKGROUND and name != "hidden"}
        # line, col, iterations: not searched (rows or columns without spans) until ``add``
        return cls(area, _background("line", shape), _background("col", shape),
                   _background("iterations", shape), diag, np.zeros(n_dems + 1, np.int64),
                   hidden=np.zeros(shape, bool) if hidden else None)

    def rows(self, r0: int, r1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(line, col, iterations) of grid rows [r0, r1) over the area's columns (views)."""
        a0 = self.area[0]
        return self.line[r0 - a0:r1 - a0], self.col[r0 - a0:r1 - a0], self.iters[r0 - a0:r1 - a0]

    def add(self, window: tuple[int, int, int, int], res: dict[str, Any],
            src: np.ndarray | None, hmode: int, hidden: np.ndarray | None = None) -> None:
        """Store the solution of grid rows [r0, r1) and columns [c0, c1) (``window``, inside
        the area; ``src``: elevation source per point, None when the heights are not the
        DEMs'; ``hidden``: its ground hidden by the relief)."""
        a0, _, b0, _ = self.area
        r0, r1, c0, c1 = window
        r0, r1, c0, c1 = r0 - a0, r1 - a0, c0 - b0, c1 - b0
        if hidden is not None and self.hidden is not None:
            self.hidden[r0:r1, c0:c1] = hidden
        for whole, part in ((self.line, res["line"]), (self.col, res["col"]),
                            (self.iters, res["iterations"])):
            if not np.may_share_memory(whole[r0:r1, c0:c1], part):  # (solved in place)
                whole[r0:r1, c0:c1] = part
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
                self.diag[name][r0:r1, c0:c1] = np.where(ok, res[name], np.nan)
        code = (src if src is not None else np.full(ok.shape, SOURCE_TIEPOINTS
                if hmode == predcorr.HEIGHT_TIEPOINTS else SOURCE_NONE, np.int8))
        self.diag["elevation_source"][r0:r1, c0:c1] = np.where(ok, code, SOURCE_NONE)


def _run(job: _Job, progress: ProgressCallback | None) -> Antecedents:
    """Prediction/correction by blocks of output rows (section 3.2); the bands are sampled
    later by the returned ``Antecedents``. With DEM heights, hidden ground is looked for
    (``occlusion.hidden_ground``) block by block in a thread of its own, one block behind the
    search: the lines of sight ``_prepare`` started are made while the first blocks are
    solved."""
    grid, spans, stack, hmode, opts = job.grid, job.spans, job.stack, job.hmode, job.options
    nr = grid.shape[0]
    area = job.area
    t_dem = t_lonlat = t_engine = 0.0
    total = nr + len(opts.bands)
    blocks = _Blocks.empty(area, opts.diagnostics, len(stack.sources) if stack is not None else 0,
                           hidden=job.sightlines is not None or job.pixel is not None)
    behind = _Behind() if job.sightlines is not None else None
    try:
        for r0 in range(0, nr, _BLOCK_ROWS):
            r1 = min(r0 + _BLOCK_ROWS, nr)
            p0, p1 = spans.ptr[r0 - spans.row_start], spans.ptr[r1 - spans.row_start]
            if p1 == p0:  # no point of these rows to search (a grid larger than the segment)
                if progress is not None:
                    progress(r1, total)
                continue
            c0, c1 = _span_columns(job, spans.start[p0:p1], spans.stop[p0:p1])
            t0 = time.perf_counter()
            lon, lat = grid.lonlat(r0, r1, col_start=c0, col_stop=c1)
            t_lonlat += time.perf_counter() - t0
            ptr = spans.ptr[r0 - spans.row_start: r1 - spans.row_start + 1] - p0
            start, stop = spans.start[p0:p1] - c0, spans.stop[p0:p1] - c0
            h = src = None
            if hmode == predcorr.HEIGHT_GIVEN:
                t0 = time.perf_counter()
                mask = np.zeros(lon.shape, bool)
                _mark(mask, ptr, start, stop)
                assert stack is not None
                h, src = dem_heights(stack, lon, lat, mask)
                t_dem += time.perf_counter() - t0
            t0 = time.perf_counter()
            whole = (c0, c1) == area[2:]  # the block's rows of the area: solved in place
            res = _solve(job, lon, lat, h, (ptr, start, stop), (r0, c0),
                         blocks.rows(r0, r1) if whole else None)
            t_engine += time.perf_counter() - t0
            window = (r0, r1, c0, c1)
            if behind is not None:  # the lines of sight marched over the DEMs
                assert h is not None and job.sightlines is not None
                behind.submit(_hidden_block, job, job.sightlines, blocks, window, lon, lat, h,
                              res, src)
            else:
                hidden = None
                if job.pixel is not None:  # the pixel geolocation's own hidden ground
                    hidden = res["iterations"] == pixelgeo.OCCLUDED
                blocks.add(window, res, src, hmode, hidden)
            if progress is not None:
                progress(r1, total)
        if behind is not None:
            t_dem += behind.finish()
    finally:
        if behind is not None:
            behind.close()
    seconds = {"lonlat": t_lonlat, "dem": t_dem, "prediction_correction": t_engine,
               "read_bands": 0.0, "resample": 0.0, "engine": t_engine}
    return _antecedents(job, blocks, seconds, progress)


def _hidden_block(job: _Job, sightlines: Future[occlusion.Sightlines], blocks: _Blocks,
                  window: tuple[int, int, int, int], lon: np.ndarray, lat: np.ndarray,
                  h: np.ndarray, res: dict, src: np.ndarray | None) -> None:
    """The hidden ground of a solved block (``occlusion.hidden_ground``), dropped with hidden
    ``mask``, then the block added to ``blocks``."""
    hidden = occlusion.hidden_ground(sightlines.result(), job.tp.kernel_args(), lon, lat, h,
                                     res, separable=job.grid.is_lonlat)
    if job.options.hidden is Hidden.MASK:
        occlusion.drop_hidden(res, hidden)
    blocks.add(window, res, src, job.hmode, hidden)


class _Behind:
    """Work done in one thread of its own, in the order given, at most ``AHEAD`` pieces
    waiting (each holds a block's points); its seconds and first exception from
    ``finish``."""

    AHEAD = 2

    def __init__(self) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="meris-ortho-behind")
        self._pending: list[Future[float]] = []
        self._seconds = 0.0

    def submit(self, fn: Callable[..., None], *args: Any) -> None:
        """``fn(*args)`` once the pieces before it are done; waits while ``AHEAD`` wait."""
        while len(self._pending) >= self.AHEAD:
            self._seconds += self._pending.pop(0).result()

        def timed() -> float:
            t0 = time.perf_counter()
            fn(*args)
            return time.perf_counter() - t0

        self._pending.append(self._pool.submit(timed))

    def finish(self) -> float:
        """Waits for every piece; the seconds of all of them."""
        while self._pending:
            self._seconds += self._pending.pop(0).result()
        return self._seconds

    def close(self) -> None:
        """The pieces not started dropped, the thread ended (after an error too)."""
        for f in self._pending:
            f.cancel()
        self._pool.shutdown(wait=True)


def _antecedents(job: _Job, blocks: _Blocks, seconds: dict[str, float],
                 progress: ProgressCallback | None) -> Antecedents:
    """The ``Antecedents`` of a run: diagnostics completed, the Appendix B statistics."""
    prod, opts, hmode = job.prod, job.options, job.hmode
    line, col, iters, diag = blocks.line, blocks.col, blocks.iters, blocks.diag
    window = antecedent_window(line, col, int(prod.height), int(prod.width), opts.sampling)
    valid = iters >= 0
    hist = predcorr.iteration_histogram(
        iters, pixelgeo.MAX_PIXEL_ITERATIONS if job.pixel is not None else predcorr.MAX_ITERATIONS)
    hidden = blocks.hidden
    if opts.diagnostics:
        diag.update(line=line, col=col, iterations=iters,
                    hidden=(hidden if hidden is not None else np.zeros(iters.shape, bool)
                            ).astype(np.uint8))
        if hmode == predcorr.HEIGHT_NONE and job.pixel is None:
            diag["elevation"] = np.where(valid, np.float32(0), np.float32(np.nan))
            diag["shift_east_m"] = diag["elevation"].copy()
            diag["shift_north_m"] = diag["elevation"].copy()
        diag = {name: on_whole_grid(a, job.grid.shape, blocks.area, _LAYERS[name][0])
                for name, a in diag.items()}
    seconds = {**seconds, "total": time.perf_counter() - job.t_start}
    stats = _stats(job, search=blocks.search, hist=hist, processed=int(valid.sum()),
                   window=window, sources=blocks.sources, seconds=seconds,
                   hidden=None if hidden is None else int(np.count_nonzero(hidden)))
    return Antecedents(prod, job.grid, blocks.area, line, col, iters, opts.sampling,
                       list(opts.bands), stats, diag, progress, job.t_start,
                       max_pixels=job.max_pixels, bands_counted=job.hold_bands,
                       whole_grid={k: diag[k] for k in BACKGROUND if k in diag},
                       area_hidden=hidden)


#: background value and type of the diagnostics layers (``OrthoResult.diagnostics``), in
#: the order of an empty result's: the antecedents' own (``BACKGROUND``), the elevation, its
#: source and the parallax shifts
_LAYERS: dict[str, tuple[float, Any]] = {
    "line": (BACKGROUND["line"], np.float32), "col": (BACKGROUND["col"], np.float32),
    "elevation": (np.nan, np.float32), "elevation_source": (SOURCE_NONE, np.int8),
    "iterations": (BACKGROUND["iterations"], np.int8), "shift_east_m": (np.nan, np.float32),
    "shift_north_m": (np.nan, np.float32), "hidden": (0, np.uint8)}


def _background(name: str, shape: tuple[int, int]) -> np.ndarray:
    """Layer ``name`` of ``_LAYERS`` over ``shape``, all background."""
    value, dtype = _LAYERS[name]
    return np.full(shape, value, dtype)


def _empty_antecedents(job: _Job) -> Antecedents:
    """No antecedent search can reach the grid (``allow_empty``): all background."""
    grid, stack = job.grid, job.stack
    nr, nc = grid.shape
    diag: dict[str, np.ndarray] = {}
    if job.options.diagnostics:
        diag = {name: _background(name, (nr, nc)) for name in _LAYERS}
    hist = np.zeros(predcorr.MAX_ITERATIONS + 1, np.int64)
    sources = np.zeros(len(stack.sources) + 1 if stack is not None else 1, np.int64)
    seconds = {**dict.fromkeys(TIMINGS, 0.0), "total": time.perf_counter() - job.t_start}
    looked = job.hmode == predcorr.HEIGHT_GIVEN or job.pixel is not None
    stats = _stats(job, search={}, hist=hist, processed=0, window=(0, 0, 0, 0), sources=sources,
                   seconds=seconds, hidden=0 if looked else None)
    none = np.zeros((0, 0), np.float32)
    return Antecedents(job.prod, grid, (0, 0, 0, 0), none, none, np.zeros((0, 0), np.int8),
                       job.options.sampling, list(job.options.bands), stats, diag, None,
                       job.t_start, max_pixels=job.max_pixels,
                       bands_counted=job.hold_bands,
                       whole_grid={k: diag[k] for k in BACKGROUND if k in diag},
                       area_hidden=np.zeros((0, 0), bool) if looked else None)


def _stats(job: _Job, *, search: dict[str, int], hist: np.ndarray, processed: int,
           window: tuple[int, int, int, int], sources: np.ndarray, seconds: dict[str, float],
           hidden: int | None = None) -> RunStats:
    """The ``RunStats`` of a run (``sources``: points per elevation source, tie points at 0,
    DEM k at k + 1; ``hidden``: points hidden by the relief, None: not looked for)."""
    prod, grid, opts, band_list = job.prod, job.grid, job.options, list(job.options.bands)
    nr, nc = grid.shape
    names = None if job.stack is None else [
        str(getattr(s, "name", None) or getattr(s, "path", f"dem{i}"))
        for i, s in enumerate(job.stack.sources)]
    return RunStats(
        product=str(getattr(prod, "path", "")),
        product_name=str(getattr(prod, "product_name", "")),
        output_lines=nr, output_columns=nc,
        crs=grid.crs.to_string(), ul_x=grid.x0, ul_y=grid.y0,
        lr_x=grid.x0 + nc * grid.dx, lr_y=grid.y0 - nr * grid.dy,
        pixel_width=grid.dx, pixel_height=grid.dy,
        orthorectification=job.hmode != predcorr.HEIGHT_NONE or job.pixel is not None,
        facet_search=search,
        iterations_histogram=[int(v) for v in hist],
        processed_points=processed,
        product_lines_read=list(window[:2]),
        product_columns_read=list(window[2:]),
        output_points=nr * nc,
        elevation_sources=source_counts(sources, names, job.hmode != predcorr.HEIGHT_NONE),
        seconds=seconds,
        bands=band_list, wavelengths=per_band(prod, "wavelengths", band_list),
        bandwidths=per_band(prod, "bandwidths", band_list),
        scale_factors=per_band(getattr(prod, "scaling", None), "radiance", band_list),
        elevation=opts.elevation.value, parallax=opts.parallax.value,
        sampling=opts.sampling.value, geolocation=opts.geolocation.value,
        tolerance=opts.tolerance, method=opts.method.value, margin_px=job.margin_px,
        points_in_boundary=job.points_in_boundary, dems=list(job.dems),
        dem_datums=[] if job.stack is None else [getattr(s, "datum", None)
                                                 for s in job.stack.sources],
        dem_gaps={k: list(v) for k, v in job.dem_gaps.items()},
        hidden=opts.hidden.value, hidden_points=hidden)


def _mark(mask: np.ndarray, ptr: np.ndarray, start: np.ndarray, stop: np.ndarray) -> None:
    """True in ``mask`` on the CSR spans of the output points to search (one block of rows)."""
    for i in range(mask.shape[0]):
        for k in range(ptr[i], ptr[i + 1]):
            mask[i, start[k]:stop[k]] = True

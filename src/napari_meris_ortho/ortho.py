"""Orthorectified mapping of a MERIS L1b product (MERSYN use case 3, handbook sections 3.1-3.4).

``orthorectify`` is the only glue between the readers (``io.n1``, ``io.dem``) and the engine:
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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .engine import predcorr
from .engine.boundary import row_spans, segment_boundary
from .engine.grid import OutputGrid, default_grid, parse_crs
from .engine.location import geolocation_code, parallax_code
from .engine.tiepoints import TiePointGrid
from .errors import DemError, OptionsError
from .progress import ProgressCallback

log = logging.getLogger(__name__)

ELEVATIONS = ("none", "tiepoints", "dem")
#: elevation source codes of the diagnostics (0..n-1: index of the DEM in the list)
SOURCE_TIEPOINTS = -1
SOURCE_NONE = -2
#: highest terrain expected (m); sets how far beyond the zero-height boundary points are tried
MAX_TERRAIN_M = 9000.0
_BLOCK_ROWS = 256


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
    def crs(self) -> Any:
        return self.grid.crs

    @property
    def transform(self) -> Any:
        return self.grid.transform


def _check_options(elevation: str, dems: Sequence[Any], bands: Sequence[int] | None,
                   tolerance: float, parallax: str, sampling: str, method: str) -> list[int]:
    """Refuse inconsistent options early (MERSYN checks parameters first, section 3.1)."""
    from .engine.resample import METHODS

    if elevation not in ELEVATIONS:
        raise OptionsError(f"unknown elevation source {elevation!r}: choose none, tiepoints or dem")
    if elevation != "dem" and len(dems) > 0:
        raise OptionsError(
            f"DEMs given with elevation {elevation!r}: DEMs are only used with elevation 'dem'")
    if not (isinstance(tolerance, (int, float)) and math.isfinite(tolerance) and tolerance > 0):
        raise OptionsError(f"tolerance must be > 0 product pixels, got {tolerance!r}")
    parallax_code(parallax)
    if sampling not in METHODS:
        raise OptionsError(
            f"unknown sampling method {sampling!r}: choose one of {', '.join(METHODS)}")
    if method not in ("primary", "handbook"):
        raise OptionsError(f"unknown search method {method!r}: choose primary or handbook")
    chosen = list(range(1, 16)) if bands is None else [int(b) for b in bands]
    bad = [b for b in chosen if not 1 <= b <= 15]
    if bad or not chosen:
        raise OptionsError(f"bands must be 1..15, got {list(bands or [])}")
    return sorted(set(chosen))


def _open_product(product: Any) -> Any:
    from .io.n1 import read_product

    if isinstance(product, (str, os.PathLike)):
        return read_product(product)
    if not hasattr(product, "tie_points"):
        raise OptionsError(f"not a MERIS L1b product: {product!r}")
    return product


def _open_dems(dems: Sequence[Any]) -> Any:
    if not dems:
        return None
    from .io.dem import DemStack

    try:
        return DemStack(list(dems))
    except DemError:
        raise
    except (OSError, ValueError) as exc:
        raise DemError(f"cannot open DEM: {exc}") from exc


def _margin_px(tp: TiePointGrid, grid: OutputGrid) -> int:
    """Output pixels beyond the zero-height boundary that a terrain point may reach."""
    shift_m = MAX_TERRAIN_M * math.tan(math.radians(float(np.nanmax(tp.view_zenith))))
    if grid.is_geographic:
        lat = min(float(np.nanmax(np.abs(tp.latitude))), 89.0)
        pix_m = min(grid.dx * math.cos(math.radians(lat)), grid.dy) * 111320.0
    else:
        pix_m = min(grid.dx, grid.dy)
    return int(math.ceil(shift_m / max(pix_m, 1e-9))) + 2


def _heights(stack: Any, lon: np.ndarray, lat: np.ndarray, mask: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """DEM heights at the output points in ``mask`` (NaN elsewhere or without data: tie points)."""
    h = np.full(lon.shape, np.nan, np.float32)
    src = np.full(lon.shape, SOURCE_TIEPOINTS, np.int8)
    if mask.any():
        hv, iv = stack.sample(lon[mask], lat[mask])
        h[mask] = hv
        src[mask] = np.where(iv >= 0, iv, SOURCE_TIEPOINTS)
    return h, src


def orthorectify(product: Any, grid: OutputGrid | None = None, dems: Sequence[Any] = (),
                 elevation: str = "dem", sampling: str = "nearest",
                 bands: Sequence[int] | None = None, tolerance: float = 0.01,
                 parallax: str = "handbook", diagnostics: bool = False,
                 progress: ProgressCallback | None = None, *, method: str = "primary",
                 crs: Any = "EPSG:4326", pixel_size: float | None = None,
                 geolocation: str | None = None) -> OrthoResult:
    """Map a MERIS L1b product onto ``grid`` with terrain correction (sections 3.1-3.4).

    ``product``: path or ``MerisL1bProduct``; ``grid``: ``OutputGrid`` (default: the smallest
    rectangle holding the segment boundary in ``crs``, ``pixel_size`` in CRS units or FR 260 m /
    RR 1040 m pixels);
    ``elevation``: "none" (MERSYN ``-ort NO``), "tiepoints" (dem_alt at the antecedent) or "dem"
    (the DEMs at the output point, tried in order, then the tie points; without DEMs: the tie
    points); ``tolerance``: prediction/correction tolerance in product pixels; ``parallax``:
    "handbook" (sphere) or "ellipsoid" (WGS84 radii); ``geolocation``: "bilinear" lon/lat
    (eq. 4a-4b) or "ecef" (default: bilinear with the handbook parallax, ecef with the
    ellipsoid one); ``method``: "primary" (primary grid + Newton) or "handbook" (MERSYN's
    facet search in the loop).
    """
    t_start = time.perf_counter()
    band_list = _check_options(elevation, dems, bands, tolerance, parallax, sampling, method)
    geo = geolocation_code(geolocation, parallax)
    if grid is None:
        crs = parse_crs(crs)
        if pixel_size is not None and not (math.isfinite(pixel_size) and pixel_size > 0):
            raise OptionsError(f"pixel size must be > 0, got {pixel_size}")
    prod = _open_product(product)
    stack = _open_dems(dems) if elevation == "dem" else None
    tp = TiePointGrid.from_product(prod)
    boundary = segment_boundary(tp.latitude, tp.longitude)
    if grid is None:
        res_m = float(getattr(getattr(prod, "resolution", None), "column_spacing_m", 260.0))
        grid = default_grid(boundary, res_m, crs, pixel_size=pixel_size)
    # MERSYN processes the points inside the segment boundary; the primary-grid path also tries
    # a margin where terrain seen obliquely can lie outside the zero-height boundary
    margin = _margin_px(tp, grid) if elevation != "none" and method == "primary" else 0
    inner = row_spans(boundary, grid)
    spans = row_spans(boundary, grid, margin=margin) if margin else inner
    in_boundary = inner.count
    if in_boundary == 0:
        raise OptionsError(f"the output extent {grid.bounds} misses the product footprint")
    hmode = {"none": predcorr.HEIGHT_NONE, "tiepoints": predcorr.HEIGHT_TIEPOINTS,
             "dem": predcorr.HEIGHT_GIVEN if stack is not None else predcorr.HEIGHT_TIEPOINTS}[
        elevation]
    try:
        return _run(prod, tp, grid, spans, stack, hmode, band_list, sampling, tolerance,
                    (parallax_code(parallax), geo), method, diagnostics, progress, t_start,
                    dict(elevation=elevation, parallax=parallax, sampling=sampling,
                         geolocation=("bilinear", "ecef")[geo],
                         tolerance=tolerance, method=method, margin_px=margin,
                         dems=[str(d) for d in dems], points_in_boundary=in_boundary))
    finally:
        if stack is not None:
            stack.close()


def _run(prod, tp, grid, spans, stack, hmode, band_list, sampling, tolerance, models, method,
         diagnostics, progress, t_start, options) -> OrthoResult:
    from .engine.resample import resample_bands

    nr, nc = grid.shape
    line = np.full((nr, nc), np.nan, np.float32)
    col = np.full((nr, nc), np.nan, np.float32)
    iters = np.full((nr, nc), -1, np.int8)
    diag: dict[str, np.ndarray] = {}
    if diagnostics:
        diag = {"elevation": np.full((nr, nc), np.nan, np.float32),
                "elevation_source": np.full((nr, nc), SOURCE_NONE, np.int8),
                "shift_east_m": np.full((nr, nc), np.nan, np.float32),
                "shift_north_m": np.full((nr, nc), np.nan, np.float32)}
    search: dict[str, int] = {}
    sources = np.zeros(len(stack.sources) + 1 if stack is not None else 1, np.int64)
    t_dem = t_lonlat = t_engine = t_resample = 0.0
    total = nr + len(band_list)
    for r0 in range(0, nr, _BLOCK_ROWS):
        r1 = min(r0 + _BLOCK_ROWS, nr)
        t0 = time.perf_counter()
        lon, lat = grid.lonlat(r0, r1)
        t_lonlat += time.perf_counter() - t0
        p0, p1 = spans.ptr[r0 - spans.row_start], spans.ptr[r1 - spans.row_start]
        ptr = spans.ptr[r0 - spans.row_start: r1 - spans.row_start + 1] - p0
        start, stop = spans.start[p0:p1], spans.stop[p0:p1]
        h = None
        src = None
        if hmode == predcorr.HEIGHT_GIVEN:
            t0 = time.perf_counter()
            mask = np.zeros(lon.shape, bool)
            _mark(mask, ptr, start, stop)
            h, src = _heights(stack, lon, lat, mask)
            t_dem += time.perf_counter() - t0
        t0 = time.perf_counter()
        res = predcorr.solve(tp, grid, lon, lat, h, hmode, (ptr, start, stop), row_start=r0,
                             tolerance=tolerance, model=models[0], geo=models[1],
                             method=method, diagnostics=diagnostics)
        t_engine += time.perf_counter() - t0
        line[r0:r1], col[r0:r1], iters[r0:r1] = res["line"], res["col"], res["iterations"]
        for k, v in res["search"].items():
            search[k] = search.get(k, 0) + v
        ok = res["iterations"] >= 0
        if src is not None:
            sources += np.bincount(src[ok].astype(np.int64) + 1, minlength=sources.size)
        else:
            sources[0] += int(ok.sum())
        if diagnostics:
            if "elevation" in res:
                diag["elevation"][r0:r1] = np.where(ok, res["elevation"], np.nan)
                diag["shift_east_m"][r0:r1] = np.where(ok, res["shift_east_m"], np.nan)
                diag["shift_north_m"][r0:r1] = np.where(ok, res["shift_north_m"], np.nan)
            code = (src if src is not None else np.full(ok.shape, SOURCE_TIEPOINTS
                    if hmode == predcorr.HEIGHT_TIEPOINTS else SOURCE_NONE, np.int8))
            diag["elevation_source"][r0:r1] = np.where(ok, code, SOURCE_NONE)
        if progress is not None:
            progress(r1, total)
    t_read = 0.0
    t0 = time.perf_counter()
    radiance = {}
    if sampling == "nearest":
        index = predcorr.nearest_pixel(line, col, tp.height, tp.width)
        t_resample += time.perf_counter() - t0
        for b in band_list:
            t1 = time.perf_counter()
            image = np.ascontiguousarray(prod.counts(b), dtype=np.uint16)
            t2 = time.perf_counter()
            t_read += t2 - t1
            radiance[b] = np.empty((nr, nc), np.float32)
            predcorr.gather(image, index, float(prod.scaling.radiance[b - 1]), radiance[b])
            t_resample += time.perf_counter() - t2
        t1 = time.perf_counter()
        image = np.ascontiguousarray(prod.flags, dtype=np.uint8)
        t_read += time.perf_counter() - t1
        t1 = time.perf_counter()
        flags = np.empty((nr, nc), np.float32)
        predcorr.gather(image, index, 1.0, flags)
        flags = flags.astype(np.uint8)
        t_resample += time.perf_counter() - t1
    else:
        images = [np.ascontiguousarray(prod.counts(b), dtype=np.uint16) for b in band_list]
        fl = np.ascontiguousarray(prod.flags, dtype=np.uint8)
        t_read = time.perf_counter() - t0
        t0 = time.perf_counter()
        out = resample_bands(images, line, col, sampling)
        flags = resample_bands([fl], line, col, "nearest")[0].astype(np.uint8)
        for b, o in zip(band_list, out, strict=True):
            o *= np.float32(prod.scaling.radiance[b - 1])
            radiance[b] = o
        t_resample += time.perf_counter() - t0
    if progress is not None:
        progress(total, total)
    valid = iters >= 0
    hist = predcorr.iteration_histogram(iters)
    if diagnostics:
        diag.update(line=line, col=col, iterations=iters)
        if hmode == predcorr.HEIGHT_NONE:
            diag["elevation"] = np.where(valid, np.float32(0), np.float32(np.nan))
            diag["shift_east_m"] = diag["elevation"].copy()
            diag["shift_north_m"] = diag["elevation"].copy()
    stats = {
        "product": str(getattr(prod, "path", "")),
        "output_lines": nr, "output_columns": nc,
        "crs": grid.crs.to_string(), "ul_x": grid.x0, "ul_y": grid.y0,
        "lr_x": grid.x0 + nc * grid.dx, "lr_y": grid.y0 - nr * grid.dy,
        "pixel_width": grid.dx, "pixel_height": grid.dy,
        "orthorectification": hmode != predcorr.HEIGHT_NONE,
        "facet_search": search,
        "iterations_histogram": [int(v) for v in hist],
        "processed_points": int(valid.sum()),
        "output_points": nr * nc,
        "elevation_sources": _source_counts(sources, stack, hmode),
        "seconds": {"lonlat": t_lonlat, "dem": t_dem, "prediction_correction": t_engine,
                    "read_bands": t_read, "resample": t_resample,
                    "engine": t_engine + t_resample,
                    "total": time.perf_counter() - t_start},
        "bands": band_list, "wavelengths": _wavelengths(prod, band_list), **options,
    }
    return OrthoResult(radiance, grid, valid, flags, stats, diag)


def _wavelengths(prod: Any, band_list: list[int]) -> dict[int, float]:
    try:
        wl = list(prod.wavelengths)
        return {b: float(wl[b - 1]) for b in band_list}
    except (AttributeError, IndexError, TypeError, ValueError):
        return {}


def _source_counts(sources: np.ndarray, stack: Any, hmode: int) -> dict[str, int]:
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

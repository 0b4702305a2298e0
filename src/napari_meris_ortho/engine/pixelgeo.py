"""Pixel geolocation: direct and inverse location models on a per-pixel lon/lat grid.

Products with a per-pixel, already terrain-corrected geolocation (AMORGOS ``MER_FRG_1P`` /
``MER_FSG_1P`` ``corr_longitude``/``corr_latitude``; fourth-reprocessing ``.SEN3``
``geo_coordinates.nc``) give the terrain point T of every pixel centre. Their direct model is
the bilinear interpolation of that grid between pixel centres (eq. 1 with DF = DJ = 1); no
parallax is applied, the producer already removed it. Its inverse follows the handbook's
prediction/correction idea (section 3.2): an exact inverse on a coarse *primary grid* of
output points (cell search: a warm-started Newton on the pixel cells, a brute-force nearest
node when that fails), interpolated as the prediction of every output point, then corrected
by Newton steps on the bilinear cell until a step is below the tolerance (bilinear inversion).
Outside the grid the edge cells are extended, so the model is continuous everywhere; points
whose antecedent leaves the product (-0.5 <= l < H-0.5, -0.5 <= p < W-0.5) are dropped.

Arrays in, arrays out: ``lon``/``lat`` grids (H, W) float64 degrees in the stored column order.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .inverse import wrap180
from .location import facet_of
from .predcorr import _columns, _predict, primary_nodes

#: subsampling (pixels) of the brute-force nearest-node search that seeds the cell search
SEED_STEP = 8
#: guesses further than this many product pixels outside the product are dropped at once
_FAR = 256.0
#: largest Newton step (pixels) of the correction
_MAX_STEP = 16.0
#: correction iterations of the pixel model (damped steps may need more than the tie points)
MAX_PIXEL_ITERATIONS = 20


@njit(cache=True)
def pixel_point(line: float, col: float, lon: np.ndarray, lat: np.ndarray):
    """Direct pixel model at fractional (line, col): (lon, lat, dlon/dl, dlon/dp, dlat/dl, dlat/dp).

    Longitudes are differenced on the branch of the cell's first corner (antimeridian safe);
    the result longitude is on that branch (not wrapped).
    """
    nl, nc = lon.shape
    i, u = facet_of(line, 1.0, nl)
    j, v = facet_of(col, 1.0, nc)
    x00 = lon[i, j]
    x01 = x00 + wrap180(lon[i, j + 1] - x00)
    x10 = x00 + wrap180(lon[i + 1, j] - x00)
    x11 = x00 + wrap180(lon[i + 1, j + 1] - x00)
    y00 = lat[i, j]
    y01 = lat[i, j + 1]
    y10 = lat[i + 1, j]
    y11 = lat[i + 1, j + 1]
    x = (1 - u) * ((1 - v) * x00 + v * x01) + u * ((1 - v) * x10 + v * x11)
    y = (1 - u) * ((1 - v) * y00 + v * y01) + u * ((1 - v) * y10 + v * y11)
    xl = (1 - v) * (x10 - x00) + v * (x11 - x01)
    xp = (1 - u) * (x01 - x00) + u * (x11 - x10)
    yl = (1 - v) * (y10 - y00) + v * (y11 - y01)
    yp = (1 - u) * (y01 - y00) + u * (y11 - y10)
    return x, y, xl, xp, yl, yp


@njit(cache=True)
def pixel_value(line: float, col: float, grid: np.ndarray) -> float:
    """Bilinear value of a per-pixel grid (altitude...) at fractional (line, col)."""
    nl, nc = grid.shape
    i, u = facet_of(line, 1.0, nl)
    j, v = facet_of(col, 1.0, nc)
    return ((1 - u) * ((1 - v) * grid[i, j] + v * grid[i, j + 1])
            + u * ((1 - v) * grid[i + 1, j] + v * grid[i + 1, j + 1]))


@njit(cache=True)
def correct(tlon: float, tlat: float, line: float, col: float, lon: np.ndarray,
            lat: np.ndarray, tol: float, max_iter: int):
    """Correction: Newton steps on the bilinear cells until a step is <= ``tol`` pixels.

    Returns (line, col, iterations, converged); NaN line/col on a degenerate cell.
    """
    it = 0
    while it < max_iter:
        it += 1
        x, y, xl, xp, yl, yp = pixel_point(line, col, lon, lat)
        rx = tlon - x
        if rx > 180.0 or rx < -180.0:
            rx = wrap180(rx)
        ry = tlat - y
        det = xl * yp - xp * yl
        if det == 0.0 or math.isnan(det):
            return math.nan, math.nan, it, False
        dl = (rx * yp - ry * xp) / det
        dp = (xl * ry - yl * rx) / det
        big = max(abs(dl), abs(dp))
        if big > _MAX_STEP:  # damped: folded (terrain-corrected) cells must not throw it far
            dl *= _MAX_STEP / big
            dp *= _MAX_STEP / big
        line += dl
        col += dp
        if abs(dl) <= tol and abs(dp) <= tol:
            return line, col, it, True
    return line, col, it, False


@njit(cache=True)
def nearest_node(tlon: float, tlat: float, lon: np.ndarray, lat: np.ndarray, step: int):
    """Brute-force cell search: the pixel of a ``step``-subsampled grid nearest to the point."""
    nl, nc = lon.shape
    c = math.cos(math.radians(tlat))
    best = math.inf
    bl = 0.0
    bp = 0.0
    for i in range(0, nl + step - 1, step):
        ii = min(i, nl - 1)
        for j in range(0, nc + step - 1, step):
            jj = min(j, nc - 1)
            dx = wrap180(lon[ii, jj] - tlon) * c
            dy = lat[ii, jj] - tlat
            d = dx * dx + dy * dy
            if d < best:
                best = d
                bl = ii
                bp = jj
    return bl, bp


@njit(cache=True)
def primary_grid_pixel(nlon, nlat, lon, lat, seed_step):
    """Exact inverse at the primary-grid nodes (2-D lon/lat): warm-started Newton, else seeded
    from the nearest subsampled pixel. Returns (line, col, counts[warm, seeded, failed])."""
    nr, nc = nlon.shape
    cl = np.full((nr, nc), np.nan)
    cp = np.full((nr, nc), np.nan)
    counts = np.zeros(3, np.int64)
    last_l = math.nan
    last_p = math.nan
    for r in range(nr):
        for c in range(nc):
            tlon = nlon[r, c]
            tlat = nlat[r, c]
            if math.isnan(tlon) or math.isnan(tlat):
                continue
            ok = False
            if not math.isnan(last_l):
                l2, p2, it, ok = correct(tlon, tlat, last_l, last_p, lon, lat, 1e-6, 30)
                if ok:
                    counts[0] += 1
            if not ok:
                g_l, g_p = nearest_node(tlon, tlat, lon, lat, seed_step)
                l2, p2, it, ok = correct(tlon, tlat, g_l, g_p, lon, lat, 1e-6, 30)
                counts[1 if ok else 2] += 1
            if ok:
                cl[r, c] = l2
                cp[r, c] = p2
                last_l = l2
                last_p = p2
    return cl, cp, counts


@njit(cache=True, parallel=True)
def find_pixel_antecedents(tlon_a, tlat_a, ptr, start, stop, cl, cp, step, lon, lat, alt,
                           tol, max_iter, diagnostics):
    """Antecedents of output points on the pixel model: rows in parallel over the column spans
    (CSR ``ptr``/``start``/``stop``). Returns line, col (float32, NaN dropped), iterations (int8,
    -1 dropped) and with ``diagnostics`` the product altitude at the antecedent (else 1x1).
    A point whose correction does not converge is dropped: a ground point hidden by the relief
    has no antecedent in a terrain-corrected geolocation (it lies in no pixel's footprint)."""
    nr, nc = tlon_a.shape
    nl, npx = lon.shape
    out_l = np.full((nr, nc), np.nan, np.float32)
    out_p = np.full((nr, nc), np.nan, np.float32)
    iters = np.full((nr, nc), -1, np.int8)
    h_used = np.full((nr, nc) if diagnostics else (1, 1), np.nan, np.float32)
    no_rates = np.zeros((3, 1, 1))  # the pixel geolocation has no height rates: h = 0
    for i in prange(nr):
        for j in _columns(ptr, start, stop, i):
            tlon = tlon_a[i, j]
            tlat = tlat_a[i, j]
            if math.isnan(tlon) or math.isnan(tlat):
                continue
            gl, gp = _predict(cl, cp, no_rates, step, i, j, 0.0)
            if math.isnan(gl) or gl < -_FAR or gl > nl + _FAR or gp < -_FAR or gp > npx + _FAR:
                continue
            l2, p2, it, ok = correct(tlon, tlat, gl, gp, lon, lat, tol, max_iter)
            if not ok or not (-0.5 <= l2 < nl - 0.5 and -0.5 <= p2 < npx - 0.5):
                continue
            out_l[i, j] = l2
            out_p[i, j] = p2
            iters[i, j] = it
            if diagnostics:
                h_used[i, j] = pixel_value(l2, p2, alt)
    return out_l, out_p, iters, h_used


def direct_pixel_location(lon: np.ndarray, lat: np.ndarray, line: np.ndarray,
                          col: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Direct pixel model at fractional (line, col) arrays: (lon wrapped to [-180, 180), lat)."""
    lon_g, lat_g = _grids(lon, lat)
    line = np.asarray(line, np.float64)
    col = np.asarray(col, np.float64)
    out = _direct_many(line.ravel(), col.ravel(), lon_g, lat_g)
    return (((out[0] + 180.0) % 360.0 - 180.0).reshape(line.shape), out[1].reshape(line.shape))


@njit(cache=True)
def _direct_many(line, col, lon, lat):
    out = np.empty((2, line.size))
    for k in range(line.size):
        r = pixel_point(line[k], col[k], lon, lat)
        out[0, k] = r[0]
        out[1, k] = r[1]
    return out


def _grids(lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lon = np.ascontiguousarray(lon, dtype=np.float64)
    lat = np.ascontiguousarray(lat, dtype=np.float64)
    if lon.shape != lat.shape or lon.ndim != 2 or min(lon.shape) < 2:
        raise ValueError(f"pixel geolocation grids must be 2-D of >= 2x2 and alike, got "
                         f"{lon.shape} and {lat.shape}")
    return lon, lat


def solve_pixel(lon_grid: np.ndarray, lat_grid: np.ndarray, grid, lon: np.ndarray,
                lat: np.ndarray, spans: tuple[np.ndarray, np.ndarray, np.ndarray], *,
                row_start: int = 0, tolerance: float = 0.01,
                max_iter: int = MAX_PIXEL_ITERATIONS,
                step: int = 16, altitude: np.ndarray | None = None,
                diagnostics: bool = False) -> dict:
    """Antecedents of output rows [row_start, row_start + lon.shape[0]) of ``grid`` on the pixel
    model (the per-pixel ``lon_grid``/``lat_grid`` of the product), like ``predcorr.solve``.

    Returns "line", "col", "iterations", "search" (primary-grid counts) and, with
    ``diagnostics`` and an ``altitude`` grid, "elevation" (product altitude at the antecedent).
    """
    lon_g, lat_g = _grids(lon_grid, lat_grid)
    lon = np.ascontiguousarray(lon, dtype=np.float64)
    lat = np.ascontiguousarray(lat, dtype=np.float64)
    ptr, start, stop = (np.ascontiguousarray(a, dtype=np.int64) for a in spans)
    nlon, nlat = primary_nodes(grid, row_start, lon.shape, step)
    cl, cp, counts = primary_grid_pixel(nlon, nlat, lon_g, lat_g, SEED_STEP)
    with_alt = diagnostics and altitude is not None
    alt = (np.ascontiguousarray(altitude, dtype=np.float64) if with_alt
           else np.zeros((2, 2)))
    line, col, iters, h_used = find_pixel_antecedents(
        lon, lat, ptr, start, stop, cl, cp, float(step), lon_g, lat_g, alt, float(tolerance),
        int(max_iter), with_alt)
    out = {"line": line, "col": col, "iterations": iters,
           "search": {"primary warm": int(counts[0]), "primary seeded": int(counts[1]),
                      "primary not found": int(counts[2])}}
    if with_alt:  # the product's altitude; no parallax shift is applied by this model
        out["elevation"] = h_used
        out["shift_east_m"] = np.full(h_used.shape, np.nan, np.float32)
        out["shift_north_m"] = out["shift_east_m"]
    return out

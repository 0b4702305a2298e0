"""Pixel geolocation with DEMs: the per-pixel grid moved back to the ellipsoid, then the DEM mode.

A per-pixel terrain point T_ij (FRG/FSG ``corr_longitude``/``corr_latitude``, ``.SEN3``
``geo_coordinates``) is the ellipsoid point E_ij of the pixel plus the parallax of its own
altitude h_ij (eq. 6a, 2c'). Between pixel centres the ground height is not in the product, so
the bilinear T (``pixelgeo``) misplaces steep ground across track (fr-steep: 0.077 px RMS).
Here each T_ij is moved back to E_ij with the tie points' viewing direction at the pixel
(``ellipsoid_grid``: eq. 6a-6b inverted by fixed point on the latitude), and an output point
of height h (the DEM at the output point) is located as the DEM mode locates it on the tie
points (section 3.2, 3.3): f(l, p, h) = E(l, p) + parallax(h, look(l, p)) with E bilinear
between pixel centres (DF = DJ = 1) and the look vector bilinear between tie points. The
prediction is the exact zero-height inverse on E at the primary-grid nodes (``pixelgeo``'s
cell search; E is smooth, without the folds of T), the correction Newton steps on f. Where the
DEM has no height, the point falls back to the product's own geolocation (``pixelgeo``'s cell
search on T from the predicted line, hidden ground reported ``OCCLUDED``), as the DEM mode falls
back to the tie-point heights.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .location import facet_of, parallax_factors
from .pixelgeo import (
    _FAR,
    OCCLUDED,
    SEED_STEP,
    _grids,
    _newton_step,
    pixel_antecedent,
    pixel_point,
    pixel_value,
    primary_grid_pixel,
)
from .predcorr import PRIMARY_STEP, _columns, _node_row, _predict, primary_nodes
from .threads import split_range

#: fixed-point passes of the parallax inversion (the latitude of the radii moves < 1e-9 deg
#: after the second one)
_PARALLAX_PASSES = 3
#: primary nodes further than this (pixels) outside the product are left out of the
#: predictions: the zero-height antecedent of terrain seen at the product edge lies up to one
#: parallax shift (30 FR pixels) outside, and E, smooth, extends linearly that far
_NODE_OUT = 64.0
#: largest Newton step (pixels) of the correction on E: the first step carries the whole
#: parallax (9 km at 41 deg: 30 FR pixels); E has no folds to throw it far
_MAX_STEP = 64.0


@njit(cache=True, inline="always")
def look_at(line: float, col: float, coef: np.ndarray, df: float, dj: float):
    """Tie-point look vector (tan vz sin va, tan vz cos va) bilinear at (line, col) and its
    derivatives per pixel: (e, n, de/dl, de/dp, dn/dl, dn/dp) (``tiepoints``, eq. 5a-5b)."""
    f, u = facet_of(line, df, coef.shape[0] + 1)
    j, v = facet_of(col, dj, coef.shape[1] + 1)
    c = coef[f, j]
    e = c[8] + c[9] * u + c[10] * v + c[11] * u * v
    n = c[12] + c[13] * u + c[14] * v + c[15] * u * v
    return (e, n, (c[9] + c[11] * v) / df, (c[10] + c[11] * u) / dj,
            (c[13] + c[15] * v) / df, (c[14] + c[15] * u) / dj)


@njit(cache=True)
def look_vectors(line: np.ndarray, col: np.ndarray, coef: np.ndarray, df: float, dj: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Tie-point look vectors (tan vz sin va, tan vz cos va) at the antecedents (``line``,
    ``col``, flat float64; ``look_at``): the direction and slope of the lines of sight."""
    e = np.empty(line.size)
    n = np.empty(line.size)
    for k in range(line.size):
        e[k], n[k], _, _, _, _ = look_at(line[k], col[k], coef, df, dj)
    return e, n


@njit(cache=True, nogil=True)
def _ellipsoid_rows(lo, hi, lon, lat, alt, coef, df, dj, model, elon, elat):
    """Rows [lo, hi) of ``ellipsoid_grid`` into its outputs."""
    nc = lon.shape[1]
    for i in range(lo, hi):
        for j in range(nc):
            h = max(alt[i, j], 0.0)  # parallax_height: no parallax below 0 (sea)
            if math.isnan(h):
                h = 0.0
            e, n, _, _, _, _ = look_at(float(i), float(j), coef, df, dj)
            y = lat[i, j]
            for _ in range(_PARALLAX_PASSES):  # the radii are taken at E's latitude
                ke, kn = parallax_factors(y, h, model)
                y = lat[i, j] - kn * h * n
            ke, kn = parallax_factors(y, h, model)
            elon[i, j] = lon[i, j] - ke * h * e
            elat[i, j] = y


def ellipsoid_grid(lon: np.ndarray, lat: np.ndarray, altitude: np.ndarray, coef: np.ndarray,
                   df: float, dj: float, model: int) -> tuple[np.ndarray, np.ndarray]:
    """Ellipsoid point E_ij of every pixel: its terrain point T_ij minus the parallax of its
    altitude (eq. 6a, 2c' inverted; radii at E's latitude by fixed point), with the tie-point
    look vector at the pixel (``coef``, DF, DJ: ``TiePointGrid.kernel_args``) and the parallax
    model's radii (``model``: ``Parallax.code``). Returns (lon, lat) grids like ``lon``."""
    lon_g, lat_g = _grids(lon, lat)
    alt = np.ascontiguousarray(altitude, dtype=np.float64)
    if alt.shape != lon_g.shape:
        raise ValueError(f"altitude grid {alt.shape} differs from the geolocation "
                         f"{lon_g.shape}")
    elon = np.empty(lon_g.shape)
    elat = np.empty(lon_g.shape)
    args = (lon_g, lat_g, alt, coef, float(df), float(dj), np.int64(model), elon, elat)
    split_range(lambda lo, hi: _ellipsoid_rows(lo, hi, *args), lon_g.shape[0])
    return elon, elat


@njit(cache=True, inline="always")
def terrain_point(line, col, h, elon, elat, coef, df, dj, model):
    """f(l, p, h) on the ellipsoid grid: (lon, lat, dlon/dl, dlon/dp, dlat/dl, dlat/dp, e, n)
    — E bilinear between pixel centres plus the parallax of h (eq. 6a, 2c') with the look
    vector (e, n) of the tie points; cos(lat) of the radii held constant in the Jacobian."""
    x, y, xl, xp, yl, yp = pixel_point(line, col, elon, elat)
    e, n, el, ep, nl, np_ = look_at(line, col, coef, df, dj)
    ke, kn = parallax_factors(y, h, model)
    return (x + ke * h * e, y + kn * h * n, xl + ke * h * el, xp + ke * h * ep,
            yl + kn * h * nl, yp + kn * h * np_, e, n)


@njit(cache=True)
def correct_dem(tlon, tlat, line, col, h, elon, elat, coef, df, dj, model, tol, max_iter):
    """Newton steps on f(l, p, h) until a step is <= ``tol`` pixels: (line, col, iterations,
    converged)."""
    it = 0
    while it < max_iter:
        it += 1
        r = terrain_point(line, col, h, elon, elat, coef, df, dj, model)
        dl, dp, ok = _newton_step(tlon, tlat, (r[0], r[1], r[2], r[3], r[4], r[5]))
        if not ok:
            return math.nan, math.nan, it, False
        big = max(abs(dl), abs(dp))
        if big > _MAX_STEP:
            dl *= _MAX_STEP / big
            dp *= _MAX_STEP / big
        line += dl
        col += dp
        if abs(dl) <= tol and abs(dp) <= tol:
            return line, col, it, True
    return line, col, it, False


@njit(cache=True, nogil=True)
def _dem_rows(lo, hi, tlon_a, tlat_a, height, ptr, start, stop, cl, cp, step, lon, lat, elon,
              elat, alt, coef, df, dj, model, tol, max_iter, diagnostics, out_l, out_p, iters,
              h_used, sh_e, sh_n):
    """Rows [lo, hi) of ``find_dem_antecedents`` into its (pre-filled) outputs."""
    nl, npx = lon.shape
    no_rates = np.zeros((3, 1, 1))  # the prediction is the zero-height inverse on E
    row = np.empty((2, cl.shape[1]))
    for i in range(lo, hi):
        if ptr[i + 1] == ptr[i]:  # no span in this row: no node row to interpolate
            continue
        _node_row(cl, cp, no_rates, step, i, False, row)
        for j in _columns(ptr, start, stop, i):
            tlon = tlon_a[i, j]
            tlat = tlat_a[i, j]
            if math.isnan(tlon) or math.isnan(tlat):
                continue
            gl, gp = _predict(row, cl, cp, step, i, j, 0.0)
            if math.isnan(gl) or gl < -_FAR or gl > nl + _FAR or gp < -_FAR or gp > npx + _FAR:
                continue
            h = float(height[i, j])
            if math.isnan(h):  # no DEM height: the product's own terrain points
                l2, p2, it = pixel_antecedent(tlon, tlat, gl, gp, step, lon, lat, tol,
                                              max_iter)
                if it == OCCLUDED:
                    iters[i, j] = OCCLUDED
                    continue
                if it < 0:
                    continue
                h = pixel_value(l2, p2, alt)
                e = n = math.nan
            else:
                l2, p2, it, ok = correct_dem(tlon, tlat, gl, gp, h, elon, elat, coef, df, dj,
                                             model, tol, max_iter)
                if not ok:
                    continue
                e, n, _, _, _, _ = look_at(l2, p2, coef, df, dj)
            if not (-0.5 <= l2 < nl - 0.5 and -0.5 <= p2 < npx - 0.5):
                continue
            out_l[i, j] = l2
            out_p[i, j] = p2
            iters[i, j] = min(it, max_iter)
            if diagnostics:
                h_used[i, j] = h
                sh_e[i, j] = h * e
                sh_n[i, j] = h * n


def find_dem_antecedents(tlon_a, tlat_a, height, ptr, start, stop, cl, cp, step, lon, lat,
                         elon, elat, alt, coef, df, dj, model, tol, max_iter, diagnostics):
    """Antecedents of output points with heights ``height`` (NaN: the product's geolocation):
    rows split over threads, over the CSR column spans, predicted from the primary grid on E,
    then corrected by ``correct_dem``. Returns line, col (float32, NaN dropped), iterations
    (int8: -1 dropped, ``OCCLUDED`` hidden ground of the fallback) and with ``diagnostics`` the
    height used and its parallax shift east/north (m), else 1x1 arrays."""
    nr, nc = tlon_a.shape
    out_l = np.full((nr, nc), np.nan, np.float32)
    out_p = np.full((nr, nc), np.nan, np.float32)
    iters = np.full((nr, nc), -1, np.int8)
    dshape = (nr, nc) if diagnostics else (1, 1)
    h_used = np.full(dshape, np.nan, np.float32)
    sh_e = np.full(dshape, np.nan, np.float32)
    sh_n = np.full(dshape, np.nan, np.float32)
    args = (tlon_a, tlat_a, height, ptr, start, stop, cl, cp, step, lon, lat, elon, elat, alt,
            coef, df, dj, model, tol, max_iter, diagnostics, out_l, out_p, iters, h_used, sh_e,
            sh_n)
    split_range(lambda lo, hi: _dem_rows(lo, hi, *args), nr)
    return out_l, out_p, iters, h_used, sh_e, sh_n


def solve_pixel_dem(lon_grid: np.ndarray, lat_grid: np.ndarray, ellipsoid: tuple[np.ndarray,
                    np.ndarray], altitude: np.ndarray, tp, model: int, grid, lon: np.ndarray,
                    lat: np.ndarray, height: np.ndarray,
                    spans: tuple[np.ndarray, np.ndarray, np.ndarray], *, row_start: int = 0,
                    tolerance: float = 0.01, max_iter: int = 20, step: int = PRIMARY_STEP,
                    diagnostics: bool = False) -> dict:
    """Antecedents of output rows [row_start, row_start + lon.shape[0]) of ``grid`` on the
    ellipsoid grid ``ellipsoid`` (``ellipsoid_grid`` of the per-pixel ``lon_grid``/``lat_grid``
    and ``altitude``) with the output points' ``height`` (the DEMs; NaN: the product's own
    geolocation), like ``predcorr.solve``; ``tp``: the product's ``TiePointGrid`` (look
    vectors), ``model``: the parallax code. Returns "line", "col", "iterations", "search" and
    with ``diagnostics`` "elevation", "shift_east_m", "shift_north_m"."""
    lon_g, lat_g = _grids(lon_grid, lat_grid)
    elon, elat = _grids(*ellipsoid)
    _, _, coef, df, dj = tp.kernel_args()
    lon = np.ascontiguousarray(lon, dtype=np.float64)
    lat = np.ascontiguousarray(lat, dtype=np.float64)
    h = np.ascontiguousarray(height, dtype=np.float32)
    if h.shape != lon.shape:
        raise ValueError("per-point heights of the output points' shape are needed")
    alt = np.ascontiguousarray(altitude, dtype=np.float64)
    ptr, start, stop = (np.ascontiguousarray(a, dtype=np.int64) for a in spans)
    nlon, nlat = primary_nodes(grid, row_start, lon.shape, step, spans=(ptr, start, stop))
    cl, cp, counts = primary_grid_pixel(nlon, nlat, elon, elat, SEED_STEP, _NODE_OUT)
    line, col, iters, h_used, sh_e, sh_n = find_dem_antecedents(
        lon, lat, h, ptr, start, stop, cl, cp, float(step), lon_g, lat_g, elon, elat, alt,
        coef, float(df), float(dj), np.int64(model), float(tolerance), np.int64(max_iter),
        bool(diagnostics))
    out = {"line": line, "col": col, "iterations": iters,
           "search": {"primary warm": int(counts[0]), "primary seeded": int(counts[1]),
                      "primary not found": int(counts[2]),
                      "primary outside": int(counts[3]),
                      "occluded": int(np.count_nonzero(iters == OCCLUDED))}}
    if diagnostics:
        out.update(elevation=h_used, shift_east_m=sh_e, shift_north_m=sh_n)
    return out

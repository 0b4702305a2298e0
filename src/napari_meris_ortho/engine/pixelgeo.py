"""Pixel geolocation: direct and inverse location models on a per-pixel lon/lat grid.

Products with a per-pixel, already terrain-corrected geolocation (AMORGOS ``MER_FRG_1P`` /
``MER_FSG_1P`` ``corr_longitude``/``corr_latitude``; fourth-reprocessing ``.SEN3``
``geo_coordinates.nc``) give the terrain point T of every pixel centre. Their direct model is
the bilinear interpolation of that grid between pixel centres (eq. 1 with DF = DJ = 1); no
parallax is applied, the producer already removed it. Its inverse follows the handbook's
prediction/correction idea (section 3.2): an exact inverse on a coarse *primary grid* of
output points, interpolated as the prediction of every output point, then the cell that holds
the point (``cell_search``) inverted exactly (Newton on the bilinear cell). Relief moves a
terrain point along its product line (a push-broom frame: its lines of sight lie in one plane),
and along a line the first intersections follow the sweep of the line of sight in order:
hidden ground makes a jump, never a fold. So the cell is bracketed along the predicted line
and its neighbours (doubling steps from the predicted column, then bisection; only the primary
nodes some output point reads are searched). A cell spanning a jump (``seen_antecedent``)
holds ground no pixel sees: it is reported (iterations ``OCCLUDED``), not mapped. The edge cells
are extended by the outer half pixel; points whose antecedent leaves the product (-0.5 <= l <
H-0.5, -0.5 <= p < W-0.5) are dropped.

Arrays in, arrays out: ``lon``/``lat`` grids (H, W) float64 degrees in the stored column order.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .inverse import wrap180
from .location import facet_of
from .predcorr import PRIMARY_STEP, _columns, _node_row, _predict, primary_nodes

#: subsampling (pixels) of the brute-force nearest-node search that seeds the cell search
SEED_STEP = 8
#: guesses further than this many product pixels outside the product are dropped at once
_FAR = 256.0
#: largest Newton step (pixels) of the correction
_MAX_STEP = 16.0
#: correction iterations of the pixel model (damped steps may need more than the tie points)
MAX_PIXEL_ITERATIONS = 20
#: iterations code of an output point hidden from the sensor by the relief (no antecedent)
OCCLUDED = -2
#: tolerance (cell fraction) of the containment test of the cell search
_EPS = 1e-7
#: product lines searched either side of the predicted one (the parallax moves along columns)
_LINE_REACH = 2
#: cells tried either side of the bracketing column (neighbour lines bracket a column apart)
_COLUMN_REACH = 3
#: states of a primary node's search
_FOUND, _OUTSIDE, _FAILED = 0, 1, 2
#: primary nodes further than this (pixels) outside the product are left out of the predictions
_NODE_OUT = 2.0
#: how far (in steps of the neighbour cell) ground seen from one side of a jump cell may reach
#: into it: 1 is the exact split for equal slopes; seen slopes are often steeper (fr-steep: with
#: 2, 88 points of seen ground are called hidden, with 3, 14; 981 and 296 points reported hidden,
#: 91 % and 95 % of them truly hidden)
_SIDE_REACH = 3.0


@njit(cache=True, inline="always")
def pixel_point(line: float, col: float, lon: np.ndarray, lat: np.ndarray):
    """Direct pixel model at fractional (line, col): (lon, lat, dlon/dl, dlon/dp, dlat/dl, dlat/dp).

    Longitudes are differenced on the branch of the cell's first corner (antimeridian safe);
    the result longitude is on that branch (not wrapped).
    """
    nl, nc = lon.shape
    i, u = facet_of(line, 1.0, nl)
    j, v = facet_of(col, 1.0, nc)
    return cell_point(i, j, u, v, lon, lat)


@njit(cache=True, inline="always")
def cell_point(i: int, j: int, u: float, v: float, lon: np.ndarray, lat: np.ndarray):
    """Bilinear model of the cell between pixel centres (i, j) and (i + 1, j + 1) at offsets
    (u, v), extended linearly outside [0, 1]: (lon, lat, dlon/du, dlon/dv, dlat/du, dlat/dv)."""
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


@njit(cache=True, inline="always")
def _newton_step(tlon: float, tlat: float, point: tuple) -> tuple[float, float, bool]:
    """One Newton step of the bilinear model towards (tlon, tlat) from ``point`` = (x, y, xl,
    xp, yl, yp), a position and its partial derivatives along the two pixel axes: (d1, d2, True), or
    (NaN, NaN, False) on a degenerate cell (zero or NaN Jacobian)."""
    x, y, xl, xp, yl, yp = point
    rx = tlon - x
    if rx > 180.0 or rx < -180.0:
        rx = wrap180(rx)
    ry = tlat - y
    det = xl * yp - xp * yl
    if det == 0.0 or math.isnan(det):
        return math.nan, math.nan, False
    return (rx * yp - ry * xp) / det, (xl * ry - yl * rx) / det, True


@njit(cache=True)
def correct(tlon: float, tlat: float, line: float, col: float, lon: np.ndarray,
            lat: np.ndarray, tol: float, max_iter: int):
    """Correction: Newton steps on the bilinear cells until a step is <= ``tol`` pixels.

    Returns (line, col, iterations, converged); NaN line/col on a degenerate cell.
    """
    it = 0
    while it < max_iter:
        it += 1
        dl, dp, ok = _newton_step(tlon, tlat, pixel_point(line, col, lon, lat))
        if not ok:
            return math.nan, math.nan, it, False
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
def cell_solve(tlon: float, tlat: float, i: int, j: int, lon: np.ndarray, lat: np.ndarray,
               tol: float, max_iter: int):
    """Exact inverse of the bilinear cell (i, j) extended linearly: Newton from its centre
    until a step is <= ``tol``. Returns (u, v, iterations, converged)."""
    u = 0.5
    v = 0.5
    it = 0
    while it < max_iter:
        it += 1
        du, dv, ok = _newton_step(tlon, tlat, cell_point(i, j, u, v, lon, lat))
        if not ok:
            return math.nan, math.nan, it, False
        u += du
        v += dv
        if abs(du) <= tol and abs(dv) <= tol:
            return u, v, it, True
        if abs(u) > 1e3 or abs(v) > 1e3:
            break
    return u, v, it, False


@njit(cache=True)
def _in_box(tlon: float, tlat: float, i: int, j: int, lo_u: float, hi_u: float, lo_v: float,
            hi_v: float, lon: np.ndarray, lat: np.ndarray) -> bool:
    """The point lies in the lon/lat bounding box of the cell (i, j) over u in [lo_u, hi_u],
    v in [lo_v, hi_v] (a bilinear patch lies in the hull of its corners)."""
    x00 = lon[i, j]
    dx = wrap180(tlon - x00)
    xlo = ylo = math.inf
    xhi = yhi = -math.inf
    for u in (lo_u, hi_u):
        for v in (lo_v, hi_v):
            x, y, _, _, _, _ = cell_point(i, j, u, v, lon, lat)
            xlo = min(xlo, x - x00)
            xhi = max(xhi, x - x00)
            ylo = min(ylo, y)
            yhi = max(yhi, y)
    return xlo - 1e-9 <= dx <= xhi + 1e-9 and ylo - 1e-9 <= tlat <= yhi + 1e-9


@njit(cache=True, inline="always")
def _valid_column(i: int, j: int, lo: int, hi: int, lon: np.ndarray, lat: np.ndarray) -> int:
    """The column of line ``i`` nearest to ``j`` within [lo, hi] whose terrain point is given
    (a no-data pixel of the geolocation is NaN), -1 when none is."""
    for k in range(2 * (hi - lo) + 1):
        m = j + ((k + 1) // 2 if k % 2 else -(k // 2))  # j, j + 1, j - 1, j + 2...
        if lo <= m <= hi and not (math.isnan(lon[i, m]) or math.isnan(lat[i, m])):
            return m
    return -1


@njit(cache=True, inline="always")
def _along(tlon: float, tlat: float, i: int, m: int, c: float, dx: float, dy: float,
           lon: np.ndarray, lat: np.ndarray) -> float:
    """Where terrain point (i, m) lies from the point along the line's direction (dx, dy)
    (longitudes scaled by ``c``): <= 0 before it, > 0 past it."""
    return wrap180(lon[i, m] - tlon) * c * dx + (lat[i, m] - tlat) * dy


@njit(cache=True)
def _bracket(tlon: float, tlat: float, i: int, lon: np.ndarray, lat: np.ndarray,
             hint: float = math.nan) -> int:
    """Column j of product line ``i`` whose terrain points j, j + 1 bracket the point along the
    line (bisection: terrain points follow the line of sight's sweep in order, the first
    intersection moves away from the sensor; hidden ground makes jumps, never folds), clamped
    to the first and last cells. No-data pixels (NaN) are passed over: each probe takes the
    nearest given pixel between the bounds, so they cost only the cells touching them. With a
    ``hint`` (the predicted column) the bounds are first closed in from it by doubling steps:
    a few probes near the hint, not a dozen across the line; the same column in order."""
    nc = lon.shape[1]
    lo = _valid_column(i, 0, 0, nc - 1, lon, lat)
    if lo < 0:
        return 0
    hi = _valid_column(i, nc - 1, lo, nc - 1, lon, lat)
    c = math.cos(math.radians(tlat))
    dx = wrap180(lon[i, hi] - lon[i, lo]) * c
    dy = lat[i, hi] - lat[i, lo]
    if _along(tlon, tlat, i, lo, c, dx, dy, lon, lat) >= 0.0:
        return 0 if lo == 0 else lo - 1
    if _along(tlon, tlat, i, hi, c, dx, dy, lon, lat) <= 0.0:
        return min(hi, nc - 2)
    # from here on: along(lo) <= 0 < along(hi)
    if hi - lo > 2 and not math.isnan(hint):
        m = _valid_column(i, min(max(int(hint), lo + 1), hi - 1), lo + 1, hi - 1, lon, lat)
        if m >= 0:
            past = _along(tlon, tlat, i, m, c, dx, dy, lon, lat) > 0.0
            if past:
                hi = m
            else:
                lo = m
            step = 1
            while hi - lo > 1:
                m = hi - step if past else lo + step
                if m <= lo or m >= hi:
                    break
                # the nearest given column on the far side of m (still between the bounds)
                m = (_valid_column(i, m, lo + 1, m, lon, lat) if past
                     else _valid_column(i, m, m, hi - 1, lon, lat))
                if m < 0:
                    break
                if (_along(tlon, tlat, i, m, c, dx, dy, lon, lat) > 0.0) != past:
                    if past:
                        lo = m
                    else:
                        hi = m
                    break
                if past:
                    hi = m
                else:
                    lo = m
                step *= 2
    while hi - lo > 1:
        mid = _valid_column(i, (lo + hi) // 2, lo + 1, hi - 1, lon, lat)
        if mid < 0:  # only no data between the bounds: the point is in one of those cells
            break
        if _along(tlon, tlat, i, mid, c, dx, dy, lon, lat) <= 0.0:
            lo = mid
        else:
            hi = mid
    return lo


@njit(cache=True)
def cell_search(tlon: float, tlat: float, gl: float, lon: np.ndarray, lat: np.ndarray,
                line_reach: int = _LINE_REACH, gp: float = math.nan):
    """The cell holding the point: on the product lines within ``line_reach`` of the predicted
    line ``gl`` (outward), the cells around the column that ``_bracket`` finds from the
    predicted column ``gp`` (NaN: none; relief moves a terrain point along its product line,
    not across lines). The edge cells are extended by the outer half pixel. Returns (i, j, u,
    v, iterations), i = -1 when no cell holds it."""
    nl, nc = lon.shape
    ic = min(max(int(math.floor(gl)), 0), nl - 2)
    for m in range(2 * line_reach + 1):
        i = ic + ((m + 1) // 2 if m % 2 else -(m // 2))  # ic, ic + 1, ic - 1, ic + 2...
        if i < 0 or i > nl - 2:
            continue
        lo_u = -0.5 if i == 0 else 0.0
        hi_u = 1.5 if i == nl - 2 else 1.0
        jb = _bracket(tlon, tlat, i, lon, lat, gp)
        for k in range(2 * _COLUMN_REACH + 1):
            j = jb + ((k + 1) // 2 if k % 2 else -(k // 2))
            if j < 0 or j > nc - 2:
                continue
            lo_v = -0.5 if j == 0 else 0.0
            hi_v = 1.5 if j == nc - 2 else 1.0
            if not _in_box(tlon, tlat, i, j, lo_u, hi_u, lo_v, hi_v, lon, lat):
                continue
            u, v, it, ok = cell_solve(tlon, tlat, i, j, lon, lat, 1e-9, 30)
            if (ok and lo_u - _EPS <= u <= hi_u + _EPS and lo_v - _EPS <= v <= hi_v + _EPS):
                return i, j, u, v, it
    return -1, -1, math.nan, math.nan, 0


@njit(cache=True, inline="always")
def _column_step(i: int, j: int, lon: np.ndarray, lat: np.ndarray) -> float:
    """Ground length (degrees of latitude) of the cell's column step, mean of its two lines."""
    c = math.cos(math.radians(lat[i, j]))
    a = math.hypot(wrap180(lon[i, j + 1] - lon[i, j]) * c, lat[i, j + 1] - lat[i, j])
    b = math.hypot(wrap180(lon[i + 1, j + 1] - lon[i + 1, j]) * c,
                   lat[i + 1, j + 1] - lat[i + 1, j])
    return 0.5 * (a + b)


@njit(cache=True)
def seen_antecedent(tlon: float, tlat: float, i: int, j: int, u: float, v: float,
                    lon: np.ndarray, lat: np.ndarray):
    """Antecedent of a point found in cell (i, j) at (u, v), or hidden by the relief.

    Terrain points of consecutive pixels of a line are contiguous on the ground except where
    the line of sight passes over a crest: there the cell spans ground no pixel sees, and its
    column step is longer than the steps of both neighbour cells together. In such a *jump
    cell* a point is seen from the near side (the cell before, extended) when that puts it
    within ``_SIDE_REACH`` of that cell's steps past the near pixel, or from the far side (the
    cell after, extended back) within as many of its steps before the far pixel; else it is
    hidden. A seen point keeps the jump cell's position. Returns (line, col, visible)."""
    nc = lon.shape[1]
    if j < 1 or j > nc - 3:
        return i + u, j + v, True
    step = _column_step(i, j, lon, lat)
    before = _column_step(i, j - 1, lon, lat)
    after = _column_step(i, j + 1, lon, lat)
    if not step > before + after:  # an ordinary cell: contiguous ground
        return i + u, j + v, True
    un, vn, _, near = cell_solve(tlon, tlat, i, j - 1, lon, lat, 1e-9, 30)
    uf, vf, _, far = cell_solve(tlon, tlat, i, j + 1, lon, lat, 1e-9, 30)
    near = near and vn - 1.0 <= _SIDE_REACH  # column j - 1 + vn: at most j + _SIDE_REACH
    far = far and -vf <= _SIDE_REACH  # column j + 1 + vf: at least j + 1 - _SIDE_REACH
    if near or far:
        return i + u, j + v, True
    return math.nan, math.nan, False


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
def primary_grid_pixel(nlon, nlat, lon, lat, seed_step, node_out=_NODE_OUT):
    """Exact inverse at the primary-grid nodes (2-D lon/lat): cell search from the previous
    node's antecedent, else from the nearest subsampled pixel (hidden ground keeps the
    antecedent of its jump cell: a prediction). Returns (line, col, counts[warm, seeded,
    failed, outside]): nodes whose antecedent lies more than ``node_out`` pixels outside the
    product are left out (the extended edge cells of T are no prediction there)."""
    nr, nc = nlon.shape
    cl = np.full((nr, nc), np.nan)
    cp = np.full((nr, nc), np.nan)
    counts = np.zeros(4, np.int64)
    last_l = math.nan
    last_p = math.nan
    for r in range(nr):
        for c in range(nc):
            tlon = nlon[r, c]
            tlat = nlat[r, c]
            if math.isnan(tlon) or math.isnan(tlat):
                continue
            state = _FAILED
            if not math.isnan(last_l):
                l2, p2, state = _node_antecedent(tlon, tlat, last_l, last_p, lon, lat,
                                                 _LINE_REACH, node_out)
                if state != _FAILED:
                    counts[0 if state == _FOUND else 3] += 1
            if state == _FAILED:
                g_l, g_p = nearest_node(tlon, tlat, lon, lat, seed_step)
                l2, p2, state = _node_antecedent(tlon, tlat, g_l, g_p, lon, lat,
                                                 seed_step + _LINE_REACH, node_out)
                counts[1 if state == _FOUND else 2 if state == _FAILED else 3] += 1
            if state == _FOUND:
                cl[r, c] = l2
                cp[r, c] = p2
                last_l = l2
                last_p = p2
    return cl, cp, counts


@njit(cache=True)
def _node_antecedent(tlon, tlat, gl, gp, lon, lat, line_reach, node_out):
    """A primary node's antecedent from a guess: its cell, else (just outside the product: the
    edge cells extended) the Newton correction. Returns (line, col, _FOUND | _OUTSIDE |
    _FAILED)."""
    i, j, u, v, it = cell_search(tlon, tlat, gl, lon, lat, line_reach, gp)
    if i >= 0:
        return i + u, j + v, _FOUND
    l2, p2, it, ok = correct(tlon, tlat, gl, gp, lon, lat, 1e-6, 30)
    if not ok:
        return l2, p2, _FAILED
    nl, nc = lon.shape
    near = -node_out <= l2 <= nl - 1 + node_out and -node_out <= p2 <= nc - 1 + node_out
    return l2, p2, _FOUND if near else _OUTSIDE


@njit(cache=True, nogil=True)
def pixel_antecedent(tlon: float, tlat: float, gl: float, gp: float, step: float,
                     lon: np.ndarray, lat: np.ndarray, tol: float, max_iter: int
                     ) -> tuple[float, float, int]:
    """Antecedent (line, col, iterations) on the pixel model of the terrain point (tlon, tlat)
    predicted at (gl, gp): its cell found by ``cell_search`` (a Newton correction from the
    prediction where no cell within reach holds it; the lines within a primary ``step`` where
    the correction is lost in folds), then checked by ``seen_antecedent``. Iterations -1: no
    cell holds it; ``OCCLUDED``: ground hidden by the relief."""
    nl, npx = lon.shape
    ci = -1
    cj = 0
    u = v = 0.0
    it = 0
    reach = step + _LINE_REACH  # predicted within a primary step of the product
    near = -reach <= gl <= nl + reach and -reach <= gp <= npx + reach
    if near:
        ci, cj, u, v, it = cell_search(tlon, tlat, gl, lon, lat, _LINE_REACH, gp)
    if ci < 0:  # beyond reach of the prediction: a correction, then its cell
        l2, p2, it, ok = correct(tlon, tlat, gl, gp, lon, lat, tol, max_iter)
        if ok and -0.5 <= l2 < nl - 0.5 and -0.5 <= p2 < npx - 0.5:
            ci, cj, u, v, it = cell_search(tlon, tlat, l2, lon, lat, _LINE_REACH, p2)
        elif not ok and near:  # lost in folds: the lines within a primary step
            ci, cj, u, v, it = cell_search(tlon, tlat, gl, lon, lat, int(step) + _LINE_REACH,
                                           gp)
        if ci < 0:
            return math.nan, math.nan, -1
    l2, p2, seen = seen_antecedent(tlon, tlat, ci, cj, u, v, lon, lat)
    if not seen:
        return l2, p2, OCCLUDED
    return l2, p2, it


@njit(cache=True, parallel=True)
def find_pixel_antecedents(tlon_a, tlat_a, ptr, start, stop, cl, cp, step, lon, lat, alt,
                           tol, max_iter, diagnostics):
    """Antecedents of output points on the pixel model: rows in parallel over the column spans
    (CSR ``ptr``/``start``/``stop``). Each point is predicted from the primary grid, its cell
    found by ``cell_search`` (a Newton correction from the prediction where no cell within
    reach holds it), then checked by ``seen_antecedent``. Returns line, col (float32, NaN
    dropped), iterations (int8: -1 dropped, ``OCCLUDED`` for ground hidden by the relief) and
    with ``diagnostics`` the product altitude at the antecedent (else 1x1)."""
    nr, nc = tlon_a.shape
    nl, npx = lon.shape
    out_l = np.full((nr, nc), np.nan, np.float32)
    out_p = np.full((nr, nc), np.nan, np.float32)
    iters = np.full((nr, nc), -1, np.int8)
    h_used = np.full((nr, nc) if diagnostics else (1, 1), np.nan, np.float32)
    no_rates = np.zeros((3, 1, 1))  # the pixel geolocation has no height rates: h = 0
    for i in prange(nr):
        if ptr[i + 1] == ptr[i]:  # no span in this row: no node row to interpolate
            continue
        row = np.empty((2, cl.shape[1]))
        _node_row(cl, cp, no_rates, step, i, False, row)
        for j in _columns(ptr, start, stop, i):
            tlon = tlon_a[i, j]
            tlat = tlat_a[i, j]
            if math.isnan(tlon) or math.isnan(tlat):
                continue
            gl, gp = _predict(row, cl, cp, step, i, j, 0.0)
            if math.isnan(gl) or gl < -_FAR or gl > nl + _FAR or gp < -_FAR or gp > npx + _FAR:
                continue
            l2, p2, it = pixel_antecedent(tlon, tlat, gl, gp, step, lon, lat, tol, max_iter)
            if it == OCCLUDED:
                iters[i, j] = OCCLUDED
                continue
            if it < 0 or not (-0.5 <= l2 < nl - 0.5 and -0.5 <= p2 < npx - 0.5):
                continue
            out_l[i, j] = l2
            out_p[i, j] = p2
            iters[i, j] = min(it, max_iter)
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
                step: int = PRIMARY_STEP, altitude: np.ndarray | None = None,
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
    nlon, nlat = primary_nodes(grid, row_start, lon.shape, step, spans=(ptr, start, stop))
    cl, cp, counts = primary_grid_pixel(nlon, nlat, lon_g, lat_g, SEED_STEP)
    with_alt = diagnostics and altitude is not None
    alt = (np.ascontiguousarray(altitude, dtype=np.float64) if with_alt
           else np.zeros((2, 2)))
    line, col, iters, h_used = find_pixel_antecedents(
        lon, lat, ptr, start, stop, cl, cp, float(step), lon_g, lat_g, alt, float(tolerance),
        int(max_iter), with_alt)
    out = {"line": line, "col": col, "iterations": iters,
           "search": {"primary warm": int(counts[0]), "primary seeded": int(counts[1]),
                      "primary not found": int(counts[2]),
                      "primary outside": int(counts[3]),
                      "occluded": int(np.count_nonzero(iters == OCCLUDED))}}
    if with_alt:  # the product's altitude; no parallax shift is applied by this model
        out["elevation"] = h_used
        out["shift_east_m"] = np.full(h_used.shape, np.nan, np.float32)
        out["shift_north_m"] = out["shift_east_m"]
    return out

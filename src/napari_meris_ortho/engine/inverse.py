"""Inverse location model of MERSYN (handbook section 3.4, Appendix C ``TimMersynLocationInverse``).

``f^-1(lon, lat)`` at zero height: the tie-point facet that holds the point and the offsets
(u, v) in it. The offsets invert the bilinear facet exactly (a quadratic in u, then v, polished
by one Newton step), which also covers degenerate facets and nearly parallel edges; this replaces
the handbook's intersection construction (fig. 27) with the same answer. Facets across +-180 deg
work because the tie-point longitudes are unwrapped and the searched longitude is moved onto the
facet's branch. The facet search follows the handbook: last facet, 4-connex, 8-connex, all.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..geometry.tiepoints import TiePointGrid

#: facet-search paths, counted in the statistics (Appendix B: "same / neighbour / all")
PATH_NAMES = ("same", "4-connex", "8-connex", "all")
NOT_FOUND = -1
_EPS = 1e-9


@njit(cache=True, inline="always")
def wrap180(x: float) -> float:
    """An angle difference brought onto [-180, 180); one already there is returned as it is
    (exact, and no floating-point modulo: the kernels call this for every cell corner)."""
    if -180.0 <= x < 180.0:
        return x
    return (x + 180.0) % 360.0 - 180.0


@njit(cache=True, inline="always")
def _cross(ax: float, ay: float, bx: float, by: float) -> float:
    return ax * by - ay * bx


@njit(cache=True, inline="always")
def _outside(u: float, v: float) -> float:
    du = -u if u < 0.0 else (u - 1.0 if u > 1.0 else 0.0)
    dv = -v if v < 0.0 else (v - 1.0 if v > 1.0 else 0.0)
    return du + dv


@njit(cache=True)
def facet_offsets(lon: float, lat: float, f: int, j: int, lat_tp: np.ndarray,
                  lon_tp: np.ndarray) -> tuple[float, float]:
    """Offsets (u along lines, v along columns) of (lon, lat) in facet (f, j), exact for eq. 4a-4b.

    Solves P = P00 + u e + v g + u v k; u, v may fall outside [0, 1] (point outside the facet);
    NaN when the facet is degenerate at the point.
    """
    x00 = lon_tp[f, j]
    y00 = lat_tp[f, j]
    px = x00 + wrap180(lon - x00) - x00
    py = lat - y00
    ex = lon_tp[f + 1, j] - x00
    ey = lat_tp[f + 1, j] - y00
    gx = lon_tp[f, j + 1] - x00
    gy = lat_tp[f, j + 1] - y00
    kx = lon_tp[f + 1, j + 1] - x00 - ex - gx
    ky = lat_tp[f + 1, j + 1] - y00 - ey - gy
    # u^2 (e x k) + u (e x g - p x k) - p x g = 0
    a = _cross(ex, ey, kx, ky)
    b = _cross(ex, ey, gx, gy) - _cross(px, py, kx, ky)
    c = -_cross(px, py, gx, gy)
    if abs(a) <= 1e-12 * (abs(b) + 1e-300):
        if b == 0.0:
            return math.nan, math.nan
        u1 = -c / b
        u2 = u1
    else:
        disc = b * b - 4.0 * a * c
        if disc < 0.0:
            disc = 0.0
        q = -0.5 * (b + math.copysign(math.sqrt(disc), b))
        u1 = q / a
        u2 = c / q if q != 0.0 else u1
    best_u = math.nan
    best_v = math.nan
    best = math.inf
    for u in (u1, u2):
        dx = gx + u * kx
        dy = gy + u * ky
        den = dx * dx + dy * dy
        if den == 0.0:
            continue
        v = ((px - u * ex) * dx + (py - u * ey) * dy) / den
        d = _outside(u, v)
        if d < best:
            best = d
            best_u = u
            best_v = v
    if math.isnan(best_u):
        return best_u, best_v
    # one Newton step on the bilinear map polishes the root (nearly parallel edges)
    u = best_u
    v = best_v
    rx = px - (u * ex + v * gx + u * v * kx)
    ry = py - (u * ey + v * gy + u * v * ky)
    j11 = ex + v * kx
    j12 = gx + u * kx
    j21 = ey + v * ky
    j22 = gy + u * ky
    det = j11 * j22 - j12 * j21
    if det != 0.0:
        u += (rx * j22 - ry * j12) / det
        v += (j11 * ry - j21 * rx) / det
    return u, v


@njit(cache=True, inline="always")
def _inside(u: float, v: float) -> bool:
    return -_EPS <= u <= 1.0 + _EPS and -_EPS <= v <= 1.0 + _EPS


#: facets tried around the last one, in the handbook's order: same, 4-connex, 8-connex
_NEAR_DF = (0, -1, 1, 0, 0, -1, -1, 1, 1)
_NEAR_DJ = (0, 0, 0, -1, 1, -1, 1, -1, 1)


@njit(cache=True)
def search_facet(lon: float, lat: float, f0: int, j0: int, lat_tp: np.ndarray,
                 lon_tp: np.ndarray):
    """Handbook facet search (section 3.4, fig. 24): last facet, 4-connex, 8-connex, all facets.

    Returns (f, j, u, v, path) with path 0..3 as ``PATH_NAMES`` or -1 when no facet holds the point.
    """
    nl, nc = lat_tp.shape
    if f0 >= 0:
        for k in range(9):
            f = f0 + _NEAR_DF[k]
            j = j0 + _NEAR_DJ[k]
            if f < 0 or j < 0 or f > nl - 2 or j > nc - 2:
                continue
            u, v = facet_offsets(lon, lat, f, j, lat_tp, lon_tp)
            if _inside(u, v):
                return f, j, u, v, (k + 3) // 4
    for f in range(nl - 1):
        for j in range(nc - 1):
            # quick bounding-box reject before the exact test
            y0 = min(lat_tp[f, j], lat_tp[f, j + 1], lat_tp[f + 1, j], lat_tp[f + 1, j + 1])
            y1 = max(lat_tp[f, j], lat_tp[f, j + 1], lat_tp[f + 1, j], lat_tp[f + 1, j + 1])
            if lat < y0 - 1e-9 or lat > y1 + 1e-9:
                continue
            x = lon_tp[f, j] + wrap180(lon - lon_tp[f, j])
            x0 = min(lon_tp[f, j], lon_tp[f, j + 1], lon_tp[f + 1, j], lon_tp[f + 1, j + 1])
            x1 = max(lon_tp[f, j], lon_tp[f, j + 1], lon_tp[f + 1, j], lon_tp[f + 1, j + 1])
            if x < x0 - 1e-9 or x > x1 + 1e-9:
                continue
            u, v = facet_offsets(lon, lat, f, j, lat_tp, lon_tp)
            if _inside(u, v):
                return f, j, u, v, 3
    return -1, -1, math.nan, math.nan, NOT_FOUND


@njit(cache=True)
def _inverse_many(lon, lat, lat_tp, lon_tp, df, dj):
    n = lon.size
    line = np.full(n, np.nan)
    col = np.full(n, np.nan)
    paths = np.zeros(5, np.int64)
    f = np.int64(-1)  # not a literal: one specialisation of search_facet
    j = np.int64(-1)
    for i in range(n):
        f2, j2, u, v, path = search_facet(lon[i], lat[i], f, j, lat_tp, lon_tp)
        paths[path + 1] += 1
        if path >= 0:
            f = f2
            j = j2
            line[i] = (f + u) * df
            col[i] = (j + v) * dj
    return line, col, paths


def inverse_location(grid: TiePointGrid, lon: np.ndarray, lat: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Zero-height inverse location (section 3.4) of many points, searched in the given order.

    Returns (line, col) — NaN where no facet holds the point — and the facet-search counts.
    """
    lon_a, lat_a = np.broadcast_arrays(np.asarray(lon, np.float64), np.asarray(lat, np.float64))
    lat_tp, lon_tp, _, df, dj = grid.kernel_args()
    line, col, paths = _inverse_many(np.ascontiguousarray(lon_a.ravel()),
                                     np.ascontiguousarray(lat_a.ravel()), lat_tp, lon_tp, df, dj)
    counts = {"not found": int(paths[0])}
    counts.update({name: int(paths[k + 1]) for k, name in enumerate(PATH_NAMES)})
    return line.reshape(lon_a.shape), col.reshape(lon_a.shape), counts

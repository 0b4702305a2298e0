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
#: jumps of the walk towards a point from the last facet, before the search through all facets
WALK_STEPS = 12
#: distance (deg) from the tie-point grid's border within which a point outside it is still
#: searched through all facets (a facet holds points up to _EPS beyond its edges)
BORDER_MARGIN_DEG = 1e-6


@njit(cache=True, inline="always")
def _edge_step(px: float, py: float, x: float, y: float, margin: float) -> tuple[bool, bool]:
    """For the border edge (px, py)-(x, y), point at the origin: (the edge crosses the ray
    towards +x, the edge passes within ``margin`` of the point)."""
    cross = (y > 0.0) != (py > 0.0) and px + (x - px) * (-py) / (y - py) > 0.0
    if (min(px, x) > margin or max(px, x) < -margin or min(py, y) > margin
            or max(py, y) < -margin):
        return cross, False
    dx = x - px
    dy = y - py
    d2 = dx * dx + dy * dy
    t = 0.0 if d2 == 0.0 else min(max(-(px * dx + py * dy) / d2, 0.0), 1.0)
    cx = px + t * dx
    cy = py + t * dy
    return cross, cx * cx + cy * cy <= margin * margin


@njit(cache=True)
def clear_of_grid(lon: float, lat: float, lat_tp: np.ndarray, lon_tp: np.ndarray) -> bool:
    """True when (lon, lat) lies outside the border of the tie-point grid by more than
    BORDER_MARGIN_DEG: no facet holds it. The bilinear facets (eq. 4a-4b) have straight edges
    in longitude and latitude, so their union is the polygon of the border tie points (first
    tie line, last tie column, last tie line and first tie column, once round); the point is
    tested against it (crossings of a ray, then the distance to each edge), longitudes taken
    relative to the point. False (not known) for a border spanning more than +-90 deg of
    longitude around the point."""
    n, m = lat_tp.shape
    px = wrap180(lon_tp[0, 0] - lon)
    py = lat_tp[0, 0] - lat
    inside = False
    for side in range(4):
        count = m - 1 if side % 2 == 0 else n - 1
        for k in range(1, count + 1):
            if side == 0:
                i, j = 0, k
            elif side == 1:
                i, j = k, m - 1
            elif side == 2:
                i, j = n - 1, m - 1 - k
            else:
                i, j = n - 1 - k, 0
            x = wrap180(lon_tp[i, j] - lon)
            y = lat_tp[i, j] - lat
            if abs(x) > 90.0:
                return False
            cross, near = _edge_step(px, py, x, y, BORDER_MARGIN_DEG)
            if near:
                return False
            if cross:
                inside = not inside
            px = x
            py = y
    return not inside


@njit(cache=True)
def search_facet(lon: float, lat: float, f0: int, j0: int, lat_tp: np.ndarray,
                 lon_tp: np.ndarray):
    """Handbook facet search (section 3.4, fig. 24): last facet, 4-connex, 8-connex, all facets.

    Returns (f, j, u, v, path) with path 0..3 as ``PATH_NAMES`` or -1 when no facet holds the point.
    "All facets" starts with a walk from the last facet, each jump by the point's offsets in
    the current facet (the bilinear facet extended), and a point clear of the grid's border
    (:func:`clear_of_grid`) is not searched through every facet: with tie points on every row
    (OLCI) they are tens of thousands, and the next point of a search lies many facets away.
    The facet holding a point is one, whichever path finds it.
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
        f = min(max(f0, 0), nl - 2)
        j = min(max(j0, 0), nc - 2)
        for _ in range(WALK_STEPS):
            u, v = facet_offsets(lon, lat, f, j, lat_tp, lon_tp)
            if not (abs(u) < 1e6 and abs(v) < 1e6):
                break
            if _inside(u, v):
                return f, j, u, v, 3
            f2 = min(max(f + int(math.floor(u)), 0), nl - 2)
            j2 = min(max(j + int(math.floor(v)), 0), nc - 2)
            if f2 == f and j2 == j:
                break
            f = f2
            j = j2
    if clear_of_grid(lon, lat, lat_tp, lon_tp):
        return -1, -1, math.nan, math.nan, NOT_FOUND
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

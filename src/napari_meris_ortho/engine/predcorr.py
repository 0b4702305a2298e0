"""Prediction/correction: the antecedent (l, p) of every output point (section 3.2, Appendix C).

Two paths find the same antecedent, the point where the direct model with height gives the
output point's lon/lat, ``f(l, p, h) = (lon, lat)``:

* ``find_antecedents`` (default, fast): the zero-height inverse is computed exactly (facet
  search, ``inverse.search_facet``) on a coarse *primary grid* of output points, every ``step``
  pixels, and interpolated bilinearly in between as the prediction (the terrain-correction
  paper's primary grids), moved by the point's height times the nodes' height rates
  (``height_rates``: the parallax of eq. 6a-6b linearised). Each point is then corrected by
  Newton steps on the direct model with its facet's analytic Jacobian until a step is below
  ``tolerance`` product pixels (one step for 93 % of the points of a DEM map, at most three).
* ``find_antecedents_handbook`` (reference): MERSYN's loop verbatim — inverse by facet search,
  then ``x <- x + (x_origin - f^-1(f(x, h)))`` until the correction is below the tolerance.

Iterations count direct-model evaluations that moved the point (MERSYN's loop passes); the
fast path's prediction is not exact, so even without heights it reports one correction where
MERSYN reports ITERATION[0]. The primary grid extends the edge facets, so it also keeps terrain
points whose zero-height position lies outside the swath (MERSYN's first inverse loses them).
The handbook path keeps MERSYN's behaviour: a point is lost when its zero-height inverse or the
first correction ``f^-1(f(x0, h))`` (about one parallax shift further out) falls outside the
tie-point facets — the outer half pixel of the product and, on high relief, terrain up to one
shift (29 FR px for 9 km at 40 deg) inside the near-nadir edge. Both paths return the same
diagnostics (``parallax_at``).
Both stop after ``max_iter`` iterations (histogram like Appendix B) and drop points whose
antecedent leaves the product (-0.5 <= l < H-0.5, -0.5 <= p < W-0.5). Heights (``hmode``):
0 none (MERSYN ``-ort NO``), 1 tie-point dem_alt at the antecedent, 2 the given per-point height
(the DEM at the output point; NaN falls back to the tie points, as MERSYN does).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numba import njit

from .inverse import search_facet, wrap180
from .location import direct_point, direct_point_inline, facet_of, parallax_factors
from .threads import split_range

if TYPE_CHECKING:
    from ..geometry.grid import OutputGrid

HEIGHT_NONE = 0
HEIGHT_TIEPOINTS = 1
HEIGHT_GIVEN = 2
MAX_ITERATIONS = 10
#: primary-grid node spacing (output pixels) of the prediction (section 3.2)
PRIMARY_STEP = 16
#: guesses further than this many product pixels outside the product are dropped at once
_FAR = 256.0


@njit(cache=True, inline="always")
def _newton(tlon, tlat, line, col, h, coef, df, dj, model, geo, tol, max_iter):
    """Correct (line, col) until f(line, col, h) = (tlon, tlat); returns (line, col, iterations)."""
    it = 0
    while it < max_iter:
        it += 1
        r = direct_point_inline(line, col, h, coef, df, dj, model, geo)
        rx = tlon - r[0]
        if rx > 180.0 or rx < -180.0:
            rx = wrap180(rx)
        ry = tlat - r[1]
        det = r[5] * r[8] - r[6] * r[7]
        if det == 0.0 or math.isnan(det):
            return math.nan, math.nan, it
        dl = (rx * r[8] - ry * r[6]) / det
        dp = (r[5] * ry - r[7] * rx) / det
        line += dl
        col += dp
        if abs(dl) <= tol and abs(dp) <= tol:
            break
    return line, col, it


def primary_grid(lon: np.ndarray, lat: np.ndarray, lat_tp: np.ndarray, lon_tp: np.ndarray,
                 coef: np.ndarray, df: float, dj: float, geo: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact zero-height inverse (section 3.4) at the primary-grid nodes (2-D lon/lat arrays).

    Nodes held by a facet come from the handbook search (warm-started from the previous node's
    facet, walking from it when the next node lies many facets away, as with OLCI's one-row
    facets: the facet found is the same from any start); nodes outside the tie-point grid from
    Newton on the extended edge facets (they are needed to predict output points near the swath
    border), started from the edge tie point nearest to the node (``_edge_start``), so that a
    node's antecedent depends on the node alone, not on the nodes computed before it (a window
    of the nodes gives their values bit for bit). Returns (line, col, path counts[5]).
    """
    lon = np.ascontiguousarray(lon, dtype=np.float64)
    lat = np.ascontiguousarray(lat, dtype=np.float64)
    line = np.full(lon.shape, np.nan)
    col = np.full(lon.shape, np.nan)
    paths = np.zeros(5, np.int64)
    _primary_nodes(lon, lat, lat_tp, lon_tp, coef, float(df), float(dj), np.int64(geo), line,
                   col, paths)
    return line, col, paths


@njit(cache=True)
def _primary_nodes(lon, lat, lat_tp, lon_tp, coef, df, dj, geo, line, col,
                   paths):  # pragma: no cover
    """``primary_grid`` into its (NaN-filled) outputs."""
    nr, nc = lon.shape
    # typed constants: a literal argument would compile a second specialisation of the callee
    f = np.int64(-1)
    j = np.int64(-1)
    model0 = np.int64(0)
    for r in range(nr):
        for c in range(nc):
            if math.isnan(lon[r, c]) or math.isnan(lat[r, c]):
                continue
            f2, j2, u, v, path = search_facet(lon[r, c], lat[r, c], f, j, lat_tp, lon_tp)
            paths[path + 1] += 1
            if path >= 0:
                f = f2
                j = j2
                line[r, c] = (f + u) * df
                col[r, c] = (j + v) * dj
                if geo == 0:
                    continue
                # the search inverts the bilinear lon/lat facet: polish
                l0, p0, most = line[r, c], col[r, c], np.int64(10)
            else:
                l0, p0 = _edge_start(lon[r, c], lat[r, c], lat_tp, lon_tp, df, dj)
                most = np.int64(30)
            # (one call: ``_newton`` is inlined)
            l2, p2, it = _newton(lon[r, c], lat[r, c], l0, p0, 0.0, coef, df, dj, model0, geo,
                                 1e-6, most)
            if not math.isnan(l2) and (path >= 0 or it < most):
                line[r, c] = l2
                col[r, c] = p2


@njit(cache=True)
def _edge_start(tlon, tlat, lat_tp, lon_tp, df, dj):  # pragma: no cover
    """(line, col) of the tie point on the edge of the tie-point grid nearest to (tlon, tlat)
    (squared degrees, longitudes scaled by cos(lat)): where Newton starts for a point outside
    the grid."""
    n, m = lat_tp.shape
    scale = math.cos(math.radians(tlat))
    best = math.inf
    best_l = 0.0
    best_p = 0.0
    for k in range(2 * (n + m)):
        if k < m:  # first tie line, last tie line, first tie column, last tie column
            i, jj = 0, k
        elif k < 2 * m:
            i, jj = n - 1, k - m
        elif k < 2 * m + n:
            i, jj = k - 2 * m, 0
        else:
            i, jj = k - 2 * m - n, m - 1
        dlat = lat_tp[i, jj] - tlat
        dlon = wrap180(lon_tp[i, jj] - tlon) * scale
        d = dlat * dlat + dlon * dlon
        if d < best:
            best = d
            best_l = i * df
            best_p = jj * dj
    return best_l, best_p


@njit(cache=True, inline="always")
def _point_height(hmode, height, i, j):  # pragma: no cover
    """The height the direct model takes at output point (i, j) (module docstring): 0 (none),
    NaN (the tie points' dem_alt at the antecedent) or the given one."""
    if hmode == HEIGHT_NONE:
        return 0.0
    if hmode == HEIGHT_TIEPOINTS:
        return math.nan
    return np.float64(height[i, j])


@njit(cache=True)
def _node_row(cl, cp, rates, step, i, moved, row):  # pragma: no cover
    """The first half of the bilinear prediction at output row i, once for the whole row: the
    primary grid (cl, cp) and, when ``moved``, its ``height_rates`` interpolated between the
    two node rows around i, into ``row`` (2 rows, or 5 when moved, by node columns); NaN where
    a node is missing."""
    a, u = facet_of(i, step, cl.shape[0])
    for b in range(cl.shape[1]):
        row[0, b] = (1 - u) * cl[a, b] + u * cl[a + 1, b]
        row[1, b] = (1 - u) * cp[a, b] + u * cp[a + 1, b]
    if moved:
        for k in range(3):
            for b in range(cl.shape[1]):
                row[2 + k, b] = (1 - u) * rates[k, a, b] + u * rates[k, a + 1, b]


@njit(cache=True, inline="always")
def _predict(row, cl, cp, step, i, j, h):
    """Primary grid interpolated bilinearly at output pixel (i, j) (its ``_node_row`` of row i,
    then between the node columns around j), moved by ``h`` times the interpolated height
    rates (``height_rates``; h NaN: the tie-point height there, 0: no move); a node missing:
    any valid one of the four around, unmoved (then Newton does the rest)."""
    b, v = facet_of(j, step, cl.shape[1])
    l = (1 - v) * row[0, b] + v * row[0, b + 1]
    p = (1 - v) * row[1, b] + v * row[1, b + 1]
    if math.isnan(l):  # a missing node: take any valid one (then Newton does the rest)
        a = facet_of(i, step, cl.shape[0])[0]
        for da in range(2):
            for db in range(2):
                if not math.isnan(cl[a + da, b + db]):
                    return cl[a + da, b + db], cp[a + da, b + db]
        return l, p
    if h != 0.0:
        if math.isnan(h):
            h = (1 - v) * row[4, b] + v * row[4, b + 1]
        rl = (1 - v) * row[2, b] + v * row[2, b + 1]
        rp = (1 - v) * row[3, b] + v * row[3, b + 1]
        if not (math.isnan(rl) or math.isnan(rp) or math.isnan(h)):
            l += h * rl
            p += h * rp
    return l, p


def height_rates(cl: np.ndarray, cp: np.ndarray, coef: np.ndarray, df: float, dj: float,
                 model: int, geo: int) -> np.ndarray:
    """At each primary-grid node, its zero-height antecedent (cl, cp) moved per metre of
    height, d(l, p)/dh = -J^-1 (ke e, kn n) (eq. 6a-6b linearised at h = 0; J the position
    Jacobian, eq. 4a-4b), and the tie-point height (dem_alt) there: (3, rows, cols), NaN
    where the node is missing. With them the prediction of a point of known height lands
    within a Newton tolerance of its antecedent: one correction, not two."""
    out = np.full((3, *cl.shape), np.nan)
    _height_rates(np.ascontiguousarray(cl, dtype=np.float64),
                  np.ascontiguousarray(cp, dtype=np.float64), coef, float(df), float(dj),
                  np.int64(model), np.int64(geo), out)
    return out


@njit(cache=True, nogil=True)
def _height_rates(cl, cp, coef, df, dj, model, geo, out):  # pragma: no cover
    """``height_rates`` into its NaN-filled output."""
    for a in range(cl.shape[0]):
        for b in range(cl.shape[1]):
            if math.isnan(cl[a, b]) or math.isnan(cp[a, b]):
                continue
            r = direct_point(cl[a, b], cp[a, b], 0.0, coef, df, dj, model, geo)
            det = r[5] * r[8] - r[6] * r[7]
            if det == 0.0 or math.isnan(det):
                continue
            ke, kn = parallax_factors(r[1], 0.0, model)
            qx = ke * r[3]  # d lon / dh, d lat / dh (eq. 6a-6b)
            qy = kn * r[4]
            out[0, a, b] = -(qx * r[8] - qy * r[6]) / det
            out[1, a, b] = -(r[5] * qy - r[7] * qx) / det
            out[2, a, b] = direct_point(cl[a, b], cp[a, b], math.nan, coef, df, dj, model,
                                        geo)[2]


@njit(cache=True)
def _columns(ptr, start, stop, i):
    """Output columns of row i inside the segment-boundary spans (CSR layout of RowSpans)."""
    n = 0
    for k in range(ptr[i], ptr[i + 1]):
        n += stop[k] - start[k]
    out = np.empty(n, np.int64)
    n = 0
    for k in range(ptr[i], ptr[i + 1]):
        for j in range(start[k], stop[k]):
            out[n] = j
            n += 1
    return out


def full_spans(n_rows: int, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR spans covering every column of every row (no segment boundary)."""
    return (np.arange(n_rows + 1, dtype=np.int64), np.zeros(n_rows, np.int64),
            np.full(n_rows, width, np.int64))


def _outputs(shape: tuple[int, int], out: tuple[np.ndarray, np.ndarray, np.ndarray] | None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """line, col (NaN) and iterations (-1) arrays of ``shape``: new, or ``out`` checked and
    filled."""
    if out is None:
        return (np.full(shape, np.nan, np.float32), np.full(shape, np.nan, np.float32),
                np.full(shape, -1, np.int8))
    for a, dtype in zip(out, (np.float32, np.float32, np.int8), strict=True):
        if a.shape != shape or a.dtype != dtype or not a.flags.c_contiguous:
            raise ValueError(f"out arrays must be C-contiguous {shape} float32, float32, int8")
    out[0].fill(np.nan)
    out[1].fill(np.nan)
    out[2].fill(-1)
    return out


@njit(cache=True, nogil=True)
def _antecedent_rows(lo, hi, lon, lat, height, hmode, ptr, start, stop, cl, cp, rates, step,
                     coef, df, dj, n_lines, n_cols, model, geo, tol, max_iter, diagnostics,
                     out_l, out_p, iters, h_used, sh_e, sh_n):  # pragma: no cover
    """Rows [lo, hi) of ``find_antecedents`` into its (pre-filled) outputs."""
    row = np.empty((5, cl.shape[1]))
    for i in range(lo, hi):
        if ptr[i + 1] > ptr[i]:
            _node_row(cl, cp, rates, step, i, hmode != HEIGHT_NONE, row)
        for k in range(ptr[i], ptr[i + 1]):
            for j in range(start[k], stop[k]):
                tlon = lon[i, j]
                tlat = lat[i, j]
                if math.isnan(tlon) or math.isnan(tlat):
                    continue
                h = _point_height(hmode, height, i, j)
                gl, gp = _predict(row, cl, cp, step, i, j, h)
                if math.isnan(gl):
                    continue
                if gl < -_FAR or gl > n_lines + _FAR or gp < -_FAR or gp > n_cols + _FAR:
                    continue
                l2, p2, it = _newton(tlon, tlat, gl, gp, h, coef, df, dj, model, geo, tol,
                                     max_iter)
                if not (-0.5 <= l2 < n_lines - 0.5 and -0.5 <= p2 < n_cols - 0.5):
                    continue
                out_l[i, j] = l2
                out_p[i, j] = p2
                iters[i, j] = it
                if diagnostics:
                    r = direct_point(l2, p2, h, coef, df, dj, model, geo)
                    h_used[i, j] = r[2]
                    sh_e[i, j] = r[2] * r[3]
                    sh_n[i, j] = r[2] * r[4]


def find_antecedents(lon: np.ndarray, lat: np.ndarray, height: np.ndarray, hmode: int,
                     ptr: np.ndarray, start: np.ndarray, stop: np.ndarray, cl: np.ndarray,
                     cp: np.ndarray, rates: np.ndarray, step: float, coef: np.ndarray,
                     df: float, dj: float,
                     n_lines: int, n_cols: int, model: int, geo: int, tol: float,
                     max_iter: int, diagnostics: bool,
                     out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                     ) -> tuple[np.ndarray, ...]:
    """Antecedents of output points: row i over the column spans ``[start[k], stop[k])`` for
    k in ``ptr[i]:ptr[i + 1]`` (``boundary.RowSpans``), rows split over threads; predicted from
    the primary grid (cl, cp) and its ``height_rates``, then corrected by Newton.

    Returns line, col (float32, NaN when dropped), iterations (int8, -1 when dropped), and when
    ``diagnostics``: elevation used (m), parallax shift east and north (m) — else 1x1 arrays.
    ``out``: C-contiguous (line, col, iterations) arrays of the points' shape to fill and
    return instead of new ones (rows of the caller's whole grid: no copy afterwards).
    """
    nr, nc = lon.shape
    out_l, out_p, iters = _outputs((nr, nc), out)
    dshape = (nr, nc) if diagnostics else (1, 1)
    h_used = np.full(dshape, np.nan, np.float32)
    sh_e = np.full(dshape, np.nan, np.float32)
    sh_n = np.full(dshape, np.nan, np.float32)
    args = (lon, lat, height, np.int64(hmode), ptr, start, stop, cl, cp, rates, float(step),
            coef,
            float(df), float(dj), np.int64(n_lines), np.int64(n_cols), np.int64(model),
            np.int64(geo), float(tol), np.int64(max_iter), bool(diagnostics), out_l, out_p,
            iters, h_used, sh_e, sh_n)
    split_range(lambda lo, hi: _antecedent_rows(lo, hi, *args), nr)
    return out_l, out_p, iters, h_used, sh_e, sh_n


@njit(cache=True, nogil=True)
def _handbook_rows(lo, hi, lon, lat, height, hmode, ptr, start, stop, lat_tp, lon_tp, coef,
                   df, dj, n_lines, n_cols, model, geo, tol, max_iter, out_l, out_p, iters,
                   paths):  # pragma: no cover
    """Rows [lo, hi) of ``find_antecedents_handbook`` into its (pre-filled) outputs."""
    for i in range(lo, hi):
        f = np.int64(-1)
        g = np.int64(-1)
        for k in range(ptr[i], ptr[i + 1]):
            for j in range(start[k], stop[k]):
                tlon = lon[i, j]
                tlat = lat[i, j]
                if math.isnan(tlon) or math.isnan(tlat):
                    continue
                f2, g2, u, v, path = search_facet(tlon, tlat, f, g, lat_tp, lon_tp)
                paths[i, path + 1] += 1
                if path < 0:
                    continue
                f = f2
                g = g2
                l0 = (f + u) * df
                p0 = (g + v) * dj
                x = l0
                y = p0
                it = 0
                ok = True
                while (hmode != 0 or geo != 0) and it < max_iter:
                    it += 1
                    h = _point_height(hmode, height, i, j)
                    r = direct_point(x, y, h, coef, df, dj, model, geo)
                    f3, g3, u3, v3, path3 = search_facet(r[0], r[1], f, g, lat_tp, lon_tp)
                    paths[i, path3 + 1] += 1
                    if path3 < 0:
                        ok = False
                        break
                    x1 = (f3 + u3) * df
                    y1 = (g3 + v3) * dj
                    x += l0 - x1
                    y += p0 - y1
                    if abs(l0 - x1) <= tol and abs(p0 - y1) <= tol:
                        break
                if not ok or not (-0.5 <= x < n_lines - 0.5 and -0.5 <= y < n_cols - 0.5):
                    continue
                out_l[i, j] = x
                out_p[i, j] = y
                iters[i, j] = it


def find_antecedents_handbook(lon: np.ndarray, lat: np.ndarray, height: np.ndarray, hmode: int,
                              ptr: np.ndarray, start: np.ndarray, stop: np.ndarray,
                              lat_tp: np.ndarray, lon_tp: np.ndarray, coef: np.ndarray,
                              df: float, dj: float, n_lines: int, n_cols: int, model: int,
                              geo: int, tol: float, max_iter: int
                              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """MERSYN's prediction/correction loop (Appendix C) with the handbook facet search.

    Rows split over threads, each row keeping its last facet. Returns line, col (float32),
    iterations (int8, -1 dropped) and the facet-search counts per path ([not found, same, 4,
    8, all]).
    """
    nr, nc = lon.shape
    out_l = np.full((nr, nc), np.nan, np.float32)
    out_p = np.full((nr, nc), np.nan, np.float32)
    iters = np.full((nr, nc), -1, np.int8)
    paths = np.zeros((nr, 5), np.int64)
    args = (lon, lat, height, np.int64(hmode), ptr, start, stop, lat_tp, lon_tp, coef,
            float(df), float(dj), np.int64(n_lines), np.int64(n_cols), np.int64(model),
            np.int64(geo), float(tol), np.int64(max_iter), out_l, out_p, iters, paths)
    split_range(lambda lo, hi: _handbook_rows(lo, hi, *args), nr)
    return out_l, out_p, iters, paths.sum(axis=0)


@njit(cache=True, nogil=True)
def _parallax_rows(lo, hi, line, col, height, hmode, coef, df, dj, model, geo, h_used, sh_e,
                   sh_n):  # pragma: no cover
    """Rows [lo, hi) of ``parallax_at`` into its (NaN-filled) outputs."""
    nc = line.shape[1]
    for i in range(lo, hi):
        for j in range(nc):
            if math.isnan(line[i, j]):
                continue
            h = _point_height(hmode, height, i, j)
            r = direct_point(np.float64(line[i, j]), np.float64(col[i, j]), h, coef, df, dj,
                             model, geo)
            h_used[i, j] = r[2]
            sh_e[i, j] = r[2] * r[3]
            sh_n[i, j] = r[2] * r[4]


def parallax_at(line: np.ndarray, col: np.ndarray, height: np.ndarray, hmode: int,
                coef: np.ndarray, df: float, dj: float, model: int, geo: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Elevation used (m) and parallax shift east/north (m) at the antecedents (NaN where
    dropped): the diagnostics of ``find_antecedents`` for any path (eq. 6a, 2c')."""
    nr, nc = line.shape
    h_used = np.full((nr, nc), np.nan, np.float32)
    sh_e = np.full((nr, nc), np.nan, np.float32)
    sh_n = np.full((nr, nc), np.nan, np.float32)
    args = (line, col, height, np.int64(hmode), coef, float(df), float(dj), np.int64(model),
            np.int64(geo), h_used, sh_e, sh_n)
    split_range(lambda lo, hi: _parallax_rows(lo, hi, *args), nr)
    return h_used, sh_e, sh_n


def iteration_histogram(iters: np.ndarray, max_iter: int = MAX_ITERATIONS) -> np.ndarray:
    """Counts of points per number of prediction/correction iterations (0..max_iter), Appendix B."""
    return solved_counts(iters, iters, 0, max_iter + 1)


def solved_counts(values: np.ndarray, iters: np.ndarray, first: int, n: int) -> np.ndarray:
    """Counts (int64, n) of the int8 ``values`` first .. first + n - 1 at the points the
    prediction/correction solved (``iters >= 0``; same shape): the iteration histogram, the
    points per elevation source. One pass, no copies (the 11 M points of a map: 10 ms)."""
    v = np.ascontiguousarray(values, dtype=np.int8).reshape(-1)
    it = np.ascontiguousarray(iters, dtype=np.int8).reshape(-1)
    if v.size != it.size:
        raise ValueError(f"values ({v.size}) and iterations ({it.size}) differ in size")
    out = np.zeros(int(n), np.int64)
    _solved_counts(v, it, np.int64(first), out)
    return out


@njit(cache=True, nogil=True)
def _solved_counts(values, iters, first, out):  # pragma: no cover
    n = out.size
    for i in range(values.size):
        if iters[i] >= 0:
            k = np.int64(values[i]) - first
            if k >= 0 and k < n:
                out[k] += 1


def needed_nodes(spans: tuple[np.ndarray, np.ndarray, np.ndarray], step: int,
                 node_shape: tuple[int, int]) -> np.ndarray:
    """True at the primary-grid nodes (``primary_nodes`` of the spans' rows, ``node_shape``)
    that the prediction of some output point of the CSR ``spans`` reads: the corners of the
    point's node cell (``_predict``). The others need no antecedent."""
    out = np.zeros(node_shape, np.bool_)
    ptr, start, stop = (np.ascontiguousarray(a, dtype=np.int64) for a in spans)
    _mark_needed(ptr, start, stop, np.int64(step), out)
    return out


@njit(cache=True)
def _mark_needed(ptr, start, stop, step, out):  # pragma: no cover
    """``needed_nodes`` into its False-filled output."""
    nr, nc = out.shape
    for i in range(ptr.size - 1):
        a = facet_of(i, step, nr)[0]
        for k in range(ptr[i], ptr[i + 1]):
            if stop[k] <= start[k]:
                continue
            for b in range(facet_of(start[k], step, nc)[0],
                           facet_of(stop[k] - 1, step, nc)[0] + 2):
                out[a, b] = True
                out[a + 1, b] = True


def primary_nodes(grid: OutputGrid, row_start: int, shape: tuple[int, int], step: int,
                  col_start: int = 0,
                  spans: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """WGS84 lon/lat (2-D) of the primary-grid nodes of output rows [row_start, row_start +
    shape[0]) and columns [col_start, col_start + shape[1]): every ``step`` pixels from the
    first row and column, at least 2 x 2 nodes, the last ones past the grid edge when needed
    (the prediction interpolates between them). With the CSR ``spans`` of those rows, NaN at
    the nodes no point of the spans reads (``needed_nodes``): the searches skip them."""
    nr, nc = shape
    rows = row_start + np.arange(0, max(nr - 1, 0) + step, step, dtype=np.float64)
    cols = col_start + np.arange(0, max(nc - 1, 0) + step, step, dtype=np.float64)
    if rows.size < 2:
        rows = np.r_[rows, rows[-1] + step]
    if cols.size < 2:
        cols = np.r_[cols, cols[-1] + step]
    lon, lat = grid.lonlat_at(rows[:, None], cols[None, :])
    if spans is None:
        return lon, lat
    unused = ~needed_nodes(spans, step, lon.shape)
    return np.where(unused, np.nan, lon), np.where(unused, np.nan, lat)


def solve(tp, grid, lon: np.ndarray, lat: np.ndarray, height: np.ndarray | None, hmode: int,
          spans: tuple[np.ndarray, np.ndarray, np.ndarray], *, row_start: int = 0,
          tolerance: float = 0.01, max_iter: int = MAX_ITERATIONS, model: int = 0,
          geo: int = 0, method: str = "primary", step: int = PRIMARY_STEP,
          diagnostics: bool = False,
          out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
          col_start: int = 0) -> dict:
    """Antecedents of output rows [row_start, row_start + lon.shape[0]) of ``grid`` (section 3.2)
    and columns [col_start, col_start + lon.shape[1]) (a multiple of ``step``: the primary-grid
    nodes of the whole rows, each depending on itself alone, so the whole rows' antecedents;
    ``spans`` then count from ``col_start``).

    ``tp``: ``TiePointGrid``; ``lon``/``lat``: WGS84 degrees of the pixel centres of those rows;
    ``height``: per-point heights for ``hmode=HEIGHT_GIVEN`` (NaN: tie points); ``spans``: CSR
    (ptr, start, stop) of the columns to process per row; ``model``/``geo``: parallax and
    geolocation codes (``location``). ``method``: "primary" (primary grid +
    Newton) or "handbook" (MERSYN's loop and facet search). Returns a dict with "line", "col",
    "iterations" and, with ``diagnostics``, "elevation", "shift_east_m", "shift_north_m"; plus
    "search" (facet-search counts by path). ``out``: as ``find_antecedents`` (primary path).
    """
    lat_tp, lon_tp, coef, df, dj = tp.kernel_args()
    lon = np.ascontiguousarray(lon, dtype=np.float64)
    lat = np.ascontiguousarray(lat, dtype=np.float64)
    if hmode == HEIGHT_GIVEN and (height is None or np.shape(height) != lon.shape):
        raise ValueError("per-point heights of the output points' shape are needed "
                         "with HEIGHT_GIVEN")
    h = (np.zeros((1, 1), np.float32) if height is None
         else np.ascontiguousarray(height, dtype=np.float32))
    ptr, start, stop = (np.ascontiguousarray(a, dtype=np.int64) for a in spans)
    names = ("not found", "same", "4-connex", "8-connex", "all")
    if method == "handbook":
        line, col, iters, paths = find_antecedents_handbook(
            lon, lat, h, hmode, ptr, start, stop, lat_tp, lon_tp, coef, df, dj,
            tp.height, tp.width, model, geo, tolerance, max_iter)
        result: dict[str, Any] = {"line": line, "col": col, "iterations": iters}
        if diagnostics:
            h_used, sh_e, sh_n = parallax_at(line, col, h, hmode, coef, df, dj, model, geo)
            result.update(elevation=h_used, shift_east_m=sh_e, shift_north_m=sh_n)
        result["search"] = {n: int(c) for n, c in zip(names, paths, strict=True)}
        return result
    if method != "primary":
        raise ValueError(f"unknown prediction/correction method {method!r}")
    if col_start % step:
        raise ValueError(f"col_start {col_start} is not a multiple of the step {step}")
    nlon, nlat = primary_nodes(grid, row_start, lon.shape, step, col_start)
    cl, cp, paths = primary_grid(nlon, nlat, lat_tp, lon_tp, coef, df, dj, geo)
    rates = (height_rates(cl, cp, coef, df, dj, model, geo) if hmode != HEIGHT_NONE
             else np.zeros((3, 1, 1)))
    line, col, iters, h_used, sh_e, sh_n = find_antecedents(
        lon, lat, h, hmode, ptr, start, stop, cl, cp, rates, float(step), coef, df, dj,
        tp.height, tp.width, model, geo, tolerance, max_iter, diagnostics, out)
    result = {"line": line, "col": col, "iterations": iters}
    if diagnostics:
        result.update(elevation=h_used, shift_east_m=sh_e, shift_north_m=sh_n)
    search = {n: int(c) for n, c in zip(names, paths, strict=True)}
    search["primary grid"] = int(np.count_nonzero(iters >= 0))
    result["search"] = search
    return result

"""DEM heights looked up in a window of posts already in memory (handbook section 3.1
"Digital elevation data", Appendix C ``TimMersynGetAltitudeFromDem``): serial compiled loops
over the output points, no temporaries.

The window is plain data (``dem.base.LatticeWindow`` gives it; engine and io never import each
other): float32 posts, NaN = no data, and the inverse geotransform of the DEM, (a, b, c, d, e,
f) with ``col + 0.5 = a x + b y + c`` and ``row + 0.5 = d x + e y + f`` (posts at pixel
centres). Interpolation as ``dem.base.DemSource.sample``: "nearest", "bilinear" (2x2 posts),
"bicubic" (4x4 posts, Keys a = -0.5, ``geometry.interpolation``); a post outside the lattice is
clamped to its edge, a post that is no data or outside -500..9000 m makes the point no data (it
goes to the next DEM). Nearest/bilinear and bicubic are two kernels: a run compiles only the
one it uses (``ortho`` asks bilinear); both run on ranges of points on a few threads
(``engine.threads``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..geometry.earth import MAX_TERRAIN_M, MIN_TERRAIN_M
from ..geometry.interpolation import keys_weights
from .threads import split_range

#: interpolation codes of :func:`window_heights` (order of ``options.Sampling``)
NEAREST, BILINEAR, BICUBIC = 0, 1, 2
METHOD_CODES = {"nearest": NEAREST, "bilinear": BILINEAR, "bicubic": BICUBIC}

_keys_weights = njit(cache=True, nogil=True)(keys_weights)


@njit(cache=True, nogil=True)
def _post(data: np.ndarray, r: int, c: int) -> float:
    """Post (r, c) of the window, NaN when no data or implausible (a background post)."""
    v = data[r, c]
    return float(v) if v >= MIN_TERRAIN_M and v <= MAX_TERRAIN_M else math.nan


def window_heights(data: np.ndarray, inv: np.ndarray, lattice: np.ndarray, wrap_centre: float,
                   method: int, x: np.ndarray, y: np.ndarray, todo: np.ndarray,
                   undulation: np.ndarray, index: int, h: np.ndarray, src: np.ndarray,
                   miss: np.ndarray) -> int:
    """Heights at the points ``todo`` (DEM coordinates ``x``, ``y``, flat float64) from the
    window ``data`` (float32 posts of the DEM lattice from row ``lattice[0]``, column
    ``lattice[1]``; lattice ``lattice[2]`` x ``lattice[3]`` posts) by the inverse geotransform
    ``inv`` (module docstring) and ``method`` (``METHOD_CODES``); bilinear sums as ``dem``
    (top and bottom rows, then between them: the same float64 numbers).

    ``wrap_centre``: geographic DEM, x is moved by whole turns of 360 deg next to it (NaN:
    none); ``undulation``: geoid N added to the heights (empty: none). Where a height is
    found: ``h`` (float32) = height + N, ``src`` = ``index``, ``todo`` cleared. Points needing
    posts outside the window are flagged in ``miss`` (the caller reads them); outside the
    lattice or no data: left ``todo``. Returns the number of ``miss`` points.
    """
    counts: list[int] = []  # misses of each range (list.append: thread-safe)
    if method == BICUBIC:
        args_b = (data, inv, lattice, wrap_centre, x, y, todo, undulation, index, h, src, miss)
        split_range(lambda lo, hi: counts.append(_bicubic(lo, hi, *args_b)), x.size,
                    min_size=1 << 16)
    else:
        args_l = (data, inv, lattice, wrap_centre, method == NEAREST, x, y, todo, undulation,
                  index, h, src, miss)
        split_range(lambda lo, hi: counts.append(_linear(lo, hi, *args_l)), x.size,
                    min_size=1 << 16)
    return int(sum(counts))


def geoid_bilinear(nodes: np.ndarray, i0: int, j0: int, step: float, lon: np.ndarray,
                   lat: np.ndarray, todo: np.ndarray, out: np.ndarray,
                   last_row: int = 719) -> None:
    """Geoid undulation N at the ``todo`` points (flat WGS84 lon in [-180, 180), lat): the
    bilinear of ``nodes`` (N at grid nodes from row ``i0``, column ``j0``, every ``step``
    degrees, rows 0..``last_row`` from -90 deg; ``dem.geoid.nodes_between``), the float64
    numbers of ``dem.geoid``'s numpy bilinear; NaN for a point beyond the nodes. Points split
    over threads."""
    split_range(lambda lo, hi: _geoid_range(lo, hi, nodes, np.int64(i0), np.int64(j0),
                                            float(step), np.int64(last_row), lon, lat, todo,
                                            out), lon.size, min_size=1 << 16)


@njit(cache=True, nogil=True)
def _geoid_range(lo, hi, nodes, i0, j0, step, last_row, lon, lat, todo,
                 out):  # pragma: no cover
    """Points [lo, hi) of ``geoid_bilinear``."""
    n_r, n_c = nodes.shape
    for k in range(lo, hi):
        if not todo[k]:
            continue
        if not (abs(lat[k]) <= 90.0 and abs(lon[k]) <= 360.0):  # NaN or no latitude
            out[k] = math.nan
            continue
        i = min(max(math.floor((lat[k] + 90.0) / step), 0), last_row)
        j = math.floor((lon[k] + 180.0) / step)
        r = int(i) - i0
        c = int(j) - j0
        if r < 0 or c < 0 or r + 1 >= n_r or c + 1 >= n_c:
            out[k] = math.nan
            continue
        u = (lat[k] + 90.0) / step - i
        v = (lon[k] + 180.0) / step - j
        out[k] = ((1.0 - u) * ((1.0 - v) * nodes[r, c] + v * nodes[r, c + 1])
                  + u * ((1.0 - v) * nodes[r + 1, c] + v * nodes[r + 1, c + 1]))


@njit(cache=True, nogil=True)
def _linear(lo: int, hi: int, data: np.ndarray, inv: np.ndarray, lattice: np.ndarray,
            wrap_centre: float, nearest: bool, x: np.ndarray, y: np.ndarray, todo: np.ndarray,
            undulation: np.ndarray, index: int, h: np.ndarray, src: np.ndarray,
            miss: np.ndarray) -> int:
    """``window_heights`` at points [lo, hi): bilinear (2x2 posts) or ``nearest`` (the post of
    the nearest centre, as a bilinear of weights 1, 0 on that post: the same number). No
    helper calls: each costs compile time."""
    n_win_r, n_win_c = data.shape
    r_off, c_off, n_rows, n_cols = lattice[0], lattice[1], lattice[2], lattice[3]
    geoid = undulation.size > 0
    k = 0 if nearest else 1
    h_min, h_max = MIN_TERRAIN_M, MAX_TERRAIN_M
    a, b, c, d, e, f = inv[0], inv[1], inv[2], inv[3], inv[4], inv[5]
    n_miss = 0
    for i in range(lo, hi):
        if not todo[i]:
            continue
        xi = x[i]
        if abs(wrap_centre - xi) > 180.0:  # else rint(...) = 0: no division; NaN: False
            xi = xi + 360.0 * np.rint((wrap_centre - xi) / 360.0)
        cc = a * xi + b * y[i] + c - 0.5
        rr = d * xi + e * y[i] + f - 0.5
        if not (rr >= -0.5 and rr < n_rows - 0.5 and cc >= -0.5 and cc < n_cols - 0.5):
            continue
        rf, cf = math.floor(rr), math.floor(cc)
        fr, fc = rr - rf, cc - cf
        ri, ci = int(rf), int(cf)
        if nearest:
            ri, ci, fr, fc = ri + (fr >= 0.5), ci + (fc >= 0.5), 0.0, 0.0
        r_lo = min(max(ri, 0), n_rows - 1) - r_off
        c_lo = min(max(ci, 0), n_cols - 1) - c_off
        r_hi = min(ri + k, n_rows - 1) - r_off
        c_hi = min(ci + k, n_cols - 1) - c_off
        if r_lo < 0 or c_lo < 0 or r_hi >= n_win_r or c_hi >= n_win_c:
            miss[i] = True
            n_miss += 1
            continue
        v00, v01 = data[r_lo, c_lo], data[r_lo, c_hi]
        v10, v11 = data[r_hi, c_lo], data[r_hi, c_hi]
        if not (v00 >= h_min and v00 <= h_max and v01 >= h_min and v01 <= h_max
                and v10 >= h_min and v10 <= h_max and v11 >= h_min and v11 <= h_max):
            continue  # a background post (no data or implausible): the next DEM
        top = v00 * (1.0 - fc) + v01 * fc
        bottom = v10 * (1.0 - fc) + v11 * fc
        v = top * (1.0 - fr) + bottom * fr
        if geoid:
            v = v + undulation[i]
        if math.isfinite(v):
            h[i] = v
            src[i] = index
            todo[i] = False
    return n_miss


@njit(cache=True, nogil=True)
def _bicubic(lo: int, hi: int, data: np.ndarray, inv: np.ndarray, lattice: np.ndarray,
             wrap_centre: float, x: np.ndarray, y: np.ndarray, todo: np.ndarray,
             undulation: np.ndarray, index: int, h: np.ndarray, src: np.ndarray,
             miss: np.ndarray) -> int:
    """``window_heights`` at points [lo, hi), bicubic: 4x4 posts from floor - 1, Keys weights;
    each row's sum weighted by its row weight."""
    n_win_r, n_win_c = data.shape
    r_off, c_off, n_rows, n_cols = lattice[0], lattice[1], lattice[2], lattice[3]
    geoid = undulation.size > 0
    n_miss = 0
    for i in range(lo, hi):
        if not todo[i]:
            continue
        xi = x[i]  # lattice (row, col) as in _linear (written out: compile time)
        if abs(wrap_centre - xi) > 180.0:
            xi = xi + 360.0 * np.rint((wrap_centre - xi) / 360.0)
        cc = inv[0] * xi + inv[1] * y[i] + inv[2] - 0.5
        rr = inv[3] * xi + inv[4] * y[i] + inv[5] - 0.5
        if not (rr >= -0.5 and rr < n_rows - 0.5 and cc >= -0.5 and cc < n_cols - 0.5):
            continue
        rf, cf = math.floor(rr), math.floor(cc)
        ri, ci = int(rf) - 1, int(cf) - 1
        if (min(max(ri, 0), n_rows - 1) < r_off or min(max(ci, 0), n_cols - 1) < c_off
                or min(ri + 3, n_rows - 1) - r_off >= n_win_r
                or min(ci + 3, n_cols - 1) - c_off >= n_win_c):
            miss[i] = True
            n_miss += 1
            continue
        w_r = _keys_weights(rr - rf)
        w_c = _keys_weights(cc - cf)
        v = 0.0
        for p in range(4):
            rp = min(max(ri + p, 0), n_rows - 1) - r_off
            row = 0.0
            for q in range(4):
                row += _post(data, rp, min(max(ci + q, 0), n_cols - 1) - c_off) * w_c[q]
            v += row * w_r[p]
        if geoid:
            v = v + undulation[i]
        if math.isfinite(v):
            h[i] = v
            src[i] = index
            todo[i] = False
    return n_miss

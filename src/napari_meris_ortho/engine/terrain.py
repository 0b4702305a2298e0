"""DEM heights looked up in a window of posts already in memory (handbook section 3.1
"Digital elevation data", Appendix C ``TimMersynGetAltitudeFromDem``): one serial compiled
pass over the output points, no temporaries.

The window is plain data (``io.dem.LatticeWindow`` gives it; engine and io never import each
other): float32 posts, NaN = no data, and the inverse geotransform of the DEM, (a, b, c, d, e,
f) with ``col + 0.5 = a x + b y + c`` and ``row + 0.5 = d x + e y + f`` (posts at pixel
centres). Interpolation as ``io.dem.DemSource.sample``: "nearest", "bilinear" (2x2 posts),
"bicubic" (4x4 posts, Keys a = -0.5, ``geometry.interpolation``); a post outside the lattice is
clamped to its edge, a post that is no data or outside -500..9000 m makes the point no data (it
goes to the next DEM).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..geometry.earth import MAX_TERRAIN_M, MIN_TERRAIN_M
from ..geometry.interpolation import keys_weights

#: interpolation codes of :func:`window_heights` (order of ``options.Sampling``)
NEAREST, BILINEAR, BICUBIC = 0, 1, 2
METHOD_CODES = {"nearest": NEAREST, "bilinear": BILINEAR, "bicubic": BICUBIC}

_keys_weights = njit(cache=True, nogil=True, inline="always")(keys_weights)


@njit(cache=True, nogil=True, inline="always")
def _post(data: np.ndarray, r: int, c: int) -> float:
    """Post (r, c) of the window, NaN when no data or implausible (a background post)."""
    v = data[r, c]
    return float(v) if v >= MIN_TERRAIN_M and v <= MAX_TERRAIN_M else math.nan


@njit(cache=True, nogil=True)
def _weights(method: int, f: float) -> tuple[float, float, float, float]:
    """1-D weights of the posts at offsets 0..3 from the first post of ``method``'s stencil
    (nearest: 1 post, bilinear: 2, bicubic: 4 from floor - 1) for the fraction ``f``."""
    if method == BICUBIC:
        return _keys_weights(f)
    if method == BILINEAR:
        return 1.0 - f, f, 0.0, 0.0
    return 1.0, 0.0, 0.0, 0.0


@njit(cache=True, nogil=True)
def window_heights(data: np.ndarray, inv: np.ndarray, lattice: np.ndarray, wrap_centre: float,
                   method: int, x: np.ndarray, y: np.ndarray, todo: np.ndarray,
                   undulation: np.ndarray, index: int, h: np.ndarray, src: np.ndarray,
                   miss: np.ndarray) -> int:
    """Heights at the points ``todo`` (DEM coordinates ``x``, ``y``, flat float64) from the
    window ``data`` (float32 posts of the DEM lattice from row ``lattice[0]``, column
    ``lattice[1]``; lattice ``lattice[2]`` x ``lattice[3]`` posts) by the inverse geotransform
    ``inv`` (module docstring) and ``method`` (``METHOD_CODES``): sum over the stencil of
    post x column weight summed along each row, rows x row weight summed (bilinear: the
    order of ``io.dem``, the same float64 sums).

    ``wrap_centre``: geographic DEM, x is moved by whole turns of 360 deg next to it (NaN:
    none); ``undulation``: geoid N added to the heights (empty: none). Where a height is
    found: ``h`` (float32) = height + N, ``src`` = ``index``, ``todo`` cleared. Points needing
    posts outside the window are flagged in ``miss`` (the caller reads them); outside the
    lattice or no data: left ``todo``. Returns the number of ``miss`` points.
    """
    n_win_r, n_win_c = data.shape
    r_off, c_off, n_rows, n_cols = lattice[0], lattice[1], lattice[2], lattice[3]
    a, b, c, d, e, f = inv[0], inv[1], inv[2], inv[3], inv[4], inv[5]
    wrap = not math.isnan(wrap_centre)
    geoid = undulation.size > 0
    k = 4 if method == BICUBIC else (2 if method == BILINEAR else 1)
    n_miss = 0
    for i in range(x.size):
        if not todo[i]:
            continue
        xi, yi = x[i], y[i]
        if wrap and abs(wrap_centre - xi) > 180.0:  # else rint(...) = 0: no division
            xi = xi + 360.0 * np.rint((wrap_centre - xi) / 360.0)
        cc = a * xi + b * yi + c - 0.5
        rr = d * xi + e * yi + f - 0.5
        if not (rr >= -0.5 and rr < n_rows - 0.5 and cc >= -0.5 and cc < n_cols - 0.5):
            continue
        rf, cf = math.floor(rr), math.floor(cc)
        fr, fc = rr - rf, cc - cf
        ri, ci = int(rf), int(cf)
        if method == BICUBIC:
            ri, ci = ri - 1, ci - 1
        elif method == NEAREST:
            ri, ci = ri + (fr >= 0.5), ci + (fc >= 0.5)
        # first and last posts of the stencil (clamped to the lattice) inside the window?
        if (min(max(ri, 0), n_rows - 1) < r_off or min(max(ci, 0), n_cols - 1) < c_off
                or min(max(ri + k - 1, 0), n_rows - 1) - r_off >= n_win_r
                or min(max(ci + k - 1, 0), n_cols - 1) - c_off >= n_win_c):
            miss[i] = True
            n_miss += 1
            continue
        if method == BILINEAR:  # the common case unrolled: the same sums as the stencil loop
            r_a, c_a = min(max(ri, 0), n_rows - 1) - r_off, min(max(ci, 0), n_cols - 1) - c_off
            r_b = min(ri + 1, n_rows - 1) - r_off
            c_b = min(ci + 1, n_cols - 1) - c_off
            top = _post(data, r_a, c_a) * (1.0 - fc) + _post(data, r_a, c_b) * fc
            bottom = _post(data, r_b, c_a) * (1.0 - fc) + _post(data, r_b, c_b) * fc
            v = top * (1.0 - fr) + bottom * fr
        else:
            wr = _weights(method, fr)
            wc = _weights(method, fc)
            v = 0.0
            for p in range(k):
                rp = min(max(ri + p, 0), n_rows - 1) - r_off
                row = 0.0
                for q in range(k):
                    row += _post(data, rp, min(max(ci + q, 0), n_cols - 1) - c_off) * wc[q]
                v += row * wr[p]
        if geoid:
            v = v + undulation[i]
        if math.isfinite(v):
            h[i] = v
            src[i] = index
            todo[i] = False
    return n_miss

"""Lines of sight marched over a DEM window in memory (hidden ground of the pixel geolocation
with DEMs, ``ortho.occlusion``).

A ground point (lon, lat, h) sees the satellite along its look vector (tan vz sin va,
tan vz cos va) (eq. 5a-5b); at a ground distance d towards the sensor the ray is
h + d / tan vz + d^2 / (2 R) above the ellipsoid (the surface drops below the tangent plane).
The terrain is the bilinear of the DEM posts, the numbers of ``terrain.window_heights``. The
march goes from cell to cell of the lattice; in a cell the terrain minus the ray is a
quadratic in d (a line through a bilinear cell), its maximum exact: no sampling. Where the ray
is above the highest post of the tiles of T x T posts around it (T of ``TILES``, largest
first) no terrain within T - 1 posts can reach it, and it jumps that far (a maximum-mipmap
march).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..geometry.earth import MAX_TERRAIN_M, MEAN_EARTH_RADIUS, MIN_TERRAIN_M
from .threads import split_range

#: posts per side of the tiles of the march's height bounds, largest first
TILES = (32, 8, 2)
#: posts per side of the tiles of ``reachable``'s bounds, smallest first
REACH_TILES = (4, 8, 16, 32, 64, 128, 256, 512)
#: results of ``march``
SEEN, HIDDEN, UNDECIDED = 0, 1, 2


def tile_maxima(data: np.ndarray, tile: int, gaps: bool = False) -> np.ndarray:
    """The highest post (float64, -inf: none) of every ``tile`` x ``tile`` tile of the window
    and its 8 neighbours: the bound of the terrain of any cell within tile - 1 posts of it.
    ``gaps``: a post without data counts as +inf (the next DEM of a stack has heights there:
    the march must not jump over it)."""
    valid = (data >= MIN_TERRAIN_M) & (data <= MAX_TERRAIN_M)
    posts = np.where(valid, data, np.inf if gaps else -np.inf).astype(np.float64)
    nr, nc = -(-posts.shape[0] // tile), -(-posts.shape[1] // tile)
    padded = np.full((nr * tile, nc * tile), -np.inf)
    padded[:posts.shape[0], :posts.shape[1]] = posts
    tiles = padded.reshape(nr, tile, nc, tile).max(axis=(1, 3))
    grown = np.full((nr + 2, nc + 2), -np.inf)
    grown[1:-1, 1:-1] = tiles
    out = tiles.copy()
    for dr in (0, 1, 2):
        for dc in (0, 1, 2):
            np.maximum(out, grown[dr:dr + nr, dc:dc + nc], out=out)
    return out


@njit(cache=True, nogil=True)
def _march_range(lo, hi, lon, lat, h, e, n, data, inv, lattice, wrap_centre, t0, t1, t2,
                 post, ceiling, tol, gaps, track, out):  # pragma: no cover
    """Points [lo, hi) of ``march``."""
    n_win_r, n_win_c = data.shape
    r_off, c_off, n_rows, n_cols = lattice[0], lattice[1], lattice[2], lattice[3]
    a, c, e_, f = inv[0], inv[2], inv[4], inv[5]  # (north-up lattice: inv[1] = inv[3] = 0)
    radius = MEAN_EARTH_RADIUS
    for k in range(lo, hi):
        out[k] = SEEN
        tz = math.hypot(e[k], n[k])
        if not tz > 0.0 or math.isnan(h[k]):
            continue
        if track.shape[0]:  # a projected lattice: the track given
            rr0, cc0, sr, sc = track[k, 0], track[k, 1], track[k, 2], track[k, 3]
        else:
            x0 = lon[k]
            if abs(wrap_centre - x0) > 180.0:
                x0 = x0 + 360.0 * np.rint((wrap_centre - x0) / 360.0)
            # fractional post (row, col) along the ray: linear in the ground distance d
            cc0 = a * x0 + c - 0.5
            rr0 = e_ * lat[k] + f - 0.5
            sc = a * math.degrees(e[k] / tz / (radius * math.cos(math.radians(lat[k]))))
            sr = e_ * math.degrees(n[k] / tz / radius)
        d = 0.0
        while True:
            ray = h[k] + d / tz + d * d / (2.0 * radius)
            if ray >= ceiling:
                break
            rr = rr0 + d * sr
            cc = cc0 + d * sc
            ri, ci = int(math.floor(rr)), int(math.floor(cc))
            r_lo, c_lo = ri - r_off, ci - c_off
            if (ri < 0 or ci < 0 or ri + 1 >= n_rows or ci + 1 >= n_cols or r_lo < 0
                    or c_lo < 0 or r_lo + 1 >= n_win_r or c_lo + 1 >= n_win_c):
                out[k] = UNDECIDED  # the lattice's edge or posts beyond the window
                break
            if ray > t0[r_lo // 32, c_lo // 32]:  # (the sizes of TILES)
                d += 31.0 * post
                continue
            if ray > t1[r_lo // 8, c_lo // 8]:
                d += 7.0 * post
                continue
            if ray > t2[r_lo // 2, c_lo // 2]:
                d += post
                continue
            # the ray's way through the cell: s in [0, span] from d
            span = math.inf
            if sr > 0.0:
                span = (ri + 1 - rr) / sr
            elif sr < 0.0:
                span = (ri - rr) / sr
            if sc > 0.0:
                span = min(span, (ci + 1 - cc) / sc)
            elif sc < 0.0:
                span = min(span, (ci - cc) / sc)
            v00, v01 = data[r_lo, c_lo], data[r_lo, c_lo + 1]
            v10, v11 = data[r_lo + 1, c_lo], data[r_lo + 1, c_lo + 1]
            valid = (v00 >= MIN_TERRAIN_M and v00 <= MAX_TERRAIN_M and v01 >= MIN_TERRAIN_M
                     and v01 <= MAX_TERRAIN_M and v10 >= MIN_TERRAIN_M
                     and v10 <= MAX_TERRAIN_M and v11 >= MIN_TERRAIN_M
                     and v11 <= MAX_TERRAIN_M)
            if not valid and gaps:
                out[k] = UNDECIDED  # no data here: the next DEM of the stack has the terrain
                break
            if valid and max(max(v00, v01), max(v10, v11)) + tol >= ray:
                # terrain - ray along the cell: bilinear of a line minus the ray, a quadratic
                # q0 + q1 s + q2 s^2; its maximum at the ends or the vertex
                u, v = rr - ri, cc - ci
                ar, ac, kk = v10 - v00, v01 - v00, v00 - v01 - v10 + v11
                q0 = v00 + ar * u + ac * v + kk * u * v - ray
                q1 = ar * sr + ac * sc + kk * (u * sc + v * sr) - (1.0 / tz + d / radius)
                q2 = kk * sr * sc - 1.0 / (2.0 * radius)
                top = max(q0, q0 + span * (q1 + span * q2))
                if q2 < 0.0:
                    sv = -q1 / (2.0 * q2)
                    if 0.0 < sv < span:
                        top = max(top, q0 + sv * (q1 + sv * q2))
                if top > tol:
                    out[k] = HIDDEN
                    break
            d += span + 1e-3  # (1 mm into the next cell)


@njit(cache=True, nogil=True)
def _reachable_range(lo, hi, lon, lat, h, inv, lattice, shape, wrap_centre, levels, sizes,
                     ceiling, reach, tol, out):  # pragma: no cover
    """Points [lo, hi) of ``reachable``."""
    n_win_r, n_win_c = shape[0], shape[1]
    r_off, c_off = lattice[0], lattice[1]
    a, c, e_, f = inv[0], inv[2], inv[4], inv[5]
    for k in range(lo, hi):
        out[k] = False
        if math.isnan(h[k]):
            continue
        x0 = lon[k]
        if abs(wrap_centre - x0) > 180.0:
            x0 = x0 + 360.0 * np.rint((wrap_centre - x0) / 360.0)
        r = int(math.floor(e_ * lat[k] + f - 0.5)) - r_off
        cc = int(math.floor(a * x0 + c - 0.5)) - c_off
        if r < 0 or cc < 0 or r >= n_win_r or cc >= n_win_c:
            out[k] = True  # beyond the window: the march decides
            continue
        top = ceiling
        while True:
            if top <= h[k] + tol:
                break  # no terrain within reach rises above the ray by more than tol
            posts = (top - h[k]) * reach  # posts the ray crosses below ``top``
            level = -1
            for i in range(sizes.shape[0]):
                if sizes[i] - 2 >= posts:
                    level = i
                    break
            if level < 0:
                out[k] = True
                break
            t = sizes[level]
            bound = levels[level][r // t, cc // t]
            if bound >= top:
                out[k] = True  # terrain within reach may rise above the ray: march it
                break
            top = bound


def reachable(lon: np.ndarray, lat: np.ndarray, h: np.ndarray, inv: np.ndarray,
              lattice: np.ndarray, shape: tuple[int, int], wrap_centre: float,
              levels: tuple[np.ndarray, ...], ceiling: float, reach: float, tol: float
              ) -> np.ndarray:
    """True where terrain of a geographic north-up window might rise more than ``tol`` above
    the line of sight of a point (flat float64 ``lon``, ``lat``, ``h``): the points ``march``
    must decide, the others are seen. The ray rises at least 1 / tan vz per metre, so below
    a height ``top`` it crosses at most (top - h) ``reach`` posts (``reach``: the largest
    tan vz of the product per shortest post, m); the highest post of the tiles around the
    point that hold them (``levels``: ``tile_maxima`` of each of ``REACH_TILES``) lowers
    ``top`` until it is below h + tol (seen) or no tile holds the ray's way (march it): a few
    look-ups a point, no look vector, no march on plains and seas."""
    out = np.empty(lon.size, np.bool_)
    sizes = np.array(REACH_TILES[:len(levels)], np.int64)
    args = (lon, lat, h, inv, lattice, np.array(shape, np.int64), float(wrap_centre), levels,
            sizes, float(ceiling), float(reach), float(tol), out)
    split_range(lambda lo, hi: _reachable_range(lo, hi, *args), lon.size, min_size=1 << 14)
    return out


def march(lon: np.ndarray, lat: np.ndarray, h: np.ndarray, e: np.ndarray, n: np.ndarray,
          data: np.ndarray, inv: np.ndarray, lattice: np.ndarray, wrap_centre: float,
          tmax: tuple[np.ndarray, ...], post: float, ceiling: float, tol: float,
          gaps: bool = False, track: np.ndarray | None = None) -> np.ndarray:
    """Per point (flat float64 ``lon``, ``lat``, ``h``, look vector ``e``, ``n``): SEEN, HIDDEN
    (terrain more than ``tol`` m above its ray) or UNDECIDED (the ray reached posts beyond the
    window ``data``/``inv``/``lattice``/``wrap_centre``, as ``terrain.window_heights``
    takes it, before the ``ceiling``); ``tmax``: ``tile_maxima`` of each of ``TILES``;
    ``post``: no more than the shortest post spacing (m) in the window; ``gaps``: a cell with
    a post without data ends the march UNDECIDED (the window is the first DEM of a stack; its
    ``tmax`` of ``tile_maxima(..., gaps=True)``), else its ray goes on (no terrain there);
    ``track``: (n, 4) fractional post row, column of each point and their rates per metre
    towards the sensor (a projected lattice, ``ortho.occlusion``), else from lon, lat."""
    out = np.empty(lon.size, np.int8)
    args = (lon, lat, h, e, n, data, inv, lattice, float(wrap_centre), *tmax, float(post),
            float(ceiling), float(tol), bool(gaps),
            np.zeros((0, 4)) if track is None else np.ascontiguousarray(track, np.float64), out)
    split_range(lambda lo, hi: _march_range(lo, hi, *args), lon.size, min_size=1 << 12)
    return out

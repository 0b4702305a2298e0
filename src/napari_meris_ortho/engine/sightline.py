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
#: a relative bound (m) of ``horizon_bound`` at or below this: the terrain cannot rise
#: above the ray (the callers' tolerance is larger)
TOLERANCE_FREE = 0.0
#: cells per side of the tiles of ``horizon_bound``'s bounds of the view zenith
VIEW_TILE = 32
#: rows of cells of the bands ``horizon_bound`` sweeps at the same time (at least), and the
#: rows of the neighbouring bands each takes as its edge
BAND_ROWS, BAND_HALO = 256, 64
#: results of ``march``
SEEN, HIDDEN, UNDECIDED = 0, 1, 2


@njit(cache=True, nogil=True)
def _post_tiles(data, tile, gaps, i_lo, i_hi, out):  # pragma: no cover
    """The highest valid post of each ``tile`` x ``tile`` tile of ``data`` in tile rows
    [``i_lo``, ``i_hi``) into ``out`` (-inf: none; a post without data +inf with ``gaps``)."""
    nr, nc = data.shape
    for i in range(i_lo, i_hi):
        for j in range(out.shape[1]):
            out[i, j] = -np.inf
    for r in range(i_lo * tile, min(i_hi * tile, nr)):
        i = r // tile
        for j in range(out.shape[1]):  # a tile's posts of the row, no division a post
            m = out[i, j]
            for c in range(j * tile, min((j + 1) * tile, nc)):
                v = data[r, c]
                if v >= MIN_TERRAIN_M and v <= MAX_TERRAIN_M:
                    if v > m:
                        m = v
                elif gaps:
                    m = np.inf
            out[i, j] = m


@njit(cache=True, nogil=True)
def _grown(tiles, out):  # pragma: no cover
    """Each tile's maximum with its 8 neighbours' into ``out`` (a row's 3, then a column's)."""
    nr, nc = tiles.shape
    row = np.empty(nc)
    for i in range(nr):
        for j in range(nc):
            m = tiles[i, j]
            if j > 0 and tiles[i, j - 1] > m:
                m = tiles[i, j - 1]
            if j + 1 < nc and tiles[i, j + 1] > m:
                m = tiles[i, j + 1]
            out[i, j] = m
    prev = np.full(nc, -np.inf)
    for i in range(nr):
        for j in range(nc):
            row[j] = out[i, j]
        for j in range(nc):
            m = row[j]
            if prev[j] > m:
                m = prev[j]
            if i + 1 < nr and out[i + 1, j] > m:
                m = out[i + 1, j]
            out[i, j] = m
        for j in range(nc):
            prev[j] = row[j]


@njit(cache=True, nogil=True)
def _coarser(raw, k, out):  # pragma: no cover
    """The maximum of each ``k`` x ``k`` block of ``raw`` into ``out``."""
    nr, nc = raw.shape
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            m = -np.inf
            for a in range(i * k, min((i + 1) * k, nr)):
                for b in range(j * k, min((j + 1) * k, nc)):
                    if raw[a, b] > m:
                        m = raw[a, b]
            out[i, j] = m


def tile_maxima(data: np.ndarray, gaps: bool = False) -> tuple[np.ndarray, ...]:
    """For each tile size of ``TILES`` (largest first), the highest post (float64, -inf: none)
    of every tile x tile tile of the window and its 8 neighbours: the bound of the terrain of
    any cell within tile - 1 posts of it. ``gaps``: a post without data counts as +inf (the
    next DEM of a stack has heights there: the march must not jump over it). Each size from
    the next smaller one's own maxima."""
    sizes = sorted(TILES)
    raw = np.empty((-(-data.shape[0] // sizes[0]), -(-data.shape[1] // sizes[0])))
    split_range(lambda lo, hi: _post_tiles(data, sizes[0], gaps, lo, hi, raw), raw.shape[0],
                min_size=max(256 // sizes[0], 1), pieces_per_thread=1)
    out = {}
    for n, tile in enumerate(sizes):
        if n:
            k = tile // sizes[n - 1]
            coarse = np.empty((-(-raw.shape[0] // k), -(-raw.shape[1] // k)))
            _coarser(raw, k, coarse)
            raw = coarse
        out[tile] = np.empty_like(raw)
        _grown(raw, out[tile])
    return tuple(out[t] for t in TILES)


@njit(cache=True, nogil=True)
def _march_range(lo, hi, lon, lat, h, e, n, data, inv, lattice, wrap_centre, jumps, t0, t1, t2,
                 post, ceiling, tol, gaps, track, bound, col, near_lo, near_hi,
                 out):  # pragma: no cover
    """Points [lo, hi) of ``march``."""
    n_win_r, n_win_c = data.shape
    bounded = bound.shape[0] > 0
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
            if bounded and not near_lo <= col[k] <= near_hi and ray + tol >= bound[r_lo, c_lo]:
                break  # seen from this cell on (``horizon_bound``)
            if jumps:
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


@njit(cache=True, nogil=True, inline="always")
def _post(v, gap):  # pragma: no cover
    """A post's height, ``gap`` without data."""
    return v if v >= MIN_TERRAIN_M and v <= MAX_TERRAIN_M else gap


#: columns of posts a sweep reads (and of bounds it writes) at a time
STRIP = 64


@njit(cache=True, nogil=True, inline="always")
def _strip(data, row0, n_r, j, step, gap, strip, s0):  # pragma: no cover
    """The strip of ``_horizon_sweep`` holding post column ``j`` (its first column ``s0``):
    itself, or the next one the sweep (``step``) reads, its posts as ``_post`` gives them."""
    if s0 <= j < s0 + STRIP:
        return s0
    s0 = max(j - STRIP + 1, 0) if step > 0 else j
    s1 = min(s0 + STRIP, data.shape[1])
    for r in range(n_r + 1):
        for jj in range(s0, s1):
            strip[jj - s0, r] = _post(data[row0 + r, jj], gap)
    return s0


@njit(cache=True, nogil=True)
def _fold(out, row0, k0, k1, folds, f0):  # pragma: no cover
    """The bounds ``folds`` of ``_horizon_sweep``'s columns from ``f0`` (none before the
    first strip) folded into ``out`` by their maximum, rows ``k0`` .. ``k1`` of the band."""
    if f0 < 0:
        return
    f1 = min(f0 + STRIP, out.shape[1])
    for r in range(k0, k1):
        for jj in range(f0, f1):
            v = folds[jj - f0, r]
            if v > out[row0 + r, jj]:
                out[row0 + r, jj] = v


@njit(cache=True, nogil=True)
def _horizon_sweep(data, row0, n_r, gaps, step, ceiling, low, col_m, row_m, tan_vz, tile, c_lo,
                   c_hi, keep, out):  # pragma: no cover
    """One direction (``step`` +1: east, -1: west) of ``horizon_bound`` over the ``n_r`` rows of
    cells of the window ``data`` from row ``row0`` (a band), columns ``c_lo`` .. ``c_hi`` of cells
    swept from the far end; ``tan_vz`` the tiles' bounds of tan vz (``view_tiles``, 0: no line
    of sight this way); the bounds of the band's rows ``keep`` (first, last + 1; the others
    are its edge) folded into ``out`` (row, column) by their maximum."""
    gap = ceiling if gaps else -np.inf
    path = math.hypot(col_m, row_m)  # the longest way of a ray across a column
    rel_edge = ceiling - low
    prev_abs = np.full(n_r, ceiling)  # the bounds the column before gives (read), this one's
    prev_rel = np.full(n_r, rel_edge)
    next_abs = np.empty(n_r)
    next_rel = np.empty(n_r)
    hi = np.empty(n_r)
    lo = np.empty(n_r)
    slope = np.empty(n_r)
    top_r = np.empty(n_r)
    span_r = np.empty(n_r)
    steep_r = np.empty(n_r)
    near_abs = np.empty(n_r)
    near_rel = np.empty(n_r)
    tz_r = np.zeros(n_r)  # the rows' tan vz and its inverse (0: no line of sight this way)
    inv_r = np.zeros(n_r)
    west = np.empty(n_r + 1)  # the posts of the cells' west and east sides
    east = np.empty(n_r + 1)
    k0, k1 = max(keep[0], 0), min(keep[1], n_r)
    # the posts read by strips of STRIP columns, a row's run at a time (a column read in place
    # would touch a page per row); the bounds written so too
    strip = np.empty((STRIP, n_r + 1))
    folds = np.full((STRIP, n_r), -np.inf)  # the bounds of columns f0 .. f0 + STRIP - 1
    f0 = s0 = -STRIP - 2  # (no strip yet)
    c = c_hi if step > 0 else c_lo
    j = c + 1 if step > 0 else c  # the first column's far side
    s0 = _strip(data, row0, n_r, j, step, gap, strip, s0)
    west[:] = strip[j - s0]
    tc = -1
    while c_lo <= c <= c_hi:
        if c // tile != tc:  # a new column of tiles: the rows' tan vz
            tc = c // tile
            for r in range(n_r):
                tz = tan_vz[tc, (r + row0) // tile]
                tz_r[r] = tz if tz > 0.0 else 0.0
                inv_r[r] = 1.0 / tz if tz > 0.0 else 0.0
        if step > 0:  # (the side shared with the column before)
            east, west = west, east
            s0 = _strip(data, row0, n_r, c, step, gap, strip, s0)
            west[:] = strip[c - s0]
        else:
            s0 = _strip(data, row0, n_r, c + 1, step, gap, strip, s0)
            east[:] = strip[c + 1 - s0]
        for r in range(n_r):  # each cell: its highest and lowest post, its steepest slope
            v00, v01, v10, v11 = west[r], east[r], west[r + 1], east[r + 1]
            hi[r] = max(max(v00, v01), max(v10, v11))
            lo[r] = min(min(v00, v01), min(v10, v11))
            gx = max(abs(v01 - v00), abs(v11 - v10)) / col_m
            gy = max(abs(v10 - v00), abs(v11 - v01)) / row_m
            g = math.sqrt(gx * gx + gy * gy)
            slope[r] = g if g == g else math.inf
        # the cell and its neighbours north and south (the window's first and last rows:
        # anything), and the next column's bounds at the rows the ray may enter it at
        top_r[0] = top_r[n_r - 1] = ceiling
        span_r[0] = span_r[n_r - 1] = rel_edge
        steep_r[0] = steep_r[n_r - 1] = math.inf
        near_abs[0] = near_abs[n_r - 1] = ceiling
        near_rel[0] = near_rel[n_r - 1] = rel_edge
        for r in range(1, n_r - 1):
            top = max(max(hi[r - 1], hi[r]), hi[r + 1])
            span = top - min(min(lo[r - 1], lo[r]), lo[r + 1])
            top_r[r] = top
            span_r[r] = span if span < rel_edge else rel_edge
            steep_r[r] = max(max(slope[r - 1], slope[r]), slope[r + 1])
            near_abs[r] = max(max(prev_abs[r - 1], prev_abs[r]), prev_abs[r + 1])
            near_rel[r] = max(max(prev_rel[r - 1], prev_rel[r]), prev_rel[r + 1])
        if not f0 <= c < f0 + STRIP:  # (written a row's run at a time, as read)
            _fold(out, row0, k0, k1, folds, f0)
            f0 = max(c - STRIP + 1, 0) if step > 0 else c
            folds[:] = -np.inf
        fold = folds[c - f0]  # this column's cells' bounds, -inf: none
        for r in range(n_r):
            top, span, steep = top_r[r], span_r[r], steep_r[r]
            tz, inv = tz_r[r], inv_r[r]
            rises = steep * tz >= 1.0
            within = min(span, (steep - inv) * path) if rises else 0.0
            gain = within if rises else (steep - inv) * col_m
            # a point of the cell: the terrain of its column, then the next column's bounds
            pa = max(top, near_abs[r])
            pr = max(near_rel[r], 0.0) + within
            seen = tz > 0.0
            fold[r] = pa if seen and min(pr, rel_edge) > TOLERANCE_FREE else -np.inf
            # crossing the whole column: the ray rises at least col_m / tan vz; the terrain
            # gains at most its span (steep) or (slope - 1 / tan vz) x width (gentle) on it;
            # no line of sight this way: the cell's terrain for the next
            next_abs[r] = min(max(top, near_abs[r] - col_m * inv), ceiling) if seen else top
            next_rel[r] = min(max(within, near_rel[r] + gain), rel_edge) if seen else 0.0
        prev_abs, next_abs = next_abs, prev_abs
        prev_rel, next_rel = next_rel, prev_rel
        if step < 0:  # the east side is the next column's west side
            east, west = west, east
        c -= step
    _fold(out, row0, k0, k1, folds, f0)


@njit(cache=True, nogil=True)
def _view_tiles(row, col, tz, east, pad_r, pad_c, tile, out_east, out_west):  # pragma: no cover
    """``view_tiles`` into ``out_east``/``out_west`` (tile column, tile row)."""
    n_i, n_k = tz.shape
    n_tc, n_tr = out_east.shape
    for i in range(max(n_i - 1, 1)):
        i1 = min(i + 1, n_i - 1)
        for k in range(max(n_k - 1, 1)):
            k1 = min(k + 1, n_k - 1)
            r_min, r_max, c_min, c_max = np.inf, -np.inf, np.inf, -np.inf
            m = 0.0
            to_east = to_west = False
            for ii, kk in ((i, k), (i, k1), (i1, k), (i1, k1)):
                r, c, t, e = row[ii, kk], col[ii, kk], tz[ii, kk], east[ii, kk]
                if not (math.isfinite(r) and math.isfinite(c) and math.isfinite(t)):
                    continue
                r_min, r_max = min(r_min, r), max(r_max, r)
                c_min, c_max = min(c_min, c), max(c_max, c)
                m = max(m, t)
                to_east = to_east or e > 0.0
                to_west = to_west or e < 0.0
            if not m > 0.0:
                continue
            tr0 = max(int(math.floor((r_min - pad_r) / tile)), 0)
            tr1 = min(int(math.floor((r_max + pad_r) / tile)), n_tr - 1)
            tc0 = max(int(math.floor((c_min - pad_c) / tile)), 0)
            tc1 = min(int(math.floor((c_max + pad_c) / tile)), n_tc - 1)
            for tc in range(tc0, tc1 + 1):
                for tr in range(tr0, tr1 + 1):
                    if to_east and out_east[tc, tr] < m:
                        out_east[tc, tr] = m
                    if to_west and out_west[tc, tr] < m:
                        out_west[tc, tr] = m


def view_tiles(row: np.ndarray, col: np.ndarray, tan_vz: np.ndarray, east: np.ndarray,
               cells: tuple[int, int], pad: tuple[float, float], tile: int = VIEW_TILE
               ) -> tuple[np.ndarray, np.ndarray]:
    """The largest tan vz of the lines of sight going east, and west, within each tile of
    ``tile`` x ``tile`` cells of a window of ``cells`` (rows, columns): per tie-point cell,
    the largest tan vz of its four corners (a bilinear look vector is no longer than the
    longest of its corners, eq. 5a-5b), over the box of their positions (``row``, ``col``:
    fractional cell indices) grown by ``pad`` (cells: rows, columns) -- the reach of its
    points' lines of sight and the parallax of their positions. ``east``: the tie points'
    eastward look component (its sign the direction). float64 arrays (tile column, tile
    row), 0 where no line of sight goes that way."""
    shape = (-(-max(cells[1], 1) // tile), -(-max(cells[0], 1) // tile))
    out_east, out_west = np.zeros(shape), np.zeros(shape)
    _view_tiles(*(np.ascontiguousarray(a, np.float64) for a in (row, col, tan_vz, east)),
                float(pad[0]), float(pad[1]), int(tile), out_east, out_west)
    return out_east, out_west


@njit(cache=True, nogil=True)
def _lowest_post(data, r0, r1):  # pragma: no cover
    """The lowest valid post of rows [r0, r1) of ``data`` (inf: none)."""
    low = np.inf
    for r in range(r0, r1):
        for c in range(data.shape[1]):
            v = data[r, c]
            if v >= MIN_TERRAIN_M and v < low:
                low = v
    return float(low)


@njit(cache=True, nogil=True)
def lowest_finite(data):  # pragma: no cover
    """The lowest finite value of ``data`` (2-D; inf: none), in one pass without masks."""
    low = np.inf
    for r in range(data.shape[0]):
        for c in range(data.shape[1]):
            v = data[r, c]
            if v < low and v > -np.inf:
                low = v
    return float(low)


def horizon_bound(data: np.ndarray, ceiling: float, gaps: bool, spacing: tuple[float, float],
                  tan_vz: tuple[np.ndarray, np.ndarray], tile: int = VIEW_TILE) -> np.ndarray:
    """Per cell of a window (posts r..r+1, c..c+1; float32, indexed [r, c] as ``data``,
    one row and column fewer than ``data``): a height such that a point of the cell above it
    (by the tolerance) is seen, -inf where every point of it is (``reachable``: no march).

    Lines of sight go east and west within 45 degrees of a row of cells (they cross less
    than a row while they cross a column, ``spacing`` = the shortest (column, row) post
    spacing, m, holds them in the cell's column and its neighbours north and south), those
    through a tile of ``tile`` x ``tile`` cells no flatter than ``tan_vz`` (east, west:
    ``view_tiles``) gives there: they rise at least 1 / tan vz per metre. Two bounds, swept
    against the direction column by column over the columns where such lines of sight are:
    the highest terrain the ray can meet less the least it has risen by then (a column's
    width / tan vz a column), and the most the terrain can rise above the ray relative to
    the point: nothing across columns whose bilinear slopes less than the ray rises (the ray
    leaves such terrain), their span elsewhere. Beyond the columns swept and, with ``gaps``,
    on posts without data (the next DEM of a stack has heights there) the terrain may reach
    ``ceiling``. Bands of rows are swept at the same time (``split_range``), each with
    ``BAND_HALO`` rows of the next as its edge: there the terrain may reach the ceiling too
    (a looser bound near the seam, never a wrong one)."""
    data = np.ascontiguousarray(data, np.float32)
    n_c, n_r = max(data.shape[1] - 1, 0), max(data.shape[0] - 1, 0)
    out = np.empty((n_r, n_c), np.float32)  # (filled by the bands, in their threads)
    sweeps = []
    for step, tz in ((1, tan_vz[0]), (-1, tan_vz[1])):
        used = np.flatnonzero((tz > 0.0).any(axis=1))
        if used.size and out.size:
            c_hi = min((int(used[-1]) + 1) * tile, n_c) - 1
            sweeps.append((step, np.ascontiguousarray(tz, np.float64), int(used[0]) * tile,
                           c_hi))
    if not sweeps:
        out.fill(-np.inf)
        return out

    def band(lo: int, hi: int) -> None:
        out[lo:hi] = -np.inf
        r0, r1 = max(lo - BAND_HALO, 0), min(hi + BAND_HALO, n_r)
        low = _lowest_post(data, r0, r1 + 1)
        for step, tz, c_lo, c_hi in sweeps:
            if c_lo <= c_hi:
                _horizon_sweep(data, r0, r1 - r0, bool(gaps), step, float(ceiling),
                               low if math.isfinite(low) else 0.0, float(spacing[0]),
                               float(spacing[1]), tz, int(tile), c_lo, c_hi,
                               (lo - r0, hi - r0), out)

    split_range(band, n_r, min_size=BAND_ROWS, pieces_per_thread=1)
    return out


@njit(cache=True, nogil=True, inline="always")
def _cell_row(lat, inv, lattice):  # pragma: no cover
    """The window row of cells holding latitude ``lat`` (-1 without a position)."""
    v = math.floor(inv[4] * lat + inv[5] - 0.5)
    return int(v) - lattice[0] if math.isfinite(v) else -1


@njit(cache=True, nogil=True, inline="always")
def _cell_col(lon, inv, lattice, wrap_centre):  # pragma: no cover
    """The window column of cells holding longitude ``lon``, taken on the turn nearest
    ``wrap_centre`` (-1 without a position)."""
    if abs(wrap_centre - lon) > 180.0:
        lon = lon + 360.0 * np.rint((wrap_centre - lon) / 360.0)
    v = math.floor(inv[0] * lon + inv[2] - 0.5)
    return int(v) - lattice[1] if math.isfinite(v) else -1


@njit(cache=True, nogil=True, inline="always")
def _marched(hk, colk, itk, r, cc, bound, tol, near_lo, near_hi):  # pragma: no cover
    """Whether a point (height ``hk``, antecedent column ``colk``, iterations ``itk``) in the
    window's cell (``r``, ``cc``) is marched: solved, with a height, and near nadir, beyond
    the window or below its ``bound`` (without branches)."""
    n_r, n_c = bound.shape
    inside = 0 <= r < n_r and 0 <= cc < n_c
    high = bound[min(max(r, 0), n_r - 1), min(max(cc, 0), n_c - 1)] > hk + tol
    go = (near_lo <= colk <= near_hi) or not inside or high
    return itk >= 0 and math.isfinite(hk) and go


@njit(cache=True, nogil=True)
def _reachable_range(lo, hi, lon, lat, h, inv, lattice, wrap_centre, bound, tol,
                     out):  # pragma: no cover
    """Points [lo, hi) of ``reachable``."""
    n_r, n_c = bound.shape
    for k in range(lo, hi):
        r = _cell_row(lat[k], inv, lattice)
        cc = _cell_col(lon[k], inv, lattice, wrap_centre)
        if r < 0 or cc < 0 or r >= n_r or cc >= n_c:
            out[k] = True  # beyond the window: the march decides
        else:
            out[k] = bound[r, cc] > h[k] + tol


def reachable(lon: np.ndarray, lat: np.ndarray, h: np.ndarray, inv: np.ndarray,
              lattice: np.ndarray, wrap_centre: float, bound: np.ndarray, tol: float
              ) -> np.ndarray:
    """True where terrain might rise more than ``tol`` above the line of sight of a point
    (flat float64 ``lon``, ``lat``, ``h`` on a geographic north-up window, as ``march``
    takes them; ``bound``: ``horizon_bound`` of the window): the points ``march`` must
    decide; the others are seen. One look-up a point (``bound`` indexed [row, column]): no
    march on plains, seas and the slopes that face the sensor."""
    out = np.empty(lon.size, np.bool_)
    args = (lon, lat, h, inv, lattice, float(wrap_centre), bound, float(tol), out)
    split_range(lambda lo, hi: _reachable_range(lo, hi, *args), lon.size, min_size=1 << 14)
    return out


@njit(cache=True, nogil=True)
def _to_march(lo, hi, lon, lat, h, col, iters, inv, lattice, wrap_centre, bound, tol, near_lo,
              near_hi, out):  # pragma: no cover
    """``to_march`` of points [lo, hi) into ``out[lo:]``; their number (without branches on
    the points: each index written, the count moved on by the ones kept)."""
    m = lo
    for k in range(lo, hi):
        r = _cell_row(lat[k], inv, lattice)
        cc = _cell_col(lon[k], inv, lattice, wrap_centre)
        out[m] = k
        m += 1 if _marched(h[k], col[k], iters[k], r, cc, bound, tol, near_lo, near_hi) else 0
    return m - lo


def to_march(lon: np.ndarray, lat: np.ndarray, h: np.ndarray, col: np.ndarray,
             iters: np.ndarray, inv: np.ndarray, lattice: np.ndarray, wrap_centre: float,
             bound: np.ndarray, tol: float, near: tuple[float, float]) -> np.ndarray:
    """The indices of the flat points (``lon``, ``lat``, ``h``; antecedent column ``col``,
    ``iters`` of the solution) whose rays ``march`` must decide: solved (``iters`` >= 0),
    with a height, and ``reachable`` or at a column within ``near`` (near nadir) -- one pass
    over a block, no masks."""
    out = np.empty(lon.size, np.int64)
    found: dict[int, int] = {}

    def part(lo: int, hi: int) -> None:
        found[lo] = _to_march(lo, hi, lon, lat, h, col, iters, inv, lattice, float(wrap_centre),
                              bound, float(tol), float(near[0]), float(near[1]), out)

    split_range(part, lon.size, min_size=1 << 16, pieces_per_thread=1)
    return np.concatenate([out[lo:lo + found[lo]] for lo in sorted(found)] or [out[:0]])


@njit(cache=True, nogil=True)
def _to_march_rows(lo, hi, cell_row, cell_col, h, col, iters, bound, tol, near_lo, near_hi,
                   out):  # pragma: no cover
    """``to_march_grid`` of the rows [lo, hi) into ``out[lo * columns:]``; their number."""
    n_cols = cell_col.size
    m = lo * n_cols
    for i in range(lo, hi):
        r = cell_row[i]
        for j in range(n_cols):
            out[m] = i * n_cols + j
            m += 1 if _marched(h[i, j], col[i, j], iters[i, j], r, cell_col[j], bound, tol,
                               near_lo, near_hi) else 0
    return m - lo * n_cols


@njit(cache=True, nogil=True)
def _grid_cells(lon, lat, inv, lattice, wrap_centre, cell_row, cell_col):  # pragma: no cover
    """The window's cells of a geographic grid's rows (``lat``) and columns (``lon``)."""
    for i in range(lat.size):
        cell_row[i] = _cell_row(lat[i], inv, lattice)
    for j in range(lon.size):
        cell_col[j] = _cell_col(lon[j], inv, lattice, wrap_centre)


def to_march_grid(lon: np.ndarray, lat: np.ndarray, h: np.ndarray, col: np.ndarray,
                  iters: np.ndarray, inv: np.ndarray, lattice: np.ndarray, wrap_centre: float,
                  bound: np.ndarray, tol: float, near: tuple[float, float]) -> np.ndarray:
    """``to_march`` of the points of a block of a geographic grid, (rows, columns) arrays
    ``h``, ``col``, ``iters``, whose longitude is ``lon`` in every row and latitude ``lat``
    in every column: the cells of the window found once a row and a column, as ``to_march``
    finds them a point (flat indices of the block)."""
    lon, lat = (np.ascontiguousarray(a, np.float64) for a in (lon, lat))
    cell_row, cell_col = np.empty(lat.size, np.int64), np.empty(lon.size, np.int64)
    _grid_cells(lon, lat, inv, lattice, float(wrap_centre), cell_row, cell_col)
    out = np.empty(h.size, np.int64)
    found: dict[int, int] = {}

    def part(lo: int, hi: int) -> None:
        found[lo] = _to_march_rows(lo, hi, cell_row, cell_col, h, col, iters, bound, float(tol),
                                   float(near[0]), float(near[1]), out)

    n_cols = max(cell_col.size, 1)
    split_range(part, h.shape[0], min_size=max((1 << 16) // n_cols, 1), pieces_per_thread=1)
    return np.concatenate([out[lo * n_cols:lo * n_cols + found[lo]] for lo in sorted(found)]
                          or [out[:0]])


def march(lon: np.ndarray, lat: np.ndarray, h: np.ndarray, e: np.ndarray, n: np.ndarray,
          data: np.ndarray, inv: np.ndarray, lattice: np.ndarray, wrap_centre: float,
          tmax: tuple[np.ndarray, ...], post: float, ceiling: float, tol: float,
          gaps: bool = False, track: np.ndarray | None = None,
          bound: np.ndarray | None = None, col: np.ndarray | None = None,
          near: tuple[float, float] = (math.inf, -math.inf)) -> np.ndarray:
    """Per point (flat float64 ``lon``, ``lat``, ``h``, look vector ``e``, ``n``): SEEN, HIDDEN
    (terrain more than ``tol`` m above its ray) or UNDECIDED (the ray reached posts beyond the
    window ``data``/``inv``/``lattice``/``wrap_centre``, as ``terrain.window_heights``
    takes it, before the ``ceiling``); ``tmax``: ``tile_maxima`` of each of ``TILES``;
    ``post``: no more than the shortest post spacing (m) in the window; ``gaps``: a cell with
    a post without data ends the march UNDECIDED (the window is the first DEM of a stack; its
    ``tmax`` of ``tile_maxima(..., gaps=True)``), else its ray goes on (no terrain there);
    ``track``: (n, 4) fractional post row, column of each point and their rates per metre
    towards the sensor (a projected lattice, ``ortho.occlusion``), else from lon, lat;
    ``bound``: the window's ``horizon_bound``, where a ray that comes within ``tol`` of it
    is seen (points of antecedent column ``col`` within ``near``, whose lines of sight it
    leaves out, excepted); ``tmax`` may then be empty (no jumps: the bound ends the rays)."""
    out = np.empty(lon.size, np.int8)
    jumps = len(tmax) == len(TILES)
    none = np.full((1, 1), np.inf)
    args = (lon, lat, h, e, n, data, inv, lattice, float(wrap_centre), jumps,
            *(tmax if jumps else (none,) * len(TILES)), float(post), float(ceiling), float(tol),
            bool(gaps),
            np.zeros((0, 4)) if track is None else np.ascontiguousarray(track, np.float64),
            np.full((0, 0), np.inf, np.float32) if bound is None else bound,
            np.zeros(0) if col is None else np.ascontiguousarray(col, np.float64),
            float(near[0]), float(near[1]), out)
    split_range(lambda lo, hi: _march_range(lo, hi, *args), lon.size, min_size=1 << 12)
    return out

"""MERIS product grid and line-of-sight geometry (handbook section 2.2, fig. 5, 8, 11).

Product line ``l`` is the frame at time ``t0 + l * frame_time``. Its ground line is the section of
the WGS84 ellipsoid by the plane through the satellite S(t) perpendicular to the ground-track
velocity (the horizontal part, at the geodetic nadir N(t), of the Earth-fixed velocity); that plane
contains the local vertical at N, so the view zenith is exactly 0 at nadir. In that plane a line of
sight is ``d(psi) = cos(psi) (-n) + sin(psi) x`` with ``x = v x n`` pointing to the right of the
flight direction. Product column ``j`` is the point E of the section whose arc length from N is
``(first_column + j) * spacing`` (signed, positive to the right): columns evenly spaced on the
ground, stored left-to-right of the flight direction, i.e. in detector (chronological) order
(East to West on a descending pass, as in Appendix E).

Everything here is numba; angles in radians inside, degrees at the Python boundary.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..geometry.earth import WGS84_A, WGS84_B
from .orbit import (
    ecef_to_geodetic,
    geodetic_to_ecef,
    orbit_state,
)

#: width (rad) of the quadrature panels of the ground arc length
PANEL = math.radians(1.0)
_GL_X = np.array([-0.9061798459386640, -0.5384693101056831, 0.0,
                  0.5384693101056831, 0.9061798459386640])
_GL_W = np.array([0.2369268850561891, 0.4786286704993665, 0.5688888888888889,
                  0.4786286704993665, 0.2369268850561891])

# grid parameter vector: t0, frame_time, spacing, first_column
G_T0, G_DT, G_SPACING, G_FIRST = 0, 1, 2, 3
# DEM geo vector: lon of first (west) post, lat of first (north) post, dlon, dlat,
#                 block size of the max grid, minimum post spacing (m), h_min, h_max
D_LON0, D_LAT0, D_DLON, D_DLAT, D_BLOCK, D_SPMIN, D_HMIN, D_HMAX = range(8)
#: ratio of the coarse to the fine block size of the block-maximum grids
FINE_DIV = 4


@njit(cache=True)
def frame_basis(orb: np.ndarray, t: float, out: np.ndarray) -> None:
    """Fill ``out`` (4, 3): S, unit ground-track velocity v, unit nadir normal n, x = v x n."""
    pos = np.empty(3)
    vel = np.empty(3)
    orbit_state(orb, t, pos, vel)
    lon, lat, _ = ecef_to_geodetic(pos[0], pos[1], pos[2])
    lo = math.radians(lon)
    la = math.radians(lat)
    n0, n1, n2 = math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)
    vn = vel[0] * n0 + vel[1] * n1 + vel[2] * n2
    v0, v1, v2 = vel[0] - vn * n0, vel[1] - vn * n1, vel[2] - vn * n2
    norm = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    v0, v1, v2 = v0 / norm, v1 / norm, v2 / norm
    out[0, 0], out[0, 1], out[0, 2] = pos[0], pos[1], pos[2]
    out[1, 0], out[1, 1], out[1, 2] = v0, v1, v2
    out[2, 0], out[2, 1], out[2, 2] = n0, n1, n2
    out[3, 0] = v1 * n2 - v2 * n1
    out[3, 1] = v2 * n0 - v0 * n2
    out[3, 2] = v0 * n1 - v1 * n0


@njit(cache=True)
def look_direction(basis: np.ndarray, psi: float, d: np.ndarray) -> None:
    """Unit line of sight at in-plane angle ``psi`` (rad, positive to the right)."""
    c, s = math.cos(psi), math.sin(psi)
    for k in range(3):
        d[k] = -c * basis[2, k] + s * basis[3, k]


@njit(cache=True)
def ray_ellipsoid(s0: np.ndarray, d: np.ndarray, h: float) -> float:
    """Distance along the ray from ``s0`` to the near intersection with the ellipsoid
    of semi-axes (a + h, b + h); NaN when the ray misses it."""
    a2 = (WGS84_A + h) ** 2
    b2 = (WGS84_B + h) ** 2
    qa = (d[0] * d[0] + d[1] * d[1]) / a2 + d[2] * d[2] / b2
    qb = 2.0 * ((s0[0] * d[0] + s0[1] * d[1]) / a2 + s0[2] * d[2] / b2)
    qc = (s0[0] * s0[0] + s0[1] * s0[1]) / a2 + s0[2] * s0[2] / b2 - 1.0
    disc = qb * qb - 4.0 * qa * qc
    if disc < 0.0:
        return np.nan
    return (-qb - math.sqrt(disc)) / (2.0 * qa)


@njit(cache=True)
def arc_rate(basis: np.ndarray, psi: float) -> float:
    """|dE/dpsi| (m/rad): speed of the ellipsoid point E(psi) along the ground line."""
    d = np.empty(3)
    look_direction(basis, psi, d)
    c, s = math.cos(psi), math.sin(psi)
    dd0 = s * basis[2, 0] + c * basis[3, 0]
    dd1 = s * basis[2, 1] + c * basis[3, 1]
    dd2 = s * basis[2, 2] + c * basis[3, 2]
    sl = ray_ellipsoid(basis[0], d, 0.0)
    e0 = basis[0, 0] + sl * d[0]
    e1 = basis[0, 1] + sl * d[1]
    e2 = basis[0, 2] + sl * d[2]
    a2 = WGS84_A * WGS84_A
    b2 = WGS84_B * WGS84_B
    g0, g1, g2 = e0 / a2, e1 / a2, e2 / b2
    ds = -sl * (g0 * dd0 + g1 * dd1 + g2 * dd2) / (g0 * d[0] + g1 * d[1] + g2 * d[2])
    t0 = ds * d[0] + sl * dd0
    t1 = ds * d[1] + sl * dd1
    t2 = ds * d[2] + sl * dd2
    return math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)


@njit(cache=True)
def arc_integral(basis: np.ndarray, psi_a: float, psi_b: float) -> float:
    """Ground arc length (m, signed) of E(psi) between ``psi_a`` and ``psi_b`` (Gauss-Legendre)."""
    half = 0.5 * (psi_b - psi_a)
    mid = 0.5 * (psi_b + psi_a)
    acc = 0.0
    for k in range(_GL_X.size):
        acc += _GL_W[k] * arc_rate(basis, mid + half * _GL_X[k])
    return acc * half


@njit(cache=True)
def ground_distance(basis: np.ndarray, psi: float) -> float:
    """Signed ground arc length (m) from the nadir N to E(psi): whole panels then the rest."""
    sign = 1.0 if psi >= 0.0 else -1.0
    a = abs(psi)
    n_full = int(a / PANEL)
    g = 0.0
    for k in range(n_full):
        g += arc_integral(basis, sign * k * PANEL, sign * (k + 1) * PANEL) * sign
    g += arc_integral(basis, sign * n_full * PANEL, psi) * sign
    return sign * g


@njit(cache=True)
def look_angle_of_distance(basis: np.ndarray, g: float) -> float:
    """In-plane angle psi whose ellipsoid point lies at signed ground distance ``g`` (Newton)."""
    sign = 1.0 if g >= 0.0 else -1.0
    target = abs(g)
    # walk whole panels, then Newton inside the last one
    acc = 0.0
    k = 0
    while True:
        step = arc_integral(basis, k * PANEL * sign, (k + 1) * PANEL * sign) * sign
        if acc + step >= target or k > 80:
            break
        acc += step
        k += 1
    psi0 = k * PANEL
    psi = psi0 + (target - acc) / arc_rate(basis, sign * psi0)
    for _ in range(8):
        cur = acc + arc_integral(basis, sign * psi0, sign * psi) * sign
        delta = (cur - target) / arc_rate(basis, sign * psi)
        psi -= delta
        if abs(delta) < 1e-13:
            break
    return sign * psi


@njit(cache=True)
def _line_table(basis: np.ndarray, g_lo: float, g_hi: float,
                psis: np.ndarray, gs: np.ndarray) -> int:
    """Nodes every PANEL from below ``g_lo`` to above ``g_hi`` with their ground distances."""
    # negative side
    k_lo = 0
    acc = 0.0
    while acc > g_lo and k_lo < 80:
        acc -= arc_integral(basis, -(k_lo + 1) * PANEL, -k_lo * PANEL)
        k_lo += 1
    n = 0
    acc = 0.0
    for k in range(k_lo):
        acc -= arc_integral(basis, -(k + 1) * PANEL, -k * PANEL)
    g_first = acc
    psis[0] = -k_lo * PANEL
    gs[0] = g_first
    n = 1
    psi = -k_lo * PANEL
    while (gs[n - 1] < g_hi or psi < 0.0) and n < psis.size:
        nxt = psi + PANEL
        gs[n] = gs[n - 1] + arc_integral(basis, psi, nxt)
        psis[n] = nxt
        psi = nxt
        n += 1
    return n


@njit(cache=True)
def _psi_from_table(basis: np.ndarray, psis: np.ndarray, gs: np.ndarray, n: int,
                    g: float) -> float:
    """psi at ground distance g: find the panel, then Newton on the exact panel integral."""
    lo, hi = 0, n - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if gs[mid] <= g:
            lo = mid
        else:
            hi = mid
    psi0 = psis[lo]
    psi = psi0 + (g - gs[lo]) / arc_rate(basis, psi0)
    for _ in range(8):
        cur = gs[lo] + arc_integral(basis, psi0, psi)
        delta = (cur - g) / arc_rate(basis, psi)
        psi -= delta
        if abs(delta) < 1e-13:
            break
    return psi


@njit(cache=True)
def dem_bilinear(dem: np.ndarray, geo: np.ndarray, lon: float, lat: float) -> float:
    """Height bilinear between the posts of ``dem`` (rows North to South); NaN outside."""
    x = ((lon - geo[D_LON0]) % 360.0) / geo[D_DLON]
    y = (geo[D_LAT0] - lat) / geo[D_DLAT]
    nr, nc = dem.shape
    if not (x >= 0.0 and y >= 0.0 and x <= nc - 1 and y <= nr - 1):
        return np.nan
    c = min(int(x), nc - 2)
    r = min(int(y), nr - 2)
    fx = x - c
    fy = y - r
    top = dem[r, c] * (1.0 - fx) + dem[r, c + 1] * fx
    bot = dem[r + 1, c] * (1.0 - fx) + dem[r + 1, c + 1] * fx
    return top * (1.0 - fy) + bot * fy


@njit(cache=True)
def _block_max(bmax: np.ndarray, geo: np.ndarray, lon: float, lat: float, b: float) -> float:
    x = ((lon - geo[D_LON0]) % 360.0) / geo[D_DLON]
    y = (geo[D_LAT0] - lat) / geo[D_DLAT]
    bj = int(math.floor(x / b))
    bi = int(math.floor(y / b))
    if bi < 0 or bj < 0 or bi >= bmax.shape[0] or bj >= bmax.shape[1]:
        return geo[D_HMAX]
    return bmax[bi, bj]


@njit(cache=True)
def _height_above_dem(dem: np.ndarray, geo: np.ndarray, p: np.ndarray) -> float:
    lon, lat, h = ecef_to_geodetic(p[0], p[1], p[2])
    z = dem_bilinear(dem, geo, lon, lat)
    if z != z:
        z = 0.0
    return h - z


@njit(cache=True)
def _refine_crossing(s0: np.ndarray, d: np.ndarray, dem: np.ndarray, geo: np.ndarray,
                     lo: float, f_lo: float, hi: float, f_hi: float) -> float:
    """Root of height-above-DEM along the ray inside [lo, hi] (f_lo > 0 >= f_hi): Illinois
    false position, safe on the piecewise-bilinear surface (to 1e-5 m along the ray)."""
    p = np.empty(3)
    side = 0
    s = hi
    for _ in range(100):
        s = (lo * f_hi - hi * f_lo) / (f_hi - f_lo)
        if not (lo < s < hi):
            s = 0.5 * (lo + hi)
        for k in range(3):
            p[k] = s0[k] + s * d[k]
        f = _height_above_dem(dem, geo, p)
        if f > 0.0:
            lo, f_lo = s, f
            if side == 1:
                f_hi *= 0.5
            side = 1
        else:
            hi, f_hi = s, f
            if side == -1:
                f_lo *= 0.5
            side = -1
        if hi - lo < 1e-5 or abs(f) < 1e-6:
            break
    return s


@njit(cache=True)
def terrain_intersection(s0: np.ndarray, d: np.ndarray, dem: np.ndarray, geo: np.ndarray,
                         bmax: np.ndarray, bmax_fine: np.ndarray, sin_zenith: float,
                         out: np.ndarray) -> None:
    """First intersection T of the ray S + s d with the bilinear DEM surface (look-point method).

    March from above the highest post, skipping safely over blocks whose (dilated) maximum lies
    below the ray (blocks of D_BLOCK posts, then of D_BLOCK / FINE_DIV posts), with steps of
    half a post elsewhere; refine the first sign change by false position (Illinois).
    ``out`` receives lon, lat, h of T.
    """
    p = np.empty(3)
    s = ray_ellipsoid(s0, d, geo[D_HMAX] + 50.0)
    s_end = ray_ellipsoid(s0, d, geo[D_HMIN] - 50.0)
    sz = max(sin_zenith, 1e-3)
    fine = 0.5 * geo[D_SPMIN] / sz
    jump_lim = 0.75 * geo[D_BLOCK] * geo[D_SPMIN] / sz
    b_fine = geo[D_BLOCK] / FINE_DIV
    jump_fine = 0.75 * b_fine * geo[D_SPMIN] / sz
    have_prev = False
    s_prev = s
    f_prev = 0.0
    while True:
        for k in range(3):
            p[k] = s0[k] + s * d[k]
        lon, lat, h = ecef_to_geodetic(p[0], p[1], p[2])
        if s < s_end:
            room = h - _block_max(bmax, geo, lon, lat, geo[D_BLOCK])
            if room > fine:
                s = min(s + min(room, jump_lim), s_end)
                have_prev = False
                continue
            room = h - _block_max(bmax_fine, geo, lon, lat, b_fine)
            if room > fine:
                s = min(s + min(room, jump_fine), s_end)
                have_prev = False
                continue
        z = dem_bilinear(dem, geo, lon, lat)
        f = h - (0.0 if z != z else z)
        if f <= 0.0:
            if have_prev:
                s = _refine_crossing(s0, d, dem, geo, s_prev, f_prev, s, f)
            break
        if s >= s_end:
            break
        have_prev = True
        s_prev = s
        f_prev = f
        s = min(s + fine, s_end)
    for k in range(3):
        p[k] = s0[k] + s * d[k]
    lon, lat, h = ecef_to_geodetic(p[0], p[1], p[2])
    out[0] = lon
    out[1] = lat
    out[2] = h


@njit(cache=True)
def view_angles(e: np.ndarray, s0: np.ndarray, lon: float, lat: float,
                nadir_az: float) -> tuple[float, float]:
    """View zenith and azimuth (deg) at ground point ``e`` towards the satellite (clockwise
    from north); ``nadir_az`` is used where the satellite is exactly overhead."""
    lo = math.radians(lon)
    la = math.radians(lat)
    u0, u1, u2 = s0[0] - e[0], s0[1] - e[1], s0[2] - e[2]
    r = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    up = (math.cos(la) * math.cos(lo) * u0 + math.cos(la) * math.sin(lo) * u1
          + math.sin(la) * u2) / r
    east = (-math.sin(lo) * u0 + math.cos(lo) * u1) / r
    north = (-math.sin(la) * math.cos(lo) * u0 - math.sin(la) * math.sin(lo) * u1
             + math.cos(la) * u2) / r
    zen = math.degrees(math.atan2(math.hypot(east, north), up))
    if math.hypot(east, north) < 1e-9:
        return zen, nadir_az
    return zen, math.degrees(math.atan2(east, north)) % 360.0


@njit(cache=True)
def _azimuth_of(vec: np.ndarray, lon: float, lat: float) -> float:
    lo = math.radians(lon)
    la = math.radians(lat)
    east = -math.sin(lo) * vec[0] + math.cos(lo) * vec[1]
    north = (-math.sin(la) * math.cos(lo) * vec[0] - math.sin(la) * math.sin(lo) * vec[1]
             + math.cos(la) * vec[2])
    return math.degrees(math.atan2(east, north)) % 360.0


@njit(cache=True)
def _column_angles(basis: np.ndarray, grid: np.ndarray, cols: np.ndarray,
                   psis: np.ndarray, gs: np.ndarray, n: int, out: np.ndarray) -> None:
    """psi of every column: exact (Newton on the arc length) at nodes at most NODE_STEP columns
    apart and at the last one, cubic Hermite in the ground distance in between (error below
    1e-4 m)."""
    nc = cols.size
    j = 0
    while j < nc:
        k = min(j + 1, nc - 1)
        while k < nc - 1 and cols[k + 1] - cols[j] <= NODE_STEP:
            k += 1
        ga = (grid[G_FIRST] + cols[j]) * grid[G_SPACING]
        pa = _psi_from_table(basis, psis, gs, n, ga)
        out[j] = pa
        if k == j:
            break
        gb = (grid[G_FIRST] + cols[k]) * grid[G_SPACING]
        pb = _psi_from_table(basis, psis, gs, n, gb)
        da = 1.0 / arc_rate(basis, pa)
        db = 1.0 / arc_rate(basis, pb)
        hg = gb - ga
        for m in range(j + 1, k):
            u = ((grid[G_FIRST] + cols[m]) * grid[G_SPACING] - ga) / hg
            h00 = (1.0 + 2.0 * u) * (1.0 - u) ** 2
            h10 = u * (1.0 - u) ** 2
            h01 = u * u * (3.0 - 2.0 * u)
            h11 = u * u * (u - 1.0)
            out[m] = h00 * pa + h10 * hg * da + h01 * pb + h11 * hg * db
        out[k] = pb
        j = k
        if k == nc - 1:
            break


NODE_STEP = 16


@njit(cache=True, parallel=True)
def locate_pixels(orb: np.ndarray, grid: np.ndarray, lines: np.ndarray, cols: np.ndarray,
                  dem: np.ndarray, geo: np.ndarray, bmax: np.ndarray, bmax_fine: np.ndarray,
                  terrain: bool,
                  side: float, out: np.ndarray) -> None:
    """Direct model of the simulator for product pixels (lines x cols, cols increasing).

    ``out[i, j]`` receives: E lon, E lat, view zenith, view azimuth, T lon, T lat, T h
    (T only when ``terrain``; otherwise NaN).
    """
    nl = lines.size
    nc = cols.size
    g_lo = (grid[G_FIRST] + cols.min()) * grid[G_SPACING]
    g_hi = (grid[G_FIRST] + cols.max()) * grid[G_SPACING]
    for i in prange(nl):
        basis = np.empty((4, 3))
        frame_basis(orb, grid[G_T0] + lines[i] * grid[G_DT], basis)
        psis = np.empty(400)
        gs = np.empty(400)
        n = _line_table(basis, g_lo, g_hi, psis, gs)
        col_psi = np.empty(nc)
        _column_angles(basis, grid, cols, psis, gs, n, col_psi)
        s0 = basis[0].copy()
        d = np.empty(3)
        e = np.empty(3)
        tpt = np.empty(3)
        side_vec = np.empty(3)
        for k in range(3):
            side_vec[k] = -side * basis[3, k]
        for j in range(nc):
            look_direction(basis, col_psi[j], d)
            s_e = ray_ellipsoid(s0, d, 0.0)
            for k in range(3):
                e[k] = s0[k] + s_e * d[k]
            lon, lat, _ = ecef_to_geodetic(e[0], e[1], e[2])
            nadir_az = _azimuth_of(side_vec, lon, lat)
            vz, va = view_angles(e, s0, lon, lat, nadir_az)
            out[i, j, 0] = lon
            out[i, j, 1] = lat
            out[i, j, 2] = vz
            out[i, j, 3] = va
            if terrain:
                terrain_intersection(s0, d, dem, geo, bmax, bmax_fine,
                                     math.sin(math.radians(vz)), tpt)
                out[i, j, 4] = tpt[0]
                out[i, j, 5] = tpt[1]
                out[i, j, 6] = tpt[2]
            else:
                out[i, j, 4] = np.nan
                out[i, j, 5] = np.nan
                out[i, j, 6] = np.nan


@njit(cache=True)
def _plane_distance(orb: np.ndarray, t: float, p: np.ndarray, basis: np.ndarray) -> float:
    frame_basis(orb, t, basis)
    return ((p[0] - basis[0, 0]) * basis[1, 0] + (p[1] - basis[0, 1]) * basis[1, 1]
            + (p[2] - basis[0, 2]) * basis[1, 2])


@njit(cache=True)
def antecedent_of_point(orb: np.ndarray, grid: np.ndarray, p: np.ndarray,
                        t_guess: float) -> tuple[float, float]:
    """Fractional (line, column) whose line of sight passes through the ECEF point ``p``.

    The frame time solves "p lies in the plane through S(t) perpendicular to v(t)" (secant
    method); the column follows from the look angle of p inside that plane (section 2.2).
    """
    basis = np.empty((4, 3))
    ta = t_guess
    fa = _plane_distance(orb, ta, p, basis)
    speed = 6700.0
    tb = ta + fa / speed
    fb = _plane_distance(orb, tb, p, basis)
    for _ in range(50):
        if fb == fa:
            break
        tc = tb - fb * (tb - ta) / (fb - fa)
        ta, fa = tb, fb
        tb = tc
        fb = _plane_distance(orb, tb, p, basis)
        if abs(tb - ta) < 1e-9:
            break
    r0 = p[0] - basis[0, 0]
    r1 = p[1] - basis[0, 1]
    r2 = p[2] - basis[0, 2]
    across = r0 * basis[3, 0] + r1 * basis[3, 1] + r2 * basis[3, 2]
    down = -(r0 * basis[2, 0] + r1 * basis[2, 1] + r2 * basis[2, 2])
    psi = math.atan2(across, down)
    g = ground_distance(basis, psi)
    line = (tb - grid[G_T0]) / grid[G_DT]
    col = g / grid[G_SPACING] - grid[G_FIRST]
    return line, col


@njit(cache=True, parallel=True)
def true_antecedents(orb: np.ndarray, grid: np.ndarray, lon: np.ndarray, lat: np.ndarray,
                     h: np.ndarray, t_guess: float, line: np.ndarray, col: np.ndarray) -> None:
    """Vectorised :func:`antecedent_of_point` over 1-D arrays of geodetic points."""
    for i in prange(lon.size):
        if not (lon[i] == lon[i] and lat[i] == lat[i] and h[i] == h[i]):
            line[i] = np.nan
            col[i] = np.nan
            continue
        p = np.empty(3)
        x, y, z = geodetic_to_ecef(lon[i], lat[i], h[i])
        p[0], p[1], p[2] = x, y, z
        line[i], col[i] = antecedent_of_point(orb, grid, p, t_guess)

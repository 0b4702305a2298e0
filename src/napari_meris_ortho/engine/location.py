"""Direct location model of MERSYN (handbook section 3.3, eq. 3a-6b', Appendix C).

``f(l, p, h) -> (lon, lat)``: bilinear interpolation of the tie-point latitude, longitude and
viewing direction in the facet that holds (l, p) (eq. 3a-5b), then the parallax (geodetic)
correction *added* to the interpolated ellipsoid position (eq. 6a, 2c', 6b'; Appendix D)::

    dlon = +h tan(vz) sin(va) / (R cos lat)      dlat = +h tan(vz) cos(va) / R

``parallax="handbook"`` uses the sphere R = 6 370 997 m (MERSYN, BEAM); ``"ellipsoid"`` uses
the WGS84 meridian radius M(lat) for dlat and the prime-vertical radius N(lat) for dlon.
The viewing direction is interpolated as a look vector (see ``tiepoints``), continuous at nadir.
Outside the tie-point grid the edge facet is extended (offsets beyond [0, 1]), so the model is
a continuous piecewise-bilinear map of the whole plane; callers decide what is inside.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..errors import OptionsError
from .tiepoints import TiePointGrid

#: mean Earth radius of MERSYN and BEAM (handbook eq. 2, 6a)
MEAN_EARTH_RADIUS = 6370997.0
WGS84_A = 6378137.0
WGS84_E2 = 6.69437999014e-3

#: parallax model codes used by the kernels; "ellipsoid_h" (radii M+h, N+h) is for measurements
PARALLAX_MODELS = {"handbook": 0, "ellipsoid": 1, "ellipsoid_h": 2}


def parallax_code(model: str) -> int:
    """Kernel code of a parallax model name, or OptionsError."""
    try:
        return PARALLAX_MODELS[model]
    except KeyError:
        raise OptionsError(
            f"unknown parallax model {model!r}: choose handbook or ellipsoid") from None


@njit(cache=True, inline="always")
def facet_of(x: float, step: float, n: int) -> tuple[int, float]:
    """Facet index (eq. 3a) clamped to the grid, and the fractional offset in it (eq. 3b)."""
    t = x / step
    k = int(math.floor(t))
    if k < 0:
        k = 0
    elif k > n - 2:
        k = n - 2
    return k, t - k


@njit(cache=True, inline="always")
def bilinear(a: np.ndarray, f: int, j: int, u: float, v: float) -> float:
    """Eq. 1 / 4a: bilinear value in facet (f, j) at offsets u (along lines), v (columns)."""
    return ((1.0 - u) * ((1.0 - v) * a[f, j] + v * a[f, j + 1])
            + u * ((1.0 - v) * a[f + 1, j] + v * a[f + 1, j + 1]))


@njit(cache=True, inline="always")
def parallax_shift(h: float, look_e: float, look_n: float, lat_deg: float,
                   model: int) -> tuple[float, float]:
    """Eq. 6a / 2c': (dlon, dlat) in degrees for height h, look vector tan(vz) (sin, cos)(va)."""
    east = h * look_e
    north = h * look_n
    phi = math.radians(lat_deg)
    c = math.cos(phi)
    if model == 0:
        rm = MEAN_EARTH_RADIUS
        rn = MEAN_EARTH_RADIUS
    else:
        s = math.sin(phi)
        w = 1.0 - WGS84_E2 * s * s
        rn = WGS84_A / math.sqrt(w)
        rm = WGS84_A * (1.0 - WGS84_E2) / (w * math.sqrt(w))
        if model == 2:
            rn += h
            rm += h
    return math.degrees(east / (rn * c)), math.degrees(north / rm)


@njit(cache=True)
def direct_point(line: float, col: float, h: float, lat: np.ndarray, lon: np.ndarray,
                 look_e: np.ndarray, look_n: np.ndarray, dem: np.ndarray, df: float, dj: float,
                 model: int):
    """Direct location f(l, p, h) (eq. 3a-6b'); h = NaN takes the tie-point dem_alt (bilinear).

    Returns (lon, lat, h, d lon/d l, d lon/d p, d lat/d l, d lat/d p); the derivatives are those
    of the ellipsoid position (the facet's analytic Jacobian), enough for Newton's method.
    """
    nl, nc = lat.shape
    f, u = facet_of(line, df, nl)
    j, v = facet_of(col, dj, nc)
    la = bilinear(lat, f, j, u, v)
    lo = bilinear(lon, f, j, u, v)
    if math.isnan(h):
        h = bilinear(dem, f, j, u, v)
    if h != 0.0:
        dlon, dlat = parallax_shift(h, bilinear(look_e, f, j, u, v),
                                    bilinear(look_n, f, j, u, v), la, model)
    else:
        dlon = 0.0
        dlat = 0.0
    a00 = lo
    # partial derivatives of the bilinear facet, per product pixel
    dlo_du = (1.0 - v) * (lon[f + 1, j] - lon[f, j]) + v * (lon[f + 1, j + 1] - lon[f, j + 1])
    dlo_dv = (1.0 - u) * (lon[f, j + 1] - lon[f, j]) + u * (lon[f + 1, j + 1] - lon[f + 1, j])
    dla_du = (1.0 - v) * (lat[f + 1, j] - lat[f, j]) + v * (lat[f + 1, j + 1] - lat[f, j + 1])
    dla_dv = (1.0 - u) * (lat[f, j + 1] - lat[f, j]) + u * (lat[f + 1, j + 1] - lat[f + 1, j])
    return (a00 + dlon, la + dlat, h, dlo_du / df, dlo_dv / dj, dla_du / df, dla_dv / dj)


@njit(cache=True, parallel=True)
def _direct_many(line, col, h, lat, lon, look_e, look_n, dem, df, dj, model):
    n = line.size
    out_lon = np.empty(n)
    out_lat = np.empty(n)
    out_h = np.empty(n)
    for i in prange(n):
        r = direct_point(line[i], col[i], h[i], lat, lon, look_e, look_n, dem, df, dj, model)
        out_lon[i] = r[0]
        out_lat[i] = r[1]
        out_h[i] = r[2]
    return out_lon, out_lat, out_h


def wrap_longitude(lon: np.ndarray) -> np.ndarray:
    """Longitudes on [-180, 180)."""
    return (np.asarray(lon) + 180.0) % 360.0 - 180.0


def direct_location(grid: TiePointGrid, line: np.ndarray, col: np.ndarray,
                    height: np.ndarray | float | None = 0.0,
                    parallax: str = "handbook") -> tuple[np.ndarray, np.ndarray]:
    """Vectorised direct location model (section 3.3): (lon, lat) in degrees of product points.

    ``height=None`` takes the tie-point dem_alt at each point (MERSYN without ``-dem``).
    """
    line_a, col_a = np.broadcast_arrays(np.asarray(line, np.float64), np.asarray(col, np.float64))
    shape = line_a.shape
    h = np.full(shape, np.nan) if height is None else np.broadcast_to(
        np.asarray(height, np.float64), shape)
    lat, lon, le, ln, dem, df, dj = grid.kernel_args()
    lo, la, _ = _direct_many(np.ascontiguousarray(line_a.ravel()),
                             np.ascontiguousarray(col_a.ravel()),
                             np.ascontiguousarray(h.ravel()), lat, lon, le, ln, dem, df, dj,
                             parallax_code(parallax))
    return wrap_longitude(lo).reshape(shape), la.reshape(shape)


def geodetic_correction(height_m, view_zenith_deg, view_azimuth_deg, lat_deg,
                        model: str = "handbook") -> tuple[np.ndarray, np.ndarray]:
    """Parallax correction (dlon, dlat) in degrees ADDED to the ellipsoid position (eq. 2c', 6b').

    ``model="handbook"``: sphere R = 6 370 997 m (MERSYN 02.05, BEAM; reproduces Appendix D).
    ``model="ellipsoid"``: WGS84 meridian (M) and prime-vertical (N) radii at ``lat_deg``.
    Vectorised over numpy broadcasting.
    """
    code = parallax_code(model)
    h, vz, va, lat = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (
        height_m, view_zenith_deg, view_azimuth_deg, lat_deg)))
    dx = h * np.tan(np.radians(vz))
    east = dx * np.sin(np.radians(va))
    north = dx * np.cos(np.radians(va))
    phi = np.radians(lat)
    if code == 0:
        rm = rn = np.full(phi.shape, MEAN_EARTH_RADIUS)
    else:
        w = 1.0 - WGS84_E2 * np.sin(phi) ** 2
        rn = WGS84_A / np.sqrt(w)
        rm = WGS84_A * (1.0 - WGS84_E2) / w ** 1.5
        if code == 2:
            rn = rn + h
            rm = rm + h
    return np.degrees(east / (rn * np.cos(phi))), np.degrees(north / rm)

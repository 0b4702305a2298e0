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
from numba import njit

from ..geometry.earth import MEAN_EARTH_RADIUS, WGS84_A, WGS84_E2
from ..geometry.parallax import geodetic_offsets
from ..geometry.tiepoints import TiePointGrid
from ..options import Geolocation, Parallax, parse
from .threads import split_range


def parallax_code(model: str) -> int:
    """Kernel code of a parallax model (``options.Parallax``), or OptionsError."""
    return parse(Parallax, model).code


def geolocation_code(geolocation: str | None, parallax: str = "handbook") -> int:
    """Kernel code of the tie-point position interpolation; None: the parallax model's default.

    "bilinear": latitude and longitude interpolated bilinearly (eq. 4a-4b, MERSYN, BEAM);
    "ecef": the tie points' unit vectors interpolated bilinearly (our improvement: 0.06 px
    less error at 70 deg latitude on the simulator's truth). ``parallax="ellipsoid"`` implies
    "ecef" unless told otherwise.
    """
    if geolocation is None:
        return Geolocation.default_for(parse(Parallax, parallax)).code
    return parse(Geolocation, geolocation).code


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
def parallax_factors(lat_deg: float, h: float, model: int) -> tuple[float, float]:
    """Eq. 6a / 2c': degrees of longitude and of latitude per metre east and north at lat_deg.

    model 0: sphere R = 6 370 997 m; 1: WGS84 prime vertical N and meridian M radii;
    2: N + h and M + h (measurements only).
    """
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
    return 57.29577951308232 / (rn * c), 57.29577951308232 / rm


@njit(cache=True)
def direct_point(line: float, col: float, h: float, coef: np.ndarray, df: float, dj: float,
                 model: int, geo: int = 0):
    """Direct location f(l, p, h) (eq. 3a-6b'); h = NaN takes the tie-point dem_alt (bilinear).

    ``coef``: ``TiePointGrid.coefficients``; ``geo``: 0 = bilinear latitude and longitude
    (eq. 4a-4b, MERSYN), 1 = bilinear unit vectors (x, y, z) of the tie points, then back to
    latitude/longitude ("ecef": no lon/lat curvature error, which grows towards the poles).
    Returns (lon, lat, h, look_east, look_north, d lon/d l, d lon/d p, d lat/d l, d lat/d p):
    the Jacobian of the whole model (position plus parallax, cos(lat) held constant).
    """
    f, u = facet_of(line, df, coef.shape[0] + 1)
    j, v = facet_of(col, dj, coef.shape[1] + 1)
    c = coef[f, j]
    uv = u * v
    if geo == 0:
        la = c[0] + c[1] * u + c[2] * v + c[3] * uv
        lo = c[4] + c[5] * u + c[6] * v + c[7] * uv
        dla_du = c[1] + c[3] * v
        dla_dv = c[2] + c[3] * u
        dlo_du = c[5] + c[7] * v
        dlo_dv = c[6] + c[7] * u
    else:
        x = c[20] + c[21] * u + c[22] * v + c[23] * uv
        y = c[24] + c[25] * u + c[26] * v + c[27] * uv
        z = c[28] + c[29] * u + c[30] * v + c[31] * uv
        q = x * x + y * y
        rho = math.sqrt(q)
        la = math.degrees(math.atan2(z, rho))
        lo = math.degrees(math.atan2(y, x))
        dxu = c[21] + c[23] * v
        dyu = c[25] + c[27] * v
        dzu = c[29] + c[31] * v
        dxv = c[22] + c[23] * u
        dyv = c[26] + c[27] * u
        dzv = c[30] + c[31] * u
        r2 = q + z * z
        dlo_du = 57.29577951308232 * (x * dyu - y * dxu) / q
        dlo_dv = 57.29577951308232 * (x * dyv - y * dxv) / q
        dla_du = 57.29577951308232 * (q * dzu - z * (x * dxu + y * dyu)) / (rho * r2)
        dla_dv = 57.29577951308232 * (q * dzv - z * (x * dxv + y * dyv)) / (rho * r2)
    dh_du = 0.0
    dh_dv = 0.0
    if math.isnan(h):
        h = c[16] + c[17] * u + c[18] * v + c[19] * uv
        dh_du = c[17] + c[19] * v
        dh_dv = c[18] + c[19] * u
    e = c[8] + c[9] * u + c[10] * v + c[11] * uv
    n = c[12] + c[13] * u + c[14] * v + c[15] * uv
    if h != 0.0 or dh_du != 0.0 or dh_dv != 0.0:
        ke, kn = parallax_factors(la, h, model)
        lo += ke * h * e
        la += kn * h * n
        dlo_du += ke * (h * (c[9] + c[11] * v) + dh_du * e)
        dlo_dv += ke * (h * (c[10] + c[11] * u) + dh_dv * e)
        dla_du += kn * (h * (c[13] + c[15] * v) + dh_du * n)
        dla_dv += kn * (h * (c[14] + c[15] * u) + dh_dv * n)
    return lo, la, h, e, n, dlo_du / df, dlo_dv / dj, dla_du / df, dla_dv / dj


#: ``direct_point`` inlined into its caller's code (numba IR): per-point loops call it without
#: the call's reference counting of its array argument (about 20 ns a call, a third of the
#: evaluation); one source, compiled once more for each caller
direct_point_inline = njit(cache=True, inline="always")(direct_point.py_func)


@njit(cache=True, nogil=True)
def _direct_range(lo, hi, line, col, h, coef, df, dj, model, geo, out_lon, out_lat):
    """Points [lo, hi) of ``direct_location`` (flat arrays)."""
    for i in range(lo, hi):
        r = direct_point(line[i], col[i], h[i], coef, df, dj, model, geo)
        out_lon[i] = r[0]
        out_lat[i] = r[1]


def wrap_longitude(lon: np.ndarray) -> np.ndarray:
    """Longitudes on [-180, 180)."""
    return (np.asarray(lon) + 180.0) % 360.0 - 180.0


def direct_location(grid: TiePointGrid, line: np.ndarray, col: np.ndarray,
                    height: np.ndarray | float | None = 0.0,
                    parallax: str = "handbook", geolocation: str | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised direct location model (section 3.3): (lon, lat) in degrees of product points.

    ``height=None`` takes the tie-point dem_alt at each point (MERSYN without ``-dem``);
    ``geolocation``: "bilinear" (eq. 4a-4b) or "ecef" (default: bilinear for the handbook
    parallax, ecef for the ellipsoid one; see ``geolocation_code``).
    """
    line_a, col_a = np.broadcast_arrays(np.asarray(line, np.float64), np.asarray(col, np.float64))
    shape = line_a.shape
    h = np.full(shape, np.nan) if height is None else np.broadcast_to(
        np.asarray(height, np.float64), shape)
    _, _, coef, df, dj = grid.kernel_args()
    n = line_a.size
    lo, la = np.empty(n), np.empty(n)
    args = (np.ascontiguousarray(line_a.ravel()), np.ascontiguousarray(col_a.ravel()),
            np.ascontiguousarray(h.ravel()), coef, float(df), float(dj),
            np.int64(parallax_code(parallax)),
            np.int64(geolocation_code(geolocation, parallax)), lo, la)
    split_range(lambda a, b: _direct_range(a, b, *args), n, min_size=4096)
    return wrap_longitude(lo).reshape(shape), la.reshape(shape)


def geodetic_correction(height_m, view_zenith_deg, view_azimuth_deg, lat_deg,
                        model: str = "handbook") -> tuple[np.ndarray, np.ndarray]:
    """Parallax correction (dlon, dlat) in degrees ADDED to the ellipsoid position (eq. 2c', 6b').

    ``model="handbook"``: sphere R = 6 370 997 m (MERSYN 02.05, BEAM; reproduces Appendix D).
    ``model="ellipsoid"``: WGS84 meridian (M) and prime-vertical (N) radii at ``lat_deg``.
    Vectorised over numpy broadcasting; ``geometry.parallax.geodetic_offsets`` with the model
    named as the options name it.
    """
    return geodetic_offsets(height_m, view_zenith_deg, view_azimuth_deg, lat_deg,
                            parallax_code(model))

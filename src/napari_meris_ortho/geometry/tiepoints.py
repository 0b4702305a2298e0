"""Tie-point grid of a MERIS L1b product as the location models use it (handbook section 2.2).

Tie point (i, k) sits on product pixel (line i*DF, column k*DJ) in the stored column order
(ARCHITECTURE.md). Longitudes are unwrapped so that every facet is continuous across +-180 deg,
the positions are also kept as unit vectors (x, y, z) of their geodetic latitude and longitude
for the "ecef" interpolation (``location``), and the viewing direction as a *look vector*
``(tan(vz) sin(va), tan(vz) cos(va))``: interpolating its two components bilinearly (instead
of vz and va separately, eq. 5a-5b) keeps the parallax vector continuous through nadir, where
the azimuth is undefined and jumps by 180 deg.
Away from nadir the two agree to far below a metre of parallax.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, fields
from typing import Any, Protocol

import numpy as np

from ..errors import GeometryError
from .earth import MEAN_EARTH_RADIUS
from .parallax import parallax_height

#: the tie-point quantities the location models need (section 2.2)
_NEEDED = ("latitude", "longitude", "view_zenith", "view_azimuth", "dem_alt")


@dataclass(frozen=True, eq=False, kw_only=True)
class TiePoints(Mapping[str, np.ndarray]):
    """The tie-point annotations of a product in physical units (Tie points ADS, Appendix A;
    the same quantities for a ``.SEN3``'s ``tie_*.nc``), float64 arrays (n_tie_lines,
    n_tie_cols) in the stored column order. The five the location models need are required;
    the others are None where a product does not carry them. Also a read-only mapping
    ``name -> array`` over the arrays present (``tp["latitude"]``, ``dict(tp)``)."""

    latitude: np.ndarray
    longitude: np.ndarray
    #: terrain height of the tie point above the ellipsoid (m; bathymetry below 0 over sea)
    dem_alt: np.ndarray
    dem_rough: np.ndarray | None = None
    #: AMORGOS/ground-segment altitude correction of the position (deg), eq. 6a'-6b'
    lat_corr: np.ndarray | None = None
    lon_corr: np.ndarray | None = None
    sun_zenith: np.ndarray | None = None
    sun_azimuth: np.ndarray | None = None
    view_zenith: np.ndarray
    view_azimuth: np.ndarray
    zonal_wind: np.ndarray | None = None
    merid_wind: np.ndarray | None = None
    atm_pressure: np.ndarray | None = None
    ozone: np.ndarray | None = None
    rel_humidity: np.ndarray | None = None

    def __post_init__(self) -> None:
        shape = None
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None:
                continue
            a = np.asarray(v, dtype=np.float64)
            if shape is None:
                shape = a.shape
            elif a.shape != shape:
                raise GeometryError(f"tie points: {f.name} of shape {a.shape}, "
                                    f"latitude of shape {shape}")
            object.__setattr__(self, f.name, a)

    @classmethod
    def from_mapping(cls, arrays: Mapping[str, Any]) -> TiePoints:
        """From ``{name: array}`` (names as the fields); GeometryError naming what is missing
        or unknown."""
        if isinstance(arrays, TiePoints):
            return arrays
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(arrays) - known)
        if unknown:
            raise GeometryError(f"tie points: unknown quantities {', '.join(unknown)}")
        missing = [name for name in _NEEDED if name not in arrays]
        if missing:
            raise GeometryError(f"tie points lack {', '.join(missing)}")
        return cls(**arrays)

    @property
    def shape(self) -> tuple[int, int]:
        """(n_tie_lines, n_tie_cols)."""
        return (int(self.latitude.shape[0]), int(self.latitude.shape[1]))

    def __getitem__(self, name: str) -> np.ndarray:
        value = getattr(self, name, None) if name in _FIELD_NAMES else None
        if value is None:
            raise KeyError(name)
        return value

    def __iter__(self) -> Iterator[str]:
        return (name for name in _FIELD_NAMES if getattr(self, name) is not None)

    def __len__(self) -> int:
        return sum(1 for _ in self)


class ProductGeometry(Protocol):
    """What a MERIS L1b product offers the location models (``products.n1.MerisL1bProduct``, the
    per-pixel geolocated products): tie points in physical units, DF, DJ and the size H x W."""

    @property
    def path(self) -> object: ...
    @property
    def tie_points(self) -> TiePoints: ...
    @property
    def lines_per_tie_point(self) -> int: ...
    @property
    def samples_per_tie_point(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def width(self) -> int: ...




def unwrap_longitudes(lon: np.ndarray) -> np.ndarray:
    """Longitudes made continuous along lines and columns (no 360 deg jump between neighbours)."""
    out = np.unwrap(np.asarray(lon, dtype=np.float64), period=360.0, axis=1)
    first = np.unwrap(out[:, 0], period=360.0)
    out += (first - out[:, 0])[:, None]
    # centre the values on the (-180, 180] branch as well as possible
    centre = out[out.shape[0] // 2, out.shape[1] // 2]
    out -= 360.0 * np.round(centre / 360.0)
    return np.ascontiguousarray(out)


#: order of the quantities in ``facet_coefficients`` (4 coefficients each)
COEFFICIENTS = ("latitude", "longitude", "look_east", "look_north", "dem_alt", "x", "y", "z")


def facet_coefficients(arrays: tuple[np.ndarray, ...]) -> np.ndarray:
    """Bilinear coefficients (a, b, c, d) of every facet (eq. 1): X = a + b u + c v + d u v.

    Shape (n_tie_lines - 1, n_tie_cols - 1, 4 * len(arrays)); u along lines, v along columns.
    One contiguous record per facet keeps the direct model's memory reads together.
    """
    parts = []
    for a in arrays:
        a00, a10, a01, a11 = a[:-1, :-1], a[1:, :-1], a[:-1, 1:], a[1:, 1:]
        parts += [a00, a10 - a00, a01 - a00, a11 - a10 - a01 + a00]
    return np.ascontiguousarray(np.stack(parts, axis=-1))


@dataclass
class TiePointGrid:
    """Tie-point arrays (n_tie_lines, n_tie_cols) plus DF, DJ and the product size H x W.

    ``dem_alt`` is kept as ``parallax.parallax_height`` gives it (0 where the product stores
    bathymetry below 0): every height the location models take from the tie points (elevation
    "tiepoints", the DEM modes' fallback, the prediction's height rates) gives no parallax over
    sea, as ESA's zero ``lat_corr``/``lon_corr`` there say.
    """

    latitude: np.ndarray
    longitude: np.ndarray
    view_zenith: np.ndarray
    view_azimuth: np.ndarray
    dem_alt: np.ndarray
    lines_per_tie_point: int
    samples_per_tie_point: int
    height: int
    width: int
    lon_unwrapped: np.ndarray = field(init=False, repr=False)
    look_east: np.ndarray = field(init=False, repr=False)
    look_north: np.ndarray = field(init=False, repr=False)
    coefficients: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        arrays = [np.ascontiguousarray(a, dtype=np.float64) for a in (
            self.latitude, self.longitude, self.view_zenith, self.view_azimuth,
            parallax_height(self.dem_alt))]
        self.latitude, self.longitude, self.view_zenith, self.view_azimuth, self.dem_alt = arrays
        shape = self.latitude.shape
        if len(shape) != 2 or shape[0] < 2 or shape[1] < 2:
            raise GeometryError(f"tie-point grid of shape {shape}: need at least 2x2")
        if any(a.shape != shape for a in arrays):
            raise GeometryError("tie-point arrays of different shapes")
        if self.lines_per_tie_point < 1 or self.samples_per_tie_point < 1:
            raise GeometryError("tie-point spacing must be positive")
        if (shape[1] - 1) * self.samples_per_tie_point < self.width - 1:
            raise GeometryError("tie-point columns do not cover the product width")
        if (shape[0] - 1) * self.lines_per_tie_point < self.height - 1:
            raise GeometryError("tie-point lines do not cover the product height")
        self.lon_unwrapped = unwrap_longitudes(self.longitude)
        tz = np.tan(np.radians(self.view_zenith))
        va = np.radians(self.view_azimuth)
        self.look_east = np.ascontiguousarray(tz * np.sin(va))
        self.look_north = np.ascontiguousarray(tz * np.cos(va))
        phi = np.radians(self.latitude)
        lam = np.radians(self.longitude)
        self.coefficients = facet_coefficients(
            (self.latitude, self.lon_unwrapped, self.look_east, self.look_north, self.dem_alt,
             np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)))

    @classmethod
    def from_product(cls, product: ProductGeometry) -> TiePointGrid:
        """Build the grid from an ``products.n1.MerisL1bProduct`` (tie points in physical units)."""
        tp = product.tie_points
        missing = [name for name in _NEEDED if name not in tp]
        if missing:
            raise GeometryError(f"{product.path}: tie points lack {', '.join(missing)}")
        return cls(tp["latitude"], tp["longitude"], tp["view_zenith"], tp["view_azimuth"],
                   tp["dem_alt"], int(product.lines_per_tie_point),
                   int(product.samples_per_tie_point), int(product.height), int(product.width))

    @property
    def shape(self) -> tuple[int, int]:
        """(n_tie_lines, n_tie_cols)."""
        return (int(self.latitude.shape[0]), int(self.latitude.shape[1]))

    def kernel_args(self) -> tuple:
        """(latitude, unwrapped longitude, facet coefficients, DF, DJ) as the kernels take them."""
        return (self.latitude, self.lon_unwrapped, self.coefficients,
                float(self.lines_per_tie_point), float(self.samples_per_tie_point))

    def inside(self, line: np.ndarray, col: np.ndarray) -> np.ndarray:
        """True where a fractional antecedent lies inside the product (pixel-centre convention)."""
        line = np.asarray(line)
        col = np.asarray(col)
        return ((line >= -0.5) & (line < self.height - 0.5)
                & (col >= -0.5) & (col < self.width - 0.5))


def analytic_swath(height: int = 600, width: int = 2241, df: int = 64, dj: int = 64,
                   lat0: float = 46.5, lon0: float = 11.0, nadir_col: float = 0.0,
                   pixel_m: float = 260.0, track_deg: float = 192.0, orbit_alt_m: float = 800e3,
                   dem_amplitude_m: float = 2000.0) -> TiePointGrid:
    """A smooth synthetic swath (no real product needed), for tests and benchmarks.

    Lines run along ``track_deg`` (192 deg: descending, like the handbook's scene); stored
    columns run to the right of the track from ``nadir_col`` (col 0 east at nadir, as Appendix E);
    pixels grow slightly towards the edges; the view azimuth points towards the ground track.
    """
    n_lines = -(-(height - 1) // df) + 1
    n_cols = -(-(width - 1) // dj) + 1
    line = np.arange(n_lines)[:, None] * float(df)
    col = np.arange(n_cols)[None, :] * float(dj)
    across = (col - nadir_col) * pixel_m * (1.0 + 2e-4 * np.abs(col - nadir_col) / 10.0)
    along = line * pixel_m
    t = np.radians(track_deg)
    # along-track unit vector (east, north) and its right-hand normal
    east = along * np.sin(t) + across * np.cos(t)
    north = along * np.cos(t) - across * np.sin(t)
    lat = lat0 + np.degrees(north / MEAN_EARTH_RADIUS)
    lon = lon0 + np.degrees(east / (MEAN_EARTH_RADIUS * np.cos(np.radians(lat))))
    vz = np.degrees(np.arctan(np.abs(across) / orbit_alt_m)) + 0.0 * line
    # towards the track: opposite to the across-track direction of the pixel
    side = np.where(across >= 0.0, 1.0, -1.0)
    va = np.degrees(np.arctan2(-side * np.cos(t), side * np.sin(t))) % 360.0 + 0.0 * line
    dem = dem_amplitude_m * (0.5 + 0.5 * np.sin(line / 300.0) * np.cos(col / 400.0))
    return TiePointGrid(lat, lon, vz, va, dem, df, dj, height, width)


_FIELD_NAMES = tuple(f.name for f in fields(TiePoints))

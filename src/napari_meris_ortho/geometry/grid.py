"""Output grid of the orthorectified image (handbook section 3.1, Appendix C "SETTING PIXEL SIZE").

``OutputGrid(crs, x0, y0, dx, dy, width, height)``: (x0, y0) is the upper-left **corner**; pixel
(i, j) has its centre at ``(x0 + (j + 0.5) dx, y0 - (i + 0.5) dy)``; rasterio transform
``Affine(dx, 0, x0, 0, -dy, y0)``. Any CRS pyproj knows; x is easting/longitude (always_xy).

Map-to-geographic conversion (``OutputGrid.lonlat``):

- geographic WGS84 (EPSG:4326, OGC:CRS84, ...): exact arithmetic, longitudes wrapped to
  [-180, 180) (an x range such as 170..190 is allowed);
- any other CRS: pyproj on a *primary grid* every N output pixels and bilinear interpolation in
  between (the terrain-correction paper's output-to-input mapping, error about 0.01 px for 64 x 64
  windows). N is chosen from the error measured at the cell midpoints of a 64-pixel trial grid
  (the error of bilinear interpolation grows as N^2) so that the measured error stays below
  ``tolerance / 4``, band by band: each band of 64 output rows (the trial grid's row of cells)
  takes the step its own cells and their neighbours' allow, so that the few rows where the
  projection bends hardest (a polar stereographic grid near the pole) do not set the step of the
  whole grid. Every cell whose measured midpoint error still exceeds ``tolerance / 2`` (or whose
  corners are outside the projection) is computed exactly with pyproj, pixel by pixel.
  ``OutputGrid.interpolation_stats`` reports the smallest and largest step, the largest measured
  error and the number of exact fallback pixels. Over an FR footprint (~3700 x 3300 px at
  260 m), against pyproj at every pixel: a 64-px primary grid errs by 0.024 px in UTM 31/33 and
  LAEA (EPSG:3035); the chosen step (20 px) gives at most 0.0023 px; EPSG:32662 is exact (step
  256). The interpolation takes about a third of the time of one pyproj call per pixel. On an
  8001-line RR segment from 79 N in EPSG:3995 (9783 x 8728 px), one step for the whole grid
  would be 4 px (11.3 s); by bands the steps are 4-14 px (4.2 s), the largest error the same
  (0.0026 px).

Default grid (``default_grid``): the smallest rectangle holding the segment boundary (section 3.1,
fig. 19). Pixel size: MERSYN's nominal FR/RR size, 260 m / 1040 m in a metric CRS and, for a
"Geographic" output, the angle of that length on the mean Earth sphere R = 6 370 997 m
(Appendix C: ``TIM_FMT_ENVIRAT_MERIS_FR_PIXEL_SIZE / TIM_MERSYN_MEAN_EARTH_RADIUS``).
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np
import pyproj
from affine import Affine

from ..errors import OptionsError
from .earth import MAX_TERRAIN_M, MEAN_EARTH_RADIUS, METRES_PER_DEGREE

FR_PIXEL_SIZE_M = 260.0
RR_PIXEL_SIZE_M = 1040.0
INTERPOLATION_TOLERANCE_PX = 0.01
_TRIAL_STEP = 64
_MIN_STEP = 4
_MAX_STEP = 256
_WGS84 = pyproj.CRS.from_epsg(4326)


class _HasPolygons(Protocol):
    def polygons(self, crs: Any) -> list[tuple[np.ndarray, np.ndarray]]: ...


def parse_crs(crs: Any) -> pyproj.CRS:
    """A pyproj CRS from anything pyproj accepts ("EPSG:32631", WKT, PROJ string...)."""
    if isinstance(crs, pyproj.CRS):
        return crs
    try:
        return pyproj.CRS.from_user_input(crs)
    except (pyproj.exceptions.CRSError, TypeError, ValueError) as exc:
        raise OptionsError(f"unknown CRS {crs!r}: pyproj cannot interpret it") from exc


def crs_wkt(crs: Any) -> str:
    """WKT of any CRS input (EPSG int, 'EPSG:32632', pyproj/rasterio CRS, WKT)."""
    return str(parse_crs(crs).to_wkt())


def same_crs(a: Any, b: Any) -> bool:
    """True when two CRS inputs describe the same coordinate system."""
    return bool(parse_crs(a) == parse_crs(b))


def lonlat_to_crs(lon: np.ndarray, lat: np.ndarray, crs: Any) -> tuple[np.ndarray, np.ndarray]:
    """Project WGS84 lon/lat (degrees) into ``crs`` (always x = easting/lon, y = northing/lat)."""
    transformer = pyproj.Transformer.from_crs("EPSG:4326", parse_crs(crs), always_xy=True)
    x, y = transformer.transform(np.asarray(lon, np.float64), np.asarray(lat, np.float64))
    return np.asarray(x, np.float64), np.asarray(y, np.float64)


@functools.lru_cache(maxsize=64)
def crs_facts(crs: str) -> tuple[str, bool]:
    """(label, geographic) of a CRS given as text, parsed once per CRS (a pyproj database
    lookup costs 10-40 ms): label 'EPSG:32632' when it has an EPSG code, else its name."""
    parsed = parse_crs(crs)
    epsg = parsed.to_epsg()
    return (f"EPSG:{epsg}" if epsg else str(parsed.name)), bool(parsed.is_geographic)


#: semi-major axes (m) and inverse flattenings of the Earth ellipsoids and spheres a grid may use
_EARTH_SEMI_MAJOR_M = (6.3e6, 6.4e6)
_EARTH_INVERSE_FLATTENING = (250.0, 350.0)


def output_crs(crs: Any) -> pyproj.CRS:
    """:func:`parse_crs` restricted to what an output grid can use: a 2-D projected or
    geographic CRS on an Earth ellipsoid (or sphere). Geocentric, 3-D, compound, engineering
    (LOCAL_CS) and other bodies' CRSs raise OptionsError."""
    given = crs
    crs = parse_crs(crs)
    name = f"{given} ({crs.name})" if isinstance(given, str) else crs.name
    if crs.is_geocentric:
        raise OptionsError(f"CRS {name!r} is geocentric: an output grid needs a 2-D projected "
                           "or geographic CRS")
    if not (crs.is_projected or crs.is_geographic) or crs.is_compound or len(crs.axis_info) != 2:
        raise OptionsError(f"CRS {name!r} is not a 2-D projected or geographic CRS")
    ellipsoid = crs.ellipsoid
    a = ellipsoid.semi_major_metre if ellipsoid is not None else math.nan
    inv_f = ellipsoid.inverse_flattening if ellipsoid is not None else math.nan
    sphere = ellipsoid is not None and ellipsoid.semi_minor_metre == a
    if not (_EARTH_SEMI_MAJOR_M[0] <= a <= _EARTH_SEMI_MAJOR_M[1]
            and (sphere or _EARTH_INVERSE_FLATTENING[0] <= inv_f <= _EARTH_INVERSE_FLATTENING[1])):
        raise OptionsError(f"CRS {name!r} is not on the Earth (ellipsoid semi-major axis {a:g} m, "
                           f"inverse flattening {inv_f:g})")
    return crs


#: share of the available memory an output grid may take unless a pixel limit is given
MEMORY_SHARE = 0.8


def available_memory_bytes() -> int:
    """MemAvailable of /proc/meminfo (else the free physical pages), in bytes."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, AttributeError):
        return 4 << 30


def size_text(n: float) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} PiB"  # pragma: no cover


def pixel_limit(bytes_per_pixel: float, max_pixels: int | None = None,
                budget_bytes: int | None = None) -> int:
    """Most output pixels allowed: ``max_pixels``, else ``budget_bytes`` (default
    :data:`MEMORY_SHARE` of the available memory) over ``bytes_per_pixel``."""
    if max_pixels is not None:
        return int(max_pixels)
    budget = MEMORY_SHARE * available_memory_bytes() if budget_bytes is None else budget_bytes
    return max(int(budget / bytes_per_pixel), 1)


def check_grid_size(
    width: float, height: float, pixel_size: tuple[float, float], bytes_per_pixel: float,
    max_pixels: int | None = None, budget_bytes: int | None = None,
    budget_what: str = f"{MEMORY_SHARE:.0%} of the available memory",
    lower_bound: bool = False,
) -> None:
    """Refuse an output grid larger than :func:`pixel_limit` before anything is allocated.

    The message gives the grid size, the estimate ("at least" with ``lower_bound``: the part
    of the cost known so far), the limit and a pixel size that fits.
    """
    pixels = float(width) * float(height)
    limit = pixel_limit(bytes_per_pixel, max_pixels, budget_bytes)
    if pixels <= limit:
        return
    factor = math.sqrt(pixels / limit) * 1.01
    dx = max(pixel_size) * factor
    digits = 1 - int(math.floor(math.log10(dx))) if dx > 0 and math.isfinite(dx) else 0
    suggest = math.ceil(dx * 10**digits) / 10**digits
    source = ("--max-pixels" if max_pixels is not None else
              f"{size_text(limit * bytes_per_pixel)}, {budget_what}")  # fmt: skip
    raise OptionsError(
        f"output grid of {width:.0f} x {height:.0f} pixels ({pixels:.3g} pixels, "
        f"{'at least' if lower_bound else 'about'} {size_text(pixels * bytes_per_pixel)}) "
        f"exceeds the limit of {limit:.3g} pixels "
        f"({source}): use a pixel size of at least {suggest:g} or a smaller extent, or raise "
        "the limit (max_pixels; the command line's --max-pixels)"
    )


def utm_crs_for(lon: float, lat: float) -> pyproj.CRS:
    """The WGS84 UTM zone CRS (EPSG:326zz north / 327zz south) holding (lon, lat) in degrees."""
    lon = ((float(lon) + 180.0) % 360.0) - 180.0
    zone = min(int((lon + 180.0) // 6.0) + 1, 60)
    return pyproj.CRS.from_epsg((32600 if lat >= 0 else 32700) + zone)


#: the ``crs`` word for the UTM zone of a product's footprint (``product_crs``; ``--crs utm``,
#: the widget's default)
FOOTPRINT_UTM = "utm"


def footprint_utm(latitude: np.ndarray, longitude: np.ndarray) -> pyproj.CRS:
    """The UTM zone CRS of a product's footprint centre from its tie points (degrees): circular
    mean of the longitudes (a footprint across the antimeridian has its centre there), mean
    latitude."""
    lon = np.radians(np.asarray(longitude, np.float64))
    centre_lon = float(np.degrees(np.angle(np.mean(np.exp(1j * lon)))))
    return utm_crs_for(centre_lon, float(np.mean(latitude)))


def is_footprint_utm(crs: Any) -> bool:
    """True when ``crs`` is the word "utm" (``FOOTPRINT_UTM``, any case)."""
    return isinstance(crs, str) and crs.strip().lower() == FOOTPRINT_UTM


def product_crs(crs: Any, latitude: np.ndarray, longitude: np.ndarray) -> pyproj.CRS:
    """The output CRS of a product: ``output_crs(crs)``, or for the word "utm" the UTM zone of
    its footprint (``footprint_utm`` of its tie-point ``latitude``/``longitude``)."""
    return footprint_utm(latitude, longitude) if is_footprint_utm(crs) else output_crs(crs)


def pixel_size_for(resolution_m: float, crs: Any) -> float:
    """Pixel size in CRS units for a ground resolution in metres (Appendix C default).

    Geographic CRS: the angle of ``resolution_m`` on the sphere R = 6 370 997 m, in degrees.
    Projected CRS: ``resolution_m`` converted to the CRS linear unit.
    """
    crs = parse_crs(crs)
    if crs.is_geographic:
        return math.degrees(resolution_m / MEAN_EARTH_RADIUS)
    factor = crs.axis_info[0].unit_conversion_factor if crs.axis_info else 1.0
    return resolution_m / (factor or 1.0)


def pixel_pair(size: float | Sequence[float] | np.ndarray) -> tuple[float, float]:
    """(dx, dy) of a pixel size given as one number or as a pair."""
    if isinstance(size, Sequence | np.ndarray):
        dx, dy = size
        return float(dx), float(dy)
    return float(size), float(size)


def _is_lonlat_identity(crs: pyproj.CRS) -> bool:
    """True when (x, y) of the CRS are WGS84 (lon, lat) in degrees (no datum shift, no scaling)."""
    if not crs.is_geographic:
        return False
    try:
        tr = pyproj.Transformer.from_crs(crs, _WGS84, always_xy=True)
        x = np.array([-170.0, 0.0, 12.5, 150.0])
        y = np.array([-60.0, 0.0, 45.0, 70.0])
        lon, lat = tr.transform(x, y)
    except pyproj.exceptions.ProjError:
        return False
    return bool(np.all(np.abs(lon - x) < 1e-11) and np.all(np.abs(lat - y) < 1e-11))


def _wrap_lon(lon: np.ndarray) -> np.ndarray:
    return ((lon + 180.0) % 360.0) - 180.0


class OutputGrid:
    """Georeferenced output raster: CRS, upper-left corner (x0, y0), pixel size (dx, dy), size."""

    def __init__(
        self, crs: Any, x0: float, y0: float, dx: float, dy: float, width: int, height: int,
        tolerance: float = INTERPOLATION_TOLERANCE_PX,
    ) -> None:
        self.crs = output_crs(crs)
        self.x0, self.y0, self.dx, self.dy = float(x0), float(y0), float(dx), float(dy)
        self.width, self.height = int(width), int(height)
        if not (math.isfinite(self.dx) and math.isfinite(self.dy) and self.dx > 0 and self.dy > 0):
            raise OptionsError(f"pixel size must be > 0, got ({dx}, {dy})")
        if self.width <= 0 or self.height <= 0:
            raise OptionsError(f"output grid size must be > 0, got {width} x {height}")
        self.tolerance = float(tolerance)
        self.is_lonlat = _is_lonlat_identity(self.crs)
        try:
            self._to_lonlat = None if self.is_lonlat else pyproj.Transformer.from_crs(
                self.crs, _WGS84, always_xy=True)
            self._from_lonlat = None if self.is_lonlat else pyproj.Transformer.from_crs(
                _WGS84, self.crs, always_xy=True)
        except pyproj.exceptions.ProjError as exc:
            raise OptionsError(f"CRS {self.crs.name!r}: no transformation to WGS84 ({exc})"
                               ) from None
        self._steps: np.ndarray | None = None
        self.interpolation_stats: dict[str, float] = {
            "step": 0, "max_step": 0, "trial_max_error_px": 0.0, "max_error_px": 0.0,
            "exact_pixels": 0}

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_extent(
        cls, crs: Any, ul: Sequence[float], lr: Sequence[float],
        pixel_size: float | Sequence[float],
    ) -> OutputGrid:
        """Grid from a user extent: upper-left and lower-right corners (x, y) and a pixel size.

        The lower-right corner is rounded outwards to whole pixels. Raises OptionsError when the
        pixel size is <= 0, upper-left is not left of and above lower-right, or the CRS is unknown.
        """
        crs = parse_crs(crs)
        dx, dy = pixel_pair(pixel_size)
        if not (dx > 0 and dy > 0 and math.isfinite(dx) and math.isfinite(dy)):
            raise OptionsError(f"pixel size must be > 0, got {pixel_size}")
        (ulx, uly), (lrx, lry) = (map(float, ul), map(float, lr))
        if not all(math.isfinite(v) for v in (ulx, uly, lrx, lry)):
            raise OptionsError(f"extent corners must be finite numbers, got {ul} and {lr}")
        check_degree_pixel(crs, dx, dy)
        if not (ulx < lrx and uly > lry):
            raise OptionsError(
                f"upper-left {tuple(ul)} must be left of and above lower-right {tuple(lr)}")
        if crs.is_geographic and not (-90.0 <= lry and uly <= 90.0):
            raise OptionsError(f"latitudes of the extent {uly:g} .. {lry:g} beyond +-90 degrees "
                               f"(a geographic CRS: corners are longitude, latitude)")
        width = max(1, math.ceil((lrx - ulx) / dx - 1e-9))
        height = max(1, math.ceil((uly - lry) / dy - 1e-9))
        return cls(crs, ulx, uly, dx, dy, width, height)

    @classmethod
    def from_transform(cls, crs: Any, transform: Sequence[float], shape: Sequence[int]
                       ) -> OutputGrid:
        """Grid of a north-up raster: rasterio/affine transform (a, b, c, d, e, f) and
        (..., rows, cols). Raises OptionsError for a rotated or south-up transform."""
        a, b, c, d, e, f = (float(v) for v in tuple(transform)[:6])
        if b != 0.0 or d != 0.0 or a <= 0.0 or e >= 0.0:
            raise OptionsError(f"raster is not north-up (transform {a, b, c, d, e, f})")
        return cls(crs, c, f, a, -e, int(shape[-1]), int(shape[-2]))

    def window(self, row0: int, row1: int, col0: int, col1: int) -> OutputGrid:
        """The sub-grid of rows [row0, row1) and columns [col0, col1): same CRS, pixel size and
        interpolation tolerance; its pixel (i, j) is pixel (row0 + i, col0 + j) of this grid.

        Raises OptionsError when the window is empty or leaves the grid.
        """
        row0, row1, col0, col1 = int(row0), int(row1), int(col0), int(col1)
        if not (0 <= row0 < row1 <= self.height and 0 <= col0 < col1 <= self.width):
            raise OptionsError(f"window rows [{row0}, {row1}) x columns [{col0}, {col1}) is "
                               f"empty or outside the {self.height} x {self.width} grid")
        return OutputGrid(self.crs, self.x0 + col0 * self.dx, self.y0 - row0 * self.dy,
                          self.dx, self.dy, col1 - col0, row1 - row0, tolerance=self.tolerance)

    def lattice_cover(self, other: OutputGrid) -> OutputGrid:
        """The grid in this grid's CRS, pixel size and pixel lattice (its pixels are this
        grid's, extended beyond its edges) that covers ``other``'s extent. Raises OptionsError
        when that extent has no finite bounds in this grid's CRS."""
        try:
            tr = pyproj.Transformer.from_crs(other.crs, self.crs, always_xy=True)
            xmin, ymin, xmax, ymax = tr.transform_bounds(*other.bounds, densify_pts=21)
        except pyproj.exceptions.ProjError as exc:
            raise OptionsError(f"{other!r} has no extent in {self.crs.name!r} ({exc})") from None
        if not all(math.isfinite(v) for v in (xmin, ymin, xmax, ymax)):
            raise OptionsError(f"{other!r} has no finite extent in {self.crs.name!r}")
        col0 = math.floor((xmin - self.x0) / self.dx + 1e-9)
        col1 = math.ceil((xmax - self.x0) / self.dx - 1e-9)
        row0 = math.floor((self.y0 - ymax) / self.dy + 1e-9)
        row1 = math.ceil((self.y0 - ymin) / self.dy - 1e-9)
        return OutputGrid(self.crs, self.x0 + col0 * self.dx, self.y0 - row0 * self.dy,
                          self.dx, self.dy, max(col1 - col0, 1), max(row1 - row0, 1),
                          tolerance=self.tolerance)

    # ------------------------------------------------------------------ properties
    @property
    def transform(self) -> Affine:
        """rasterio/GDAL affine transform of the pixel corners."""
        return Affine(self.dx, 0.0, self.x0, 0.0, -self.dy, self.y0)

    @property
    def is_geographic(self) -> bool:
        return bool(self.crs.is_geographic)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the pixel corners."""
        return (self.x0, self.y0 - self.height * self.dy, self.x0 + self.width * self.dx, self.y0)

    def __repr__(self) -> str:
        name = self.crs.to_string()
        return (f"OutputGrid({name!r}, x0={self.x0!r}, y0={self.y0!r}, dx={self.dx!r}, "
                f"dy={self.dy!r}, width={self.width}, height={self.height})")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, OutputGrid):
            return NotImplemented
        return (self.crs == other.crs and self.shape == other.shape and np.allclose(
            [self.x0, self.y0, self.dx, self.dy], [other.x0, other.y0, other.dx, other.dy],
            rtol=1e-12, atol=0.0))

    __hash__ = None  # type: ignore[assignment]

    def same_grid(self, other: OutputGrid, rtol: float = 1e-9) -> bool:
        """True when both grids have the same CRS and pixel size (origins and sizes may differ)."""
        return bool(self.crs == other.crs and np.allclose(
            (self.dx, self.dy), (other.dx, other.dy), rtol=rtol, atol=0.0))

    # ------------------------------------------------------------------ coordinates
    def xy(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map coordinates of fractional (row, col) pixel positions (integers = centres)."""
        rows = np.asarray(rows, dtype=np.float64)
        cols = np.asarray(cols, dtype=np.float64)
        return self.x0 + (cols + 0.5) * self.dx, self.y0 - (rows + 0.5) * self.dy

    def lonlat_exact(self, row_start: int = 0, row_stop: int | None = None, *,
                     col_start: int = 0, col_stop: int | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
        """WGS84 (lon, lat) of every pixel centre of rows [row_start, row_stop) and columns
        [col_start, col_stop), one pyproj call per pixel (reference for ``lonlat``)."""
        row_start, row_stop = self._row_range(row_start, row_stop)
        col_start, col_stop = self._col_range(col_start, col_stop)
        cols = np.arange(col_start, col_stop, dtype=np.float64)
        rows = np.arange(row_start, row_stop, dtype=np.float64)
        x, y = self.xy(rows[:, None], cols[None, :])
        shape = (rows.size, cols.size)
        if self.is_lonlat:  # separable: one row of longitudes, one column of latitudes
            lon, lat = self._xy_to_lonlat(x, y)
            return np.broadcast_to(lon, shape).copy(), np.broadcast_to(lat, shape).copy()
        x, y = np.broadcast_arrays(x, y)
        return self._xy_to_lonlat(x, y)

    def lonlat(self, row_start: int = 0, row_stop: int | None = None, *,
               col_start: int = 0, col_stop: int | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """WGS84 (lon, lat) float64 arrays (rows, columns) of the pixel centres of rows
        [row_start, row_stop) and columns [col_start, col_stop) (default: the whole rows),
        exact to ``tolerance`` output pixel (module docstring). A column window holds the
        values of the whole rows bit for bit (the same nodes, cells and fallbacks).

        Longitudes in [-180, 180); NaN where the CRS has no geographic position.
        """
        row_start, row_stop = self._row_range(row_start, row_stop)
        col_start, col_stop = self._col_range(col_start, col_stop)
        if self.is_lonlat:
            return self.lonlat_exact(row_start, row_stop, col_start=col_start, col_stop=col_stop)
        return self._lonlat_primary(row_start, row_stop, col_start, col_stop)

    def lonlat_at(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """WGS84 (lon, lat) of fractional (row, col) pixel positions, exact (one pyproj call per
        point; positions may lie past the grid edge); broadcast; NaN without a position."""
        x, y = np.broadcast_arrays(*self.xy(rows, cols))
        return self._xy_to_lonlat(x, y)

    def xy_of_lonlat(self, lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fractional (row, col) of WGS84 (lon, lat) points (integers = pixel centres).

        Geographic grids take the longitude turn (+-360) closest to the grid centre.
        """
        lon = np.asarray(lon, dtype=np.float64)
        lat = np.asarray(lat, dtype=np.float64)
        if self.is_lonlat:
            xc = self.x0 + 0.5 * self.width * self.dx
            x = lon + 360.0 * np.round((xc - lon) / 360.0)
            y = lat
        else:
            assert self._from_lonlat is not None
            x, y = self._from_lonlat.transform(lon, lat)
            x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
            bad = ~(np.isfinite(x) & np.isfinite(y))
            if np.any(bad):
                x, y = np.where(bad, np.nan, x), np.where(bad, np.nan, y)
        return (self.y0 - y) / self.dy - 0.5, (x - self.x0) / self.dx - 0.5

    # ------------------------------------------------------------------ internals
    def _row_range(self, row_start: int, row_stop: int | None) -> tuple[int, int]:
        return _index_range("row", row_start, row_stop, self.height)

    def _col_range(self, col_start: int, col_stop: int | None) -> tuple[int, int]:
        return _index_range("column", col_start, col_stop, self.width)

    def _xy_to_lonlat(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.is_lonlat:
            return _wrap_lon(np.array(x, dtype=np.float64)), np.array(y, dtype=np.float64)
        assert self._to_lonlat is not None
        lon, lat = self._to_lonlat.transform(x, y, errcheck=False)
        lon = np.asarray(lon, dtype=np.float64)
        lat = np.asarray(lat, dtype=np.float64)
        bad = ~(np.isfinite(lon) & np.isfinite(lat))
        if np.any(bad):
            lon, lat = np.where(bad, np.nan, lon), np.where(bad, np.nan, lat)
        return _wrap_lon(lon), lat

    def _band_nodes(self, band: int, step: int) -> tuple[np.ndarray, np.ndarray]:
        """Primary-grid node rows and columns of band ``band`` (output rows [64 band, 64 band +
        64)): every ``step`` rows from the band's first row, then the next band's first row (the
        grid's last row in the last band); every ``step`` columns and the last column."""
        first = band * _TRIAL_STEP
        end = min(first + _TRIAL_STEP, self.height - 1)
        rows = _nodes(first, end + 1, step)
        cols = _nodes(0, self.width, step)
        return rows, cols

    def _cell_errors(self, rows: np.ndarray, cols: np.ndarray, lon: np.ndarray, lat: np.ndarray
                     ) -> np.ndarray:
        """Interpolation error (output px) measured at the centre and edge midpoints of each
        primary cell; +inf where the cell cannot be interpolated."""
        nr, nc = max(rows.size - 1, 1), max(cols.size - 1, 1)
        if rows.size < 2 or cols.size < 2:
            return np.full((nr, nc), np.inf)
        err = np.zeros((nr, nc))
        rm = 0.5 * (rows[:-1] + rows[1:])
        cm = 0.5 * (cols[:-1] + cols[1:])
        probes = [(rm, cm, (0.5, 0.5)), (rows[:-1], cm, (0.0, 0.5)), (rm, cols[:-1], (0.5, 0.0))]
        lon_u = _unwrap_cells(lon)
        drow = np.diff(rows)[:, None]
        dcol = np.diff(cols)[None, :]
        jlc = (lon_u[1] - lon_u[0]) / dcol
        jlr = (lon_u[2] - lon_u[0]) / drow
        jpc = (lat[:-1, 1:] - lat[:-1, :-1]) / dcol
        jpr = (lat[1:, :-1] - lat[:-1, :-1]) / drow
        det = jlc * jpr - jlr * jpc
        for pr, pc, (fr, fc) in probes:
            x, y = self.xy(pr[:, None], pc[None, :])
            x, y = np.broadcast_arrays(x, y)
            elon, elat = self._xy_to_lonlat(x, y)
            ilon = _bilinear_cells(lon_u, fr, fc)
            ilat = _bilinear_cells((lat[:-1, :-1], lat[:-1, 1:], lat[1:, :-1], lat[1:, 1:]), fr, fc)
            dlon = ((elon - ilon + 180.0) % 360.0) - 180.0
            dlat = elat - ilat
            with np.errstate(divide="ignore", invalid="ignore"):
                ec = (jpr * dlon - jlr * dlat) / det
                er = (-jpc * dlon + jlc * dlat) / det
                e = np.hypot(ec, er)
            err = np.maximum(err, np.where(np.isfinite(e), e, np.inf))
        return err

    def primary_steps(self) -> np.ndarray:
        """Primary-grid step N (pixels) of each band of 64 output rows, from the error measured on
        a 64-pixel trial grid over the band's cells and its neighbours' (module docstring)."""
        if self._steps is None:
            all_rows = _nodes(0, self.height, _TRIAL_STEP)
            cols = _nodes(0, self.width, _TRIAL_STEP)
            x, y = self.xy(all_rows[:, None], cols[None, :])
            x, y = np.broadcast_arrays(x, y)
            lon, lat = self._xy_to_lonlat(x, y)
            err = self._cell_errors(all_rows, cols, lon, lat)
            band_err = np.max(np.where(np.isfinite(err), err, 0.0), axis=1)
            near = band_err.copy()  # the band's own cells and those of the bands beside it
            near[1:] = np.maximum(near[1:], band_err[:-1])
            near[:-1] = np.maximum(near[:-1], band_err[1:])
            with np.errstate(divide="ignore"):
                steps = _TRIAL_STEP * np.sqrt(0.25 * self.tolerance / near)
            n_bands = (self.height + _TRIAL_STEP - 1) // _TRIAL_STEP
            steps = np.clip(np.nan_to_num(steps, posinf=_MAX_STEP), _MIN_STEP, _MAX_STEP)
            steps = steps.astype(np.int64)  # a last band of one row has no cell of its own
            self._steps = np.r_[steps, np.full(max(n_bands - steps.size, 0), steps[-1])]
            self.interpolation_stats["step"] = int(self._steps.min())
            self.interpolation_stats["max_step"] = int(self._steps.max())
            self.interpolation_stats["trial_max_error_px"] = float(band_err.max())
        return self._steps

    def _lonlat_primary(self, row_start: int, row_stop: int, col_start: int, col_stop: int
                        ) -> tuple[np.ndarray, np.ndarray]:
        lon = np.empty((row_stop - row_start, col_stop - col_start))
        lat = np.empty((row_stop - row_start, col_stop - col_start))
        if lon.size == 0:
            return lon, lat
        steps = self.primary_steps()
        for band in range(row_start // _TRIAL_STEP, (row_stop - 1) // _TRIAL_STEP + 1):
            r0 = max(row_start, band * _TRIAL_STEP)
            r1 = min(row_stop, (band + 1) * _TRIAL_STEP)
            if r1 > r0:
                self._lonlat_band(band, int(steps[band]), (r0, r1, col_start, col_stop),
                                  lon[r0 - row_start:r1 - row_start],
                                  lat[r0 - row_start:r1 - row_start])
        return lon, lat

    def _lonlat_band(self, band: int, step: int, window: tuple[int, int, int, int],
                     lon: np.ndarray, lat: np.ndarray) -> None:
        """Rows [r0, r1) and columns [c0, c1) (``window``) of band ``band`` into ``lon``/``lat``:
        bilinear between the band's primary-grid nodes (those around the columns only),
        exactly (pyproj per pixel) in cells measured too far off."""
        row_start, _, col_start, col_stop = window
        rows, cols = self._band_nodes(band, step)
        if cols.size > 2:  # the cells the whole rows would use for these columns
            last = cols.size - 2
            k0 = min(max(int(np.searchsorted(cols, col_start, side="right")) - 1, 0), last)
            k1 = min(max(int(np.searchsorted(cols, col_stop - 1, side="right")) - 1, 0), last)
            cols = cols[k0:k1 + 2]
        x, y = self.xy(rows[:, None], cols[None, :])
        x, y = np.broadcast_arrays(x, y)
        nlon, nlat = self._xy_to_lonlat(x, y)
        err = self._cell_errors(rows, cols, nlon, nlat)
        bad = ~(err <= 0.5 * self.tolerance)
        ok = err[~bad]
        if ok.size:
            stats = self.interpolation_stats
            stats["max_error_px"] = max(stats["max_error_px"], float(ok.max()))
        _interpolate_primary(rows.astype(np.int64), cols.astype(np.int64), nlon, nlat,
                             bad, (row_start, col_start), lon, lat)
        need = np.isnan(lon)
        if np.any(need):
            ii, jj = np.nonzero(need)
            ex, ey = self.xy(ii + row_start, jj + col_start)
            elon, elat = self._xy_to_lonlat(ex, ey)
            lon[ii, jj], lat[ii, jj] = elon, elat
            self.interpolation_stats["exact_pixels"] += int(ii.size)


def _nodes(start: int, stop: int, step: int) -> np.ndarray:
    """Primary-grid node positions: every ``step`` from ``start`` below ``stop``, and
    ``stop - 1``."""
    return np.unique(np.r_[np.arange(start, stop, step), stop - 1])


def _index_range(what: str, start: int, stop: int | None, size: int) -> tuple[int, int]:
    """[start, stop) as ints (stop None: ``size``); ValueError unless 0 <= start <= stop <= size."""
    stop = size if stop is None else int(stop)
    start = int(start)
    if not 0 <= start <= stop <= size:
        raise ValueError(f"{what} range [{start}, {stop}) outside 0..{size}")
    return start, stop


def _unwrap_cells(lon: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Corner longitudes (00, 01, 10, 11) of every cell, unwrapped relative to corner 00."""
    c00 = lon[:-1, :-1]

    def near(c: np.ndarray) -> np.ndarray:
        return c00 + (((c - c00) + 180.0) % 360.0 - 180.0)

    return c00, near(lon[:-1, 1:]), near(lon[1:, :-1]), near(lon[1:, 1:])


def _bilinear_cells(corners: tuple[np.ndarray, ...], fr: float, fc: float) -> np.ndarray:
    c00, c01, c10, c11 = corners
    return (c00 * (1 - fr) * (1 - fc) + c01 * (1 - fr) * fc + c10 * fr * (1 - fc)
            + c11 * fr * fc)


def _cell_index(x: np.ndarray, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Primary cell (k, k1) holding each x (edge cells extended) and the offset in it."""
    k = np.clip(np.searchsorted(nodes, x, side="right") - 1, 0, max(nodes.size - 2, 0))
    k1 = np.minimum(k + 1, nodes.size - 1)
    span = (nodes[k1] - nodes[k]).astype(np.float64)
    f = np.where(k1 == k, 0.0, (x - nodes[k]) / np.where(span == 0.0, 1.0, span))
    return k, k1, f


def _interpolate_primary(rows: np.ndarray, cols: np.ndarray, nlon: np.ndarray, nlat: np.ndarray,
                         bad: np.ndarray, origin: tuple[int, int], lon: np.ndarray,
                         lat: np.ndarray) -> None:
    """Bilinear interpolation of lon/lat between primary-grid nodes (terrain-correction paper);
    NaN in cells marked bad (computed exactly by the caller). Longitudes are unwrapped relative
    to each cell's first node. One band of output rows per row of primary cells: along the
    columns on the two node rows, then between them."""
    n_rows, width = lon.shape
    row_start, col_start = origin  # of lon[0, 0] in the grid
    c, c1, fc = _cell_index(np.arange(col_start, col_start + width), cols)
    r_of, r1_of, fr_of = _cell_index(np.arange(row_start, row_start + n_rows), rows)
    bad_cols = np.minimum(c, bad.shape[1] - 1)
    starts = np.flatnonzero(np.r_[True, r_of[1:] != r_of[:-1]])
    for k, i0 in enumerate(starts):
        i1 = starts[k + 1] if k + 1 < starts.size else n_rows
        r, r1 = r_of[i0], r1_of[i0]
        f = fr_of[i0:i1, None]
        a = nlon[r, c]
        top = a + fc * _wrap_lon(nlon[r, c1] - a)
        bottom = a + (1.0 - fc) * _wrap_lon(nlon[r1, c] - a) + fc * _wrap_lon(nlon[r1, c1] - a)
        lon[i0:i1] = _wrap_lon((1.0 - f) * top + f * bottom)
        top = (1.0 - fc) * nlat[r, c] + fc * nlat[r, c1]
        bottom = (1.0 - fc) * nlat[r1, c] + fc * nlat[r1, c1]
        lat[i0:i1] = (1.0 - f) * top + f * bottom
        cell_bad = bad[min(r, bad.shape[0] - 1), bad_cols]
        lon[i0:i1, cell_bad] = np.nan
        lat[i0:i1, cell_bad] = np.nan


def terrain_margin_px(grid: OutputGrid, view_zenith_deg: float, max_abs_lat_deg: float,
                      max_terrain_m: float = MAX_TERRAIN_M) -> int:
    """Output pixels beyond the zero-height segment boundary that a terrain point may reach
    (section 3.1): the parallax ``max_terrain_m x tan(view_zenith_deg)`` over the narrower pixel
    side (geographic grids: at ``max_abs_lat_deg``, at most 89 deg), plus 2."""
    shift_m = max_terrain_m * math.tan(math.radians(view_zenith_deg))
    if grid.is_geographic:
        lat = min(max_abs_lat_deg, 89.0)
        pixel_m = min(grid.dx * math.cos(math.radians(lat)), grid.dy) * METRES_PER_DEGREE
    else:
        pixel_m = min(grid.dx, grid.dy)
    return int(math.ceil(shift_m / max(pixel_m, 1e-9))) + 2


#: a footprint cut in pieces by the CRS (at the antimeridian) whose rectangle is this many
#: times the pieces' own rectangles spans the CRS's world, not the footprint
CUT_FOOTPRINT_RATIO = 4.0


def _check_not_cut(pieces: list[tuple[np.ndarray, np.ndarray]], crs: pyproj.CRS,
                   area: float) -> None:
    """Refuse a footprint that ``crs`` cuts (the boundary polygons of fig. 20 land at both
    ends of its x range, e.g. Web Mercator at 180 deg): the smallest rectangle holding them
    would be as wide as the world, the footprint a few percent of it."""
    own = 0.0
    for x, y in pieces:
        ok = np.isfinite(x) & np.isfinite(y)
        if ok.any():
            own += float(np.ptp(x[ok]) * np.ptp(y[ok]))
    if own > 0 and area > CUT_FOOTPRINT_RATIO * own:
        raise OptionsError(
            f"the footprint crosses the antimeridian, where {crs.name} cuts the world: its "
            f"rectangle would be {area / own:.0f} times the footprint's own; use a CRS that "
            "does not cut there (EPSG:4326, EPSG:3832 Pacific Mercator, the footprint's UTM "
            "zone) or give the extent (--ul/--lr)")


#: the largest pixel (degrees) a user may ask of a geographic CRS: more is a size in metres
#: given in degrees (``--pixel-size 260`` with EPSG:4326: a 260-degree pixel)
MAX_DEGREE_PIXEL = 1.0


def check_degree_pixel(crs: pyproj.CRS, dx: float, dy: float) -> None:
    """Refuse a pixel of more than ``MAX_DEGREE_PIXEL`` in a geographic CRS (OptionsError
    saying the unit, where 260 "m" in EPSG:4326 would otherwise end in "the extent misses the
    product footprint")."""
    if crs.is_geographic and max(dx, dy) > MAX_DEGREE_PIXEL:
        raise OptionsError(
            f"pixel size {max(dx, dy):g} in {crs.name} is in degrees ({max(dx, dy):g} deg is "
            f"about {max(dx, dy) * 111.2:.0f} km): a MERIS FR pixel is 0.0023 deg (260 m), RR "
            "0.0094 deg (1040 m); for metres choose a projected CRS")


def default_grid(
    boundary: _HasPolygons, resolution_m: float = FR_PIXEL_SIZE_M, crs: Any = "EPSG:4326", *,
    pixel_size: float | Sequence[float] | None = None, mersyn_size: bool = False,
) -> OutputGrid:
    """The smallest rectangle holding the segment boundary (section 3.1, fig. 19).

    Pixel size: ``pixel_size`` in CRS units, else ``pixel_size_for(resolution_m, crs)``
    (260 m FR, 1040 m RR; geographic: that angle on R = 6 370 997 m, Appendix C).
    The size is rounded up to whole pixels; ``mersyn_size=True`` reproduces MERSYN instead
    (Appendix C "COMPUTING IMAGE SIZE AND ORIGIN", Appendix B logs: y_max grows by 1/10000 of the
    height, lines = int((y_max - y_min + 1) / dy), columns = int((x_max - x_min) / dx)).
    In a projected CRS the upper-left corner moves out to the next multiples of the pixel size
    (``aligned_origin``), so that the default grids of different products line up pixel for
    pixel; a geographic grid keeps MERSYN's origin, the boundary's corner.
    """
    crs = output_crs(crs)
    if pixel_size is None:
        dx = dy = pixel_size_for(resolution_m, crs)
    else:
        dx, dy = pixel_pair(pixel_size)
    if not (dx > 0 and dy > 0 and math.isfinite(dx) and math.isfinite(dy)):
        raise OptionsError(f"pixel size must be > 0, got {dx}, {dy}")
    if pixel_size is not None:
        check_degree_pixel(crs, dx, dy)
    pts = [p for p in boundary.polygons(crs) if p[0].size]
    if not pts:
        raise OptionsError(f"the segment boundary has no position in {crs.name}")
    xs = np.concatenate([p[0] for p in pts])
    ys = np.concatenate([p[1] for p in pts])
    ok = np.isfinite(xs) & np.isfinite(ys)
    x_min, x_max = float(xs[ok].min()), float(xs[ok].max())
    y_min, y_max = float(ys[ok].min()), float(ys[ok].max())
    if _is_lonlat_identity(crs):  # west edge in [-180, 180); the east edge may pass 180
        turn = 360.0 * math.floor((x_min + 180.0) / 360.0)
        x_min, x_max = x_min - turn, x_max - turn
    elif len(pts) > 1:
        _check_not_cut(pts, crs, (x_max - x_min) * (y_max - y_min))
    if mersyn_size:
        y_max = y_max + (y_max - y_min) / 10000.0
        height = int((y_max - y_min + 1.0) / dy)
        width = int((x_max - x_min) / dx)
    else:
        if crs.is_projected:
            x_min, y_max = aligned_origin(x_min, y_max, dx, dy)
        height = math.ceil((y_max - y_min) / dy - 1e-9)
        width = math.ceil((x_max - x_min) / dx - 1e-9)
    return OutputGrid(crs, x_min, y_max, dx, dy, max(width, 1), max(height, 1))


def aligned_origin(x_min: float, y_max: float, dx: float, dy: float) -> tuple[float, float]:
    """The upper-left corner (``x_min``, ``y_max``) moved west and north to the nearest
    multiples of the pixel size (``dx``, ``dy``): less than a pixel, so the rectangle still
    holds what it held."""
    return math.floor(x_min / dx + 1e-9) * dx, math.ceil(y_max / dy - 1e-9) * dy

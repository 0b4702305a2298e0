"""DEM quality control against GPS points (DEMCHK, handbook section 5.2 and Appendix F).

For each ground control point (X_i, Y_i, H_i) (longitude, latitude in degrees, ellipsoidal
height in metres) DEMCHK checks whether the point is inside the DEM; if so the DEM height h_i is
interpolated (nearest neighbour, bilinear or bicubic) and the differences H_i - h_i are summarised:

    ARITHMETIC MEAN    = 1/N sum (H_i - h_i)
    QUADRATIC MEAN     = sqrt(1/N sum (h_i - H_i)^2)
    STANDARD DEVIATION = sqrt(1/N sum (h_i - H_i)^2 - [1/N sum (h_i - H_i)]^2)
    MINIMUM, MAXIMUM   = min, max of (H_i - h_i)

A point is "inside" where a DEM of the list gives a height (``dem.stack.DemStack``: outside or a
no-data post used by the interpolation sends the point to the next DEM, then outside).
DEM heights above the geoid are put on the ellipsoid, h = H_dem + N, by the same code as the
orthorectification (``dem.geoid``, EGM96 from proj-data): each DEM entry has its vertical datum
(``PATH:egm96``, SRTM30 and Copernicus by default); ``geoid="egm96"`` takes every entry without
an explicit datum as EGM96 heights. A raster of undulations N (any raster ``dem.stack.open_dem``
reads) may be given instead; the DEM heights are then used as stored.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._atomic import atomic_path, check_input_file
from ..dem.base import METHODS, DemSource
from ..dem.geoid import EGM96, ELLIPSOID, GEOID_GRID, split_datum
from ..dem.stack import DemStack, open_dem
from ..display import fixed
from ..errors import OptionsError

__all__ = [
    "METHOD_TITLES", "DemCheckResult", "ElevationStatistics", "GroundControlPoints", "MethodCheck",
    "demcheck", "elevation_statistics", "plot_histogram", "read_points",
]

METHOD_TITLES = {"nearest": "Nearest neighbour", "bilinear": "Bi-linear", "bicubic": "Bi-cubic"}

_ALIASES = {
    "lon": ("lon", "long", "longitude", "easting", "x", "lambda", "lng"),
    "lat": ("lat", "latitude", "northing", "y", "phi"),
    "h": ("h", "height", "elevation", "ellipsoidalheight", "ellipsoidheight", "hell", "z",
          "alt", "altitude", "gcpelevation", "gcpelevat", "gcpheight"),
}
_LISTING = re.compile(r"(\d+)\s*:\s+(-?\d+\.\d+)\s+(-?\d+\.\d+)\s+(-?\d+\.\d+)")


@dataclass(frozen=True)
class GroundControlPoints:
    """GPS points: longitude, latitude (deg), ellipsoidal height H (m), their numbers, a label."""

    lon: np.ndarray
    lat: np.ndarray
    h: np.ndarray
    number: np.ndarray
    label: str = "points"

    def __len__(self) -> int:
        return int(self.lon.size)

    @classmethod
    def from_arrays(cls, lon, lat, h, label: str = "points") -> GroundControlPoints:
        """Points from three equal-length sequences (numbered from 1)."""
        lon, lat, h = (np.asarray(v, dtype=np.float64).ravel() for v in (lon, lat, h))
        if not lon.size == lat.size == h.size:
            raise OptionsError(f"{label}: lon, lat and h have different lengths")
        _check_values(lon, lat, h, label)
        return cls(lon, lat, h, np.arange(1, lon.size + 1), label)


@dataclass(frozen=True)
class ElevationStatistics:
    """The five DEMCHK statistics of H - h (section 5.2) over N processed points."""

    n: int
    arithmetic_mean: float
    quadratic_mean: float
    standard_deviation: float
    minimum: float
    maximum: float


@dataclass
class MethodCheck:
    """One interpolation method: DEM heights (NaN outside), inside mask, H - h, statistics."""

    method: str
    dem_heights: np.ndarray
    inside: np.ndarray
    differences: np.ndarray
    statistics: ElevationStatistics


@dataclass
class DemCheckResult:
    """DEMCHK of a point set against a DEM list, per interpolation method (Appendix F)."""

    points: GroundControlPoints
    dem_label: str
    methods: dict[str, MethodCheck] = field(default_factory=dict)
    geoid_label: str | None = None

    def report(self, listing: bool = True) -> str:
        """Appendix F's logs (one per method), with the GCP listing when ``listing``."""
        return "\n".join(_method_report(self, m, listing) for m in self.methods.values())

    def summary_table(self) -> str:
        """Table 4 of section 5.2: the statistics side by side, one column per method."""
        names = list(self.methods)
        rows = [("", [METHOD_TITLES[n] for n in names])]
        for label, key, signed in _STAT_ROWS:
            values = [getattr(self.methods[n].statistics, key) for n in names]
            rows.append((label, [_number(v, signed) for v in values]))
        return "\n".join(f"{label:<20}" + "".join(f"{v:>20}" for v in vals) for label, vals in rows)


_STAT_ROWS = (("ARITHMETIC MEAN", "arithmetic_mean", True),
              ("QUADRATIC MEAN", "quadratic_mean", False),
              ("STANDARD DEVIATION", "standard_deviation", False),
              ("MINIMUM", "minimum", True), ("MAXIMUM", "maximum", True))


def _number(value: float, signed: bool) -> str:
    """3 decimals as Appendix F ('-' when no point was processed)."""
    if not math.isfinite(value):
        return "-"
    return f"{value:+.3f}" if signed else f"{value:.3f}"


def elevation_statistics(gcp_heights, dem_heights) -> ElevationStatistics:
    """Section 5.2 formulas over the points where both heights are finite (H = GCP, h = DEM)."""
    H = np.asarray(gcp_heights, dtype=np.float64)
    h = np.asarray(dem_heights, dtype=np.float64)
    ok = np.isfinite(H) & np.isfinite(h)
    d = H[ok] - h[ok]
    n = int(d.size)
    if n == 0:
        nan = math.nan
        return ElevationStatistics(0, nan, nan, nan, nan, nan)
    mean = float(d.sum() / n)
    square = float(np.sum(d * d) / n)
    std = math.sqrt(max(square - mean * mean, 0.0))
    return ElevationStatistics(n, mean, math.sqrt(square), std, float(d.min()), float(d.max()))


def demcheck(
    points: GroundControlPoints | str | os.PathLike[str],
    dems: Sequence[DemSource | str | os.PathLike[str]] | DemSource | str | os.PathLike[str],
    methods: Sequence[str] = ("nearest", "bilinear", "bicubic"),
    geoid: DemSource | str | os.PathLike[str] | None = None,
) -> DemCheckResult:
    """Compare GPS points with a DEM list for each interpolation method (section 5.2, DEMCHK).

    ``geoid``: "egm96" (DEM entries without a datum suffix are EGM96 heights, ``dem.geoid``)
    or a raster of geoid undulations N (m) added to the stored DEM heights (points where N is
    unknown are outside).
    """
    if not isinstance(points, GroundControlPoints):
        points = read_points(points)
    methods = tuple(methods)
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise OptionsError(f"unknown interpolation method(s) {bad}; choose among {METHODS}")
    if isinstance(dems, DemSource | str | os.PathLike):
        dems = [dems]
    if not dems:
        raise OptionsError("no DEM given to control")
    labels = ", ".join(_label(d) for d in dems)
    if geoid is not None:
        dems = [_with_datum(d, EGM96 if geoid == EGM96 else ELLIPSOID,
                            force=geoid != EGM96) for d in dems]
    stack = DemStack([d if isinstance(d, DemSource) else Path(d) for d in dems])
    undulation = _geoid_undulation(None if geoid == EGM96 else geoid, points)
    label = f"EGM96 ({GEOID_GRID})" if geoid == EGM96 else (
        None if geoid is None else _label(geoid))
    result = DemCheckResult(points, labels, geoid_label=label)
    for method in methods:
        h, _index = stack.sample(points.lon, points.lat, method)
        h = h + undulation
        inside = np.isfinite(h)
        diff = np.where(inside, points.h - h, np.nan)
        result.methods[method] = MethodCheck(method, h, inside, diff,
                                             elevation_statistics(points.h, h))
    return result


def _label(source) -> str:
    return getattr(source, "name", None) or str(getattr(source, "path", source))


def _with_datum(dem, datum: str, force: bool) -> DemSource | str:
    """The DEM entry with ``datum`` unless it names one (``force``: always ``datum``)."""
    if isinstance(dem, DemSource):
        if force or dem.datum is None:
            dem.set_datum(datum)
        return dem
    path, named = split_datum(dem)
    return f"{path}:{datum if force or named is None else named}"


def _geoid_undulation(geoid, points: GroundControlPoints) -> np.ndarray:
    """N at the points (bilinear) from a raster of undulations, or zeros without one."""
    if geoid is None:
        return np.zeros(len(points))
    if isinstance(geoid, DemSource):
        source = geoid
    else:
        check_input_file(geoid, "geoid undulation grid")
        source = open_dem(f"{geoid}:{ELLIPSOID}")
    return np.asarray(source.sample(points.lon, points.lat, "bilinear"), dtype=np.float64)


def read_points(path: str | os.PathLike[str]) -> GroundControlPoints:
    """GPS points from a CSV (columns lon, lat, h; header names tolerant: longitude/easting/x,
    latitude/northing/y, height/elevation/z...; ',', ';', tab or blanks; '#' comments) or from
    a DEMCHK listing of Appendix F (``N : easting northing elevation ...``)."""
    p = check_input_file(path, "points file")
    try:
        text = p.read_text(encoding="utf-8-sig", errors="replace")
    except OSError as exc:
        raise OptionsError(f"{p}: cannot read the points file ({exc.strerror or exc})") from exc
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise OptionsError(f"{p}: no points in the file")
    if any(_LISTING.match(ln.strip()) for ln in lines[:20]):
        lon, lat, h, number = _read_listing(lines)
    else:
        lon, lat, h, number = _read_csv(lines, p)
    if lon.size == 0:
        raise OptionsError(f"{p}: no points in the file")
    _check_values(lon, lat, h, str(p))
    return GroundControlPoints(lon, lat, h, number, p.name)


def _read_listing(lines: list[str]):
    rows = {}
    for ln in lines:
        for m in _LISTING.finditer(ln):
            rows[int(m.group(1))] = [float(m.group(k)) for k in (2, 3, 4)]
    number = np.array(sorted(rows), dtype=np.int64)
    values = np.array([rows[k] for k in number], dtype=np.float64).reshape(-1, 3)
    return values[:, 0], values[:, 1], values[:, 2], number


def _dialect(sample: str) -> str | None:
    for delimiter in (",", ";", "\t"):
        if delimiter in sample:
            return delimiter
    return None  # blanks


def _split(line: str, delimiter: str | None) -> list[str]:
    if delimiter is None:
        return line.split()
    return [c.strip() for c in next(csv.reader(io.StringIO(line), delimiter=delimiter))]


def _read_csv(lines: list[str], p: Path):
    delimiter = _dialect(lines[0])
    first = _split(lines[0], delimiter)
    try:
        [float(c) for c in first[:3]]
        columns = (0, 1, 2)  # no header: lon, lat, h
        body = lines
    except ValueError:
        columns = _columns(first, p)
        body = lines[1:]
    lon, lat, h = [], [], []
    for k, line in enumerate(body, start=2 if body is not lines else 1):
        cells = _split(line, delimiter)
        try:
            lon.append(float(cells[columns[0]]))
            lat.append(float(cells[columns[1]]))
            h.append(float(cells[columns[2]]))
        except (ValueError, IndexError) as exc:
            raise OptionsError(f"{p}: line {k}: expected numbers for lon, lat, h "
                               f"({line.strip()[:60]!r})") from exc
    return (np.array(lon), np.array(lat), np.array(h), np.arange(1, len(lon) + 1))


def _columns(header: list[str], p: Path) -> tuple[int, int, int]:
    keys = [re.sub(r"[^a-z0-9]", "", c.lower()) for c in header]
    found = []
    for name, aliases in _ALIASES.items():
        hits = [i for i, k in enumerate(keys) if k in aliases]
        if not hits:
            raise OptionsError(f"{p}: no {name} column in the header {header} "
                               f"(expected one of {', '.join(aliases)})")
        found.append(hits[0])
    return found[0], found[1], found[2]


def _check_values(lon: np.ndarray, lat: np.ndarray, h: np.ndarray, label: str) -> None:
    bad = ~(np.isfinite(lon) & np.isfinite(lat) & np.isfinite(h))
    bad |= (np.abs(lat) > 90) | (lon < -180) | (lon > 360)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise OptionsError(f"{label}: point {k + 1} has an invalid position or height "
                           f"({lon[k]}, {lat[k]}, {h[k]})")


def _method_report(result: DemCheckResult, check: MethodCheck, listing: bool) -> str:
    """One Appendix F log: counts, the five statistics, the processed GCPs."""
    pts = result.points
    n_in, n_all = int(check.inside.sum()), len(pts)
    pct_in = 100.0 * n_in / n_all if n_all else 0.0
    pct_out = 100.0 - pct_in if n_all else 0.0
    s = check.statistics
    geoid = f" (+ geoid {result.geoid_label})" if result.geoid_label else ""
    lines = [
        f"DIFFERENCES BETWEEN GPS POINTS AND DEM - {METHOD_TITLES[check.method].upper()}", "",
        f'DEM "{result.dem_label}"{geoid} controlled by "{pts.label}" GCPs:', "",
        f"NUMBER OF GCPs IN INPUT : {n_all}",
        f"NUMBER OF PROCESSED GCPs : {n_in} ({pct_in:.1f}%)",
        f"NUMBER OF GCPs OUTSIDE THE DEM : {n_all - n_in} ({pct_out:.1f}%)",
        "ELEVATION DIFFERENCES :",
    ]
    for label, key, _signed in _STAT_ROWS:
        lines.append(f". {label} : {_number(getattr(s, key), False)}")
    if listing:
        lines += ["", "GCP #\tEASTING\tNORTHING\tGCP ELEVAT.\tDEM ELEVAT.\tDIFFERENCE"]
        for k, i in enumerate(np.flatnonzero(check.inside), start=1):
            lines.append(f"{k} :\t{pts.lon[i]:.6f}\t{pts.lat[i]:.6f}\t{pts.h[i]:.3f}\t"
                         f"{check.dem_heights[i]:.3f} ->\t{check.differences[i]:.3f}")
    return "\n".join(lines) + "\n"


def plot_histogram(result: DemCheckResult, path: str | os.PathLike[str],
                   bin_width: float = 10.0) -> Path:
    """PNG of the distribution of H - h per method, as fig. 64 (section 5.2); written atomically."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if not bin_width > 0:
        raise OptionsError(f"histogram bin width must be positive, got {bin_width}")
    diffs = [c.differences[c.inside] for c in result.methods.values()]
    every = np.concatenate(diffs) if diffs else np.zeros(0)
    lo = math.floor((every.min() if every.size else -bin_width) / bin_width) * bin_width
    hi = math.ceil((every.max() if every.size else bin_width) / bin_width) * bin_width
    edges = np.arange(lo, hi + bin_width * 1.001, bin_width)
    fig = Figure(figsize=(8, 4.5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    centres = 0.5 * (edges[:-1] + edges[1:])
    for check, d in zip(result.methods.values(), diffs, strict=True):
        counts, _ = np.histogram(d, bins=edges)
        s = check.statistics
        ax.plot(centres, counts, marker="o", ms=3,
                label=f"{METHOD_TITLES[check.method]} (N={s.n}, "
                      f"mean {fixed(s.arithmetic_mean, 1, sign=True)} m, "
                      f"std {s.standard_deviation:.1f} m)")
    ax.axvline(0.0, color="grey", lw=0.8)
    ax.set_xlabel("H - h: GPS height minus DEM height (m)")
    ax.set_ylabel(f"number of points per {bin_width:g} m")
    ax.set_title(f"Elevation errors distribution: {result.dem_label} vs {result.points.label}")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    out = Path(path)
    with atomic_path(out) as tmp:
        fig.savefig(tmp, format="png")
    return out

"""Plausibility checks of a parsed MERIS L1b product (one place, cheap, before any big array).

The structural checks of :mod:`n1_reader` make sure every data set lies inside the file; these
make sure the numbers in it can be a MERIS product: dimensions of the product type (FR/RR tie
point spacing and line length, at most one orbit of lines), tie-point lines consistent with the
product lines, finite positive scaling factors and tie points within their physical ranges.
A sparse or forged file that passes the structure (sizes consistent, data sets in the file)
therefore still cannot make the reader or the engine allocate more than a real product needs.
Every error names the field and the value.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ...errors import N1FormatError
from ...geometry.earth import MAX_TERRAIN_M, MIN_SEABED_M
from .format import Resolution, ScalingFactors, tie_lines

#: an Envisat orbit lasts 6036 s: no product holds more lines than one orbit (FR 137 189)
MAX_PRODUCT_DURATION_S = 6100.0
#: widest MERIS line: the FR full swath (MER_FRS_1P) has 4481 samples
MAX_FR_WIDTH = 4481
#: heights a tie point may hold (m): the deepest seabed (bathymetry over sea) to above Everest
HEIGHT_RANGE_M = (MIN_SEABED_M, MAX_TERRAIN_M)
#: largest stored DEM correction (deg): h tan(vz)/R at 9000 m and 60 deg is 0.14 deg; the
#: longitude correction grows as 1/cos(lat)
MAX_CORRECTION_DEG = 10.0
#: LINE_TIME_INTERVAL (1e-6 s) of a pushbroom line: 1 us .. 10 s
LINE_TIME_INTERVAL_RANGE_US = (1, 10_000_000)
#: record times (days since 2000-01-01) of a plausible product: 1990 .. 2100
DAYS_RANGE = (-3653, 36525)

#: physical ranges of the per-pixel geolocation of FRG/FSG/RRG products, by MDS(17..19) band
#: name (``format.GEOLOCATION_MDS``); a value outside is no data
PIXEL_GEOLOCATION_RANGES: dict[str, tuple[float, float]] = {
    "corr_longitude": (-180.0, 180.0),
    "corr_latitude": (-90.0, 90.0),
    "altitude": HEIGHT_RANGE_M,
}

#: physical ranges of the tie points the geometry uses: (low, high, high included)
TIE_POINT_RANGES: dict[str, tuple[float, float, bool]] = {
    "latitude": (-90.0, 90.0, True),
    "longitude": (-180.0, 180.0, True),
    "dem_alt": (*HEIGHT_RANGE_M, True),
    "dem_rough": (0.0, MAX_TERRAIN_M, True),
    "lat_corr": (-MAX_CORRECTION_DEG, MAX_CORRECTION_DEG, True),
    "lon_corr": (-MAX_CORRECTION_DEG, MAX_CORRECTION_DEG, True),
    "sun_zenith": (0.0, 180.0, True),
    "sun_azimuth": (-360.0, 360.0, True),
    "view_zenith": (0.0, 90.0, False),  # tan(vz) is taken (eq. 2c')
    "view_azimuth": (-360.0, 360.0, True),
}


def max_lines(resolution: Resolution) -> int:
    """Most product lines a product of ``resolution`` can hold (one orbit)."""
    return int(MAX_PRODUCT_DURATION_S / resolution.line_interval_s)


def check_dimensions(
    path: Path, product_type: str, res: Resolution, width: int, df: int, dj: int
) -> None:
    """Tie-point spacing and line length of the product type (an FR product relabelled RR,
    or a widened LINE_LENGTH, is refused)."""
    if (df, dj) != (res.lines_per_tie_point, res.samples_per_tie_point):
        raise N1FormatError(
            path, f"SPH LINES_PER_TIE_PT={df}, SAMPLES_PER_TIE_PT={dj}: a {product_type} product "
            f"has tie points every {res.lines_per_tie_point} lines and "
            f"{res.samples_per_tie_point} samples"
        )  # fmt: skip
    widest = MAX_FR_WIDTH if res.name == "FR" else res.width
    if width > widest:
        raise N1FormatError(
            path, f"SPH LINE_LENGTH={width}: a {product_type} line has at most {widest} samples"
        )


def check_counts(path: Path, res: Resolution, height: int, n_tie_lines: int, df: int) -> None:
    """At most one orbit of lines, and exactly the tie-point lines the product lines need
    (one more is tolerated)."""
    if height > max_lines(res):
        raise N1FormatError(
            path, f"Radiance MDS(1) NUM_DSR={height}: more lines than one orbit "
            f"({max_lines(res)} {res.name} lines)"
        )  # fmt: skip
    need = tie_lines(height, df)
    if not need <= n_tie_lines <= need + 1:
        raise N1FormatError(
            path, f"Tie points ADS has {n_tie_lines} tie-point lines, {height} product lines "
            f"every {df} need {need}"
        )  # fmt: skip


def check_header_numbers(path: Path, sph: dict) -> None:
    """SPH integers the reader interprets must lie in their ranges."""
    value = sph.get("LINE_TIME_INTERVAL")
    low, high = LINE_TIME_INTERVAL_RANGE_US
    if isinstance(value, int) and not low <= value <= high:
        raise N1FormatError(
            path, f"SPH LINE_TIME_INTERVAL={value} (1e-6 s) is outside {low}..{high}"
        )


def check_scaling(path: Path, scaling: ScalingFactors) -> None:
    """Every scaling factor finite and positive (Scaling Factor GADS)."""
    named = [
        (name, getattr(scaling, name))
        for name in ("altitude", "roughness", "zonal_wind", "merid_wind", "atm_pressure",
                     "ozone", "rel_humidity")
    ]  # fmt: skip
    named += [(f"radiance[{b + 1}]", v) for b, v in enumerate(scaling.radiance)]
    for name, value in named:
        if not math.isfinite(value):
            raise N1FormatError(path, f"Scaling Factor GADS {name}={value} is non-finite")
        if value <= 0:
            raise N1FormatError(path, f"Scaling Factor GADS {name}={value:g} is not positive")


def check_tie_points(path: Path, tie_points: Mapping[str, np.ndarray], days: np.ndarray) -> None:
    """Tie points within their physical ranges; record times within 1990..2100."""
    for name, (low, high, closed) in TIE_POINT_RANGES.items():
        values = tie_points[name]
        bad = ~((values >= low) & ((values <= high) if closed else (values < high)))
        if bad.any():
            i, k = (int(v) for v in np.argwhere(bad)[0])
            end = "]" if closed else ")"
            raise N1FormatError(
                path, f"Tie points ADS {name}[{i}, {k}] = {values[i, k]:.6g} is outside its "
                f"physical range [{low:g}, {high:g}{end} ({bad.sum()} tie points)"
            )  # fmt: skip
    low, high = DAYS_RANGE
    bad = (days < low) | (days > high)
    if bad.any():
        i = int(np.argmax(bad))
        raise N1FormatError(
            path, f"Tie points ADS record {i} time: {int(days[i])} days since 2000-01-01 "
            "is not a plausible MERIS date"
        )  # fmt: skip

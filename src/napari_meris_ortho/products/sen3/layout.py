"""What a MERIS fourth-reprocessing ``.SEN3`` product holds: member files, variables, the
quality-flag coding, the column order and the CF decoding of packed values.

Facts of ESA's products (``ENV_ME_1_RRG____20120406T085654``, 1121 x 1617 pixels, tie points every
16 x 16, as the test resources of SNAP's Sentinel-3 reader describe it; SNAP's and NASA ocssw's
SAFE readers):

- **Columns run west to east on a descending pass** (longitude grows with the column), the mirror
  of the N1 "chronological" order. Every product this package returns exposes the N1 order
  (ARCHITECTURE.md "Conventions"), so a ``.SEN3`` and the N1 of one acquisition give the engine
  the same arrays: :func:`mirror_columns` on read and on write (it is its own inverse); a file
  already in the N1 order (:func:`esa_column_order` says so from its tie points) is read as is.
- Values are CF-packed: each variable has its own ``scale_factor``, ``add_offset``,
  ``_FillValue`` and ``valid_min``/``valid_max`` (:func:`cf_decode`); radiances are uint16 with
  ``_FillValue`` 65535 (SNAP's no-data of M01 is 65535 x its scale, 620.94).
- ``quality_flags`` (uint32) carries its coding in ``flag_masks``/``flag_meanings``: land 2^31,
  coastline 2^30, fresh_inland_water 2^29, tidal_region 2^28, bright 2^27, invalid 2^25,
  cosmetic 2^24, duplicated 2^23, sun_glint_risk 2^22, dubious 2^21, saturated_M01..M21
  2^20..2^0 (:data:`QUALITY_FLAGS`, used where a file does not carry its own coding).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

import numpy as np

from ... import flags as fl
from ..n1.format import FULL_RESOLUTION, NUM_BANDS, REDUCED_RESOLUTION, Resolution

#: product types (``ME_1_FRG___`` FR full swath, ``ME_1_RRG___`` RR) and their resolution
SEN3_TYPES: dict[str, Resolution] = {"ME_1_FRG___": FULL_RESOLUTION,
                                     "ME_1_RRG___": REDUCED_RESOLUTION}
MANIFEST = "xfdumanifest.xml"
GEO_FILE = "geo_coordinates.nc"
INSTRUMENT_FILE = "instrument_data.nc"
QUALITY_FILE = "qualityFlags.nc"
TIE_GEO_FILE = "tie_geo_coordinates.nc"
TIE_GEOMETRY_FILE = "tie_geometries.nc"
TIE_METEO_FILE = "tie_meteo.nc"
TIME_FILE = "time_coordinates.nc"
#: kg m-2 of one Dobson unit (total_ozone is stored in kg m-2)
DOBSON_KG_M2 = 2.1415e-5
#: nominal number of detectors (instrument_data ``detectors`` dimension)
DETECTORS = {"FR": 3700, "RR": 925}
#: saturation bits of quality_flags: saturated_M01 is bit 20 ... saturated_M21 bit 0
SATURATION_BANDS = 21
RADIANCE_FILL = 65535
INT32_FILL = -2147483648
INT16_FILL = -32768

#: the full quality_flags coding of ESA's products: (meaning, bit)
QUALITY_FLAGS: tuple[tuple[str, int], ...] = (
    ("land", 31), ("coastline", 30), ("fresh_inland_water", 29), ("tidal_region", 28),
    ("bright", 27), ("invalid", 25), ("cosmetic", 24), ("duplicated", 23),
    ("sun_glint_risk", 22), ("dubious", 21),
    *((f"saturated_M{b:02d}", SATURATION_BANDS - b) for b in range(1, SATURATION_BANDS + 1)),
)
#: quality meanings and the third-reprocessing L1b flag each sets (SNAP's adapter)
L1B_OF_QUALITY: dict[str, int] = {
    "land": fl.FLAG_LAND_OCEAN, "coastline": fl.FLAG_COASTLINE, "bright": fl.FLAG_BRIGHT,
    "invalid": fl.FLAG_INVALID, "cosmetic": fl.FLAG_COSMETIC, "duplicated": fl.FLAG_DUPLICATED,
    "sun_glint_risk": fl.FLAG_GLINT_RISK, "dubious": fl.FLAG_SUSPECT,
}

#: product names: ESA's ``ENV_ME_1_FRG____``/``ENV_ME_1_RRG____`` and the
#: ``EN1_MDSI_MER_FRS_1P_``/``EN1_MDSI_MER_RR__1P_`` names ESA also delivers them under
_NAMES = (re.compile(r"ME_1_(FR|RR)G"), re.compile(r"MER_(FR|RR)[S_]_1P"))


def product_type_of(text: str) -> str | None:
    """``ME_1_FRG___``/``ME_1_RRG___`` named by a product type or file name, or None."""
    for pattern in _NAMES:
        m = pattern.search(text)
        if m is not None:
            return f"ME_1_{m.group(1)}G___"
    return None


def radiance_file(band: int) -> str:
    return f"M{band:02d}_radiance.nc"


def radiance_variable(band: int) -> str:
    return f"M{band:02d}_radiance"


def required_files() -> list[str]:
    """Member files the reader needs (``tie_meteo.nc`` is optional)."""
    return [MANIFEST, *(radiance_file(b) for b in range(1, NUM_BANDS + 1)), GEO_FILE,
            INSTRUMENT_FILE, QUALITY_FILE, TIE_GEO_FILE, TIE_GEOMETRY_FILE, TIME_FILE]


def mirror_columns(a: np.ndarray) -> np.ndarray:
    """The columns of an image or tie-point grid (rows, columns[, ...]) in the other order:
    ``.SEN3`` order (west to east on a descending pass) <-> N1 order; a C-contiguous copy."""
    return np.ascontiguousarray(np.asarray(a)[:, ::-1])


def esa_column_order(latitude: np.ndarray, longitude: np.ndarray) -> bool:
    """True when a tie-point grid's columns run as ESA's ``.SEN3`` columns do: column 0 on the
    right of the flight direction (the west on a descending pass), the mirror of the N1 order,
    whose column 0 is on the left. From the sign of the cross product, on the local east-north
    plane, of the along-track (next line) and across-track (next column) steps (the median
    sign over the grid; True when it says nothing: a single line or column)."""
    lat, lon = np.asarray(latitude, np.float64), np.asarray(longitude, np.float64)
    if lat.ndim != 2 or min(lat.shape) < 2:
        return True
    east = np.cos(np.deg2rad(lat))[:-1, :-1]  # metres east per degree of longitude, relative

    def d_lon(axis: int) -> np.ndarray:  # across the antimeridian too
        return (np.diff(lon, axis=axis) + 180.0) % 360.0 - 180.0

    along_e, along_n = d_lon(0)[:, :-1] * east, np.diff(lat, axis=0)[:, :-1]
    across_e, across_n = d_lon(1)[:-1, :] * east, np.diff(lat, axis=1)[:-1, :]
    with np.errstate(invalid="ignore"):
        return bool(np.nanmedian(np.sign(along_e * across_n - along_n * across_e)) >= 0.0)


# ------------------------------------------------------------------------------------------
# CF decoding
# ------------------------------------------------------------------------------------------


#: CF packing attributes that hold one number each (``valid_range`` holds two)
PACKING_ATTRIBUTES = ("scale_factor", "add_offset", "_FillValue", "valid_min", "valid_max")


def packing_problem(attrs: Mapping[str, Any], variable: str) -> str | None:
    """What is wrong with the CF packing attributes of ``variable`` (each one number;
    ``valid_range`` two; ``scale_factor`` and ``add_offset`` finite, ``scale_factor``
    non-zero), or None."""
    for key in (*PACKING_ATTRIBUTES, "valid_range"):
        if key not in attrs:
            continue
        what = f"{key} of {variable!r}"
        try:
            values = np.asarray(attrs[key]).astype(np.float64).reshape(-1)
        except (TypeError, ValueError):
            return f"{what} ({attrs[key]!r}) is not a number"
        if values.size != (2 if key == "valid_range" else 1):
            return f"{what} is not one number ({values.size} values)"
        if key in ("scale_factor", "add_offset") and not np.isfinite(values[0]):
            return f"{what} ({values[0]!r}) is not a finite number"
        if key == "scale_factor" and values[0] == 0.0:
            return f"{what} is 0"
    return None


def attribute_number(attrs: Mapping[str, Any], key: str, default: float) -> float:
    """A packing attribute as one float (checked by :func:`packing_problem`)."""
    return float(np.asarray(attrs.get(key, default)).astype(np.float64).reshape(-1)[0])


def no_data(raw: np.ndarray, attrs: Mapping[str, Any]) -> np.ndarray:
    """Packed values that are no data (CF 1.8 section 2.5.1): equal to ``_FillValue``, or
    outside ``valid_min``/``valid_max``/``valid_range`` (in packed units, as stored); in a
    floating-point variable also NaN and infinities."""
    raw = np.asarray(raw)
    floating = raw.dtype.kind == "f"
    # the type's own range: a bound at or beyond it excludes nothing and is not compared
    # (a band of 5 Mpixel costs 3-5 ms per comparison)
    lowest, highest = (-np.inf, np.inf) if floating else (np.iinfo(raw.dtype).min,
                                                          np.iinfo(raw.dtype).max)
    tests: list[np.ndarray] = [~np.isfinite(raw)] if floating else []
    if "_FillValue" in attrs:
        fill = attribute_number(attrs, "_FillValue", 0.0)
        if floating or (np.isfinite(fill) and fill == round(fill) and lowest <= fill <= highest):
            tests.append(raw == np.asarray(fill).astype(raw.dtype))
    low = attribute_number(attrs, "valid_min", -np.inf)
    high = attribute_number(attrs, "valid_max", np.inf)
    if "valid_range" in attrs:
        low, high = np.asarray(attrs["valid_range"]).astype(np.float64).reshape(-1)[:2].tolist()
    if low > lowest:
        tests.append(raw < low)
    if high < highest:
        tests.append(raw > high)
    if not tests:
        return np.zeros(raw.shape, bool)
    bad = tests[0]
    for test in tests[1:]:
        bad |= test
    return bad


def cf_decode(raw: np.ndarray, attrs: Mapping[str, Any], dtype: Any = np.float64
              ) -> tuple[np.ndarray, int]:
    """Physical values of a CF-packed variable: ``raw x scale_factor + add_offset`` (CF 1.8
    section 8.1) with no-data (:func:`no_data`) as NaN; (values, number of no-data values)."""
    scale = attribute_number(attrs, "scale_factor", 1.0)
    offset = attribute_number(attrs, "add_offset", 0.0)
    with np.errstate(invalid="ignore", over="ignore"):
        out = np.asarray(raw).astype(dtype)
        if scale != 1.0:
            out *= dtype(scale)
        if offset != 0.0:
            out += dtype(offset)
    bad = no_data(np.asarray(raw), attrs)
    n_bad = int(bad.sum())
    if n_bad:
        out[bad] = np.nan
    return out, n_bad


# ------------------------------------------------------------------------------------------
# quality flags
# ------------------------------------------------------------------------------------------


#: seconds per unit of a CF time ``units`` string
_TIME_UNITS = {"microseconds": 1e-6, "milliseconds": 1e-3, "seconds": 1.0, "minutes": 60.0,
               "hours": 3600.0, "days": 86_400.0}
_TIME_SINCE = re.compile(r"^\s*(\w+)\s+since\s+(\d{4})-(\d{1,2})-(\d{1,2})"
                         r"(?:[ T](\d{1,2}):(\d{1,2})(?::(\d{1,2}(?:\.\d*)?))?)?\s*(?:Z|UTC)?\s*$")
#: ESA's ``time_stamp``: microseconds since 2000-01-01 (also when a file names no units)
ESA_TIME_UNITS = "microseconds since 2000-01-01 00:00:00"


def time_units(units: str) -> tuple[float, float] | None:
    """(seconds per unit, the epoch in seconds since 2000-01-01) of a CF time ``units`` string
    (CF 1.8 section 4.4, Gregorian calendar, UTC), e.g. ``"microseconds since 2000-01-01
    00:00:00"`` -> (1e-6, 0.0); None when it is not one."""
    import datetime as dt

    m = _TIME_SINCE.match(str(units))
    if m is None or m.group(1).lower() not in _TIME_UNITS:
        return None
    year, month, day = (int(g) for g in m.group(2, 3, 4))
    hour, minute = int(m.group(5) or 0), int(m.group(6) or 0)
    second = float(m.group(7) or 0.0)
    try:
        epoch = dt.datetime(year, month, day, hour, minute)
    except ValueError:
        return None
    offset = (epoch - dt.datetime(2000, 1, 1)).total_seconds() + second
    return _TIME_UNITS[m.group(1).lower()], offset


def flag_coding(attrs: Mapping[str, Any]) -> dict[str, int]:
    """meaning -> mask of a flag variable from its own ``flag_masks``/``flag_meanings`` (CF 1.8
    section 3.5), or ESA's coding (:data:`QUALITY_FLAGS`) when it carries none."""
    masks, meanings = attrs.get("flag_masks"), attrs.get("flag_meanings")
    if masks is not None and meanings is not None:
        names = _words(meanings)
        # masks stored as signed 32-bit integers (a rewrite as NETCDF4_CLASSIC): land is
        # -2**31 there; the same 32 bits as ESA's uint32 masks
        values = (np.atleast_1d(np.asarray(masks)).astype(np.int64) & 0xFFFFFFFF).tolist()
        if len(names) == len(values):
            return {n: int(v) for n, v in zip(names, values, strict=True)}
    return {name: 1 << bit for name, bit in QUALITY_FLAGS}


def _words(value: Any) -> list[str]:
    """The blank-separated words of a string attribute, also stored as an array of strings
    (one meaning per element, or bytes)."""
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if isinstance(value, str):
        return value.split()
    return [w for v in np.ravel(np.asarray(value, dtype=object)) for w in _words(v)]


def quality_to_l1b(quality: np.ndarray, coding: Mapping[str, int] | None = None) -> np.ndarray:
    """L1b flags (uint8, ``flags.FLAG_*``) of ``quality_flags`` with ``coding``
    (:func:`flag_coding`; default ESA's)."""
    coding = dict(coding) if coding is not None else flag_coding({})
    pairs = [(coding[name], l1b) for name, l1b in L1B_OF_QUALITY.items() if name in coding]
    return _translate(quality, pairs, np.uint8)


def l1b_to_quality(flags: np.ndarray) -> np.ndarray:
    """``quality_flags`` (uint32, ESA's coding) holding the given L1b flags (the inverse of
    :func:`quality_to_l1b`)."""
    f = np.asarray(flags).astype(np.uint8)
    coding = flag_coding({})
    out = np.zeros(f.shape, np.uint32)
    for name, l1b in L1B_OF_QUALITY.items():
        out |= np.where(f & np.uint8(l1b), np.uint32(coding[name]), np.uint32(0))
    return out


def saturated_bands(quality: np.ndarray, coding: Mapping[str, int]) -> np.ndarray:
    """uint16 (rows, columns): bit b-1 set where band b (1..15) is saturated
    (``saturated_Mnn`` of ``coding``)."""
    pairs = [(coding.get(f"saturated_M{b:02d}", 0), 1 << (b - 1)) for b in range(1, NUM_BANDS + 1)]
    return _translate(quality, pairs, np.uint16)


def _translate(quality: np.ndarray, pairs: list[tuple[int, int]], dtype: type) -> np.ndarray:
    """``dtype`` values of ``quality`` (uint32 flags): for each (mask, bits) of ``pairs``,
    ``bits`` set where ``quality & mask`` is not 0. One table of 256 values per byte of the
    flags, looked up and or-ed (4 passes whatever the number of pairs)."""
    q = np.ascontiguousarray(quality, dtype="<u4")
    by_byte = q.view(np.uint8).reshape(*q.shape, 4)
    values = np.arange(256)
    out: np.ndarray = np.zeros(q.shape, dtype)
    for k in range(4):
        table: np.ndarray = np.zeros(256, dtype)
        for mask, bits in pairs:
            part = (int(mask) >> (8 * k)) & 0xFF
            if part:
                table[(values & part) != 0] |= dtype(bits)
        if table.any():
            out |= table[by_byte[..., k]]
    return out

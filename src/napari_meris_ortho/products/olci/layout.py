"""What a Sentinel-3 OLCI Level 1B product (``OL_1_EFR___`` full, ``OL_1_ERR___`` reduced
resolution) holds: member files, variables, sizes, the quality-flag codings of both processing
baselines, and where its tie points sit.

Facts of ESA's products (*Sentinel-3 OLCI Product Data Format Specification*, the *Sentinel-3
OLCI User Guide*; the manifests of ``S3A_OL_1_EFR____20240526`` and ``S3B_OL_1_ERR____20210831``
as public readers' test resources hold them):

- The SAFE layout of the MERIS fourth-reprocessing ``.SEN3`` (``products.sen3``): a directory or
  zip archive of netCDF-4 members and an ``xfdumanifest.xml``; columns west to east on a
  descending pass (``sen3.layout.mirror_columns`` gives the N1 order every product exposes).
- ``Oa01_radiance.nc`` .. ``Oa21_radiance.nc``: ``OaNN_radiance`` uint16, its own
  ``scale_factor`` (Oa01 0.013946459628641605), ``_FillValue`` 65535, mW m-2 sr-1 nm-1.
- ``geo_coordinates.nc``: per-pixel ``latitude``/``longitude`` int32 x 1e-6 deg, "DEM corrected"
  (ortho-geolocated over GETASSE30), ``altitude`` int16 m.
- ``tie_geo_coordinates.nc``: tie-point ``latitude``/``longitude`` on the ellipsoid, and **no
  altitude**; ``tie_geometries.nc``: ``SZA``, ``SAA``, ``OZA``, ``OAA`` with their own scale
  factors; ``tie_meteo.nc``. Tie points on every row and every 64 (EFR) or 16 (ERR) columns:
  (tie columns - 1) x 64 + 1 = 4865 columns (77 tie columns), 1217 for ERR.
- ``instrument_data.nc``: ``detector_index`` (rows, columns) int16, ``lambda0``, ``FWHM``,
  ``solar_flux`` (21 bands x detectors; 5 cameras x 740), ``frame_offset``;
  ``qualityFlags.nc``: ``quality_flags`` uint32; ``time_coordinates.nc``; EFR only
  ``removed_pixels.nc``.

Tie-point heights: the reader takes the product's own per-pixel ``altitude`` at the tie points
(tie column k is image column k x 64, or k x 16), the tie files carrying none.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from enum import StrEnum

import numpy as np

from ..n1.format import Resolution
from ..sen3.layout import (
    GEO_FILE,
    INSTRUMENT_FILE,
    MANIFEST,
    QUALITY_FILE,
    TIE_GEO_FILE,
    TIE_GEOMETRY_FILE,
    TIME_FILE,
)

N_BANDS = 21
#: OLCI's frame period (s): one product row of EFR; ERR rows are 4 frames
FRAME_PERIOD_S = 0.044
#: EFR: 4865 columns, tie points every row and every 64 columns, 270 m across track at nadir
EFR = Resolution("FR", 4865, 1, 64, FRAME_PERIOD_S, 270.0, 1)
#: ERR: 1217 columns, tie points every row and every 16 columns, 1080 m across track
ERR = Resolution("RR", 1217, 1, 16, 4 * FRAME_PERIOD_S, 1080.0, 1)
#: product types and their sampling
OLCI_TYPES: dict[str, Resolution] = {"OL_1_EFR___": EFR, "OL_1_ERR___": ERR}
#: along-track sampling at nadir (m) of each resolution
ALONG_TRACK_M = {"FR": 294.0, "RR": 1176.0}
#: cameras and detectors per camera (``instrument_data`` ``detectors`` dimension: 3700)
CAMERAS = 5
DETECTORS_PER_CAMERA = 740
DETECTORS = CAMERAS * DETECTORS_PER_CAMERA
REMOVED_PIXELS_FILE = "removed_pixels.nc"

#: where ESA's tie point (i, k) sits, in pixel-centre coordinates of the file's own (ESA's)
#: column order: row i, column k x DJ + TIE_COLUMN_SHIFT. Half a pixel towards column 0, the
#: edge of the pixel on which it is named: SNAP places OLCI tie-point grids with offset 0 in
#: its pixel-corner coordinates (``OlciProductFactory``), and on real EFR products the tie
#: positions equal the per-pixel ones shifted by half a pixel across track at altitude 0. The
#: reader moves the tie points onto the pixel centres (:func:`tie_points_on_pixels`) so that
#: the engine sees tie point (i, k) at pixel (i, k x DJ) as for MERIS; the writer undoes it.
TIE_COLUMN_SHIFT = -0.5


class FlagBaseline(StrEnum):
    """The two ``quality_flags`` codings: ``saturated_Oa01``..``Oa21`` (bits 20..0) before
    processing baseline 2.24 (27 April 2023); since then one ``saturated`` and one
    ``partially_saturated`` flag, saturated samples being set to the band's fill value."""

    PER_BAND = "per-band"
    SINCE_2_24 = "2.24"


_COMMON_FLAGS: tuple[tuple[str, int], ...] = (
    ("land", 31), ("coastline", 30), ("fresh_inland_water", 29), ("tidal_region", 28),
    ("bright", 27), ("straylight_risk", 26), ("invalid", 25), ("cosmetic", 24),
    ("duplicated", 23), ("sun_glint_risk", 22), ("dubious", 21),
)
#: (meaning, bit) of each baseline's coding; the file's own ``flag_masks``/``flag_meanings``
#: come first. ESA names no bits of ``saturated``/``partially_saturated`` in the documents at
#: hand: this table (the writer's) puts them on bits 20 and 19
QUALITY_FLAGS: dict[FlagBaseline, tuple[tuple[str, int], ...]] = {
    FlagBaseline.PER_BAND: (*_COMMON_FLAGS,
                            *((f"saturated_Oa{b:02d}", N_BANDS - b)
                              for b in range(1, N_BANDS + 1))),
    FlagBaseline.SINCE_2_24: (*_COMMON_FLAGS, ("saturated", 20), ("partially_saturated", 19)),
}

#: product names: ``S3A_OL_1_EFR____...``, ``S3B_OL_1_ERR____...``
_TYPE = re.compile(r"OL_1_(EFR|ERR)")
#: other Sentinel-3 products a user may hand over: (pattern, what it is)
FOREIGN_TYPES: tuple[tuple[re.Pattern[str], str], ...] = (
    (re.compile(r"OL_2_(WFR|WRR|LFR|LRR)"), "an OLCI Level 2 product"),
    (re.compile(r"OL_1_(RAC|SPC)"), "an OLCI calibration product"),
    (re.compile(r"SY_[12]_\w{3}"), "a SYNERGY product"),
    (re.compile(r"SL_[12]_\w{3}"), "an SLSTR product"),
    (re.compile(r"SR_[12]_\w{3}"), "an SRAL altimetry product"),
    (re.compile(r"MW_[12]_\w{3}"), "an MWR product"),
)


def product_type_of(text: str) -> str | None:
    """``OL_1_EFR___``/``OL_1_ERR___`` named in a product type or name, or None."""
    m = _TYPE.search(text)
    return f"OL_1_{m.group(1)}___" if m is not None else None


def foreign_type_of(text: str) -> str | None:
    """What a Sentinel-3 product that is no OLCI Level 1B is ("an OLCI Level 2 product"...),
    from its type or name, or None."""
    for pattern, what in FOREIGN_TYPES:
        m = pattern.search(text)
        if m is not None:
            return f"{what} ({m.group(0)})"
    return None


def radiance_file(band: int) -> str:
    return f"Oa{band:02d}_radiance.nc"


def radiance_variable(band: int) -> str:
    return f"Oa{band:02d}_radiance"


def required_files() -> list[str]:
    """Member files the reader needs (``tie_meteo.nc``, ``removed_pixels.nc`` and the
    ``OaNN_radiance_unc.nc`` of collection 004 are not read)."""
    return [MANIFEST, *(radiance_file(b) for b in range(1, N_BANDS + 1)), GEO_FILE,
            INSTRUMENT_FILE, QUALITY_FILE, TIE_GEO_FILE, TIE_GEOMETRY_FILE, TIME_FILE]


def baseline_of(coding: Mapping[str, int]) -> FlagBaseline:
    """The baseline of a ``quality_flags`` coding (meaning -> mask)."""
    return FlagBaseline.PER_BAND if "saturated_Oa01" in coding else FlagBaseline.SINCE_2_24


def flag_table(baseline: FlagBaseline | str) -> dict[str, int]:
    """meaning -> mask of a baseline's coding (:data:`QUALITY_FLAGS`)."""
    return {name: 1 << bit for name, bit in QUALITY_FLAGS[FlagBaseline(baseline)]}


# ------------------------------------------------------------------------------------------
# tie-point positions
# ------------------------------------------------------------------------------------------


#: tie-point values that are angles (degrees), shifted along the shortest arc
ANGLES = frozenset({"longitude", "sun_azimuth", "view_azimuth"})


def shift_tie_columns(values: np.ndarray, shift_px: float, dj: int,
                      angle: bool = False) -> np.ndarray:
    """Tie-point values (rows, tie columns) moved by ``shift_px`` image columns: the value at
    column k x dj + shift_px, linear between neighbouring tie columns (extrapolated from the
    nearest pair at the edges); ``angle``: degrees, differences taken on (-180, 180]."""
    v = np.asarray(values, np.float64)
    if v.ndim != 2 or v.shape[1] < 2 or shift_px == 0.0:
        return v.copy()
    t = shift_px / dj
    diff = np.diff(v, axis=1)
    if angle:
        diff = (diff + 180.0) % 360.0 - 180.0
    # towards lower columns: the step before each tie column (the first: the one after)
    step = np.concatenate([diff[:, :1], diff], axis=1) if t < 0 else \
        np.concatenate([diff, diff[:, -1:]], axis=1)
    out = v + t * step
    if angle:
        out = (out + 180.0) % 360.0 - 180.0 if v.min() < 0 else out % 360.0
    return out


def tie_points_on_pixels(tie_points: Mapping[str, np.ndarray], dj: int,
                         n1_order: bool = True) -> dict[str, np.ndarray]:
    """ESA's tie points (:data:`TIE_COLUMN_SHIFT`) moved onto the pixel centres (i, k x dj);
    ``n1_order``: the arrays are in the N1 column order already (mirrored: ESA's shift towards
    its column 0 is one towards the last N1 column)."""
    shift = -TIE_COLUMN_SHIFT * (-1.0 if n1_order else 1.0)
    return {k: shift_tie_columns(v, shift, dj, k in ANGLES) if np.ndim(v) == 2 else v
            for k, v in tie_points.items()}


def tie_points_as_esa(tie_points: Mapping[str, np.ndarray], dj: int,
                      n1_order: bool = True) -> dict[str, np.ndarray]:
    """Tie points on the pixel centres moved where ESA's products have them (the inverse of
    :func:`tie_points_on_pixels`, exact for values linear across the tie columns)."""
    shift = TIE_COLUMN_SHIFT * (-1.0 if n1_order else 1.0)
    return {k: shift_tie_columns(v, shift, dj, k in ANGLES) if np.ndim(v) == 2 else v
            for k, v in tie_points.items()}

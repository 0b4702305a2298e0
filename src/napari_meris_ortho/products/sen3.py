"""MERIS fourth-reprocessing Level 1 products in the Sentinel-3-like SAFE layout (``.SEN3``).

``ENV_ME_1_FRG____<start>_<stop>_..._R_NT____.SEN3`` (FR) / ``ENV_ME_1_RRG____...`` (RR): a
directory of netCDF-4 files and an ``xfdumanifest.xml`` (format spec MER4RP-PFS-001-ACR; file
and variable names as satpy's ``meris_nc_sen3``/``olci_l1b``, SNAP's Sentinel-3 reader and
NASA's ``l1_safe`` read them):

===========================  ===========================================================
``Mnn_radiance.nc``           ``Mnn_radiance`` (rows, columns) uint16, ``scale_factor``,
                              ``add_offset`` 0, ``_FillValue`` 65535, mW.m-2.sr-1.nm-1
``geo_coordinates.nc``        per-pixel ``latitude``/``longitude`` int32 x 1e-6 deg and
                              ``altitude`` int16 m: the *terrain-corrected* position
``instrument_data.nc``        ``detector_index`` (rows, columns) int16; ``solar_flux``,
                              ``lambda0``, ``FWHM`` (bands, detectors)
``qualityFlags.nc``           ``quality_flags`` uint32, CF ``flag_masks``/``flag_meanings``
``tie_geo_coordinates.nc``    tie-point ``latitude``/``longitude`` (ellipsoid) and ``altitude``
``tie_geometries.nc``         ``SZA``, ``OZA`` uint32 and ``SAA``, ``OAA`` int32 (-180..180],
                              x 1e-6 deg; global ``al_subsampling_factor`` (lines per tie point)
                              and ``ac_subsampling_factor`` (columns per tie point)
``tie_meteo.nc``              ``horizontal_wind`` (.., wind_vectors) m s-1, ``sea_level_pressure``
                              hPa, ``total_ozone`` kg m-2, ``humidity`` % (optional)
``time_coordinates.nc``       ``time_stamp`` (rows) int64 microseconds since 2000-01-01
===========================  ===========================================================

Quality flag bits mapped onto the third-reprocessing L1b flags (SNAP's 3rd/4th reprocessing
adapter): land 31 -> LAND_OCEAN, coastline 30 -> COASTLINE, bright 27 -> BRIGHT, invalid 25 ->
INVALID, cosmetic 24 -> COSMETIC, duplicated 23 -> DUPLICATED, sun_glint_risk 22 -> GLINT_RISK,
dubious 21 -> SUSPECT. :func:`read_sen3` gives the interface of ``products.n1.MerisL1bProduct``
(stored column order, tie points in physical units, ``counts``/``scaling``, L1b ``flags``) plus the
per-pixel geolocation; the tie-point ``lat_corr``/``lon_corr`` (absent from the format) are
derived from ``dem_alt`` and the view angles with the N1 convention (NOTES.md).
"""

from __future__ import annotations

import math
import os
import re
import threading
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from .. import flags as fl
from .._atomic import atomic_dir
from ..errors import OptionsError, Sen3FormatError
from ..geometry.parallax import stored_corrections
from ..geometry.tiepoints import TiePoints
from ..progress import ProgressCallback
from .n1.format import (
    APPENDIX_A_BANDWIDTHS,
    APPENDIX_A_WAVELENGTHS,
    FULL_RESOLUTION,
    NUM_BANDS,
    REDUCED_RESOLUTION,
    Resolution,
    ScalingFactors,
    format_utc,
    tie_columns,
    tie_lines,
)

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
#: (name in flag_meanings, bit of quality_flags, L1b flag bit)
QUALITY_BITS: tuple[tuple[str, int, int], ...] = (
    ("land", 31, fl.FLAG_LAND_OCEAN), ("coastline", 30, fl.FLAG_COASTLINE),
    ("bright", 27, fl.FLAG_BRIGHT), ("invalid", 25, fl.FLAG_INVALID),
    ("cosmetic", 24, fl.FLAG_COSMETIC), ("duplicated", 23, fl.FLAG_DUPLICATED),
    ("sun_glint_risk", 22, fl.FLAG_GLINT_RISK), ("dubious", 21, fl.FLAG_SUSPECT),
)
#: nominal number of detectors (instrument_data ``detectors`` dimension)
DETECTORS = {"FR": 3700, "RR": 925}
_RADIANCE_FILL = 65535
_INT32_FILL = -2147483648
_INT16_FILL = -32768
#: netCDF/HDF5 is not thread-safe: one read at a time (napari reads in worker threads)
_LOCK = threading.Lock()
_NAME = re.compile(r"ME_1_(FRG|RRG)_")


def radiance_file(band: int) -> str:
    return f"M{band:02d}_radiance.nc"


def radiance_variable(band: int) -> str:
    return f"M{band:02d}_radiance"


def required_files() -> list[str]:
    """Member files the reader needs (``tie_meteo.nc`` is optional)."""
    return [MANIFEST, *(radiance_file(b) for b in range(1, NUM_BANDS + 1)), GEO_FILE,
            INSTRUMENT_FILE, QUALITY_FILE, TIE_GEO_FILE, TIE_GEOMETRY_FILE, TIME_FILE]


def is_sen3(path: str | os.PathLike[str]) -> bool:
    """True for a directory (or its manifest) that looks like a SAFE ``.SEN3`` product."""
    p = Path(path)
    if p.name == MANIFEST:
        p = p.parent
    return p.is_dir() and (p.suffix.upper() == ".SEN3" or (p / MANIFEST).is_file())


# ------------------------------------------------------------------------------------------
# quality flags
# ------------------------------------------------------------------------------------------


def quality_to_l1b(quality: np.ndarray) -> np.ndarray:
    """L1b flags (uint8, ``products.n1.FLAG_*``) of 4th-reprocessing ``quality_flags``."""
    q = np.asarray(quality).astype(np.uint32)
    out = np.zeros(q.shape, np.uint8)
    for _, bit, l1b in QUALITY_BITS:
        out |= np.where(q & np.uint32(1 << bit), np.uint8(l1b), np.uint8(0))
    return out


def l1b_to_quality(flags: np.ndarray) -> np.ndarray:
    """``quality_flags`` (uint32) holding the given L1b flags (the inverse of quality_to_l1b)."""
    f = np.asarray(flags).astype(np.uint8)
    out = np.zeros(f.shape, np.uint32)
    for _, bit, l1b in QUALITY_BITS:
        out |= np.where(f & np.uint8(l1b), np.uint32(1 << bit), np.uint32(0))
    return out


# ------------------------------------------------------------------------------------------
# the product
# ------------------------------------------------------------------------------------------


class MerisSen3Product:
    """An opened ``.SEN3`` MERIS Level 1 product; build with :func:`read_sen3`.

    Same attributes and methods as ``products.n1.MerisL1bProduct`` (``mph``/``sph`` hold a summary
    in N1 keys, ``dsds`` is empty) plus ``quality_flags`` and the per-pixel geolocation
    (``has_pixel_geolocation`` is True; ``pixel_longitude()``, ``pixel_latitude()``,
    ``pixel_altitude()``). Bands are read from the netCDF files on demand.
    """

    has_pixel_geolocation = True
    dsds: list = []

    def __init__(self, path: Path, product_type: str, width: int, height: int, df: int, dj: int,
                 tie_points: Mapping[str, np.ndarray], line_times: np.ndarray,
                 scaling: ScalingFactors, wavelengths: tuple[float, ...],
                 bandwidths: tuple[float, ...], attrs: dict[str, Any]) -> None:
        self.path = path
        self.product_type = product_type
        self.resolution = SEN3_TYPES[product_type]
        self.width = width
        self.height = height
        self.lines_per_tie_point = df
        self.samples_per_tie_point = dj
        self.tie_points = TiePoints.from_mapping(tie_points)
        self.line_times = line_times
        self.scaling = scaling
        self.wavelengths = wavelengths
        self.bandwidths = bandwidths
        self.attrs = attrs
        n = self.n_tie_lines
        self.tie_point_times = line_times[0] + self.line_interval_s * df * np.arange(n)
        self.mph = {"PRODUCT": self.product_name, "PROC_CENTER": str(attrs.get("institution", "")),
                    "SENSING_START": format_utc(self._utc(line_times[0])),
                    "SENSING_STOP": format_utc(self._utc(line_times[-1])),
                    "SPH_SIZE": 0, "NUM_DSD": 0}
        self.sph = {"FIRST_LINE_TIME": self.mph["SENSING_START"],
                    "LAST_LINE_TIME": self.mph["SENSING_STOP"], "LINE_LENGTH": width,
                    "LINES_PER_TIE_PT": df, "SAMPLES_PER_TIE_PT": dj, "NUM_BANDS": NUM_BANDS,
                    "LINE_TIME_INTERVAL": int(round(self.line_interval_s * 1e6)),
                    "BAND_WAVELEN": tuple(int(round(w * 1000)) for w in wavelengths),
                    "BANDWIDTH": tuple(int(round(w * 1000)) for w in bandwidths)}

    def __repr__(self) -> str:
        return f"<MerisSen3Product {self.product_type} {self.width}x{self.height} ({self.path})>"

    @staticmethod
    def _utc(seconds: float) -> np.datetime64:
        return np.datetime64("2000-01-01T00:00:00", "us") + np.timedelta64(
            int(round(float(seconds) * 1e6)), "us")

    @property
    def product_name(self) -> str:
        return self.path.name.removesuffix(".SEN3")

    @property
    def n_tie_lines(self) -> int:
        return int(self.tie_points["latitude"].shape[0])

    @property
    def n_tie_columns(self) -> int:
        return int(self.tie_points["latitude"].shape[1])

    @property
    def first_line_time(self) -> np.datetime64:
        return self._utc(self.line_times[0])

    @property
    def line_interval_s(self) -> float:
        if self.line_times.size < 2:
            return self.resolution.line_interval_s
        return float(np.median(np.diff(self.line_times)))

    def _read(self, name: str, variable: str, lines: slice | None = None) -> np.ndarray:
        return _read_variable(self.path, name, variable, lines)

    def counts(self, band: int) -> np.ndarray:
        """Stored uint16 values of ``band`` (1..15), radiance = counts x scaling.radiance[b-1]."""
        if isinstance(band, bool) or not isinstance(band, int | np.integer):
            raise TypeError(f"band must be an integer 1..15, got {band!r}")
        if not 1 <= band <= NUM_BANDS:
            raise ValueError(f"band must be 1..15, got {band}")
        return self._read(radiance_file(band), radiance_variable(band))

    def radiance(self, band: int, lines: slice | None = None) -> np.ndarray:
        """TOA radiance (mW m-2 sr-1 nm-1) of ``band``, float32 (H, W) or the given lines."""
        counts = self.counts(band)
        if lines is not None:
            counts = counts[lines]
        return counts.astype(np.float32) * np.float32(self.scaling.radiance[band - 1])

    @cached_property
    def quality_flags(self) -> np.ndarray:
        """``quality_flags`` (uint32 (H, W))."""
        return self._read(QUALITY_FILE, "quality_flags")

    @cached_property
    def flags(self) -> np.ndarray:
        """L1b flags (uint8 (H, W)) mapped from ``quality_flags`` (module docstring)."""
        return quality_to_l1b(self.quality_flags)

    @cached_property
    def detector_index(self) -> np.ndarray:
        return self._read(INSTRUMENT_FILE, "detector_index")

    def pixel_longitude(self, lines: slice | None = None) -> np.ndarray:
        """Terrain-corrected longitude of every pixel (geo_coordinates.nc), float64 deg."""
        return _scaled(self._read(GEO_FILE, "longitude", lines), 1e-6, _INT32_FILL)

    def pixel_latitude(self, lines: slice | None = None) -> np.ndarray:
        """Terrain-corrected latitude of every pixel (geo_coordinates.nc), float64 deg."""
        return _scaled(self._read(GEO_FILE, "latitude", lines), 1e-6, _INT32_FILL)

    def pixel_altitude(self, lines: slice | None = None) -> np.ndarray:
        """Altitude of every pixel's terrain point (geo_coordinates.nc), float32 m."""
        return _scaled(self._read(GEO_FILE, "altitude", lines), 1.0, _INT16_FILL, np.float32)


def _scaled(raw: np.ndarray, scale: float, fill: int, dtype: type = np.float64) -> np.ndarray:
    out = raw.astype(dtype) * dtype(scale)
    out[raw == fill] = np.nan
    return out


def _read_variable(directory: Path, name: str, variable: str,
                   lines: slice | None = None) -> np.ndarray:
    """Raw (unscaled) values of a variable, or the given lines of it."""
    import netCDF4

    path = directory / name
    with _LOCK:
        try:
            with netCDF4.Dataset(path) as ds:
                var = ds.variables[variable]
                var.set_auto_maskandscale(False)
                return np.asarray(var[lines] if lines is not None else var[...])
        except (OSError, KeyError, IndexError, RuntimeError) as exc:
            raise Sen3FormatError(path, f"cannot read {variable}: {exc}") from None


# ------------------------------------------------------------------------------------------
# read_sen3
# ------------------------------------------------------------------------------------------


def read_sen3(path: str | os.PathLike[str]) -> MerisSen3Product:
    """Open a MERIS Level 1 ``.SEN3`` directory (or its ``xfdumanifest.xml``).

    Checks that every member file is there and that every variable has the shape of the
    radiances (tie-point variables: of the tie-point grid); reads the tie points, times and
    scale factors; bands and per-pixel geolocation are read on demand. Raises
    :class:`Sen3FormatError` naming the directory and the problem.
    """
    p = Path(path)
    if p.name == MANIFEST:
        p = p.parent
    if not p.is_dir():
        raise Sen3FormatError(p, "not a directory (a .SEN3 product is a directory)")
    missing = [f for f in required_files() if not (p / f).is_file()]
    if missing:
        raise Sen3FormatError(p, f"missing member file(s): {', '.join(missing)}")
    try:
        return _read(p)
    except OSError as exc:
        raise Sen3FormatError(p, f"cannot read: {exc.strerror or exc}") from None


class _Files:
    """Open netCDF members one at a time, with errors naming file and variable."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory

    def read(self, name: str, variables: list[str], shape: tuple[int, ...] | None,
             optional: bool = False) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Raw values of ``variables`` (each checked against ``shape``, None: any), their
        attributes and the file's global attributes (key ``""``)."""
        import netCDF4

        path = self.directory / name
        if optional and not path.is_file():
            return {}, {}
        out: dict[str, np.ndarray] = {}
        attrs: dict[str, Any] = {}
        with _LOCK:
            try:
                ds = netCDF4.Dataset(path)
            except OSError as exc:
                raise Sen3FormatError(path, f"not a netCDF file ({exc})") from None
            with ds:
                attrs[""] = {k: ds.getncattr(k) for k in ds.ncattrs()}
                for v in variables:
                    if v not in ds.variables:
                        raise Sen3FormatError(path, f"has no variable {v!r}")
                    var = ds.variables[v]
                    if shape is not None and tuple(var.shape[: len(shape)]) != shape:
                        raise Sen3FormatError(
                            path, f"variable {v!r} has shape {tuple(var.shape)}, expected "
                            f"{shape}")
                    var.set_auto_maskandscale(False)
                    out[v] = np.asarray(var[...])
                    attrs[v] = {k: var.getncattr(k) for k in var.ncattrs()}
        return out, attrs

    def shape(self, name: str, variable: str) -> tuple[int, ...]:
        import netCDF4

        path = self.directory / name
        with _LOCK:
            try:
                with netCDF4.Dataset(path) as ds:
                    if variable not in ds.variables:
                        raise Sen3FormatError(path, f"has no variable {variable!r}")
                    return tuple(ds.variables[variable].shape)
            except OSError as exc:
                raise Sen3FormatError(path, f"not a netCDF file ({exc})") from None

    def attributes(self, name: str, variable: str) -> dict[str, Any]:
        import netCDF4

        with _LOCK, netCDF4.Dataset(self.directory / name) as ds:
            var = ds.variables[variable]
            return {k: var.getncattr(k) for k in var.ncattrs()}


def _product_type(p: Path, files: _Files) -> str:
    m = _NAME.search(p.name)
    if m is None:
        _, attrs = files.read(INSTRUMENT_FILE, [], None)
        m = _NAME.search(str(attrs[""].get("product_name", "")))
    if m is None:
        raise Sen3FormatError(p, "not a MERIS Level 1 product (ME_1_FRG___ or ME_1_RRG___ in "
                              "the directory name or instrument_data.nc product_name)")
    return f"ME_1_{m.group(1)}___"


def _read(p: Path) -> MerisSen3Product:
    files = _Files(p)
    product_type = _product_type(p, files)
    shape = files.shape(radiance_file(1), radiance_variable(1))
    if len(shape) != 2 or min(shape) < 2:
        raise Sen3FormatError(p / radiance_file(1), f"M01_radiance has shape {shape}, a 2-D "
                              "(rows, columns) image expected")
    height, width = shape
    factors = []
    for b in range(1, NUM_BANDS + 1):
        got = files.shape(radiance_file(b), radiance_variable(b))
        if got != shape:
            raise Sen3FormatError(p / radiance_file(b), f"variable {radiance_variable(b)!r} has "
                                  f"shape {got}, M01_radiance has {shape}")
        a = files.attributes(radiance_file(b), radiance_variable(b))
        if float(a.get("add_offset", 0.0)) != 0.0:
            raise Sen3FormatError(p / radiance_file(b), "radiances with a non-zero add_offset "
                                  "are not supported")
        factors.append(float(a.get("scale_factor", 1.0)))
    for v in ("latitude", "longitude", "altitude"):
        if files.shape(GEO_FILE, v) != shape:
            raise Sen3FormatError(p / GEO_FILE, f"variable {v!r} has shape "
                                  f"{files.shape(GEO_FILE, v)}, the radiances have {shape}")
    for name, v in ((INSTRUMENT_FILE, "detector_index"), (QUALITY_FILE, "quality_flags")):
        if files.shape(name, v) != shape:
            raise Sen3FormatError(p / name, f"variable {v!r} has shape {files.shape(name, v)}, "
                                  f"the radiances have {shape}")
    times, _ = files.read(TIME_FILE, ["time_stamp"], (height,))
    tie_points, df, dj = _tie_points(p, files, height, width)
    spectral = ["solar_flux", "lambda0", "FWHM"] if _has_spectral(files) else []
    instrument, _ = files.read(INSTRUMENT_FILE, spectral, None)
    wavelengths = _band_means(instrument.get("lambda0"), APPENDIX_A_WAVELENGTHS)
    bandwidths = _band_means(instrument.get("FWHM"), APPENDIX_A_BANDWIDTHS)
    sun_flux = _band_means(instrument.get("solar_flux"), ScalingFactors().sun_flux)
    scaling = replace(ScalingFactors(), radiance=tuple(factors), sun_flux=sun_flux)
    _, gattrs = files.read(INSTRUMENT_FILE, [], None)
    return MerisSen3Product(
        p, product_type, width, height, df, dj, tie_points,
        times["time_stamp"].astype(np.float64) * 1e-6, scaling, wavelengths, bandwidths,
        gattrs[""])


def _has_spectral(files: _Files) -> bool:
    import netCDF4

    with _LOCK, netCDF4.Dataset(files.directory / INSTRUMENT_FILE) as ds:
        return all(v in ds.variables for v in ("solar_flux", "lambda0", "FWHM"))


def _band_means(values: np.ndarray | None, default: tuple[float, ...]) -> tuple[float, ...]:
    """Per-band mean over the detectors (bands, detectors), or the default."""
    if values is None or values.ndim != 2 or values.shape[0] != NUM_BANDS:
        return tuple(default)
    v = np.where(np.isfinite(values) & (values > 0), values, np.nan)
    means = np.nanmean(v, axis=1) if np.isfinite(v).any() else np.full(NUM_BANDS, np.nan)
    return tuple(float(m) if math.isfinite(m) else float(d)
                 for m, d in zip(means, default, strict=True))


def _tie_points(p: Path, files: _Files, height: int, width: int
                ) -> tuple[dict[str, np.ndarray], int, int]:
    """Tie points in physical units with the N1 names; (tie points, DF, DJ)."""
    shape = files.shape(TIE_GEOMETRY_FILE, "SZA")
    geom, attrs = files.read(TIE_GEOMETRY_FILE, ["SZA", "SAA", "OZA", "OAA"], shape)
    try:
        df = int(attrs[""]["al_subsampling_factor"])
        dj = int(attrs[""]["ac_subsampling_factor"])
    except (KeyError, TypeError, ValueError):
        raise Sen3FormatError(p / TIE_GEOMETRY_FILE, "global attributes al_subsampling_factor "
                              "and ac_subsampling_factor are required") from None
    if len(shape) != 2 or df < 1 or dj < 1:
        raise Sen3FormatError(p / TIE_GEOMETRY_FILE, f"tie-point grid {shape} every {df} x {dj}"
                              " is not valid")
    n_cols = tie_columns(width, dj)
    if shape[1] != n_cols or (width - 1) % dj or shape[0] < tie_lines(height, df):
        raise Sen3FormatError(
            p / TIE_GEOMETRY_FILE, f"tie-point grid of {shape[0]} x {shape[1]} every {df} "
            f"lines x {dj} columns does not cover {height} x {width} pixels (needs "
            f"{tie_lines(height, df)} x {n_cols})")
    geo, _ = files.read(TIE_GEO_FILE, ["latitude", "longitude", "altitude"], shape)
    meteo, _ = files.read(TIE_METEO_FILE, ["horizontal_wind", "sea_level_pressure",
                                           "total_ozone", "humidity"], shape, optional=True)

    def deg(a: np.ndarray) -> np.ndarray:
        return a.astype(np.float64) * 1e-6

    lat = deg(geo["latitude"])
    tp = {"latitude": lat, "longitude": deg(geo["longitude"]),
          "dem_alt": geo["altitude"].astype(np.float64),
          "dem_rough": np.zeros(shape),
          "sun_zenith": deg(geom["SZA"]), "sun_azimuth": deg(geom["SAA"]) % 360.0,
          "view_zenith": deg(geom["OZA"]), "view_azimuth": deg(geom["OAA"]) % 360.0}
    # the DEM corrections as operational N1 products store them (0 over sea), derived
    tp["lat_corr"], tp["lon_corr"] = stored_corrections(
        tp["dem_alt"], tp["view_zenith"], tp["view_azimuth"], lat)
    if meteo:
        wind = meteo["horizontal_wind"].astype(np.float64)
        tp["zonal_wind"], tp["merid_wind"] = wind[..., 0], wind[..., 1]
        tp["atm_pressure"] = meteo["sea_level_pressure"].astype(np.float64)
        tp["ozone"] = meteo["total_ozone"].astype(np.float64) / DOBSON_KG_M2
        tp["rel_humidity"] = meteo["humidity"].astype(np.float64)
    else:
        for k in ("zonal_wind", "merid_wind", "atm_pressure", "ozone", "rel_humidity"):
            tp[k] = np.full(shape, np.nan)
    return tp, df, dj


# ------------------------------------------------------------------------------------------
# write_sen3
# ------------------------------------------------------------------------------------------


def default_sen3_name(resolution: str, start: np.datetime64, duration_s: float) -> str:
    """``ENV_ME_1_FRG____<start>_<stop>_________________<dur>_000_000______MOR_R_NT____.SEN3``."""
    stop = start + np.timedelta64(int(round(duration_s * 1e6)), "us")

    def stamp(t: np.datetime64) -> str:
        return str(t.astype("datetime64[s]")).replace("-", "").replace(":", "")

    return (f"ENV_ME_1_{resolution}G____{stamp(start)}_{stamp(stop)}_{'_' * 17}"
            f"{int(round(duration_s)):04d}_000_000______MOR_R_NT____.SEN3")


def write_sen3(path: str | os.PathLike[str], *, resolution: str,
               tie_points: Mapping[str, np.ndarray], counts: Any, flags: np.ndarray,
               detector_index: np.ndarray, pixel_geolocation: dict[str, np.ndarray],
               first_line_time: np.datetime64, line_interval_s: float,
               scaling: ScalingFactors | None = None,
               progress: ProgressCallback | None = None) -> Path:
    """Write a MERIS Level 1 ``.SEN3`` directory (layout of the module docstring) at ``path``.

    ``resolution`` "FR" or "RR"; ``counts``: 15 uint16 (H, W) arrays, stored column order;
    ``flags``: L1b uint8 flags (mapped to ``quality_flags``); ``tie_points``: physical values
    with the N1 names; ``pixel_geolocation``: (H, W) ``longitude``, ``latitude`` (deg) and
    ``altitude`` (m); ``scaling``: radiance factors of the counts (default Appendix A).
    Written to a temporary directory and renamed. Bad arguments raise :class:`OptionsError`.
    """
    out = Path(path)
    if out.suffix != ".SEN3":
        raise OptionsError(f"{out}: a SAFE product directory name ends with .SEN3")
    if resolution not in ("FR", "RR"):
        raise OptionsError(f"resolution must be FR or RR, not {resolution!r}")
    res = FULL_RESOLUTION if resolution == "FR" else REDUCED_RESOLUTION
    df, dj = res.lines_per_tie_point, res.samples_per_tie_point
    height, width = np.shape(counts[0])
    shape = (height, width)
    for key in ("longitude", "latitude", "altitude"):
        if key not in pixel_geolocation or np.shape(pixel_geolocation[key]) != shape:
            raise OptionsError(f"pixel_geolocation[{key!r}] must have the bands' shape {shape}")
    tshape = np.shape(tie_points["latitude"])
    if tshape[0] < tie_lines(height, df) or tshape[1] != tie_columns(width, dj):
        raise OptionsError(f"tie points {tshape} do not cover {shape} every {df} x {dj}")
    scaling = scaling or ScalingFactors()
    t0: Any = np.asarray(first_line_time).astype("datetime64[us]")[()]
    t0_us = int((t0 - np.datetime64("2000-01-01T00:00:00", "us")) / np.timedelta64(1, "us"))
    stamps = t0_us + np.round(np.arange(height) * line_interval_s * 1e6).astype(np.int64)
    common = {"Conventions": "CF-1.6", "title": f"MERIS Level 1 {resolution} (simulated)",
              "product_name": out.name, "institution": "meris-ortho simulator",
              "absolute_orbit_number": np.uint16(0), "ac_subsampling_factor": np.uint16(dj),
              "al_subsampling_factor": np.uint16(df),
              "start_time": str(t0) + "Z", "source": "napari-meris-ortho"}
    with atomic_dir(out) as tmp:
        nc = _NcWriter(tmp, common)
        _write_bands(nc, counts, scaling, progress)
        with nc.dataset(GEO_FILE, {"rows": height, "columns": width}) as ds:
            _write_geo(nc.var, ds, ("rows", "columns"), pixel_geolocation)
        _write_instrument(nc, detector_index, flags, scaling, DETECTORS[resolution])
        _write_tie_points(nc, tie_points)
        with nc.dataset(TIME_FILE, {"rows": height}) as ds:
            nc.var(ds, "time_stamp", "i8", ("rows",), stamps, None,
                   units="microseconds since 2000-01-01 00:00:00", standard_name="time",
                   calendar="gregorian", long_name="Elapsed time since 01 Jan 2000 0h")
        (tmp / MANIFEST).write_text(_manifest(out.name.removesuffix(".SEN3"), resolution,
                                              height, width, df, dj, t0, stamps[-1] - t0_us))
        if progress is not None:
            progress(NUM_BANDS + 1, NUM_BANDS + 1)
    return out


class _NcWriter:
    """netCDF-4 member files of one product: the global attributes they share, CF variables."""

    def __init__(self, directory: Path, common: dict[str, Any]) -> None:
        self.directory = directory
        self.common = common

    def dataset(self, name: str, dims: dict[str, int]) -> Any:
        import netCDF4

        ds = netCDF4.Dataset(self.directory / name, "w", format="NETCDF4")
        ds.setncatts(self.common)
        for d, n in dims.items():
            ds.createDimension(d, n)
        return ds

    @staticmethod
    def var(ds: Any, name: str, dtype: str, dims: tuple[str, ...], data: Any,
            fill: Any = None, **attrs: Any) -> Any:
        """A compressed variable holding ``data`` cast to ``dtype`` (raw, attributes as given)."""
        v = ds.createVariable(name, dtype, dims, zlib=True, complevel=1, fill_value=fill)
        v.set_auto_maskandscale(False)
        v.setncatts(attrs)
        v[...] = np.asarray(data).astype(v.dtype)
        return v


def _write_bands(nc: _NcWriter, counts: Any, scaling: ScalingFactors,
                 progress: ProgressCallback | None) -> None:
    """``Mnn_radiance.nc``: the counts with the radiance factor as CF ``scale_factor``."""
    height, width = np.shape(counts[0])
    for b in range(1, NUM_BANDS + 1):
        with nc.dataset(radiance_file(b), {"rows": height, "columns": width}) as ds:
            nc.var(ds, radiance_variable(b), "u2", ("rows", "columns"),
                   np.asarray(counts[b - 1], np.uint16), _RADIANCE_FILL,
                   scale_factor=np.float32(scaling.radiance[b - 1]),
                   add_offset=np.float32(0.0), units="mW.m-2.sr-1.nm-1",
                   standard_name="toa_upwelling_spectral_radiance",
                   long_name=f"TOA radiance for band M{b:02d}",
                   valid_min=np.uint16(0), valid_max=np.uint16(65534))
        if progress is not None:
            progress(b, NUM_BANDS + 1)


def _write_instrument(nc: _NcWriter, detector_index: np.ndarray, flags: np.ndarray,
                      scaling: ScalingFactors, det: int) -> None:
    """``instrument_data.nc`` (detector index, per-detector spectral data) and
    ``qualityFlags.nc`` (the L1b flags as 4th-reprocessing quality bits)."""
    height, width = np.shape(flags)
    img = {"rows": height, "columns": width}
    with nc.dataset(INSTRUMENT_FILE, {**img, "bands": NUM_BANDS, "detectors": det}) as ds:
        nc.var(ds, "detector_index", "i2", ("rows", "columns"),
               np.asarray(detector_index, np.int16), np.int16(-1),
               long_name="Detector index", valid_min=np.int16(0), valid_max=np.int16(det - 1))
        for name, values, unit, long in (
                ("lambda0", APPENDIX_A_WAVELENGTHS, "nm", "Central wavelength"),
                ("FWHM", APPENDIX_A_BANDWIDTHS, "nm", "Bandwidth (full width at half max)"),
                ("solar_flux", scaling.sun_flux, "mW.m-2.nm-1", "In-band solar irradiance")):
            nc.var(ds, name, "f4", ("bands", "detectors"),
                   np.repeat(np.asarray(values, np.float32)[:, None], det, axis=1),
                   np.float32(np.nan), units=unit, long_name=long)
    with nc.dataset(QUALITY_FILE, img) as ds:
        nc.var(ds, "quality_flags", "u4", ("rows", "columns"), l1b_to_quality(flags), None,
               long_name="Classification and quality flags",
               flag_masks=np.array([1 << b for _, b, _ in QUALITY_BITS], np.uint32),
               flag_meanings=" ".join(n for n, _, _ in QUALITY_BITS))


def _write_tie_points(nc: _NcWriter, tie_points: Mapping[str, np.ndarray]) -> None:
    """``tie_geo_coordinates.nc``, ``tie_geometries.nc`` (azimuths on (-180, 180]) and
    ``tie_meteo.nc`` (ozone in kg m-2) from N1-named physical tie points."""
    tshape = np.shape(tie_points["latitude"])
    tdims = {"tie_rows": tshape[0], "tie_columns": tshape[1]}
    tie = ("tie_rows", "tie_columns")

    def get(key: str) -> np.ndarray:
        return np.asarray(tie_points.get(key, np.zeros(tshape)), np.float64)

    with nc.dataset(TIE_GEO_FILE, tdims) as ds:
        _write_geo(nc.var, ds, tie, {"longitude": get("longitude"), "latitude": get("latitude"),
                                     "altitude": get("dem_alt")})
    with nc.dataset(TIE_GEOMETRY_FILE, tdims) as ds:
        for name, key, long in (("SZA", "sun_zenith", "Sun zenith angle"),
                                ("SAA", "sun_azimuth", "Sun azimuth angle"),
                                ("OZA", "view_zenith", "Observation zenith angle"),
                                ("OAA", "view_azimuth", "Observation azimuth angle")):
            zenith = name[1] == "Z"
            deg = get(key) if zenith else 180.0 - (180.0 - get(key)) % 360.0
            nc.var(ds, name, "u4" if zenith else "i4", tie, np.round(deg * 1e6), None,
                   scale_factor=1e-6, units="degrees", long_name=long,
                   standard_name=("solar_" if name[0] == "S" else "sensor_")
                   + ("zenith_angle" if zenith else "azimuth_angle"))
    with nc.dataset(TIE_METEO_FILE, {**tdims, "wind_vectors": 2}) as ds:
        wind = np.stack([get("zonal_wind"), get("merid_wind")], axis=-1)
        nc.var(ds, "horizontal_wind", "f4", (*tie, "wind_vectors"), wind, None,
               units="m s-1", long_name="Horizontal wind vector at 10 m (east, north)")
        for name, key, factor, unit in (("sea_level_pressure", "atm_pressure", 1.0, "hPa"),
                                        ("total_ozone", "ozone", DOBSON_KG_M2, "kg.m-2"),
                                        ("humidity", "rel_humidity", 1.0, "%")):
            nc.var(ds, name, "f4", tie, get(key) * factor, None, units=unit,
                   long_name=name.replace("_", " ").capitalize())


def _write_geo(var, ds, dims: tuple[str, str], geo: dict[str, np.ndarray]) -> None:
    for key, std, unit in (("latitude", "latitude", "degrees_north"),
                           ("longitude", "longitude", "degrees_east")):
        values = np.asarray(geo[key], np.float64)
        if key == "longitude":
            values = (values + 180.0) % 360.0 - 180.0
        var(ds, key, "i4", dims, np.round(values * 1e6), np.int32(_INT32_FILL),
            scale_factor=1e-6, units=unit, standard_name=std, long_name=f"DEM corrected {key}")
    var(ds, "altitude", "i2", dims, np.round(np.asarray(geo["altitude"], np.float64)),
        np.int16(_INT16_FILL), units="m", standard_name="height_above_reference_ellipsoid",
        long_name="DEM corrected altitude")


def _manifest(name: str, resolution: str, height: int, width: int, df: int, dj: int,
              t0: np.datetime64, duration_us: int) -> str:
    """A minimal XFDU manifest: the data objects and the MERIS product information."""
    files = [MANIFEST, *required_files()[1:], TIE_METEO_FILE]
    stop = t0 + np.timedelta64(int(duration_us), "us")
    objects = "\n".join(
        f'    <dataObject ID="{Path(f).stem}Data"><byteStream mimeType="application/x-netcdf">'
        f'<fileLocation locatorType="URL" href="./{f}"/></byteStream></dataObject>'
        for f in files[1:])
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<xfdu:XFDU xmlns:xfdu="urn:ccsds:schema:xfdu:1" xmlns:sentinel-safe="http://www.esa.int/safe/sentinel/1.1" xmlns:envisat="http://www.esa.int/safe/sentinel/envisat/1.0" version="esa/safe/sentinel/1.0/envisat/meris/level1">
  <metadataSection>
    <metadataObject ID="acquisitionPeriod"><metadataWrap><xmlData><sentinel-safe:acquisitionPeriod>
      <sentinel-safe:startTime>{t0}Z</sentinel-safe:startTime>
      <sentinel-safe:stopTime>{stop}Z</sentinel-safe:stopTime>
    </sentinel-safe:acquisitionPeriod></xmlData></metadataWrap></metadataObject>
    <metadataObject ID="generalProductInformation"><metadataWrap><xmlData>
      <envisat:generalProductInformation><envisat:productName>{name}.SEN3</envisat:productName>
      <envisat:productType>ME_1_{resolution}G___</envisat:productType>
      </envisat:generalProductInformation></xmlData></metadataWrap></metadataObject>
    <metadataObject ID="merisProductInformation"><metadataWrap><xmlData>
      <envisat:merisProductInformation>
        <envisat:imageSize><envisat:rows>{height}</envisat:rows><envisat:columns>{width}</envisat:columns></envisat:imageSize>
        <envisat:samplingParameters><envisat:rowsPerTiePoint>{df}</envisat:rowsPerTiePoint><envisat:columnsPerTiePoint>{dj}</envisat:columnsPerTiePoint></envisat:samplingParameters>
      </envisat:merisProductInformation></xmlData></metadataWrap></metadataObject>
  </metadataSection>
  <dataObjectSection>
{objects}
  </dataObjectSection>
</xfdu:XFDU>
"""  # noqa: E501


def manifest_summary(path: str | os.PathLike[str]) -> dict[str, str]:
    """Product name, type, times, image size and data-object files of an ``xfdumanifest.xml``
    (by local element names; absent entries are left out)."""
    p = Path(path)
    if p.is_dir():
        p = p / MANIFEST
    try:
        root = ET.parse(p).getroot()
    except (OSError, ET.ParseError) as exc:
        raise Sen3FormatError(p, f"manifest cannot be parsed: {exc}") from None
    out: dict[str, str] = {}
    files = []
    for el in root.iter():
        local = el.tag.rsplit("}", 1)[-1]
        if local in ("productName", "productType", "startTime", "stopTime", "rows", "columns",
                     "rowsPerTiePoint", "columnsPerTiePoint") and el.text:
            out.setdefault(local, el.text.strip())
        if local == "fileLocation" and el.get("href"):
            files.append(el.get("href", "").removeprefix("./"))
    out["files"] = " ".join(files)
    return out

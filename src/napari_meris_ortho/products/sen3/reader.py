"""Read a MERIS fourth-reprocessing ``.SEN3`` product (directory or zip archive).

:func:`read_sen3` gives the interface of ``products.n1.MerisL1bProduct`` (N1 column order, tie
points in physical units, ``counts``/``scaling``, L1b ``flags``) plus the per-pixel geolocation,
the full ``quality_flags`` and the per-band saturation. Every variable is decoded from its own
CF attributes (``layout.cf_decode``); no-data is NaN (radiances, geolocation, meteo), or the
band's ``no_data_count`` in ``counts``, which the mapping keeps out of every resampling.

The tie-point ``lat_corr``/``lon_corr`` (absent from the format) are derived from ``dem_alt``
and the view angles as operational N1 products store them (``geometry.parallax``; 0 over sea).
"""

from __future__ import annotations

import logging
import math
import os
import threading
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import closing
from dataclasses import dataclass, replace
from functools import cached_property, partial
from pathlib import Path
from typing import Any

import numpy as np

from ...bands import MERIS, Sensor
from ...cores import usable_threads
from ...errors import Sen3FormatError
from ...geometry.earth import MAX_TERRAIN_M, MIN_SEABED_M
from ...geometry.parallax import stored_corrections
from ...geometry.tiepoints import TiePoints
from ..n1.checks import DAYS_RANGE, MAX_FR_WIDTH, max_lines
from ..n1.format import (
    APPENDIX_A_BANDWIDTHS,
    APPENDIX_A_WAVELENGTHS,
    NUM_BANDS,
    Resolution,
    ScalingFactors,
    format_utc,
    tie_columns,
    tie_lines,
)
from ..protocol import radiance_of_counts
from .chunks import DamagedChunk, chunk_index, decode
from .kept import KeptBands
from .layout import (
    DETECTORS,
    DOBSON_KG_M2,
    ESA_TIME_UNITS,
    GEO_FILE,
    INSTRUMENT_FILE,
    MANIFEST,
    QUALITY_FILE,
    RADIANCE_FILL,
    SEN3_TYPES,
    TIE_GEO_FILE,
    TIE_GEOMETRY_FILE,
    TIE_METEO_FILE,
    TIME_FILE,
    attribute_number,
    cf_decode,
    esa_column_order,
    flag_coding,
    mirror_columns,
    no_data,
    packing_problem,
    product_type_of,
    quality_to_l1b,
    radiance_file,
    radiance_variable,
    required_files,
    saturated_bands,
    time_units,
)
from .members import Members, product_name_of

log = logging.getLogger(__name__)

#: physical range of each geolocation and angle variable (degrees, metres)
PHYSICAL_RANGE: dict[str, tuple[float, float]] = {
    "latitude": (-90.0, 90.0), "longitude": (-180.0, 360.0),
    "altitude": (MIN_SEABED_M, MAX_TERRAIN_M),
    "SZA": (0.0, 180.0), "OZA": (0.0, 90.0), "SAA": (-180.0, 360.0), "OAA": (-180.0, 360.0),
}
#: optional tie-point meteo variables, each on its own (none is used by the geometry)
METEO = ("horizontal_wind", "sea_level_pressure", "total_ozone", "humidity")


class MerisSen3Product:
    """An opened ``.SEN3`` MERIS Level 1 product; build with :func:`read_sen3`.

    Same attributes and methods as ``products.n1.MerisL1bProduct`` (``mph``/``sph`` hold a summary
    in N1 keys, ``dsds`` is empty) plus ``quality_flags``, ``saturated`` and the per-pixel
    geolocation (``pixel_longitude()``, ``pixel_latitude()``, ``pixel_altitude()``). Arrays in
    the N1 column order (``layout.mirror_columns``); bands read on demand.
    """

    has_pixel_geolocation = True
    #: the sensor's facts (band members, product types): ``Sen3Kind``, set below the class
    kind: Sen3Kind
    sensor = Sensor.MERIS
    n_bands = MERIS.n_bands
    band_names = MERIS.names
    dsds: list = []

    def __init__(self, members: Members, product_type: str, width: int, height: int, df: int,
                 dj: int, tie_points: Mapping[str, np.ndarray], line_times: np.ndarray,
                 scaling: ScalingFactors, wavelengths: tuple[float, ...],
                 bandwidths: tuple[float, ...], attrs: dict[str, Any],
                 variables: dict[str, dict[str, Any]], dtypes: dict[str, np.dtype],
                 mirrored: bool = True) -> None:
        self.members = members
        #: the file's columns in ESA's order, mirrored on reading (``layout.esa_column_order``)
        self.mirrored = mirrored
        self.path = members.path
        self.product_type = product_type
        self.resolution = self.kind.types[product_type]
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
        #: CF attributes of the image variables, by variable name
        self.variables = variables
        #: stored dtypes of the radiance variables, by variable name
        self.dtypes = dtypes
        self._warned: set[str] = set()
        #: bands being read ahead (``read_ahead``), each taken once by ``counts``
        self._ahead: dict[int, Future[np.ndarray]] = {}
        #: the bands decoded while a run keeps them (``kept``: decoded once per process, in
        #: file maps; once per host for the processes of a run)
        self.kept = KeptBands(self, key=str(members.path), shape=(height, width))
        n = self.n_tie_lines
        self.tie_point_times = line_times[0] + self.line_interval_s * df * np.arange(n)
        self.mph = {"PRODUCT": self.product_name, "PROC_CENTER": str(attrs.get("institution", "")),
                    "SENSING_START": format_utc(self._utc(line_times[0])),
                    "SENSING_STOP": format_utc(self._utc(line_times[-1])),
                    "SPH_SIZE": 0, "NUM_DSD": 0}
        self.sph = {"FIRST_LINE_TIME": self.mph["SENSING_START"],
                    "LAST_LINE_TIME": self.mph["SENSING_STOP"], "LINE_LENGTH": width,
                    "LINES_PER_TIE_PT": df, "SAMPLES_PER_TIE_PT": dj, "NUM_BANDS": self.n_bands,
                    "LINE_TIME_INTERVAL": int(round(self.line_interval_s * 1e6)),
                    "BAND_WAVELEN": tuple(int(round(w * 1000)) for w in wavelengths),
                    "BANDWIDTH": tuple(int(round(w * 1000)) for w in bandwidths)}

    def __repr__(self) -> str:
        return f"<MerisSen3Product {self.product_type} {self.width}x{self.height} ({self.path})>"

    def band_file(self, band: int) -> str:
        """The member holding band ``band`` (``Mnn_radiance.nc``, ``OaNN_radiance.nc``)."""
        return self.kind.band_file(band)

    def band_variable(self, band: int) -> str:
        """The variable of band ``band`` (``Mnn_radiance``, ``OaNN_radiance``)."""
        return self.kind.band_variable(band)

    @staticmethod
    def _utc(seconds: float) -> np.datetime64:
        return np.datetime64("2000-01-01T00:00:00", "us") + np.timedelta64(
            int(round(float(seconds) * 1e6)), "us")

    @property
    def product_name(self) -> str:
        return product_name_of(self.path, self.members.prefix)

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

    def _raw(self, name: str, variable: str, lines: slice | None = None) -> np.ndarray:
        """Stored values of an image variable (or the given lines), in the N1 column order."""
        with self.members.dataset(name) as ds:
            try:
                var = ds.variables[variable]
            except KeyError as exc:
                raise Sen3FormatError(self.members.where(name),
                                      f"cannot read {variable}: {exc}") from None
            raw = _stored(self.members, name, variable, var, lines)
        return mirror_columns(raw) if self.mirrored else raw

    def _warn(self, what: str, n: int, total: int) -> None:
        if n and what not in self._warned:
            self._warned.add(what)
            log.warning("%s: %d of %d %s masked as no data", self.product_name, n, total, what)

    # -- bands ----------------------------------------------------------------------------

    def no_data_count(self, band: int) -> int:
        """The value of a band's no-data pixels in :meth:`counts`: its ``_FillValue`` where
        that is a uint16 value, else 65535 (which no valid value of a 16-bit band takes)."""
        attrs = self.variables[self.band_variable(band)]
        fill = attribute_number(attrs, "_FillValue", RADIANCE_FILL)
        # not ``fill in range(65536)``: a float is searched for there, value by value (4 ms)
        if self.dtypes[self.band_variable(band)] == np.uint16 and fill.is_integer() \
                and 0 <= fill <= 65535:
            return int(fill)
        return RADIANCE_FILL

    def counts(self, band: int) -> np.ndarray:
        """Stored uint16 values of ``band`` (1..n_bands), radiance = counts x
        scaling.radiance[b-1], read-only; no-data pixels (fill, outside valid_min/valid_max,
        negative) hold ``no_data_count(band)`` (counted in a warning, once per band). Decoded
        once while a run keeps decoded bands (``kept``)."""
        n = self.n_bands
        if isinstance(band, bool) or not isinstance(band, int | np.integer):
            raise TypeError(f"band must be an integer 1..{n}, got {band!r}")
        if not 1 <= band <= n:
            raise ValueError(f"band must be 1..{n}, got {band}")
        kept = self.kept.get(int(band))
        if kept is not None:
            return kept
        ahead = self._ahead.pop(int(band), None)
        if ahead is not None:
            return self.kept.keep(int(band), ahead.result())
        return self.kept.fetch(int(band), partial(self._counts, int(band)))

    def prepare_bands(self, bands: Sequence[int]) -> None:
        """While a run keeps decoded bands: decode ``bands`` (1..n_bands) now, those no other
        process of the run is decoding first (``KeptBands.prepare``)."""
        self.kept.prepare([int(b) for b in bands if 1 <= int(b) <= self.n_bands], self._decoded)

    def _decoded(self, band: int) -> np.ndarray:
        """``band`` decoded: taken from ``read_ahead`` when its thread has begun it (else
        that is called off and it is decoded here)."""
        ahead = self._ahead.pop(band, None)
        if ahead is not None and not ahead.cancel():
            return ahead.result()
        return self._counts(band)

    def release_pages(self) -> None:
        """Drop the kept bands' pages a task read from the resident memory (``kept``), as an
        N1 drops its file's."""
        self.kept.release_pages()

    def read_ahead(self, bands: Sequence[int]) -> None:
        """Start reading ``bands`` (1..n_bands) whole, in order, in the background (bands kept
        already are not; ``reading_pool``: every product's bands in the order asked, several
        at once): a band inflates outside the GIL (``chunks``), so the reading overlaps the
        caller's work (a mapping's prediction/correction, the synthesis of the products
        before). A band read is kept while a run keeps bands (``kept``); :meth:`counts` and
        :meth:`prepare_bands` take each band read ahead once (a later call reads it again,
        or takes it kept). Errors are raised by that call."""
        todo = [int(b) for b in bands if 1 <= int(b) <= self.n_bands and int(b) not in self._ahead
                and self.kept.get(int(b)) is None]
        if not todo:
            return
        pool = reading_pool()
        for b in todo:
            self._ahead[b] = pool.submit(self._read_kept, b)

    def _read_kept(self, band: int) -> np.ndarray:
        """``band`` decoded and kept, its pages out of the resident memory until a task
        reads them (the page cache holds them). ``keep``, not ``fetch``: a reading thread
        takes no band lock of a run's directory (its caller may hold that lock while it
        waits for this band: ``prepare_bands``)."""
        counts = self.kept.keep(band, self._counts(band))
        self.kept.release_band_pages(band)
        return counts

    def cancel_read_ahead(self) -> None:
        """Call off the bands :meth:`read_ahead` has not begun, and forget those read."""
        for ahead in self._ahead.values():
            ahead.cancel()
        self._ahead.clear()

    def _band_values(self, band: int) -> np.ndarray:
        """Stored values of ``band``, whole, in the N1 column order: inflated from its chunks
        here (``chunks``: several bands at once on several cores), or through netCDF4 when
        its storage is not one read so."""
        name, variable = self.band_file(band), self.band_variable(band)
        source = self.members.read_bytes(name) if self.members.archived \
            else self.members.path / name
        index = chunk_index(source, variable)
        if index is None or index.shape != (self.height, self.width):
            return self._raw(name, variable)
        try:
            return decode(index, source, self.mirrored)
        except (DamagedChunk, OSError) as exc:
            raise Sen3FormatError(self.members.where(name),
                                  f"cannot read {variable}: {exc}") from None

    def _counts(self, band: int) -> np.ndarray:
        raw = self._band_values(band)
        attrs = self.variables[self.band_variable(band)]
        nd = self.no_data_count(band)
        if raw.dtype == np.uint16 and not any(k in attrs for k in ("valid_min", "valid_max",
                                                                   "valid_range")):
            out = raw
        else:
            bad = no_data(raw, attrs)
            if raw.dtype.kind == "i":
                bad |= raw < 0
            out = raw.astype(np.uint16, copy=False)
            np.putmask(out, bad, nd)
        self._warn(f"{self.band_variable(band)} values (fill or outside the valid range)",
                   int(np.count_nonzero(out == nd)), out.size)
        return out

    def radiance(self, band: int, lines: slice | None = None) -> np.ndarray:
        """TOA radiance (mW m-2 sr-1 nm-1) of ``band``, float32 (H, W) or the given lines;
        no data is NaN."""
        counts = self.counts(band)
        if lines is not None:
            counts = counts[lines]
        return radiance_of_counts(counts, self.scaling.radiance[band - 1],
                                  self.no_data_count(band))

    # -- flags ----------------------------------------------------------------------------

    @cached_property
    def quality_flags(self) -> np.ndarray:
        """``quality_flags`` (uint32 (H, W))."""
        return self._raw(QUALITY_FILE, "quality_flags")

    @cached_property
    def quality_coding(self) -> dict[str, int]:
        """meaning -> mask of ``quality_flags``, from the file's own ``flag_masks`` and
        ``flag_meanings`` (ESA's coding when it has none)."""
        return flag_coding(self.variables["quality_flags"])

    @cached_property
    def flags(self) -> np.ndarray:
        """L1b flags (uint8 (H, W)) mapped from ``quality_flags`` (``layout``)."""
        return quality_to_l1b(self.quality_flags, self.quality_coding)

    @cached_property
    def saturated(self) -> np.ndarray:
        """uint16 (H, W): bit b-1 set where band b is saturated (``saturated_Mnn``)."""
        return saturated_bands(self.quality_flags, self.quality_coding)

    @cached_property
    def detector_index(self) -> np.ndarray:
        return self._raw(INSTRUMENT_FILE, "detector_index")

    # -- per-pixel geolocation ------------------------------------------------------------

    def _geo(self, variable: str, lines: slice | None, dtype: Any) -> np.ndarray:
        raw = self._raw(GEO_FILE, variable, lines)
        values, n_fill = cf_decode(raw, self.variables[f"geo.{variable}"], dtype)
        low, high = PHYSICAL_RANGE[variable]
        with np.errstate(invalid="ignore"):
            outside = (values < low) | (values > high)
        values[outside] = np.nan
        self._warn(f"{variable}s of {GEO_FILE} (fill or outside [{low:g}, {high:g}])",
                   n_fill + int(outside.sum()), raw.size)
        return values

    def pixel_longitude(self, lines: slice | None = None) -> np.ndarray:
        """Longitude of every pixel (geo_coordinates.nc), float64 deg on (-180, 180]; NaN: none."""
        lon = self._geo("longitude", lines, np.float64)
        return np.where(lon > 180.0, lon - 360.0, lon)

    def pixel_latitude(self, lines: slice | None = None) -> np.ndarray:
        """Latitude of every pixel (geo_coordinates.nc), float64 deg; NaN: none."""
        return self._geo("latitude", lines, np.float64)

    def pixel_altitude(self, lines: slice | None = None) -> np.ndarray:
        """Altitude of every pixel's terrain point (geo_coordinates.nc), float32 m; NaN: none."""
        return self._geo("altitude", lines, np.float32)


# ------------------------------------------------------------------------------------------
# read_sen3
# ------------------------------------------------------------------------------------------


def _meris_widest(res: Resolution) -> int:
    return MAX_FR_WIDTH if res.name == "FR" else res.width


_pool: dict[str, ThreadPoolExecutor] = {}
_pool_lock = threading.Lock()


def reading_pool() -> ThreadPoolExecutor:
    """The threads that read bands ahead (``MerisSen3Product.read_ahead``), one per usable core
    (``cores.usable_threads``), the bands in the order asked; made at the first use."""
    with _pool_lock:
        if "pool" not in _pool:
            _pool["pool"] = ThreadPoolExecutor(usable_threads(), thread_name_prefix="sen3-bands")
        return _pool["pool"]


def read_sen3(path: str | os.PathLike[str]) -> MerisSen3Product:
    """Open a MERIS Level 1 ``.SEN3`` directory (or its ``xfdumanifest.xml``), or a zip archive
    of one.

    Parses the manifest (the product type comes from its ``productType``, the name as a
    fallback), checks that every member file is there and that every variable has the shape
    of the radiances (tie-point variables: of the tie-point grid), decodes the tie points,
    times and scale factors; bands and per-pixel geolocation are read on demand. Raises
    :class:`Sen3FormatError` naming the product (or member) and the problem.
    """
    members = Members(path)
    missing = [f for f in required_files() if not members.exists(f)]
    if missing:
        raise Sen3FormatError(members.path, f"missing member file(s): {', '.join(missing)}")
    try:
        return read_members(members, MERIS_KIND, _product_type(members))
    except OSError as exc:
        raise Sen3FormatError(members.path, f"cannot read: {exc.strerror or exc}") from None


def _stored(members: Members, name: str, variable: str, var: Any,
            lines: slice | None = None) -> np.ndarray:
    """Stored values of ``variable`` of member ``name`` open as ``var`` (or the given lines),
    not CF-decoded; a damaged chunk ("NetCDF: HDF error") is one error naming the member."""
    var.set_auto_maskandscale(False)
    try:
        return np.asarray(var[lines] if lines is not None else var[...])
    except (IndexError, RuntimeError) as exc:
        raise Sen3FormatError(members.where(name), f"cannot read {variable}: {exc}") from None


def _variables(members: Members, name: str, variables: list[str], shape: tuple[int, ...] | None,
               *, optional: bool | Collection[str] = False, data: bytes | None = None
               ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Raw values of ``variables`` (each checked against ``shape``, None: any; a missing one
    that is ``optional`` (True: any; else those named) is left out), their attributes and the
    file's global attributes (key ``""``); ``data``: an archived member's bytes when already
    read."""
    out: dict[str, np.ndarray] = {}
    attrs: dict[str, Any] = {}
    with members.dataset(name, data) as ds:
        attrs[""] = {k: ds.getncattr(k) for k in ds.ncattrs()}
        for v in variables:
            if v not in ds.variables:
                if optional is True or (optional and v in optional):
                    continue
                raise Sen3FormatError(members.where(name), f"has no variable {v!r}")
            var = ds.variables[v]
            if shape is not None and tuple(var.shape[: len(shape)]) != shape:
                raise Sen3FormatError(members.where(name), f"variable {v!r} has shape "
                                      f"{tuple(var.shape)}, expected {shape}")
            out[v] = _stored(members, name, v, var)
            attrs[v] = {k: var.getncattr(k) for k in var.ncattrs()}
            _check_packing(members, name, v, attrs[v])
    return out, attrs


def _variable_info(members: Members, name: str, variable: str, ds: Any
                   ) -> tuple[tuple[int, ...], dict[str, Any], np.dtype]:
    """Shape, attributes (their CF packing checked) and stored dtype of one variable of member
    ``name``, open as ``ds`` (no data read)."""
    if variable not in ds.variables:
        raise Sen3FormatError(members.where(name), f"has no variable {variable!r}")
    var = ds.variables[variable]
    attrs = {k: var.getncattr(k) for k in var.ncattrs()}
    _check_packing(members, name, variable, attrs)
    return tuple(var.shape), attrs, np.dtype(var.dtype)


def _check_packing(members: Members, name: str, variable: str, attrs: dict[str, Any]) -> None:
    problem = packing_problem(attrs, variable)
    if problem is not None:
        raise Sen3FormatError(members.where(name), problem)


def _product_type(members: Members) -> str:
    """From the manifest's ``productType``; else the product name; else instrument_data.nc's
    ``product_name`` attribute."""
    root = members.manifest()
    for el in root.iter():
        if el.tag.rsplit("}", 1)[-1] == "productType" and el.text:
            found = product_type_of(el.text.strip())
            if found is not None:
                return found
    found = product_type_of(members.path.name)
    if found is None:
        _, attrs = _variables(members, INSTRUMENT_FILE, [], None)
        found = product_type_of(str(attrs[""].get("product_name", "")))
    if found is None:
        raise Sen3FormatError(members.path, "not a MERIS Level 1 product (ME_1_FRG___ or "
                              "ME_1_RRG___ in the manifest's productType, the product name or "
                              "instrument_data.nc product_name)")
    return found


@dataclass(frozen=True)
class Sen3Kind:
    """What tells the ``.SEN3`` products of one sensor apart: band members and their count,
    product types and their sampling, the widest line of each, spectral defaults (used where
    ``instrument_data.nc`` has none), the product class, whether the tie files carry an
    altitude, and the tie points' own adjustment (``None``: as read)."""

    name: str
    n_bands: int
    band_file: Callable[[int], str]
    band_variable: Callable[[int], str]
    types: Mapping[str, Resolution]
    widest: Callable[[Resolution], int]
    wavelengths: tuple[float, ...]
    bandwidths: tuple[float, ...]
    sun_flux: tuple[float, ...]
    product_class: Callable[..., Any]
    detectors: Mapping[str, int] | None = None
    tie_altitude: bool = True
    adjust_tie_points: Callable[[dict[str, np.ndarray], int, bool],
                                dict[str, np.ndarray]] | None = None


def read_members(members: Members, kind: Sen3Kind, product_type: str) -> Any:
    """The product of ``kind`` held by ``members``, of ``product_type`` (a key of
    ``kind.types``): every member and variable checked, tie points, times and scale factors
    decoded (bands and per-pixel geolocation read on demand)."""
    # the image members, each opened once (an archive's read ahead, ``Members.read_ahead``)
    image_members = [*(kind.band_file(b) for b in range(1, kind.n_bands + 1)), GEO_FILE,
                     QUALITY_FILE, INSTRUMENT_FILE]
    with closing(members.read_ahead(image_members)) as contents:
        shape, variables, dtypes = _band_variables(members, kind, product_type, contents)
        for name, names in ((GEO_FILE, ("latitude", "longitude", "altitude")),
                            (QUALITY_FILE, ("quality_flags",)),
                            (INSTRUMENT_FILE, ("detector_index",))):
            data = next(contents)
            with members.dataset(name, data) as ds:
                for v in names:
                    got, a, _ = _variable_info(members, name, v, ds)
                    if got != shape:
                        raise Sen3FormatError(members.where(name), f"variable {v!r} has shape "
                                              f"{got}, the radiances have {shape}")
                    variables[f"geo.{v}" if name == GEO_FILE else v] = a
        # the instrument member (read last): its spectral variables from the same bytes
        spectral, instrument = _variables(members, INSTRUMENT_FILE,
                                          ["solar_flux", "lambda0", "FWHM"], None,
                                          optional=True, data=data)
    height, width = shape
    times, time_attrs = _variables(members, TIME_FILE, ["time_stamp"], (height,))
    line_times = _line_times(members, product_type, times["time_stamp"],
                             time_attrs["time_stamp"])
    tie_points, df, dj, mirrored = _tie_points(members, height, width, kind)
    if kind.detectors is not None:
        _check_detectors(members, product_type, spectral, kind)
    wavelengths = _band_means(spectral.get("lambda0"), kind.wavelengths)
    bandwidths = _band_means(spectral.get("FWHM"), kind.bandwidths)
    sun_flux = _band_means(spectral.get("solar_flux"), kind.sun_flux)
    scaling = replace(ScalingFactors(), radiance=tuple(
        attribute_number(variables[kind.band_variable(b)], "scale_factor", 1.0)
        for b in range(1, kind.n_bands + 1)), sun_flux=sun_flux)
    return kind.product_class(
        members, product_type, width, height, df, dj, tie_points,
        line_times, scaling, wavelengths, bandwidths,
        instrument[""], variables, dtypes, mirrored)


def _band_variables(members: Members, kind: Sen3Kind, product_type: str,
                    contents: Iterator[bytes | None]
                    ) -> tuple[tuple[int, int], dict[str, dict[str, Any]], dict[str, np.dtype]]:
    """The radiances' shape, attributes and stored types, each band checked (16-bit integers,
    the shape of M01, no add_offset, a positive scale_factor); ``contents``: the band members'
    bytes in band order (``Members.read_ahead``)."""
    variables: dict[str, dict[str, Any]] = {}
    dtypes: dict[str, np.dtype] = {}
    shape: tuple[int, int] = (0, 0)
    for b in range(1, kind.n_bands + 1):
        file, variable = kind.band_file(b), kind.band_variable(b)
        with members.dataset(file, next(contents)) as ds:
            got, a, dtype = _variable_info(members, file, variable, ds)
        if b == 1:
            if len(got) != 2 or min(got) < 2:
                raise Sen3FormatError(members.where(file), f"{variable} has shape {got}, a "
                                      "2-D (rows, columns) image expected")
            shape = (int(got[0]), int(got[1]))
            _check_size(members, kind, product_type, *shape)
        _check_band(members, kind, b, got, shape, a, dtype)
        dtypes[variable] = dtype
        variables[variable] = a
    return shape, variables, dtypes


def _check_band(members: Members, kind: Sen3Kind, b: int, got: tuple[int, ...],
                shape: tuple[int, int], a: dict[str, Any], dtype: np.dtype) -> None:
    """Band ``b``'s variable as the format has it (shape ``got``, attributes ``a``, stored
    ``dtype``), or Sen3FormatError naming its member."""
    where = members.where(kind.band_file(b))
    variable, first = kind.band_variable(b), kind.band_variable(1)
    if dtype.kind not in "iu" or dtype.itemsize > 2:
        raise Sen3FormatError(where, f"{variable} is stored as {dtype}: {kind.name} Level "
                              "1 radiances are 16-bit integers with a scale_factor (ESA's "
                              "products: uint16); other types are not supported")
    if got != shape:
        raise Sen3FormatError(where, f"variable {variable!r} has shape {got}, "
                              f"{first} has {shape}")
    if attribute_number(a, "add_offset", 0.0) != 0.0:
        raise Sen3FormatError(where, "radiances with a non-zero add_offset are not supported")
    scale = attribute_number(a, "scale_factor", 1.0)
    if not (math.isfinite(scale) and scale > 0):
        raise Sen3FormatError(where, f"scale_factor {scale!r} of {variable} is not "
                              "a positive number")


def _check_size(members: Members, kind: Sen3Kind, product_type: str, height: int,
                width: int) -> None:
    """At most one orbit of lines and the instrument's widest line (``n1.checks``), before any
    array is read: a forged file of a few kB can declare billions of pixels."""
    res = kind.types[product_type]
    where = members.where(kind.band_file(1))
    if height > max_lines(res):
        raise Sen3FormatError(where, f"{height} rows: more lines than one orbit "
                              f"({max_lines(res)} {res.name} lines)")
    widest = kind.widest(res)
    if width > widest:
        raise Sen3FormatError(where, f"{width} columns: a {product_type} line has at most "
                              f"{widest} columns")


def _line_times(members: Members, product_type: str, stamps: np.ndarray,
                attrs: dict[str, Any]) -> np.ndarray:
    """Seconds since 2000-01-01 of every row from ``time_stamp`` in its CF ``units`` (ESA's:
    microseconds since 2000-01-01, also when it names none). A stamp that is fill, not
    positive (ocssw's "no time") or no MERIS time (days 1990 .. 2100,
    ``n1.checks.DAYS_RANGE``) is interpolated between the valid ones (extrapolated at the
    ends with their median interval) and counted in a warning; fewer than two valid stamps,
    or units that are no CF time, is one error (the map does not use the times)."""
    units = str(attrs.get("units", ESA_TIME_UNITS))
    scale = time_units(units)
    if scale is None:
        raise Sen3FormatError(members.where(TIME_FILE), f"time_stamp units {units!r} are not "
                              "'<unit> since <date>' (CF)")
    factor, epoch = scale
    low, high = DAYS_RANGE
    with np.errstate(invalid="ignore", over="ignore"):
        seconds = stamps.astype(np.float64) * factor + epoch
        bad = ~((seconds >= low * 86_400.0) & (seconds <= high * 86_400.0))
        if epoch <= 0.0:  # an epoch before MERIS: every MERIS time is a positive count
            bad |= ~(stamps > 0)
    bad |= no_data(stamps, attrs)
    if not bad.any():
        return seconds
    rows = np.arange(seconds.size)
    good = rows[~bad]
    if good.size < 2:
        raise Sen3FormatError(members.where(TIME_FILE), f"{int(bad.sum())} of {seconds.size} "
                              "time_stamp values are fill or not MERIS times (1990 to 2100)")
    step = float(np.median(np.diff(seconds[good]) / np.diff(good)))
    out = np.interp(rows, good, seconds[good])
    out[rows < good[0]] = seconds[good[0]] - (good[0] - rows[rows < good[0]]) * step
    out[rows > good[-1]] = seconds[good[-1]] + (rows[rows > good[-1]] - good[-1]) * step
    log.warning("%s: %d of %d time_stamp values of %s are fill or not MERIS times (1990 to "
                "2100): interpolated", members.path.name, int(bad.sum()), seconds.size,
                TIME_FILE)
    return out


def _check_detectors(members: Members, product_type: str, spectral: dict[str, np.ndarray],
                     kind: Sen3Kind) -> None:
    """The (bands, detectors) arrays of instrument_data.nc must not have the detectors of the
    other resolution (FR 3700, RR 925): a product type contradicted by the data."""
    counts = kind.detectors or {}
    res = kind.types[product_type].name
    for name, values in spectral.items():
        n = values.shape[-1] if values.ndim == 2 else None
        other = next((r for r, count in counts.items() if count == n and r != res), None)
        if other is not None:
            raise Sen3FormatError(members.where(INSTRUMENT_FILE), f"a {product_type} product, "
                                  f"but {INSTRUMENT_FILE} has {n} detectors ({other}) in {name}")


def _band_means(values: np.ndarray | None, default: tuple[float, ...]) -> tuple[float, ...]:
    """Per-band mean over the detectors (bands, detectors), or the default."""
    n = len(default)
    if values is None or values.ndim != 2 or values.shape[0] != n:
        return tuple(default)
    v = np.where(np.isfinite(values) & (values > 0), values, np.nan)
    means = np.nanmean(v, axis=1) if np.isfinite(v).any() else np.full(n, np.nan)
    return tuple(float(m) if math.isfinite(m) else float(d)
                 for m, d in zip(means, default, strict=True))


def _tie_points(members: Members, height: int, width: int, kind: Sen3Kind
                ) -> tuple[dict[str, np.ndarray], int, int, bool]:
    """Tie points in physical units with the N1 names, N1 column order; (tie points, DF, DJ,
    whether the file's columns were mirrored: ESA's order, ``layout.esa_column_order``)."""
    with members.dataset(TIE_GEOMETRY_FILE) as ds:
        shape, _, _ = _variable_info(members, TIE_GEOMETRY_FILE, "SZA", ds)
    geom, attrs = _variables(members, TIE_GEOMETRY_FILE, ["SZA", "SAA", "OZA", "OAA"], shape)
    where = members.where(TIE_GEOMETRY_FILE)
    try:
        df = int(attrs[""]["al_subsampling_factor"])
        dj = int(attrs[""]["ac_subsampling_factor"])
    except (KeyError, TypeError, ValueError):
        raise Sen3FormatError(where, "global attributes al_subsampling_factor and "
                              "ac_subsampling_factor are required") from None
    if len(shape) != 2 or df < 1 or dj < 1:
        raise Sen3FormatError(where, f"tie-point grid {shape} every {df} x {dj} is not valid")
    n_cols = tie_columns(width, dj)
    if shape[1] != n_cols or (width - 1) % dj or shape[0] < tie_lines(height, df):
        raise Sen3FormatError(
            where, f"tie-point grid of {shape[0]} x {shape[1]} every {df} lines x {dj} columns "
            f"does not cover {height} x {width} pixels (needs {tie_lines(height, df)} x "
            f"{n_cols})")
    geo, geo_attrs = _variables(members, TIE_GEO_FILE, ["latitude", "longitude", "altitude"],
                                shape, optional={"altitude"})
    # the tie-point altitude (SNAP's TP_altitude, "DEM corrected altitude"): optional, as no
    # format description at hand names its member; else the pixels' own at the tie points
    alt_file = TIE_GEO_FILE
    if "altitude" not in geo:
        geo["altitude"], geo_attrs["altitude"] = _tie_altitude_of_pixels(
            members, shape, df, dj, (height, width), expected=not kind.tie_altitude)
        alt_file = GEO_FILE
    meteo, meteo_attrs = _variables(members, TIE_METEO_FILE, list(METEO), shape, optional=True
                                    ) if members.exists(TIE_METEO_FILE) else ({}, {})

    def decoded(raw: dict[str, np.ndarray], all_attrs: dict[str, Any], name: str, file: str,
                key: str | None = None) -> np.ndarray:
        values, n_fill = cf_decode(raw[name], all_attrs[name])
        key = key or name
        low, high = PHYSICAL_RANGE[key]
        with np.errstate(invalid="ignore"):
            bad = ~((values >= low) & (values <= high))
        if n_fill or bad.any():
            if name == "altitude":  # usable: sea level where the tie-point height is missing
                log.warning("%s: %d tie-point altitudes of %s are fill or outside [%g, %g] m: "
                            "taken as 0 m", members.path.name, int(bad.sum()), file, low, high)
                return np.where(bad, 0.0, values)
            raise Sen3FormatError(members.where(file), f"{int(bad.sum())} tie points of {name} "
                                  f"are fill values or outside their physical range "
                                  f"[{low:g}, {high:g}]")
        return values

    lat = decoded(geo, geo_attrs, "latitude", TIE_GEO_FILE)
    lon = decoded(geo, geo_attrs, "longitude", TIE_GEO_FILE)
    mirrored = esa_column_order(lat, lon)
    if not mirrored:
        log.warning("%s: its columns run in the N1 column order (column 0 on the left of the "
                    "flight direction), not ESA's: read as they are, not mirrored",
                    members.path.name)
    tp = {"latitude": lat, "longitude": np.where(lon > 180.0, lon - 360.0, lon),
          "dem_alt": decoded(geo, geo_attrs, "altitude", alt_file),
          "dem_rough": np.zeros(shape),
          "sun_zenith": decoded(geom, attrs, "SZA", TIE_GEOMETRY_FILE),
          "sun_azimuth": decoded(geom, attrs, "SAA", TIE_GEOMETRY_FILE) % 360.0,
          "view_zenith": decoded(geom, attrs, "OZA", TIE_GEOMETRY_FILE),
          "view_azimuth": decoded(geom, attrs, "OAA", TIE_GEOMETRY_FILE) % 360.0}
    tp.update(_meteo(meteo, meteo_attrs, shape))
    if mirrored:  # ESA's columns in the N1 order
        tp = {k: mirror_columns(v) for k, v in tp.items()}
    if kind.adjust_tie_points is not None:
        tp = kind.adjust_tie_points(tp, dj, mirrored)
    # the DEM corrections as operational N1 products store them (Appendix E; 0 over sea)
    tp["lat_corr"], tp["lon_corr"] = stored_corrections(
        tp["dem_alt"], tp["view_zenith"], tp["view_azimuth"], tp["latitude"])
    return tp, df, dj, mirrored


def _tie_altitude_of_pixels(members: Members, shape: tuple[int, int], df: int, dj: int,
                            image: tuple[int, int], expected: bool = False
                            ) -> tuple[np.ndarray, dict[str, Any]]:
    """``altitude`` of geo_coordinates.nc (and its attributes) at the tie points (line ``k df``,
    column ``j dj`` in the file's order; tie lines past the last image line take the last), for
    a product whose tie_geo_coordinates.nc has none; logged."""
    pixels, attrs = _variables(members, GEO_FILE, ["altitude"], image)
    lines = np.minimum(np.arange(shape[0]) * df, image[0] - 1)
    columns = np.arange(shape[1]) * dj
    (log.debug if expected else log.warning)(
        "%s: %s has no tie-point altitude: taken from %s at the tie points",
        members.path.name, TIE_GEO_FILE, GEO_FILE)
    return pixels["altitude"][np.ix_(lines, columns)], attrs["altitude"]


def _meteo(raw: dict[str, np.ndarray], attrs: dict[str, Any], shape: tuple[int, ...]
           ) -> dict[str, np.ndarray]:
    """The N1 meteo annotations from whichever tie_meteo variables there are (each optional;
    fill -> NaN). A variable on other dimensions than the tie grid's (``humidity`` on pressure
    levels, as OLCI's and some MERIS files have it) has no N1 counterpart: left NaN, logged."""
    def value(name: str) -> np.ndarray | None:
        if name not in raw:
            return None
        return cf_decode(raw[name], attrs[name])[0]

    nan = np.full(shape, np.nan)
    out = {k: nan for k in ("zonal_wind", "merid_wind", "atm_pressure", "ozone",
                            "rel_humidity")}
    wind = value("horizontal_wind")
    if wind is not None and wind.ndim == 3 and wind.shape[-1] == 2:
        out["zonal_wind"], out["merid_wind"] = wind[..., 0], wind[..., 1]
    for name, key, factor in (("sea_level_pressure", "atm_pressure", 1.0),
                              ("total_ozone", "ozone", 1.0 / DOBSON_KG_M2),
                              ("humidity", "rel_humidity", 1.0)):
        v = value(name)
        if v is not None and v.shape == tuple(shape):
            out[key] = v * factor
        elif v is not None:
            log.info("%s: %s has shape %s, not the tie grid's %s (pressure levels?): not read",
                     TIE_METEO_FILE, name, v.shape, tuple(shape))
    return out


def manifest_summary(path: str | os.PathLike[str]) -> dict[str, str]:
    """Product name, type, times, image size and data-object files of an ``xfdumanifest.xml``
    (by local element names; absent entries are left out)."""
    root = Members(Path(path).parent if Path(path).name == MANIFEST else path).manifest()
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


#: MERIS fourth-reprocessing products
MERIS_KIND = Sen3Kind(
    name="MERIS", n_bands=NUM_BANDS, band_file=radiance_file, band_variable=radiance_variable,
    types=SEN3_TYPES, widest=_meris_widest, wavelengths=APPENDIX_A_WAVELENGTHS,
    bandwidths=APPENDIX_A_BANDWIDTHS, sun_flux=ScalingFactors().sun_flux,
    product_class=MerisSen3Product, detectors=DETECTORS)
MerisSen3Product.kind = MERIS_KIND

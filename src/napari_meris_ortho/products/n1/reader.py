"""Reader of MERIS L1b ENVISAT N1 products (MER_FR__1P, MER_RR__1P and the other FR L1b types).

:func:`read_product` validates the whole structure (MPH, SPH, every DSD against the file size and
the record sizes of the product type) before it builds any view; nothing of the bands is read at
open: :meth:`MerisL1bProduct.counts` is a memory map striding over the 13-byte record headers.
Any inconsistency raises :class:`N1FormatError` naming the file and the problem.

Arrays are in the stored column order (chronological/detector order, as MERSYN and the
handbook's benchmark use them); :func:`west_to_east` gives the mirrored view BEAM and EPR show.
"""

from __future__ import annotations

import logging
import math
import os
import re
import stat
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from ...bands import MERIS, Sensor
from ...errors import N1FormatError
from ...flags import FLAG_INVALID
from ...geometry.tiepoints import TiePoints
from ..pages import drop_resident_pages
from .checks import (
    PIXEL_GEOLOCATION_RANGES,
    check_counts,
    check_dimensions,
    check_header_numbers,
    check_scaling,
    check_tie_points,
)
from .format import (
    DSD_SIZE,
    FLAGS_MDS,
    GADS_DTYPE,
    GADS_SIZE,
    GEOLOCATION_MDS,
    MPH_SIZE,
    NUM_BANDS,
    PIXEL_GEOLOCATION_TYPES,
    PRODUCT_TYPES,
    SCALING_GADS,
    SPARE_DSD,
    TIE_POINT_FIELDS,
    TIE_POINTS_ADS,
    Dsd,
    Resolution,
    ScalingFactors,
    flags_dtype,
    flags_record_size,
    geolocation_dtype,
    geolocation_record_size,
    mjd2000_to_seconds,
    parse_utc,
    radiance_dtype,
    radiance_mds,
    radiance_record_size,
    tie_columns,
    tie_point_dtype,
    tie_point_record_size,
)

log = logging.getLogger(__name__)

#: largest header block we accept (a MERIS SPH is 9942 bytes; ASAR ones are larger)
_MAX_SPH_SIZE = 1 << 20
#: largest plausible MERIS line length (FR full swath: 4481)
_MAX_WIDTH = 1 << 15

_INT = re.compile(r"[+-]\d+")
_INTS = re.compile(r"(?:[+-]\d+)+")
_FLOAT = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")


def west_to_east(a: np.ndarray) -> np.ndarray:
    """Mirror the columns (last axis) of a product array: the west-to-east view of BEAM and EPR.

    Product arrays are stored in chronological (detector) order, which for MERIS runs from east
    to west (Appendix E: "tie-points are ordered from East to West"). The tie-point grid maps onto
    itself: FR/RR widths satisfy (W-1) % DJ == 0, so mirrored tie column k sits on mirrored pixel
    k*DJ. Returns a view (no copy).
    """
    return np.asarray(a)[..., ::-1]


# --------------------------------------------------------------------------------------------
# ASCII headers
# --------------------------------------------------------------------------------------------


def parse_value(text: str) -> Any:
    """Typed value of a header entry: ``"..."`` -> str (right-stripped), ``+00036`` or ``0`` ->
    int, ``+0000412545+0000442401...`` -> tuple of ints, ``+2.6e+02`` -> float, else the raw
    text. Units (``<bytes>``) are dropped. Raises ValueError on an unterminated string."""
    if text.startswith('"'):
        end = text.find('"', 1)
        if end < 0:
            raise ValueError("unterminated string")
        return text[1:end].rstrip()
    value = text.split("<", 1)[0].strip()
    if _INT.fullmatch(value) or (value.isdigit() and value.isascii()):
        return int(value)
    if _INTS.fullmatch(value):
        return tuple(int(v) for v in _INT.findall(value))
    if _FLOAT.fullmatch(value) and any(c.isdigit() for c in value):
        return float(value)
    return value


def parse_header(block: bytes, what: str, path: object) -> dict[str, Any]:
    """Parse an ASCII header block of ``KEY=value`` lines into a typed dict (file keys).

    Lines of spaces are spare; anything else without ``=`` or with an empty key is an error.
    """
    try:
        text = block.decode("ascii")
    except UnicodeDecodeError:
        raise N1FormatError(path, f"{what} is not ASCII text") from None
    out: dict[str, Any] = {}
    for n, line in enumerate(text.split("\n"), start=1):
        if not line.strip(" "):
            continue
        key, sep, value = line.partition("=")
        if not sep or not key or not key.replace("_", "").isalnum() or not key.isascii():
            raise N1FormatError(path, f"{what} line {n} is not KEY=value: {line[:40]!r}")
        try:
            out[key] = parse_value(value)
        except ValueError as exc:
            raise N1FormatError(path, f"{what} {key}: {exc}") from None
    return out


def parse_dsd(block: bytes, path: object = "<dsd>") -> Dsd:
    """Parse one 280-byte Data Set Descriptor (all spaces: a spare DSD)."""
    if not block.strip(b" \n\x00"):
        return SPARE_DSD
    d = parse_header(block, "DSD", path)
    try:
        name, kind, filename = d["DS_NAME"], d["DS_TYPE"], d.get("FILENAME", "")
        numbers = [d[k] for k in ("DS_OFFSET", "DS_SIZE", "NUM_DSR", "DSR_SIZE")]
    except KeyError as exc:
        raise N1FormatError(path, f"DSD without {exc.args[0]}: {block[:40]!r}") from None
    if not isinstance(name, str) or not isinstance(kind, str) or not isinstance(filename, str):
        raise N1FormatError(path, f"DSD {name!r}: DS_NAME, DS_TYPE and FILENAME must be text")
    if not all(isinstance(v, int) and v >= 0 for v in numbers):
        raise N1FormatError(path, f"DSD {name!r}: offset and sizes must be integers >= 0")
    return Dsd(name, kind, filename, *numbers)


def _get(header: dict, key: str, kind: type, what: str, path: object) -> Any:
    if key not in header:
        raise N1FormatError(path, f"{what} has no {key}")
    value = header[key]
    if not isinstance(value, kind) or isinstance(value, bool):
        raise N1FormatError(path, f"{what} {key}={value!r} is not a {kind.__name__}")
    return value


# --------------------------------------------------------------------------------------------
# The product
# --------------------------------------------------------------------------------------------


class MerisL1bProduct:
    """An opened MERIS L1b product. Build with :func:`read_product`.

    Attributes: ``path``, ``mph``/``sph`` (typed dicts by file key), ``dsds`` (all DSDs, spare
    ones included), ``product_type``, ``width``, ``height``, ``lines_per_tie_point``,
    ``samples_per_tie_point``, ``scaling`` (:class:`ScalingFactors`), ``tie_points`` (physical
    float64 grids), ``tie_point_times``, ``line_times`` (float64 seconds since 2000-01-01),
    ``wavelengths`` (nm); methods ``counts(band)``, ``radiance(band)``; properties ``flags``,
    ``detector_index``. Band arrays are big-endian memory maps of the file (``>u2``, ``>i2``).
    FRG/FSG/RRG (AMORGOS) products also have a per-pixel geolocation (``has_pixel_geolocation``,
    ``pixel_longitude()``, ``pixel_latitude()``, ``pixel_altitude()``: MDS(17..19)).
    """
    sensor = Sensor.MERIS
    n_bands = MERIS.n_bands
    band_names = MERIS.names

    def __init__(
        self,
        path: Path,
        mph: dict[str, Any],
        sph: dict[str, Any],
        dsds: list[Dsd],
        datasets: dict[str, Dsd],
        product_type: str,
        resolution: Resolution,
        width: int,
        height: int,
        lines_per_tie_point: int,
        samples_per_tie_point: int,
        scaling: ScalingFactors,
        tie_records: np.ndarray,
    ) -> None:
        self.path = path
        self._warned: set[str] = set()
        self.mph = mph
        self.sph = sph
        self.dsds = dsds
        self._datasets = datasets
        self.product_type = product_type
        self.resolution = resolution
        self.width = width
        self.height = height
        self.lines_per_tie_point = lines_per_tie_point
        self.samples_per_tie_point = samples_per_tie_point
        self.scaling = scaling
        self._tie_records = tie_records
        self.tie_points = TiePoints(**{
            f.name: tie_records[f.name].astype(np.float64) * scaling.factor(f)
            for f in TIE_POINT_FIELDS
        })
        self.tie_point_times = mjd2000_to_seconds(
            tie_records["days"], tie_records["seconds"], tie_records["microseconds"]
        )

    def __repr__(self) -> str:
        return (
            f"<MerisL1bProduct {self.product_type} {self.width}x{self.height} "
            f"{self.mph.get('PRODUCT', '')!s} ({self.path})>"
        )

    # -- data sets ------------------------------------------------------------------------
    def dsd(self, name: str) -> Dsd:
        """The DSD called ``name`` (the validated one of a data set stored in the product, else
        the first DSD of that name; KeyError if absent)."""
        if name in self._datasets:
            return self._datasets[name]
        for d in self.dsds:
            if d.name == name:
                return d
        raise KeyError(name)

    @property
    def product_name(self) -> str:
        return str(self.mph.get("PRODUCT", ""))

    @property
    def n_tie_lines(self) -> int:
        return int(self._tie_records.shape[0])

    @property
    def n_tie_columns(self) -> int:
        return tie_columns(self.width, self.samples_per_tie_point)

    @property
    def first_line_time(self) -> np.datetime64 | None:
        """SPH FIRST_LINE_TIME (None when it does not parse)."""
        try:
            return parse_utc(str(self.sph.get("FIRST_LINE_TIME", "")))
        except ValueError:
            return None

    @cached_property
    def wavelengths(self) -> tuple[float, ...]:
        """Central wavelengths (nm) of bands 1..15 (SPH BAND_WAVELEN, 1e-3 nm)."""
        return tuple(v / 1000.0 for v in self.sph["BAND_WAVELEN"])

    @cached_property
    def bandwidths(self) -> tuple[float, ...]:
        """Bandwidths (nm) of bands 1..15 (SPH BANDWIDTH, 1e-3 nm); NaN when absent."""
        values = self.sph.get("BANDWIDTH")
        if isinstance(values, tuple) and len(values) == NUM_BANDS:
            return tuple(v / 1000.0 for v in values)
        return (math.nan,) * NUM_BANDS

    @cached_property
    def _file_map(self) -> np.memmap:
        """The whole file, memory-mapped read-only on first use (nothing is read)."""
        return np.memmap(self.path, dtype=np.uint8, mode="r")

    def release_pages(self) -> None:
        """Drop the pages of the file map that this process has read from its resident memory
        (``madvise(MADV_DONTNEED)`` on the read-only map). The kernel keeps them in its page
        cache, so a later read maps them again without going to the disk. Does nothing if the
        file was never mapped, is closed, or the platform lacks ``MADV_DONTNEED``."""
        mapped = self.__dict__.get("_file_map")  # cached_property: present once opened
        drop_resident_pages(getattr(mapped, "_mmap", None))

    def _records(self, name: str, dtype: np.dtype) -> np.ndarray:
        """Records of data set ``name`` as a structured memmap view (validated at open)."""
        d = self._datasets[name]
        return self._file_map[d.offset : d.offset + d.num_dsr * dtype.itemsize].view(dtype)

    def _check_band(self, band: int) -> None:
        if isinstance(band, bool) or not isinstance(band, int | np.integer):
            raise TypeError(f"band must be an integer 1..15, got {band!r}")
        if not 1 <= band <= NUM_BANDS:
            raise ValueError(f"band must be 1..15, got {band}")

    def counts(self, band: int) -> np.ndarray:
        """Raw counts of ``band`` (1..15): a read-only memory map (H, W) of big-endian uint16."""
        self._check_band(band)
        return self._records(radiance_mds(band), radiance_dtype(self.width))["counts"]

    #: N1 products carry no per-band saturation flags
    saturated = None

    def no_data_count(self, band: int) -> int | None:
        """None: N1 counts have no fill value (invalid pixels are flagged, ``FLAG_INVALID``)."""
        self._check_band(band)
        return None

    def radiance(self, band: int, lines: slice | None = None) -> np.ndarray:
        """TOA radiance of ``band`` in W m-2 sr-1 um-1: counts x ``scaling.radiance[band-1]``
        (float32 (H, W), or the given slice of lines)."""
        counts = self.counts(band)
        if lines is not None:
            counts = counts[lines]
        factor = np.float32(self.scaling.radiance[band - 1])
        with np.errstate(over="ignore", invalid="ignore"):
            return counts.astype(np.float32) * factor

    @cached_property
    def _flags_records(self) -> np.ndarray:
        return self._records(FLAGS_MDS, flags_dtype(self.width))

    @property
    def flags(self) -> np.ndarray:
        """L1b flags (uint8 (H, W) memory map); bits as the ``FLAG_*`` constants. Lines whose
        record is blank (:attr:`blank_lines`) are INVALID (an array then, not a map)."""
        flags = self._flags_records["flags"]
        blank = self.blank_lines
        if blank.size == 0:
            return flags
        out = np.array(flags)
        out[blank] |= FLAG_INVALID
        return out

    @cached_property
    def blank_lines(self) -> np.ndarray:
        """Lines whose Flags MDS(16) record is blank: record header quality indicator -1
        (the DDDB's "Quality Indicator (-1 for blank MDSR)"); their counts are no data."""
        quality = self._flags_records["quality"].view(np.int8)
        blank = np.flatnonzero(quality < 0)
        if blank.size:
            log.warning("%s: %d blank record(s) (quality indicator -1), lines %s: flagged "
                        "INVALID", self.path.name, blank.size, _line_ranges(blank))
        return blank

    @property
    def detector_index(self) -> np.ndarray:
        """Detector index (big-endian int16 (H, W) memory map), EPR layout of Flags MDS(16)."""
        return self._flags_records["detector_index"]

    @cached_property
    def line_times(self) -> np.ndarray:
        """Time of each product line: float64 seconds since 2000-01-01 (MJD2000 of Radiance
        MDS(1) record headers)."""
        rec = self._records(radiance_mds(1), radiance_dtype(self.width))  # headers only read
        return mjd2000_to_seconds(rec["days"], rec["seconds"], rec["microseconds"])

    # -- per-pixel geolocation (MER_FRG_1P / MER_FSG_1P / MER_RRG_1P) -----------------------
    @property
    def has_pixel_geolocation(self) -> bool:
        """True for products with the Corrected Longitude/Latitude and Altitude MDS(17..19)."""
        return self.product_type in PIXEL_GEOLOCATION_TYPES

    def _geolocation(self, k: int, lines: slice | None, dtype: type) -> np.ndarray:
        if not self.has_pixel_geolocation:
            raise N1FormatError(self.path, f"{self.product_type} products have no per-pixel "
                                f"geolocation (only {', '.join(PIXEL_GEOLOCATION_TYPES)})")
        mds = GEOLOCATION_MDS[k]
        raw = self._records(mds.name, geolocation_dtype(mds, self.width))["values"]
        if lines is not None:
            raw = raw[lines]
        values = raw.astype(dtype) * dtype(mds.scale)
        low, high = PIXEL_GEOLOCATION_RANGES[mds.band]
        outside = (values < low) | (values > high)
        n = int(outside.sum())
        if n:
            values[outside] = np.nan
            if mds.name not in self._warned:
                self._warned.add(mds.name)
                what = mds.band.replace("corr_", "corrected ")
                log.warning("%s: %d of %d %ss of %s (outside [%g, %g]) masked as no data",
                            self.path.name, n, raw.size, what, mds.name, low, high)
        return values

    def pixel_longitude(self, lines: slice | None = None) -> np.ndarray:
        """Terrain-corrected longitude of every pixel (Corrected Longitude MDS(17)), float64 deg."""
        return self._geolocation(0, lines, np.float64)

    def pixel_latitude(self, lines: slice | None = None) -> np.ndarray:
        """Terrain-corrected latitude of every pixel (Corrected Latitude MDS(18)), float64 deg."""
        return self._geolocation(1, lines, np.float64)

    def pixel_altitude(self, lines: slice | None = None) -> np.ndarray:
        """DEM altitude of every pixel's terrain point (Altitude MDS(19)), float32 m."""
        return self._geolocation(2, lines, np.float32)

    @property
    def line_interval_s(self) -> float:
        """SPH LINE_TIME_INTERVAL in seconds (falls back to the resolution's nominal value)."""
        value = self.sph.get("LINE_TIME_INTERVAL")
        if isinstance(value, int) and value > 0:
            return value * 1e-6
        return self.resolution.line_interval_s


# --------------------------------------------------------------------------------------------
# read_product
# --------------------------------------------------------------------------------------------


def read_product(path: str | os.PathLike[str]) -> MerisL1bProduct:
    """Open a MERIS L1b N1 product; see :class:`MerisL1bProduct`.

    Reads and checks the headers, the Scaling Factor GADS and the Tie points ADS; the bands are
    memory-mapped on demand. Raises :class:`N1FormatError` for anything it cannot read.
    """
    path = Path(path)
    try:
        if not stat.S_ISREG(path.stat().st_mode):  # a FIFO would block open(): never hang
            raise N1FormatError(path, "not a regular file")
        with open(path, "rb") as f:
            file_size = os.fstat(f.fileno()).st_size
            head = f.read(MPH_SIZE)
            if len(head) < MPH_SIZE or not head.startswith(b"PRODUCT="):
                if not head.startswith(b"PRODUCT="[: len(head)]) or not head:
                    raise N1FormatError(path, "not an ENVISAT product (no PRODUCT= header)")
                raise N1FormatError(
                    path, f"truncated: {file_size} bytes, the main product header needs {MPH_SIZE}"
                )
            return _read(path, f, file_size, head)
    except OSError as exc:
        raise N1FormatError(path, f"cannot read: {exc.strerror or exc}") from None
    except MemoryError:  # pragma: no cover - absurd sizes are refused before allocating
        raise N1FormatError(path, "inconsistent sizes") from None


def _read(path: Path, f, file_size: int, head: bytes) -> MerisL1bProduct:
    mph = parse_header(head, "MPH", path)
    product = _get(mph, "PRODUCT", str, "MPH", path)
    product_type = product[:10]
    if product_type not in PRODUCT_TYPES:
        raise N1FormatError(
            path, f"unsupported product type {product_type!r}: MERIS Level 1b products only "
            f"({', '.join(PRODUCT_TYPES)})"
        )  # fmt: skip
    resolution = PRODUCT_TYPES[product_type]

    sph_size = _get(mph, "SPH_SIZE", int, "MPH", path)
    num_dsd = _get(mph, "NUM_DSD", int, "MPH", path)
    dsd_size = _get(mph, "DSD_SIZE", int, "MPH", path)
    tot_size = _get(mph, "TOT_SIZE", int, "MPH", path)
    if dsd_size != DSD_SIZE:
        raise N1FormatError(path, f"MPH DSD_SIZE={dsd_size}, ENVISAT DSDs have {DSD_SIZE} bytes")
    if not 1 <= num_dsd or num_dsd * DSD_SIZE > sph_size or sph_size > _MAX_SPH_SIZE:
        raise N1FormatError(
            path, f"MPH SPH_SIZE={sph_size} cannot hold NUM_DSD={num_dsd} DSDs of {DSD_SIZE} bytes"
        )
    if MPH_SIZE + sph_size > file_size:
        raise N1FormatError(
            path, f"truncated: {file_size} bytes, the headers need {MPH_SIZE + sph_size}"
        )
    if tot_size > file_size:
        raise N1FormatError(path, f"truncated: {file_size} bytes, MPH TOT_SIZE says {tot_size}")

    block = f.read(sph_size)
    text_size = sph_size - num_dsd * DSD_SIZE
    sph = parse_header(block[:text_size], "SPH", path)
    dsds = [
        parse_dsd(block[text_size + i * DSD_SIZE : text_size + (i + 1) * DSD_SIZE], path)
        for i in range(num_dsd)
    ]

    width = _get(sph, "LINE_LENGTH", int, "SPH", path)
    df = _get(sph, "LINES_PER_TIE_PT", int, "SPH", path)
    dj = _get(sph, "SAMPLES_PER_TIE_PT", int, "SPH", path)
    if not 2 <= width <= _MAX_WIDTH:
        raise N1FormatError(path, f"SPH LINE_LENGTH={width} is not a MERIS line length")
    if not (1 <= df <= 4096 and 1 <= dj < width):
        raise N1FormatError(path, f"SPH tie-point spacing {df} lines x {dj} samples is invalid")
    check_dimensions(path, product_type, resolution, width, df, dj)
    check_header_numbers(path, sph)
    wavelengths = sph.get("BAND_WAVELEN")
    if not (isinstance(wavelengths, tuple) and len(wavelengths) == NUM_BANDS):
        raise N1FormatError(path, f"SPH BAND_WAVELEN does not hold {NUM_BANDS} wavelengths")

    by_name = _check_dsds(path, dsds, file_size, MPH_SIZE + sph_size)
    n_cols = tie_columns(width, dj)
    tie_dsd = by_name[TIE_POINTS_ADS]
    if tie_dsd.dsr_size != tie_point_record_size(n_cols):
        raise N1FormatError(
            path,
            f"Tie points ADS record size {tie_dsd.dsr_size} is not 13 + 50 x {n_cols} = "
            f"{tie_point_record_size(n_cols)} (LINE_LENGTH={width}, SAMPLES_PER_TIE_PT={dj})",
        )
    gads = by_name[SCALING_GADS]
    if gads.dsr_size != GADS_SIZE or gads.num_dsr < 1:
        raise N1FormatError(
            path, f"Scaling Factor GADS record size {gads.dsr_size}, expected {GADS_SIZE}"
        )
    band1 = by_name[radiance_mds(1)]
    height = band1.num_dsr
    for band in range(1, NUM_BANDS + 1):
        d = by_name[radiance_mds(band)]
        if d.dsr_size != radiance_record_size(width):
            raise N1FormatError(
                path, f"{d.name} record size {d.dsr_size}, expected 13 + 2 x {width} = "
                f"{radiance_record_size(width)}"
            )  # fmt: skip
        if d.num_dsr != height:
            raise N1FormatError(path, f"{d.name} has {d.num_dsr} lines, band 1 has {height}")
    flags = by_name[FLAGS_MDS]
    if flags.dsr_size != flags_record_size(width):
        old = " (the IODD5 layout of 2002 products is not supported)" if (
            flags.dsr_size == radiance_record_size(width)
        ) else ""  # fmt: skip
        raise N1FormatError(
            path, f"Flags MDS(16) record size {flags.dsr_size}, expected 13 + 3 x {width} = "
            f"{flags_record_size(width)}{old}"
        )  # fmt: skip
    if flags.num_dsr != height:
        raise N1FormatError(path, f"Flags MDS(16) has {flags.num_dsr} lines, band 1 has {height}")
    if height < 1:
        raise N1FormatError(path, "the product has no lines (Radiance MDS(1) NUM_DSR=0)")
    if product_type in PIXEL_GEOLOCATION_TYPES:
        _check_geolocation_mds(path, by_name, product_type, width, height)
    check_counts(path, resolution, height, tie_dsd.num_dsr, df)

    gads_rec = _read_records(f, path, gads.offset, GADS_DTYPE, 1)
    scaling = ScalingFactors.from_record(gads_rec)
    check_scaling(path, scaling)
    tie_records = _read_records(
        f, path, tie_dsd.offset, tie_point_dtype(n_cols), tie_dsd.num_dsr
    )
    product = MerisL1bProduct(
        path=path,
        mph=mph,
        sph=sph,
        dsds=dsds,
        datasets=by_name,
        product_type=product_type,
        resolution=resolution,
        width=width,
        height=height,
        lines_per_tie_point=df,
        samples_per_tie_point=dj,
        scaling=scaling,
        tie_records=tie_records,
    )
    check_tie_points(path, product.tie_points, tie_records["days"])
    return product


def _check_dsds(path: Path, dsds: list[Dsd], file_size: int, data_start: int) -> dict[str, Dsd]:
    """Every stored data set lies inside the file after the headers, with NUM_DSR x DSR_SIZE ==
    DS_SIZE; the data sets a MERIS L1b product needs are all there. Returns them by name."""
    by_name: dict[str, Dsd] = {}
    for d in dsds:
        if not d.has_data:
            continue
        if d.num_dsr * d.dsr_size != d.size:
            raise N1FormatError(
                path, f"DSD {d.name!r}: NUM_DSR {d.num_dsr} x DSR_SIZE {d.dsr_size} != "
                f"DS_SIZE {d.size}"
            )  # fmt: skip
        if d.size and d.offset < data_start:
            raise N1FormatError(
                path, f"DSD {d.name!r}: DS_OFFSET {d.offset} points into the headers "
                f"(data start at {data_start})"
            )  # fmt: skip
        if d.offset + d.size > file_size:
            raise N1FormatError(
                path, f"DSD {d.name!r} points outside the file: bytes {d.offset}.."
                f"{d.offset + d.size} of a {file_size}-byte file (truncated?)"
            )  # fmt: skip
        by_name.setdefault(d.name, d)
    needed = [SCALING_GADS, TIE_POINTS_ADS, *(radiance_mds(b) for b in range(1, 16)), FLAGS_MDS]
    missing = [n for n in needed if n not in by_name]
    if missing:
        raise N1FormatError(path, f"missing data sets: {', '.join(missing)}")
    return by_name


def _check_geolocation_mds(path: Path, by_name: dict[str, Dsd], product_type: str, width: int,
                           height: int) -> None:
    """FRG/FSG/RRG products need MDS(17..19), one record of W values per product line."""
    for mds in GEOLOCATION_MDS:
        d = by_name.get(mds.name)
        if d is None:
            raise N1FormatError(path, f"{product_type} product without {mds.name} (its "
                                f"per-pixel {mds.band})")
        size = geolocation_record_size(mds, width)
        if d.dsr_size != size or d.num_dsr != height:
            raise N1FormatError(
                path, f"{mds.name}: {d.num_dsr} records of {d.dsr_size} bytes, expected "
                f"{height} of {size} (LINE_LENGTH={width})")


def _read_records(f, path: Path, offset: int, dtype: np.dtype, count: int) -> np.ndarray:
    f.seek(offset)
    data = f.read(dtype.itemsize * count)
    if len(data) != dtype.itemsize * count:  # pragma: no cover - sizes checked before
        raise N1FormatError(path, f"truncated at byte {offset}")
    return np.frombuffer(data, dtype=dtype, count=count)


def _line_ranges(lines: np.ndarray, most: int = 4) -> str:
    """'3-7, 120' for sorted line numbers (the first ``most`` runs, then '...')."""
    runs: list[str] = []
    start = prev = int(lines[0])
    for n in [*map(int, lines[1:]), None]:
        if n is not None and n == prev + 1:
            prev = n
            continue
        runs.append(f"{start}" if start == prev else f"{start}-{prev}")
        if n is not None:
            start = prev = n
    return ", ".join(runs[:most]) + (", ..." if len(runs) > most else "")

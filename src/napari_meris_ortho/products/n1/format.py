"""Byte layouts of MERIS Level 1b ENVISAT N1 products (MER_FR__1P, MER_RR__1P).

Sources: Appendix A of the *MERIS Geometry Handbook* (a real FR product's MPH/SPH decoding log,
its 30 DSDs and Scaling Factor GADS), EPR-API's DDDB (``epr_dddb.c``: record layouts, DSD line
widths, IODD detection) and GDAL's ENVISAT driver (``EnvisatFile.c``).

Everything here is pure data and small pure functions shared by the reader and the writer:

- the ASCII header layouts (MPH 1247 bytes; MERIS SPH text 1542 bytes; DSD 280 bytes), as lists of
  :class:`HeaderField` with the fixed widths real products use;
- the binary record layouts as big-endian numpy dtypes (every record starts with the 13-byte
  header: MJD2000 ``dsr_time`` as int32 days, uint32 seconds, uint32 microseconds, and a 1-byte
  quality/attachment flag);
- the tie-point field table (name in this package, name in the DDDB, raw dtype, scaling);
- :func:`plan_layout`, the DSD table of a product of a given size, which reproduces Appendix A.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...bands import BAND_TABLES
from ...bands import MERIS as MERIS_BANDS

#: size of the Main Product Header (ASCII), all ENVISAT products
MPH_SIZE = 1247
#: size of one Data Set Descriptor (ASCII)
DSD_SIZE = 280
#: size of the text part of a MERIS L1b SPH (before the DSDs): 9942 - 30 x 280 in Appendix A
SPH_TEXT_SIZE = 1542
#: number of DSDs of a MERIS L1b product (Appendix A: 19 data sets, 10 references, 1 spare)
NUM_DSD = 30
#: size of the per-record header: dsr_time (12 bytes MJD2000) + quality/attachment flag
RECORD_HEADER_SIZE = 13
#: number of radiance bands
NUM_BANDS = MERIS_BANDS.n_bands
#: the band counts of the sensors' products (``radiance``/``sun_flux`` of ScalingFactors)
BAND_COUNTS = frozenset(t.n_bands for t in BAND_TABLES.values())
#: Quality ADS record: header + range_flag ushort[5] + range_blind_flag ushort[5]
QUALITY_RECORD_SIZE = 33
#: Scaling Factor GADS record size
GADS_SIZE = 292

FR = "MER_FR__1P"
RR = "MER_RR__1P"


@dataclass(frozen=True)
class Resolution:
    """Fixed geometry of a MERIS resolution (handbook section 2.1, Appendix A and E)."""

    name: str
    width: int  #: samples per line of a standard product
    lines_per_tie_point: int
    samples_per_tie_point: int
    line_interval_s: float  #: time between two product lines
    column_spacing_m: float  #: on-ground spacing between columns at nadir
    quality_lines: int  #: product lines per Quality ADS record


#: FR: 2241 columns, tie points every 64 lines/columns, 0.043997 s per line (Appendix A).
FULL_RESOLUTION = Resolution("FR", 2241, 64, 64, 0.043997, 260.0, 512)
#: RR: 4x4 FR pixels, 1121 columns, tie points every 16 lines/columns, 4 x 0.043997 s per line
#: (Appendix E.15: 22.526464 s between tie lines 9 and 17, i.e. 128 lines).
REDUCED_RESOLUTION = Resolution("RR", 1121, 16, 16, 0.175988, 1040.0, 128)

#: product types the reader accepts, with their resolution. MER_FRS_1P (FR full swath) and
#: MER_FRG_1P / MER_FSG_1P (geo-corrected FR variants) share the FR L1b datasets, MER_RRG_1P
#: (the geo-corrected RR variant) the RR ones; extra datasets they carry are ignored.
PRODUCT_TYPES: dict[str, Resolution] = {
    FR: FULL_RESOLUTION,
    "MER_FRS_1P": FULL_RESOLUTION,
    "MER_FRG_1P": FULL_RESOLUTION,
    "MER_FSG_1P": FULL_RESOLUTION,
    RR: REDUCED_RESOLUTION,
    "MER_RRG_1P": REDUCED_RESOLUTION,
}
#: AMORGOS (third reprocessing) geo-corrected types: three more MDS after Flags MDS(16) hold
#: the per-pixel terrain-corrected position (SNAP's DDDB ``MER_FSG_1P.dd``, ``MER_FRG_1P.dd``
#: and ``MER_RRG_1P.dd``: the same MDS 17-19 at FR and RR)
PIXEL_GEOLOCATION_TYPES = ("MER_FRG_1P", "MER_FSG_1P", "MER_RRG_1P")
#: product types the writer produces
WRITABLE_PRODUCT_TYPES = (FR, RR, *PIXEL_GEOLOCATION_TYPES)


def tie_columns(width: int, samples_per_tie_point: int) -> int:
    """Number of tie points per tie line: ``(W - 1) // DJ + 1`` (EPR's ``tiePointGridWidth``)."""
    return (width - 1) // samples_per_tie_point + 1


def tie_lines(height: int, lines_per_tie_point: int) -> int:
    """Number of tie-point lines covering ``height`` product lines: ``ceil((H-1)/DF) + 1``.

    The last tie line may lie beyond the last product line (Appendix A: 36 tie lines for 2241
    lines; Appendix E.8: 19 tie lines for a shorter product).
    """
    return -(-(height - 1) // lines_per_tie_point) + 1


# --------------------------------------------------------------------------------------------
# ASCII headers
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class HeaderField:
    """One ``KEY=value<unit>\\n`` line of an ASCII header, or a line of spaces (``key=""``).

    ``kind``: ``"s"`` quoted string of ``width`` characters; ``"c"`` unquoted text of ``width``
    characters (``PHASE=X``, flags ``0``/``1``); ``"i"`` signed integer of ``width`` characters
    including the sign (``+0000000036``); ``"ia"`` ``count`` such integers; ``"f"`` fixed point with
    ``width`` integer and ``frac`` fraction digits (``-7162215.231``, ``+.000000``); ``"e"``
    exponent form ``+2.60000000e+02``; ``"spare"`` ``width`` spaces.
    """

    key: str
    kind: str
    width: int
    unit: str | None = None
    count: int = 1
    frac: int = 0

    @property
    def size(self) -> int:
        """Bytes of the whole line, newline included."""
        if self.kind == "spare":
            return self.width + 1
        n = len(self.key) + 1 + 1  # KEY= ... \n
        if self.kind == "s":
            n += self.width + 2
        elif self.kind == "ia":
            n += self.width * self.count
        elif self.kind == "f":
            n += 1 + self.width + 1 + self.frac
        else:
            n += self.width
        if self.unit is not None:
            n += len(self.unit) + 2
        return n


def _spare(n: int) -> HeaderField:
    return HeaderField("", "spare", n)


def _s(key: str, width: int) -> HeaderField:
    return HeaderField(key, "s", width)


def _c(key: str) -> HeaderField:
    return HeaderField(key, "c", 1)


def _i(key: str, width: int, unit: str | None = None) -> HeaderField:
    return HeaderField(key, "i", width, unit)


def _f(key: str, idig: int, frac: int, unit: str) -> HeaderField:
    return HeaderField(key, "f", idig, unit, frac=frac)


#: Main Product Header (PO-RS-MDA-GS-2009, as EPR, BEAM and GDAL read it): 1247 bytes.
MPH_FIELDS: tuple[HeaderField, ...] = (
    _s("PRODUCT", 62),
    _c("PROC_STAGE"),
    _s("REF_DOC", 23),
    _spare(40),
    _s("ACQUISITION_STATION", 20),
    _s("PROC_CENTER", 6),
    _s("PROC_TIME", 27),
    _s("SOFTWARE_VER", 14),
    _spare(40),
    _s("SENSING_START", 27),
    _s("SENSING_STOP", 27),
    _spare(40),
    _c("PHASE"),
    _i("CYCLE", 4),
    _i("REL_ORBIT", 6),
    _i("ABS_ORBIT", 6),
    _s("STATE_VECTOR_TIME", 27),
    _f("DELTA_UT1", 0, 6, "s"),
    _f("X_POSITION", 7, 3, "m"),
    _f("Y_POSITION", 7, 3, "m"),
    _f("Z_POSITION", 7, 3, "m"),
    _f("X_VELOCITY", 4, 6, "m/s"),
    _f("Y_VELOCITY", 4, 6, "m/s"),
    _f("Z_VELOCITY", 4, 6, "m/s"),
    _s("VECTOR_SOURCE", 2),
    _spare(40),
    _s("UTC_SBT_TIME", 27),
    _i("SAT_BINARY_TIME", 11),
    _i("CLOCK_STEP", 11, "ps"),
    _spare(32),
    _s("LEAP_UTC", 27),
    _i("LEAP_SIGN", 4),
    _c("LEAP_ERR"),
    _spare(40),
    _c("PRODUCT_ERR"),
    _i("TOT_SIZE", 21, "bytes"),
    _i("SPH_SIZE", 11, "bytes"),
    _i("NUM_DSD", 11),
    _i("DSD_SIZE", 11, "bytes"),
    _i("NUM_DATA_SETS", 11),
    _spare(40),
)

_LAT, _LON = "10-6degN", "10-6degE"

#: MERIS L1b Specific Product Header text (before the DSDs): 1542 bytes.
SPH_FIELDS: tuple[HeaderField, ...] = (
    _s("SPH_DESCRIPTOR", 28),
    _i("STRIPLINE_CONTINUITY_INDICATOR", 4),
    _i("SLICE_POSITION", 4),
    _i("NUM_SLICES", 4),
    _s("FIRST_LINE_TIME", 27),
    _s("LAST_LINE_TIME", 27),
    _i("FIRST_FIRST_LAT", 11, _LAT),
    _i("FIRST_FIRST_LONG", 11, _LON),
    _i("FIRST_MID_LAT", 11, _LAT),
    _i("FIRST_MID_LONG", 11, _LON),
    _i("FIRST_LAST_LAT", 11, _LAT),
    _i("FIRST_LAST_LONG", 11, _LON),
    _i("LAST_FIRST_LAT", 11, _LAT),
    _i("LAST_FIRST_LONG", 11, _LON),
    _i("LAST_MID_LAT", 11, _LAT),
    _i("LAST_MID_LONG", 11, _LON),
    _i("LAST_LAST_LAT", 11, _LAT),
    _i("LAST_LAST_LONG", 11, _LON),
    _spare(47),
    _c("TRANS_ERR_FLAG"),
    _c("FORMAT_ERR_FLAG"),
    _c("DATABASE_FLAG"),
    _c("COARSE_ERR_FLAG"),
    _c("ECMWF_TYPE"),
    _i("NUM_TRANS_ERR", 11),
    _i("NUM_FORMAT_ERR", 11),
    HeaderField("TRANS_ERR_THRESH", "e", 15, "%"),
    HeaderField("FORMAT_ERR_THRESH", "e", 15, "%"),
    _spare(77),
    _i("NUM_BANDS", 4),
    HeaderField("BAND_WAVELEN", "ia", 11, "10-3nm", count=NUM_BANDS),
    HeaderField("BANDWIDTH", "ia", 6, "10-3nm", count=NUM_BANDS),
    _i("INST_FOV", 11, "10-6deg"),
    _c("PROC_MODE"),
    _c("OFFSET_COMP"),
    _i("LINE_TIME_INTERVAL", 11, "10-6s"),
    _i("LINE_LENGTH", 6, "samples"),
    _i("LINES_PER_TIE_PT", 4),
    _i("SAMPLES_PER_TIE_PT", 4),
    HeaderField("COLUMN_SPACING", "e", 15, "m"),
    _spare(41),
)

#: One Data Set Descriptor: 280 bytes (EPR checks every line width).
DSD_FIELDS: tuple[HeaderField, ...] = (
    _s("DS_NAME", 28),
    _c("DS_TYPE"),
    _s("FILENAME", 62),
    _i("DS_OFFSET", 21, "bytes"),
    _i("DS_SIZE", 21, "bytes"),
    _i("NUM_DSR", 11),
    _i("DSR_SIZE", 11, "bytes"),
    _spare(32),
)

assert sum(f.size for f in MPH_FIELDS) == MPH_SIZE
assert sum(f.size for f in SPH_FIELDS) == SPH_TEXT_SIZE
assert sum(f.size for f in DSD_FIELDS) == DSD_SIZE

#: Appendix A central wavelengths (nm) and bandwidths (nm) of the 15 bands (``bands.MERIS``).
APPENDIX_A_WAVELENGTHS = MERIS_BANDS.centres
APPENDIX_A_BANDWIDTHS = MERIS_BANDS.widths

# --------------------------------------------------------------------------------------------
# Binary records (all big-endian)
# --------------------------------------------------------------------------------------------

#: the 13-byte header of every record: MJD2000 time and quality/attachment flag
RECORD_HEADER_FIELDS = [
    ("days", ">i4"),
    ("seconds", ">u4"),
    ("microseconds", ">u4"),
    ("quality", "u1"),
]


@dataclass(frozen=True)
class TiePointField:
    """A tie-point array of the Tie points ADS (EPR's ``MER_RR__1P_ADSR_tie_pt``)."""

    name: str  #: name in ``MerisL1bProduct.tie_points``
    dddb_name: str  #: field name in EPR's record (``lat_tie_pt``...)
    dtype: str  #: big-endian raw type
    unit: str
    scale: float | str  #: fixed factor, or the ScalingFactors attribute that holds it


TIE_POINT_FIELDS: tuple[TiePointField, ...] = (
    TiePointField("latitude", "lat_tie_pt", ">i4", "deg", 1e-6),
    TiePointField("longitude", "long_tie_pt", ">i4", "deg", 1e-6),
    TiePointField("dem_alt", "dem_alt_tie_pt", ">i4", "m", "altitude"),
    TiePointField("dem_rough", "dem_rough", ">u4", "m", "roughness"),
    TiePointField("lat_corr", "dem_lat_corrc", ">i4", "deg", 1e-6),
    TiePointField("lon_corr", "dem_long_corrc", ">i4", "deg", 1e-6),
    TiePointField("sun_zenith", "sun_zen_ang", ">u4", "deg", 1e-6),
    TiePointField("sun_azimuth", "sun_azi_ang", ">i4", "deg", 1e-6),
    TiePointField("view_zenith", "vw_zen_ang", ">u4", "deg", 1e-6),
    TiePointField("view_azimuth", "vw_azi_ang", ">i4", "deg", 1e-6),
    TiePointField("zonal_wind", "zon_wind", ">i2", "m/s", "zonal_wind"),
    TiePointField("merid_wind", "meri_wind", ">i2", "m/s", "merid_wind"),
    TiePointField("atm_pressure", "atm_pres", ">u2", "hPa", "atm_pressure"),
    TiePointField("ozone", "tot_ozone", ">u2", "DU", "ozone"),
    TiePointField("rel_humidity", "rel_humid", ">u2", "%", "rel_humidity"),
)
TIE_POINT_NAMES = tuple(f.name for f in TIE_POINT_FIELDS)
#: bytes per tie point in a Tie points ADS record (10 x 4 + 5 x 2)
TIE_POINT_BYTES = sum(np.dtype(f.dtype).itemsize for f in TIE_POINT_FIELDS)
assert TIE_POINT_BYTES == 50


def tie_point_record_size(n_columns: int) -> int:
    """Bytes of a Tie points ADS record: 13 + 50 N (FR 1813, RR 3563)."""
    return RECORD_HEADER_SIZE + TIE_POINT_BYTES * n_columns


def tie_point_dtype(n_columns: int) -> np.dtype:
    """Record dtype of the Tie points ADS for ``n_columns`` tie points per line."""
    return np.dtype(
        RECORD_HEADER_FIELDS + [(f.name, f.dtype, (n_columns,)) for f in TIE_POINT_FIELDS]
    )


def radiance_record_size(width: int) -> int:
    """Bytes of a Radiance MDS record: 13 + 2 W (FR 4495, RR 2255)."""
    return RECORD_HEADER_SIZE + 2 * width


def radiance_dtype(width: int) -> np.dtype:
    return np.dtype(RECORD_HEADER_FIELDS + [("counts", ">u2", (width,))])


def flags_record_size(width: int) -> int:
    """Bytes of a Flags MDS(16) record: 13 + W flags + 2 W detector indices (FR 6736)."""
    return RECORD_HEADER_SIZE + 3 * width


def flags_dtype(width: int) -> np.dtype:
    """EPR/BEAM layout: ``flags`` uchar[W] then ``detector_index`` short[W]."""
    return np.dtype(
        RECORD_HEADER_FIELDS + [("flags", "u1", (width,)), ("detector_index", ">i2", (width,))]
    )


@dataclass(frozen=True)
class GeolocationMds:
    """A per-pixel geolocation MDS of FRG/FSG/RRG products (BEAM's ``MER_FSG_1P_MDSR_17..19``):
    13-byte header + ``dtype``[W]; physical = raw x ``scale``."""

    name: str  #: DS_NAME
    band: str  #: band name in BEAM / EPR
    dtype: str  #: big-endian raw type
    scale: float
    unit: str


#: Corrected Longitude MDS(17), Corrected Latitude MDS(18) (int32, 1e-6 deg), Altitude MDS(19)
#: (int16, m): the AMORGOS terrain point of each pixel centre
GEOLOCATION_MDS: tuple[GeolocationMds, ...] = (
    GeolocationMds("Corrected Longitude MDS(17)", "corr_longitude", ">i4", 1e-6, "deg"),
    GeolocationMds("Corrected Latitude MDS(18)", "corr_latitude", ">i4", 1e-6, "deg"),
    GeolocationMds("Altitude MDS(19)", "altitude", ">i2", 1.0, "m"),
)


def geolocation_record_size(mds: GeolocationMds, width: int) -> int:
    """Bytes of a geolocation MDS record: 13 + 4 W (longitude, latitude) or 13 + 2 W (altitude)."""
    return RECORD_HEADER_SIZE + np.dtype(mds.dtype).itemsize * width


def geolocation_dtype(mds: GeolocationMds, width: int) -> np.dtype:
    return np.dtype(RECORD_HEADER_FIELDS + [("values", mds.dtype, (width,))])


QUALITY_DTYPE = np.dtype(
    RECORD_HEADER_FIELDS + [("range_flag", ">u2", (5,)), ("range_blind_flag", ">u2", (5,))]
)
assert QUALITY_DTYPE.itemsize == QUALITY_RECORD_SIZE

#: Scaling Factor GADS (EPR's ``MER_RR__1P_GADS_sfgi``): 292 bytes.
GADS_DTYPE = np.dtype(
    [
        ("altitude", ">f4"),
        ("roughness", ">f4"),
        ("zonal_wind", ">f4"),
        ("merid_wind", ">f4"),
        ("atm_pressure", ">f4"),
        ("ozone", ">f4"),
        ("rel_humidity", ">f4"),
        ("radiance", ">f4", (NUM_BANDS,)),
        ("gain_settings", "u1", (80,)),
        ("sampling_rate", ">u4"),
        ("sun_flux", ">f4", (NUM_BANDS,)),
        ("spare", "V60"),
    ]
)
assert GADS_DTYPE.itemsize == GADS_SIZE

# --------------------------------------------------------------------------------------------
# Data sets and the DSD table
# --------------------------------------------------------------------------------------------

QUALITY_ADS = "Quality ADS"
SCALING_GADS = "Scaling Factor GADS"
TIE_POINTS_ADS = "Tie points ADS"
FLAGS_MDS = "Flags MDS(16)"


def radiance_mds(band: int) -> str:
    return f"Radiance MDS({band})"


#: the reference DSDs of Appendix A (DS_TYPE=R, no data in the product), with the file names
#: of the Appendix A product as defaults
REFERENCE_DSDS: tuple[tuple[str, str], ...] = tuple(
    (name, f"{prefix}_{dates}")
    for name, prefix, dates in (
        ("MERIS_SOURCE_PACKETS", "MER_FR__0PNPDE20030921",
         "092217_000002582020_00079_08149_1418.N1"),
        ("INSTRUMENT_DATA_FILE", "MER_INS_AXVIEC20030620",
         "120000_20020321_193100_20121008_190821"),
        ("PROCESSING_PARAMS_L1B_FILE", "MER_CP1_AXVIEC20030620",
         "120000_20020429_040000_20120920_173421"),
        ("RADIOMETRIC_CALIBRATION_FILE", "MER_RAC_AXVIEC20030620",
         "120000_20021224_121445_20121224_121445"),
        ("DIGITAL_ELEVATION_MODEL_FILE", "AUX_DEM_AXVIEC20020123",
         "121901_20020101_000000_20200101_000000"),
        ("DIGITAL_ROUGHNESS_MODEL_FILE", "MER_DRM_AXVIEC20020122",
         "083343_20020101_000000_20200101_000000"),
        ("LAND_SEA_MASK_DATA_FILE", "AUX_LSM_AXVIEC20020123",
         "141228_20020101_000000_20200101_000000"),
        ("ECMWF_DATA_FILE", "AUX_ECA_AXNECM20030921",
         "233653_20030921_090000_20030921_210000"),
        ("ORBIT_STATE_VECTOR_FILE", "AUX_FRO_AXVPDS20030924",
         "101146_20030920_221000_20030923_005000"),
        ("ATTITUDE_DATA_FILE", "AUX_ATT_AXVIEC20020924",
         "131534_20020703_120000_20781231_235959"),
    )
)  # fmt: skip


@dataclass(frozen=True)
class Dsd:
    """A Data Set Descriptor. A spare DSD (280 spaces in the file) has ``name == ""``."""

    name: str
    type: str
    filename: str
    offset: int
    size: int
    num_dsr: int
    dsr_size: int

    @property
    def is_spare(self) -> bool:
        return self.name == ""

    @property
    def has_data(self) -> bool:
        """True for the data sets stored in the product (types A, G, M), not references."""
        return not self.is_spare and self.type in ("A", "G", "M")


SPARE_DSD = Dsd("", "", "", 0, 0, 0, 0)


def plan_layout(product_type: str, width: int, height: int, n_tie_lines: int) -> list[Dsd]:
    """The 30 DSDs of a MERIS L1b product of ``width`` x ``height`` pixels, laid out like
    Appendix A: Quality ADS, Scaling Factor GADS, Tie points ADS, Radiance MDS(1..15),
    Flags MDS(16), 10 reference DSDs, 1 spare. Offsets follow MPH (1247) + SPH (9942).
    FRG/FSG/RRG products have 33: the three geolocation MDS (17..19) follow Flags MDS(16).
    """
    res = PRODUCT_TYPES[product_type]
    n_cols = tie_columns(width, res.samples_per_tie_point)
    n_quality = max(1, math.ceil(height / res.quality_lines))
    stored: list[tuple[str, str, int, int]] = [
        (QUALITY_ADS, "A", n_quality, QUALITY_RECORD_SIZE),
        (SCALING_GADS, "G", 1, GADS_SIZE),
        (TIE_POINTS_ADS, "A", n_tie_lines, tie_point_record_size(n_cols)),
    ]
    stored += [(radiance_mds(b), "M", height, radiance_record_size(width)) for b in range(1, 16)]
    stored.append((FLAGS_MDS, "M", height, flags_record_size(width)))
    if product_type in PIXEL_GEOLOCATION_TYPES:
        stored += [(m.name, "M", height, geolocation_record_size(m, width))
                   for m in GEOLOCATION_MDS]
    n_dsd = num_dsd(product_type)
    offset = MPH_SIZE + sph_size(n_dsd)
    dsds = []
    for name, kind, num, size in stored:
        dsds.append(Dsd(name, kind, "", offset, num * size, num, size))
        offset += num * size
    dsds += [Dsd(name, "R", filename, 0, 0, 0, 0) for name, filename in REFERENCE_DSDS]
    dsds.append(SPARE_DSD)
    assert len(dsds) == n_dsd
    return dsds


def num_dsd(product_type: str) -> int:
    """DSDs of a product type: 30, plus the 3 geolocation MDS of FRG/FSG/RRG products."""
    return NUM_DSD + (len(GEOLOCATION_MDS) if product_type in PIXEL_GEOLOCATION_TYPES else 0)


def sph_size(num_dsd: int = NUM_DSD) -> int:
    """SPH_SIZE of the MPH: SPH text plus the DSDs (Appendix A: 9942)."""
    return SPH_TEXT_SIZE + num_dsd * DSD_SIZE


# --------------------------------------------------------------------------------------------
# Times
# --------------------------------------------------------------------------------------------

MONTHS = ("JAN", "FEB", "MAR", "APR", "MAY", "JUN", "JUL", "AUG", "SEP", "OCT", "NOV", "DEC")

#: origin of the MJD2000 times of the records and of ``line_times``
EPOCH_2000 = np.datetime64("2000-01-01T00:00:00", "us")


def format_utc(t: np.datetime64) -> str:
    """``21-SEP-2003 09:23:41.714409`` (the 27-character ENVISAT UTC string)."""
    s = str(np.asarray(t, dtype="datetime64[us]"))  # 2003-09-21T09:23:41.714409
    year, month, day = s[:4], int(s[5:7]), s[8:10]
    return f"{day}-{MONTHS[month - 1]}-{year} {s[11:26]}"


def parse_utc(text: str) -> np.datetime64:
    """Inverse of :func:`format_utc`; raises ValueError on anything else."""
    text = text.strip()
    day, month, rest = text[:2], text[3:6].upper(), text[7:]
    if len(text) < 20 or text[2] != "-" or text[6] != "-" or month not in MONTHS:
        raise ValueError(f"not an ENVISAT UTC time: {text!r}")
    year, _, clock = rest.partition(" ")
    iso = f"{year}-{MONTHS.index(month) + 1:02d}-{day}T{clock}"
    return np.datetime64(iso, "us")


def seconds_to_mjd2000(seconds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seconds since 2000-01-01 -> (days int32, seconds uint32, microseconds uint32)."""
    us = np.round(np.asarray(seconds, dtype=np.float64) * 1e6).astype(np.int64)
    days, rem = np.divmod(us, 86_400_000_000)
    secs, micro = np.divmod(rem, 1_000_000)
    return days.astype(np.int32), secs.astype(np.uint32), micro.astype(np.uint32)


def mjd2000_to_seconds(days: np.ndarray, secs: np.ndarray, micro: np.ndarray) -> np.ndarray:
    """(days, seconds, microseconds) -> float64 seconds since 2000-01-01."""
    return (
        np.asarray(days, dtype=np.float64) * 86400.0
        + np.asarray(secs, dtype=np.float64)
        + np.asarray(micro, dtype=np.float64) * 1e-6
    )


# --------------------------------------------------------------------------------------------
# Scaling Factor GADS
# --------------------------------------------------------------------------------------------

_APPENDIX_A_RADIANCE = (
    0.009333, 0.010466, 0.011501, 0.010642, 0.009280, 0.008147, 0.006815, 0.006899,
    0.006270, 0.008617, 0.008811, 0.003613, 0.003546, 0.006090, 0.005418,
)  # fmt: skip
_APPENDIX_A_SUN_FLUX = (
    1703.201782, 1859.746582, 1911.582886, 1914.315063, 1789.023315, 1637.997314,
    1519.083252, 1459.818726, 1395.926514, 1255.756104, 1243.889160, 1167.314209,
    950.546509, 922.478821, 888.092041,
)  # fmt: skip
#: gain setting of bands 1..16 of each of the 5 camera modules (Appendix A)
_APPENDIX_A_GAINS = (9, 10, 11, 11, 11, 11, 11, 10, 11, 11, 11, 10, 9, 11, 10, 0) * 5


@dataclass(frozen=True)
class ScalingFactors:
    """The Scaling Factor GADS: factors from stored integers to physical units.

    ``radiance[b - 1]`` converts the counts of band ``b`` to W m-2 sr-1 um-1 (= mW m-2 sr-1 nm-1),
    one per band of the product (15 MERIS; 21 for an OLCI product, from its ``scale_factor``s);
    the tie-point factors convert DEM altitude and roughness (m), winds (m/s), pressure (hPa),
    ozone (DU) and relative humidity (%). Defaults are the values of Appendix A. Stored as float32
    in the file, so a round trip gives ``float(np.float32(value))``.
    """

    altitude: float = 1.0
    roughness: float = 1.0
    zonal_wind: float = 0.1
    merid_wind: float = 0.1
    atm_pressure: float = 0.1
    ozone: float = 0.01
    rel_humidity: float = 0.1
    radiance: tuple[float, ...] = _APPENDIX_A_RADIANCE
    gain_settings: tuple[int, ...] = _APPENDIX_A_GAINS
    sampling_rate_us: int = 43997
    sun_flux: tuple[float, ...] = _APPENDIX_A_SUN_FLUX

    def __post_init__(self) -> None:
        if len(self.radiance) not in BAND_COUNTS or len(self.sun_flux) != len(self.radiance):
            raise ValueError("ScalingFactors: radiance and sun_flux need one value per band "
                             "(15 MERIS, 21 OLCI)")
        if len(self.gain_settings) != 80:
            raise ValueError("ScalingFactors: gain_settings needs 80 values (5 modules x 16)")

    @classmethod
    def appendix_a(cls) -> ScalingFactors:
        """The Scaling Factor GADS printed in Appendix A (FR product of 21/09/2003, Italy)."""
        return cls()

    def factor(self, field: TiePointField) -> float:
        """Scale of a tie-point field: physical = raw x factor."""
        return field.scale if isinstance(field.scale, float) else float(getattr(self, field.scale))

    def to_record(self) -> np.ndarray:
        """The 292-byte GADS record (big-endian)."""
        rec = np.zeros(1, dtype=GADS_DTYPE)
        for name in ("altitude", "roughness", "zonal_wind", "merid_wind", "atm_pressure"):
            rec[name] = getattr(self, name)
        rec["ozone"] = self.ozone
        rec["rel_humidity"] = self.rel_humidity
        rec["radiance"] = self.radiance
        rec["gain_settings"] = self.gain_settings
        rec["sampling_rate"] = self.sampling_rate_us
        rec["sun_flux"] = self.sun_flux
        return rec

    @classmethod
    def from_record(cls, rec: np.ndarray) -> ScalingFactors:
        """Decode a GADS record (a 0-d or 1-element array of :data:`GADS_DTYPE`)."""
        r = rec.reshape(-1)[0]
        return cls(
            altitude=float(r["altitude"]),
            roughness=float(r["roughness"]),
            zonal_wind=float(r["zonal_wind"]),
            merid_wind=float(r["merid_wind"]),
            atm_pressure=float(r["atm_pressure"]),
            ozone=float(r["ozone"]),
            rel_humidity=float(r["rel_humidity"]),
            radiance=tuple(float(v) for v in r["radiance"]),
            gain_settings=tuple(int(v) for v in r["gain_settings"]),
            sampling_rate_us=int(r["sampling_rate"]),
            sun_flux=tuple(float(v) for v in r["sun_flux"]),
        )

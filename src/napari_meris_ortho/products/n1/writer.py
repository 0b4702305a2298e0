"""Writer of MERIS L1b ENVISAT N1 products (MER_FR__1P, MER_RR__1P) laid out like real ones.

MPH (1247 bytes), SPH text (1542 bytes) and 30 DSDs of 280 bytes, then Quality ADS, Scaling Factor
GADS, Tie points ADS, Radiance MDS(1..15) and Flags MDS(16), with the offsets and sizes of
Appendix A for a 2241 x 2241 FR product. AMORGOS types (MER_FRG_1P, MER_FSG_1P, MER_RRG_1P) add the
Corrected Longitude/Latitude and Altitude MDS(17..19) of the per-pixel terrain point. The bands
are streamed a block of lines at a time, so memory-mapped inputs of any size are welcome. The file
is written to a temporary name and renamed.
"""

from __future__ import annotations

import datetime as _dt
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ... import __version__
from ..._atomic import atomic_path
from ...errors import OptionsError
from ...progress import ProgressCallback
from .format import (
    APPENDIX_A_BANDWIDTHS,
    APPENDIX_A_WAVELENGTHS,
    DSD_FIELDS,
    GEOLOCATION_MDS,
    MPH_FIELDS,
    MPH_SIZE,
    NUM_BANDS,
    PIXEL_GEOLOCATION_TYPES,
    PRODUCT_TYPES,
    QUALITY_DTYPE,
    SPH_FIELDS,
    TIE_POINT_FIELDS,
    TIE_POINT_NAMES,
    WRITABLE_PRODUCT_TYPES,
    Dsd,
    HeaderField,
    ScalingFactors,
    flags_dtype,
    format_utc,
    geolocation_dtype,
    num_dsd,
    plan_layout,
    radiance_dtype,
    seconds_to_mjd2000,
    sph_size,
    tie_columns,
    tie_lines,
    tie_point_dtype,
)

#: header keys computed from the data; ``mph=``/``sph=`` overrides may not change them
STRUCTURAL_KEYS = frozenset(
    {
        "TOT_SIZE", "SPH_SIZE", "NUM_DSD", "DSD_SIZE", "NUM_DATA_SETS", "NUM_BANDS",
        "LINE_LENGTH", "LINES_PER_TIE_PT", "SAMPLES_PER_TIE_PT",
    }
)  # fmt: skip

#: product lines per block when streaming the bands
_BLOCK_LINES = 512


# --------------------------------------------------------------------------------------------
# ASCII headers
# --------------------------------------------------------------------------------------------


def _format_value(field: HeaderField, value: Any) -> str:
    """The text after ``KEY=`` (units excluded) for ``value``; ValueError if it does not fit."""
    kind, width = field.kind, field.width
    if kind == "s":
        text = str(value)
        if len(text) > width or '"' in text or "\n" in text or not text.isascii():
            raise ValueError(f"{field.key}: {text!r} is not an ASCII string of <= {width} chars")
        return f'"{text:<{width}}"'
    if kind == "c":
        text = str(value)
        if len(text) != width or not text.isascii() or not text.strip():
            raise ValueError(f"{field.key}: {text!r} is not {width} character(s)")
        return text
    if kind == "i":
        return _format_int(field, value)
    if kind == "ia":
        values = list(value)
        if len(values) != field.count:
            raise ValueError(f"{field.key}: needs {field.count} integers, got {len(values)}")
        return "".join(_format_int(field, v) for v in values)
    if kind == "f":
        v = float(value)
        body = f"{abs(v):0{width + 1 + field.frac}.{field.frac}f}"
        if width == 0:
            body = body[1:] if body.startswith("0") else body
        text = ("-" if v < 0 else "+") + body
        if len(text) != width + 2 + field.frac or not np.isfinite(v):
            raise ValueError(f"{field.key}: {v} does not fit {width}.{field.frac} digits")
        return text
    if kind == "e":
        v = float(value)
        text = f"{v:+.8e}"
        if len(text) != width or not np.isfinite(v):
            raise ValueError(f"{field.key}: {v} does not fit the +d.dddddddde+dd form")
        return text
    raise AssertionError(kind)  # pragma: no cover


def _format_int(field: HeaderField, value: Any) -> str:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ValueError(f"{field.key}: {value!r} is not an integer")
    text = f"{int(value):+0{field.width}d}"
    if len(text) != field.width:
        raise ValueError(f"{field.key}: {value} does not fit {field.width - 1} digits")
    return text


def format_header(fields: Sequence[HeaderField], values: Mapping[str, Any]) -> bytes:
    """ASCII block of ``KEY=value<unit>\\n`` lines with the fixed widths of ``fields``."""
    lines = []
    for field in fields:
        if field.kind == "spare":
            lines.append(" " * field.width + "\n")
            continue
        unit = f"<{field.unit}>" if field.unit is not None else ""
        lines.append(f"{field.key}={_format_value(field, values[field.key])}{unit}\n")
    text = "".join(lines).encode("ascii")
    assert len(text) == sum(f.size for f in fields)
    return text


def format_dsd(dsd: Dsd) -> bytes:
    """The 280-byte DSD (a spare DSD is 279 spaces and a newline)."""
    if dsd.is_spare:
        return b" " * 279 + b"\n"
    values = {
        "DS_NAME": dsd.name,
        "DS_TYPE": dsd.type,
        "FILENAME": dsd.filename,
        "DS_OFFSET": dsd.offset,
        "DS_SIZE": dsd.size,
        "NUM_DSR": dsd.num_dsr,
        "DSR_SIZE": dsd.dsr_size,
    }
    return format_header(DSD_FIELDS, values)


# --------------------------------------------------------------------------------------------
# write_product
# --------------------------------------------------------------------------------------------


def _as_datetime64(t: _dt.datetime | np.datetime64 | str) -> np.datetime64:
    if isinstance(t, _dt.datetime):
        if t.tzinfo is not None:
            t = t.astimezone(_dt.UTC).replace(tzinfo=None)
        return np.datetime64(t, "us")
    try:
        return np.datetime64(str(np.asarray(t, dtype="datetime64[us]")), "us")
    except (ValueError, TypeError) as exc:
        raise OptionsError(f"first_line_time: {t!r} is not a UTC date and time") from exc


def _interp_tie(grid: np.ndarray, line: float, col: float, df: int, dj: int) -> float:
    """Bilinear value of a tie-point grid at product pixel (line, col), clamped to the grid
    (tie point (i, k) sits on pixel (i*DF, k*DJ))."""
    rows = np.arange(grid.shape[0]) * df
    along_track = [np.interp(line, rows, grid[:, k]) for k in range(grid.shape[1])]
    return float(np.interp(col, np.arange(grid.shape[1]) * dj, along_track))


def _corners(lat: np.ndarray, lon: np.ndarray, height: int, width: int, df: int, dj: int):
    """SPH corner keys (first/mid/last sample of first/last line) in 1e-6 degrees."""
    ref = lon.flat[0]
    lon_unwrapped = ref + (lon - ref + 180.0) % 360.0 - 180.0
    out = {}
    for lname, line in (("FIRST", 0), ("LAST", height - 1)):
        for cname, col in (("FIRST", 0), ("MID", (width - 1) / 2), ("LAST", width - 1)):
            la = _interp_tie(lat, line, col, df, dj)
            lo = _interp_tie(lon_unwrapped, line, col, df, dj)
            lo = (lo + 180.0) % 360.0 - 180.0
            out[f"{lname}_{cname}_LAT"] = int(round(la * 1e6))
            out[f"{lname}_{cname}_LONG"] = int(round(lo * 1e6))
    return out


#: mission phase of simulated products (MPH ``PHASE`` and the file name's phase digit)
PHASE = "2"


def default_product_name(product_type: str, start: np.datetime64, duration_s: float,
                         counter: int = 0) -> str:
    """An ENVISAT product file name (62 characters), e.g.
    ``MER_FR__1PNSIM20030921_092341_000000982000_00000_00000_0000.N1``: duration (s), phase
    (2, as the MPH's ``PHASE``), cycle, relative and absolute orbit (0, as the MPH's: no
    orbit is simulated); ``counter`` is the file counter (last 4 digits: products of one
    acquisition told apart)."""
    s = str(np.asarray(start, dtype="datetime64[s]"))
    s = s.replace("-", "").replace(":", "").replace("T", "_")
    duration = min(int(round(duration_s)), 99_999_999)
    return (f"{product_type}NSIM{s}_{duration:08d}{PHASE}000_00000_00000_"
            f"{int(counter) % 10000:04d}.N1")


def _check_overrides(which: str, overrides: Mapping[str, Any] | None, fields) -> dict:
    if not overrides:
        return {}
    keys = {f.key for f in fields if f.kind != "spare"}
    for key in overrides:
        if key not in keys:
            raise OptionsError(f"{which} override: unknown key {key!r}")
        if key in STRUCTURAL_KEYS:
            raise OptionsError(f"{which} override: {key} is computed from the data")
    return dict(overrides)


def _quantize_tie_points(
    tie_points: Mapping[str, np.ndarray], shape: tuple[int, int], scaling: ScalingFactors
) -> dict[str, np.ndarray]:
    unknown = set(tie_points) - set(TIE_POINT_NAMES)
    if unknown:
        raise OptionsError(f"tie_points: unknown names {sorted(unknown)}")
    out = {}
    for field in TIE_POINT_FIELDS:
        values = np.asarray(tie_points.get(field.name, np.zeros(shape)), dtype=np.float64)
        if values.shape != shape:
            raise OptionsError(
                f"tie_points[{field.name!r}]: shape {values.shape}, expected {shape} "
                "(tie-point lines, tie-point columns)"
            )
        factor = scaling.factor(field)
        raw = np.round(values / factor)
        info = np.iinfo(np.dtype(field.dtype))
        if not np.all(np.isfinite(raw)) or raw.min() < info.min or raw.max() > info.max:
            raise OptionsError(
                f"tie_points[{field.name!r}]: values outside what {field.dtype[1:]} stores "
                f"at a scale of {factor:g} {field.unit}"
            )
        out[field.name] = raw.astype(field.dtype)
    return out


def write_product(
    path: str | os.PathLike[str],
    *,
    product_type: str,
    tie_points: Mapping[str, np.ndarray],
    counts: Sequence[np.ndarray],
    flags: np.ndarray,
    detector_index: np.ndarray,
    first_line_time: _dt.datetime | np.datetime64,
    line_interval_s: float | None = None,
    scaling: ScalingFactors | None = None,
    product_name: str | None = None,
    mph: Mapping[str, Any] | None = None,
    sph: Mapping[str, Any] | None = None,
    pixel_geolocation: Mapping[str, np.ndarray] | None = None,
    progress: ProgressCallback | None = None,
) -> Path:
    """Write a MERIS L1b product (``MER_FR__1P`` or ``MER_RR__1P``) and return its path.

    ``counts``: 15 uint16 (H, W) arrays (memmaps welcome, streamed), stored column order;
    ``flags``: uint8 (H, W); ``detector_index``: int16 (H, W); ``tie_points``: physical values
    (names as :data:`TIE_POINT_NAMES`, ``latitude`` and ``longitude`` required, others default
    to 0) of shape (tie lines, tie columns) with tie lines >= ceil((H-1)/DF)+1 and tie columns =
    (W-1)/DJ+1; ``first_line_time``: UTC of line 0 (naive datetimes are UTC);
    ``line_interval_s``: default 0.043997 s (FR) / 0.175988 s (RR); ``scaling``: default
    :meth:`ScalingFactors.appendix_a` with the sampling rate set to the line interval;
    ``mph``/``sph``: overrides of header values by file key (``{"PROC_CENTER": "UK-PAC"}``);
    ``pixel_geolocation``: for MER_FRG_1P / MER_FSG_1P / MER_RRG_1P only (and required there),
    the per-pixel terrain point as (H, W) ``longitude``, ``latitude`` (deg, stored in 1e-6 deg)
    and ``altitude`` (m, stored as int16). Bad arguments raise :class:`OptionsError`.
    """
    if product_type not in WRITABLE_PRODUCT_TYPES:
        raise OptionsError(
            f"product_type {product_type!r}: the writer makes {' or '.join(WRITABLE_PRODUCT_TYPES)}"
        )
    res = PRODUCT_TYPES[product_type]
    df, dj = res.lines_per_tie_point, res.samples_per_tie_point
    if len(counts) != NUM_BANDS:
        raise OptionsError(f"counts: {NUM_BANDS} bands needed, got {len(counts)}")
    shape = tuple(np.shape(counts[0]))
    if len(shape) != 2 or shape[0] < 1 or shape[1] < 2:
        raise OptionsError(f"counts: bands must be 2-D (lines, columns), got shape {shape}")
    height, width = shape
    for i, band in enumerate(counts):
        if tuple(np.shape(band)) != shape:
            raise OptionsError(f"counts[{i}]: shape {np.shape(band)}, band 1 has {shape}")
    for name, arr in (("flags", flags), ("detector_index", detector_index)):
        if tuple(np.shape(arr)) != shape:
            raise OptionsError(f"{name}: shape {np.shape(arr)}, the bands have {shape}")
    if (width - 1) % dj:
        raise OptionsError(
            f"counts: width {width} does not end on a tie-point column ((W-1) must be a "
            f"multiple of {dj} for {product_type})"
        )
    n_cols = tie_columns(width, dj)
    for required in ("latitude", "longitude"):
        if required not in tie_points:
            raise OptionsError(f"tie_points: {required!r} is required")
    lat = np.asarray(tie_points["latitude"], dtype=np.float64)
    n_tie = lat.shape[0] if lat.ndim == 2 else 0
    if n_tie < tie_lines(height, df):
        raise OptionsError(
            f"tie_points: {n_tie} tie-point lines, a product of {height} lines needs "
            f"{tie_lines(height, df)} (one every {df} lines, the last at or after line "
            f"{height - 1})"
        )
    dt = float(line_interval_s) if line_interval_s is not None else res.line_interval_s
    if not (np.isfinite(dt) and dt > 0):
        raise OptionsError(f"line_interval_s: {line_interval_s!r} must be a positive number")
    if scaling is None:
        scaling = ScalingFactors(sampling_rate_us=int(round(dt * 1e6)))
    # quantize with the factors as stored (float32), which the reader multiplies back
    stored_scaling = ScalingFactors.from_record(scaling.to_record())
    raw_tie = _quantize_tie_points(tie_points, (n_tie, n_cols), stored_scaling)
    geo_raw = _quantize_geolocation(product_type, pixel_geolocation, shape)
    mph_over = _check_overrides("mph", mph, MPH_FIELDS)
    sph_over = _check_overrides("sph", sph, SPH_FIELDS)

    t0 = _as_datetime64(first_line_time)
    t0_s = (t0 - np.datetime64("2000-01-01T00:00:00", "us")) / np.timedelta64(1, "s")
    line_times = t0_s + dt * np.arange(height, dtype=np.float64)
    t_last = t0 + np.timedelta64(int(round(dt * (height - 1) * 1e6)), "us")

    dsds = plan_layout(product_type, width, height, n_tie)
    tot_size = max(d.offset + d.size for d in dsds)
    name = product_name or default_product_name(product_type, t0, dt * height)

    mph_values: dict[str, Any] = {
        "PRODUCT": name,
        "PROC_STAGE": "N",
        "REF_DOC": "PO-RS-MDA-GS-2009_11/3J",
        "ACQUISITION_STATION": "meris-ortho",
        "PROC_CENTER": "MORTHO",
        "PROC_TIME": format_utc(t0),
        "SOFTWARE_VER": f"MORTHO/{__version__}",
        "SENSING_START": format_utc(t0),
        "SENSING_STOP": format_utc(t_last),
        "PHASE": PHASE,
        "CYCLE": 0,
        "REL_ORBIT": 0,
        "ABS_ORBIT": 0,
        "STATE_VECTOR_TIME": format_utc(t0),
        "DELTA_UT1": 0.0,
        "X_POSITION": 0.0,
        "Y_POSITION": 0.0,
        "Z_POSITION": 0.0,
        "X_VELOCITY": 0.0,
        "Y_VELOCITY": 0.0,
        "Z_VELOCITY": 0.0,
        "VECTOR_SOURCE": "FR",
        "UTC_SBT_TIME": format_utc(t0),
        "SAT_BINARY_TIME": 0,
        "CLOCK_STEP": 3906249810,
        "LEAP_UTC": "",
        "LEAP_SIGN": 0,
        "LEAP_ERR": "0",
        "PRODUCT_ERR": "0",
        **mph_over,
        "TOT_SIZE": tot_size,
        "SPH_SIZE": sph_size(len(dsds)),
        "NUM_DSD": len(dsds),
        "DSD_SIZE": 280,
        "NUM_DATA_SETS": sum(d.has_data for d in dsds),
    }
    sph_values: dict[str, Any] = {
        "SPH_DESCRIPTOR": f"{product_type} SPECIFIC HEADER",
        "STRIPLINE_CONTINUITY_INDICATOR": 0,
        "SLICE_POSITION": 1,
        "NUM_SLICES": 1,
        "FIRST_LINE_TIME": format_utc(t0),
        "LAST_LINE_TIME": format_utc(t_last),
        **_corners(
            np.asarray(tie_points["latitude"], dtype=np.float64),
            np.asarray(tie_points["longitude"], dtype=np.float64),
            height, width, df, dj,
        ),
        "TRANS_ERR_FLAG": "0",
        "FORMAT_ERR_FLAG": "0",
        "DATABASE_FLAG": "0",
        "COARSE_ERR_FLAG": "0",
        "ECMWF_TYPE": "1",
        "NUM_TRANS_ERR": 0,
        "NUM_FORMAT_ERR": 0,
        "TRANS_ERR_THRESH": 0.0,
        "FORMAT_ERR_THRESH": 0.0,
        "BAND_WAVELEN": [int(round(w * 1000)) for w in APPENDIX_A_WAVELENGTHS],
        "BANDWIDTH": [int(round(w * 1000)) for w in APPENDIX_A_BANDWIDTHS],
        "INST_FOV": 19159,
        "PROC_MODE": "1",
        "OFFSET_COMP": "1",
        "LINE_TIME_INTERVAL": int(round(dt * 1e6)),
        "COLUMN_SPACING": res.column_spacing_m,
        **sph_over,
        "NUM_BANDS": NUM_BANDS,
        "LINE_LENGTH": width,
        "LINES_PER_TIE_PT": df,
        "SAMPLES_PER_TIE_PT": dj,
    }  # fmt: skip
    try:
        header = format_header(MPH_FIELDS, mph_values) + format_header(SPH_FIELDS, sph_values)
        header += b"".join(format_dsd(d) for d in dsds)
    except ValueError as exc:
        raise OptionsError(f"{path}: header value: {exc}") from exc
    assert len(header) == MPH_SIZE + sph_size(num_dsd(product_type))

    # annotation data sets
    quality = dsds[0]
    q = np.zeros(quality.num_dsr, dtype=QUALITY_DTYPE)
    _set_times(q, line_times[:: res.quality_lines][: quality.num_dsr])
    tie = np.zeros(n_tie, dtype=tie_point_dtype(n_cols))
    _set_times(tie, t0_s + dt * df * np.arange(n_tie, dtype=np.float64))
    for key, raw in raw_tie.items():
        tie[key] = raw
    annotations = q.tobytes() + scaling.to_record().tobytes() + tie.tobytes()

    total = (NUM_BANDS + 1 + len(geo_raw)) * height
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(header)
        f.write(annotations)
        for b in range(NUM_BANDS):
            assert f.tell() == dsds[3 + b].offset
            _write_band(f, counts[b], radiance_dtype(width), line_times, b, progress, total)
        assert f.tell() == dsds[18].offset
        _write_flags(f, flags, detector_index, width, line_times, progress, total)
        for k, (mds, raw) in enumerate(zip(GEOLOCATION_MDS, geo_raw, strict=False)):
            assert f.tell() == dsds[19 + k].offset
            _write_geolocation(f, raw, geolocation_dtype(mds, width), line_times)
            if progress is not None:
                progress((NUM_BANDS + 2 + k) * height, total)
        if f.tell() != tot_size:  # pragma: no cover - a bug, not a user error
            raise AssertionError(f"wrote {f.tell()} bytes, planned {tot_size}")
    return Path(path)


def _quantize_geolocation(product_type: str, geo: Mapping[str, np.ndarray] | None,
                          shape: tuple[int, ...]) -> list[np.ndarray]:
    """Stored integers of the geolocation MDS(17..19) (empty for the other types)."""
    if product_type not in PIXEL_GEOLOCATION_TYPES:
        if geo is not None:
            raise OptionsError(f"pixel_geolocation: only {' and '.join(PIXEL_GEOLOCATION_TYPES)} "
                               f"products carry a per-pixel geolocation, not {product_type}")
        return []
    if geo is None:
        raise OptionsError(f"pixel_geolocation: required for {product_type} (longitude, "
                           "latitude, altitude)")
    out = []
    for mds in GEOLOCATION_MDS:
        key = mds.band.removeprefix("corr_")
        if key not in geo:
            raise OptionsError(f"pixel_geolocation: {key!r} is required")
        values = np.asarray(geo[key], dtype=np.float64)
        if values.shape != shape:
            raise OptionsError(f"pixel_geolocation[{key!r}]: shape {values.shape}, the bands "
                               f"have {shape}")
        raw = np.round(values / mds.scale)
        info = np.iinfo(np.dtype(mds.dtype))
        if not np.all(np.isfinite(raw)) or raw.min() < info.min or raw.max() > info.max:
            raise OptionsError(f"pixel_geolocation[{key!r}]: values not finite or out of range")
        out.append(raw.astype(mds.dtype))
    return out


def _write_geolocation(f, raw: np.ndarray, dtype: np.dtype, line_times: np.ndarray) -> None:
    height = len(line_times)
    for i0 in range(0, height, _BLOCK_LINES):
        i1 = min(i0 + _BLOCK_LINES, height)
        rec = np.zeros(i1 - i0, dtype=dtype)
        _set_times(rec, line_times[i0:i1])
        rec["values"] = raw[i0:i1]
        f.write(rec.tobytes())


def _set_times(records: np.ndarray, seconds: np.ndarray) -> None:
    days, secs, micro = seconds_to_mjd2000(seconds)
    records["days"], records["seconds"], records["microseconds"] = days, secs, micro


def _block_as(values: np.ndarray, dtype: np.dtype, what: str) -> np.ndarray:
    """Check an input block fits ``dtype`` (integer range) before it is cast."""
    block = np.asarray(values)
    if block.dtype.newbyteorder("=") == dtype.newbyteorder("="):
        return block
    if not np.issubdtype(block.dtype, np.integer) and block.dtype != np.bool_:
        raise OptionsError(f"{what}: {block.dtype} values, {dtype.name} integers expected")
    info = np.iinfo(dtype)
    if block.size and (block.min() < info.min or block.max() > info.max):
        raise OptionsError(f"{what}: values outside {info.min}..{info.max}")
    return block


def _write_band(f, band, dtype, line_times, b, progress, total) -> None:
    height = len(line_times)
    counts_dtype = np.dtype(np.uint16)
    for i0 in range(0, height, _BLOCK_LINES):
        i1 = min(i0 + _BLOCK_LINES, height)
        rec = np.zeros(i1 - i0, dtype=dtype)
        _set_times(rec, line_times[i0:i1])
        rec["counts"] = _block_as(band[i0:i1], counts_dtype, f"counts[{b}]")
        f.write(rec.tobytes())
        if progress is not None:
            progress(b * height + i1, total)


def _write_flags(f, flags, detector_index, width, line_times, progress, total) -> None:
    height = len(line_times)
    dtype = flags_dtype(width)
    for i0 in range(0, height, _BLOCK_LINES):
        i1 = min(i0 + _BLOCK_LINES, height)
        rec = np.zeros(i1 - i0, dtype=dtype)
        _set_times(rec, line_times[i0:i1])
        rec["flags"] = _block_as(flags[i0:i1], np.dtype(np.uint8), "flags")
        rec["detector_index"] = _block_as(
            detector_index[i0:i1], np.dtype(np.int16), "detector_index"
        )
        f.write(rec.tobytes())
        if progress is not None:
            progress(NUM_BANDS * height + i1, total)

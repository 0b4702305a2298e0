"""Write a Sentinel-3 OLCI Level 1B product as ESA's look (``layout``): a ``.SEN3`` directory
(or its zip archive) of the members ESA's products hold, with ESA's variable names, dimensions,
types and attributes, columns west to east on a descending pass, the quality flags of either
processing baseline, and an ``xfdumanifest.xml`` with what SNAP and satpy read (product type,
platform, image size, tie-point sampling, band descriptions).

The arrays given are in the N1 column order every product of this package exposes
(ARCHITECTURE.md "Conventions") and the tie points on the pixel centres, as the reader gives
them back: the writer mirrors the columns and moves the tie points where ESA has them
(``layout.TIE_COLUMN_SHIFT``).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import zipfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..._atomic import atomic_dir, atomic_path
from ...bands import OLCI
from ...errors import OptionsError
from ...progress import ProgressCallback
from ..n1.format import tie_columns
from ..sen3.layout import (
    GEO_FILE,
    INSTRUMENT_FILE,
    MANIFEST,
    QUALITY_FILE,
    RADIANCE_FILL,
    TIE_GEO_FILE,
    TIE_METEO_FILE,
    TIME_FILE,
)
from ..sen3.writer import NcWriter, write_geo, write_tie_angles_and_meteo
from .layout import (
    N_BANDS,
    OLCI_TYPES,
    QUALITY_FLAGS,
    REMOVED_PIXELS_FILE,
    FlagBaseline,
    flag_table,
    product_type_of,
    radiance_file,
    radiance_variable,
    required_files,
    tie_points_as_esa,
)

#: platforms and the processing centre code of their names
PLATFORMS = {"S3A": ("A", "PS1"), "S3B": ("B", "PS2")}
#: the collection (processing baseline family) written in names and attributes
COLLECTION = "004"


def default_olci_name(product_type: str, platform: str, start: np.datetime64,
                      duration_s: float, creation: np.datetime64 | None = None) -> str:
    """``S3A_OL_1_EFR____<start>_<stop>_<creation>_<duration>_<cycle>_<orbit>_<frame>_<centre>
    _O_NT_004.SEN3`` as ESA names its products (cycle, relative orbit and frame 0)."""
    stop = start + np.timedelta64(int(round(duration_s * 1e6)), "us")

    def stamp(t: np.datetime64) -> str:
        return str(np.asarray(t).astype("datetime64[s]")).replace("-", "").replace(":", "")

    kind = product_type[5:8]
    centre = PLATFORMS[platform][1]
    return (f"{platform}_OL_1_{kind}____{stamp(start)}_{stamp(stop)}_"
            f"{stamp(creation if creation is not None else stop)}_"
            f"{int(round(duration_s)):04d}_000_000_0000_{centre}_O_NT_{COLLECTION}.SEN3")


def quality_flags_of(flags: np.ndarray, saturated: np.ndarray | None = None,
                     baseline: FlagBaseline | str = FlagBaseline.PER_BAND) -> np.ndarray:
    """``quality_flags`` (uint32, the baseline's coding) of L1b flags (uint8, ``flags.FLAG_*``)
    and per-band saturation bits (bit b-1: band b; the 2.24 baseline: ``saturated`` where any
    band is)."""
    from ..sen3.layout import L1B_OF_QUALITY

    coding = flag_table(baseline)
    f = np.asarray(flags).astype(np.uint8)
    out = np.zeros(f.shape, np.uint32)
    for name, l1b in L1B_OF_QUALITY.items():
        out |= np.where(f & np.uint8(l1b), np.uint32(coding[name]), np.uint32(0))
    if saturated is not None:
        sat = np.asarray(saturated).astype(np.uint32)
        if FlagBaseline(baseline) is FlagBaseline.PER_BAND:
            for b in range(1, N_BANDS + 1):
                out |= np.where(sat & np.uint32(1 << (b - 1)),
                                np.uint32(coding[f"saturated_Oa{b:02d}"]), np.uint32(0))
        else:
            out |= np.where(sat != 0, np.uint32(coding["saturated"]), np.uint32(0))
    return out


def write_olci(path: str | os.PathLike[str], *, product_type: str,
               counts: Sequence[Any], scale_factors: Sequence[float],
               quality_flags: np.ndarray, pixel_geolocation: Mapping[str, np.ndarray],
               tie_points: Mapping[str, np.ndarray], detector_index: np.ndarray,
               lambda0: np.ndarray, fwhm: np.ndarray, solar_flux: np.ndarray,
               start_time: np.datetime64, line_interval_s: float | None = None,
               time_stamps: np.ndarray | None = None, platform: str = "S3A",
               baseline: FlagBaseline | str = FlagBaseline.PER_BAND,
               progress: ProgressCallback | None = None) -> Path:
    """Write an OLCI Level 1B product; the path written.

    ``path``: the product (``<name>.SEN3`` directory, or ``<name>.SEN3.zip``/``.zip`` archive
    holding ``<name>.SEN3/``), or an existing directory to write it into under its default
    name (:func:`default_olci_name`). Every image is (H, W) in the **N1 column order**
    (stored mirrored), H rows, W = 4865 (EFR) or 1217 (ERR) columns:

    - ``product_type``: ``"OL_1_EFR___"``/``"OL_1_ERR___"`` (or ``"EFR"``/``"ERR"``);
    - ``counts``: 21 uint16 (H, W), band b at index b-1, 65535 = no data (``_FillValue``);
    - ``scale_factors``: 21 floats, radiance (mW m-2 sr-1 nm-1) = counts x factor (stored
      float32 ``scale_factor``);
    - ``quality_flags``: uint32 (H, W) in ``baseline``'s coding (:func:`quality_flags_of`
      builds them from L1b flags); ``baseline``: ``FlagBaseline.PER_BAND`` (before 2.24) or
      ``SINCE_2_24``; its ``flag_masks``/``flag_meanings`` are written;
    - ``pixel_geolocation``: ``latitude``, ``longitude`` (deg, float64; stored int32 x 1e-6,
      NaN -> fill) and ``altitude`` (m; int16) of every pixel, (H, W);
    - ``tie_points``: (H, T) float64 with T = (W - 1) / DJ + 1 tie columns (77 EFR, DJ 64;
      77 ERR, DJ 16), tie point (i, k) at pixel (i, k x DJ) of the N1 order (the reader's
      convention; moved by ``layout.TIE_COLUMN_SHIFT`` on writing), N1 names: ``latitude``,
      ``longitude`` (ellipsoid, deg), ``sun_zenith``, ``sun_azimuth``, ``view_zenith``,
      ``view_azimuth`` (deg; azimuths stored on (-180, 180]); optional meteo ``zonal_wind``,
      ``merid_wind`` (m/s), ``atm_pressure`` (hPa), ``ozone`` (DU), ``rel_humidity`` (%)
      (written 0 / NaN-free when absent); no tie altitude (ESA's tie files have none);
    - ``detector_index``: int16 (H, W), -1 = none; ``lambda0``, ``fwhm`` (nm), ``solar_flux``
      (mW m-2 nm-1): float32 (21, D), D detectors (3700 = 5 cameras x 740);
    - ``start_time``: the first row's time (UTC); ``line_interval_s``: seconds between rows
      (default the frame period: EFR 0.044 s, ERR 0.176 s) or ``time_stamps``: int64 (H,)
      microseconds since 2000-01-01 (then ``start_time`` is only used for the name);
    - ``platform``: ``"S3A"`` or ``"S3B"``.

    Written aside and renamed (nothing is left by a failure). Bad arguments raise
    :class:`OptionsError`.
    """
    ptype = product_type_of(product_type) or product_type_of(f"OL_1_{product_type}")
    if ptype is None:
        raise OptionsError(f"product type {product_type!r}: OL_1_EFR___ or OL_1_ERR___")
    if platform not in PLATFORMS:
        raise OptionsError(f"platform {platform!r}: S3A or S3B")
    res = OLCI_TYPES[ptype]
    dj = res.samples_per_tie_point
    if len(counts) != N_BANDS or len(scale_factors) != N_BANDS:
        raise OptionsError(f"counts and scale_factors need {N_BANDS} bands, got "
                           f"{len(counts)} and {len(scale_factors)}")
    shape = tuple(np.shape(counts[0]))
    if len(shape) != 2 or shape[1] < 2 or (shape[1] - 1) % dj:
        raise OptionsError(f"bands of shape {shape}: W - 1 must be a multiple of {dj}")
    height, width = shape
    for name, a in (("quality_flags", quality_flags), ("detector_index", detector_index),
                    *((f"counts[{b}]", c) for b, c in enumerate(counts)),
                    *((f"pixel_geolocation[{k!r}]", pixel_geolocation.get(k))
                      for k in ("latitude", "longitude", "altitude"))):
        if a is None or np.shape(a) != shape:
            raise OptionsError(f"{name} must have the bands' shape {shape}")
    tshape = (height, tie_columns(width, dj))
    for key in ("latitude", "longitude", "sun_zenith", "sun_azimuth", "view_zenith",
                "view_azimuth"):
        if key not in tie_points or np.shape(tie_points[key]) != tshape:
            raise OptionsError(f"tie_points[{key!r}] must be {tshape} (every row, every "
                               f"{dj} columns)")
    spectral = {"lambda0": lambda0, "FWHM": fwhm, "solar_flux": solar_flux}
    n_det = np.shape(lambda0)[-1] if np.ndim(lambda0) == 2 else 0
    for name, a in spectral.items():
        if np.ndim(a) != 2 or np.shape(a) != (N_BANDS, n_det):
            raise OptionsError(f"{name} must be (21, detectors), got {np.shape(a)}")
    t0: Any = np.asarray(start_time).astype("datetime64[us]")[()]
    epoch = np.datetime64("2000-01-01T00:00:00", "us")
    if time_stamps is None:
        step = res.line_interval_s if line_interval_s is None else float(line_interval_s)
        t0_us = int((t0 - epoch) / np.timedelta64(1, "us"))
        stamps = t0_us + np.round(np.arange(height) * step * 1e6).astype(np.int64)
    else:
        stamps = np.asarray(time_stamps, np.int64)
        if stamps.shape != (height,):
            raise OptionsError(f"time_stamps must be ({height},), got {stamps.shape}")
        t0 = epoch + np.timedelta64(int(stamps[0]), "us")
    t_stop = epoch + np.timedelta64(int(stamps[-1]), "us")
    duration = float((t_stop - t0) / np.timedelta64(1, "s"))

    out = Path(path)
    if out.is_dir() and out.suffix.upper() != ".SEN3":
        out = out / default_olci_name(ptype, platform, t0, duration)
    archive = out.suffix.lower() == ".zip"
    if not archive and out.suffix != ".SEN3":
        raise OptionsError(f"{out}: an OLCI product is a <name>.SEN3 directory or a .zip")
    name = out.name.removesuffix(".zip").removesuffix(".ZIP")
    name = name if name.endswith(".SEN3") else name + ".SEN3"
    common = {"Conventions": "CF-1.6",
              "title": f"OLCI Level 1b Product, {'Full' if res.name == 'FR' else 'Reduced'} "
                       f"Resolution {ptype[5:8]} (simulated)",
              "product_name": name, "institution": "meris-ortho simulator",
              "source": f"Sentinel-3{PLATFORMS[platform][0]} OLCI (napari-meris-ortho)",
              "absolute_orbit_number": np.uint32(0), "ac_subsampling_factor": np.uint16(dj),
              "al_subsampling_factor": np.uint16(1), "start_time": str(t0) + "Z",
              "stop_time": str(t_stop) + "Z",
              "processing_baseline": ("OL__L1_.003.03.01" if FlagBaseline(baseline)
                                      is FlagBaseline.SINCE_2_24 else "OL__L1_.002.23.00")}
    facts = dict(name=name, ptype=ptype, platform=platform, height=height, width=width, dj=dj,
                 t0=t0, t_stop=t_stop)

    def write_members(tmp: Path) -> None:
        nc = NcWriter(tmp, common)
        _write_bands(nc, counts, scale_factors, progress)
        img = {"rows": height, "columns": width}
        with nc.dataset(GEO_FILE, img) as ds:
            write_geo(nc.var, ds, ("rows", "columns"), dict(pixel_geolocation))
        _write_instrument(nc, img, detector_index, spectral, quality_flags, baseline)
        _write_tie_points(nc, tie_points_as_esa(tie_points, dj), tshape)
        with nc.dataset(TIME_FILE, {"rows": height}) as ds:
            nc.var(ds, "time_stamp", "i8", ("rows",), stamps, None,
                   units="microseconds since 2000-01-01 00:00:00", standard_name="time",
                   calendar="gregorian", long_name="Elapsed time since 01 Jan 2000 0h")
        if ptype == "OL_1_EFR___":
            with nc.dataset(REMOVED_PIXELS_FILE, {"removed_pixels": 0}) as ds:
                nc.var(ds, "detector_index", "i2", ("removed_pixels",), np.zeros(0), None,
                       long_name="Detector index of the removed pixels")
        (tmp / MANIFEST).write_text(_manifest(**facts))
        if progress is not None:
            progress(N_BANDS + 1, N_BANDS + 1)

    if not archive:
        with atomic_dir(out) as tmp:
            write_members(tmp)
        return out
    with tempfile.TemporaryDirectory(dir=out.parent if out.parent.is_dir() else None) as work:
        folder = Path(work) / name
        folder.mkdir()
        write_members(folder)
        with atomic_path(out) as tmp_zip, zipfile.ZipFile(tmp_zip, "w",
                                                           zipfile.ZIP_DEFLATED) as z:
            for f in sorted(folder.iterdir()):
                z.write(f, f"{name}/{f.name}")
        shutil.rmtree(folder, ignore_errors=True)
    return out


def _write_bands(nc: NcWriter, counts: Sequence[Any], scale_factors: Sequence[float],
                 progress: ProgressCallback | None) -> None:
    """``OaNN_radiance.nc``: the counts with their ``scale_factor`` (no ``add_offset``)."""
    height, width = np.shape(counts[0])
    for b in range(1, N_BANDS + 1):
        with nc.dataset(radiance_file(b), {"rows": height, "columns": width}) as ds:
            nc.var(ds, radiance_variable(b), "u2", ("rows", "columns"),
                   np.asarray(counts[b - 1], np.uint16), np.uint16(RADIANCE_FILL),
                   scale_factor=np.float32(scale_factors[b - 1]),
                   units="mW.m-2.sr-1.nm-1", standard_name="toa_upwelling_spectral_radiance",
                   long_name=f"TOA radiance for OLCI acquisition band {OLCI.name(b)}",
                   valid_max=np.uint16(65534), valid_min=np.uint16(0))
        if progress is not None:
            progress(b, N_BANDS + 1)


def _write_instrument(nc: NcWriter, img: dict[str, int], detector_index: np.ndarray,
                      spectral: dict[str, np.ndarray], quality_flags: np.ndarray,
                      baseline: FlagBaseline | str) -> None:
    """``instrument_data.nc`` (detector index, frame offset, per-detector spectral data) and
    ``qualityFlags.nc`` (with the baseline's ``flag_masks``/``flag_meanings``)."""
    det = int(np.shape(spectral["lambda0"])[1])
    with nc.dataset(INSTRUMENT_FILE, {**img, "bands": N_BANDS, "detectors": det}) as ds:
        nc.var(ds, "detector_index", "i2", ("rows", "columns"),
               np.asarray(detector_index, np.int16), np.int16(-1),
               long_name="Detector index", valid_min=np.int16(0), valid_max=np.int16(det - 1))
        nc.var(ds, "frame_offset", "i1", ("rows", "columns"),
               np.zeros((img["rows"], img["columns"]), np.int8), np.int8(-128),
               long_name="Re-sampling along-track frame offset", valid_min=np.int8(-20),
               valid_max=np.int8(20))
        for name, unit, long in (("lambda0", "nm", "Central wavelength"),
                                 ("FWHM", "nm", "Full width at half maximum"),
                                 ("solar_flux", "mW.m-2.nm-1", "In-band solar irradiance, "
                                  "seasonally corrected")):
            nc.var(ds, name, "f4", ("bands", "detectors"),
                   np.asarray(spectral[name], np.float32), np.float32(-1.0), units=unit,
                   long_name=long)
    table = QUALITY_FLAGS[FlagBaseline(baseline)]
    with nc.dataset(QUALITY_FILE, img) as ds:
        nc.var(ds, "quality_flags", "u4", ("rows", "columns"),
               np.asarray(quality_flags, np.uint32), np.uint32(4294967295),
               long_name="Classification and quality flags",
               flag_masks=np.array([1 << b for _, b in table], np.uint32),
               flag_meanings=" ".join(n for n, _ in table))


def _write_tie_points(nc: NcWriter, tie_points: Mapping[str, np.ndarray],
                      tshape: tuple[int, int]) -> None:
    """``tie_geo_coordinates.nc`` (latitude, longitude: no altitude, as ESA's),
    ``tie_geometries.nc`` (azimuths on (-180, 180]) and ``tie_meteo.nc``."""
    tdims = {"tie_rows": tshape[0], "tie_columns": tshape[1]}
    tie = ("tie_rows", "tie_columns")

    def get(key: str) -> np.ndarray:
        v = np.asarray(tie_points.get(key, np.zeros(tshape)), np.float64)
        return np.where(np.isfinite(v), v, 0.0)

    with nc.dataset(TIE_GEO_FILE, tdims) as ds:
        for key, unit in (("latitude", "degrees_north"), ("longitude", "degrees_east")):
            values = get(key)
            if key == "longitude":
                values = (values + 180.0) % 360.0 - 180.0
            nc.var(ds, key, "i4", tie, np.round(values * 1e6), np.int32(-2147483648),
                   scale_factor=1e-6, units=unit, standard_name=key,
                   long_name=key.capitalize(),
                   valid_min=np.int32(-90_000_000 if key == "latitude" else -180_000_000),
                   valid_max=np.int32(90_000_000 if key == "latitude" else 180_000_000))
    write_tie_angles_and_meteo(
        nc, tdims, get,
        {("SZA", "sun_zenith"): "Sun Zenith Angle", ("SAA", "sun_azimuth"): "Sun Azimuth Angle",
         ("OZA", "view_zenith"): "Viewing (observation) zenith angle",
         ("OAA", "view_azimuth"): "Viewing (observation) azimuth angle"},
        "Horizontal wind vector at 10m altitude", fills=True)


def _manifest(*, name: str, ptype: str, platform: str, height: int, width: int, dj: int,
              t0: np.datetime64, t_stop: np.datetime64) -> str:
    """The XFDU manifest: acquisition period, platform and instrument, product information
    (name, type, image size, tie-point sampling, band descriptions) and the data objects."""
    files = [f for f in required_files()[1:]] + [TIE_METEO_FILE]
    if ptype == "OL_1_EFR___":
        files.append(REMOVED_PIXELS_FILE)
    objects = "\n".join(
        f'    <dataObject ID="{Path(f).stem}Data"><byteStream mimeType="application/x-netcdf">'
        f'<fileLocation locatorType="URL" href="./{f}"/></byteStream></dataObject>'
        for f in files)
    pointers = "\n".join(
        f'      <xfdu:contentUnit ID="{Path(f).stem}Unit" unitType="Measurement Data Unit">'
        f'<dataObjectPointer dataObjectID="{Path(f).stem}Data"/></xfdu:contentUnit>'
        for f in files)
    bands = "\n".join(
        f'          <olci:band name="{OLCI.name(b)}"><olci:centralWavelength>{w:.3f}'
        f'</olci:centralWavelength><olci:bandWidth>{bw:.3f}</olci:bandWidth></olci:band>'
        for b, (w, bw) in enumerate(zip(OLCI.centres, OLCI.widths, strict=True), start=1))
    number = PLATFORMS[platform][0]
    nssdc = "2016-011A" if number == "A" else "2018-039A"
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<xfdu:XFDU xmlns:xfdu="urn:ccsds:schema:xfdu:1" xmlns:sentinel-safe="http://www.esa.int/safe/sentinel/1.1" xmlns:sentinel3="http://www.esa.int/safe/sentinel/sentinel-3/1.0" xmlns:olci="http://www.esa.int/safe/sentinel/sentinel-3/olci/1.0" version="esa/safe/sentinel/sentinel-3/olci/level-1/1.0">
  <informationPackageMap>
    <xfdu:contentUnit ID="packageUnit" unitType="Information Package" textInfo="SENTINEL-3 OLCI Level 1 Product" dmdID="acquisitionPeriod platform generalProductInformation olciProductInformation">
{pointers}
    </xfdu:contentUnit>
  </informationPackageMap>
  <metadataSection>
    <metadataObject ID="acquisitionPeriod" classification="DESCRIPTION" category="DMD"><metadataWrap mimeType="text/xml" vocabularyName="Sentinel-SAFE" textInfo="Acquisition Period"><xmlData><sentinel-safe:acquisitionPeriod>
      <sentinel-safe:startTime>{t0}Z</sentinel-safe:startTime>
      <sentinel-safe:stopTime>{t_stop}Z</sentinel-safe:stopTime>
    </sentinel-safe:acquisitionPeriod></xmlData></metadataWrap></metadataObject>
    <metadataObject ID="platform" classification="DESCRIPTION" category="DMD"><metadataWrap mimeType="text/xml" vocabularyName="Sentinel-SAFE" textInfo="Platform Description"><xmlData><sentinel-safe:platform>
      <sentinel-safe:nssdcIdentifier>{nssdc}</sentinel-safe:nssdcIdentifier>
      <sentinel-safe:familyName>Sentinel-3</sentinel-safe:familyName>
      <sentinel-safe:number>{number}</sentinel-safe:number>
      <sentinel-safe:instrument><sentinel-safe:familyName abbreviation="OLCI">Ocean Land Colour Instrument</sentinel-safe:familyName></sentinel-safe:instrument>
    </sentinel-safe:platform></xmlData></metadataWrap></metadataObject>
    <metadataObject ID="generalProductInformation" classification="DESCRIPTION" category="DMD"><metadataWrap mimeType="text/xml" vocabularyName="Sentinel-SAFE" textInfo="General Product Information"><xmlData>
      <sentinel3:generalProductInformation><sentinel3:productName>{name}</sentinel3:productName>
      <sentinel3:productType>{ptype}</sentinel3:productType>
      <sentinel3:timeliness>NT</sentinel3:timeliness>
      <sentinel3:baselineCollection>{COLLECTION}</sentinel3:baselineCollection>
      </sentinel3:generalProductInformation></xmlData></metadataWrap></metadataObject>
    <metadataObject ID="olciProductInformation" classification="DESCRIPTION" category="DMD"><metadataWrap mimeType="text/xml" vocabularyName="Sentinel-SAFE" textInfo="OLCI Product Information"><xmlData>
      <olci:olciProductInformation>
        <olci:imageSize grid="Full Resolution"><sentinel3:rows>{height}</sentinel3:rows><sentinel3:columns>{width}</sentinel3:columns></olci:imageSize>
        <olci:samplingParameters><olci:rowsPerTiePoint>1</olci:rowsPerTiePoint><olci:columnsPerTiePoint>{dj}</olci:columnsPerTiePoint></olci:samplingParameters>
        <olci:bandDescriptions>
{bands}
        </olci:bandDescriptions>
      </olci:olciProductInformation></xmlData></metadataWrap></metadataObject>
  </metadataSection>
  <dataObjectSection>
{objects}
  </dataObjectSection>
</xfdu:XFDU>
"""  # noqa: E501

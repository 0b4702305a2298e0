"""Write a MERIS fourth-reprocessing ``.SEN3`` product as ESA's look (``layout``): columns
west to east on a descending pass, CF-packed variables with ``_FillValue`` and valid ranges, the
full ``quality_flags`` coding, and an ``xfdumanifest.xml`` with what SNAP, ocssw and ACOLITE read
(product type, platform and instrument, data objects with their ``contentUnit`` descriptions).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..._atomic import atomic_dir
from ...errors import OptionsError
from ...progress import ProgressCallback
from ..n1.format import (
    APPENDIX_A_BANDWIDTHS,
    APPENDIX_A_WAVELENGTHS,
    FULL_RESOLUTION,
    NUM_BANDS,
    REDUCED_RESOLUTION,
    ScalingFactors,
    tie_columns,
    tie_lines,
)
from .layout import (
    DETECTORS,
    DOBSON_KG_M2,
    GEO_FILE,
    INSTRUMENT_FILE,
    INT16_FILL,
    INT32_FILL,
    MANIFEST,
    QUALITY_FILE,
    QUALITY_FLAGS,
    RADIANCE_FILL,
    TIE_GEO_FILE,
    TIE_GEOMETRY_FILE,
    TIE_METEO_FILE,
    TIME_FILE,
    l1b_to_quality,
    mirror_columns,
    radiance_file,
    radiance_variable,
    required_files,
)


def default_sen3_name(resolution: str, start: np.datetime64, duration_s: float) -> str:
    """``ENV_ME_1_FRG____<start>_<stop>_________________<dur>_000_000______MOR_R_NT____.SEN3``:
    99 characters, 17 underscores between the stop time and the duration, as ESA's names."""
    stop = start + np.timedelta64(int(round(duration_s * 1e6)), "us")

    def stamp(t: np.datetime64) -> str:
        return str(t.astype("datetime64[s]")).replace("-", "").replace(":", "")

    return (f"ENV_ME_1_{resolution}G____{stamp(start)}_{stamp(stop)}{'_' * 17}"
            f"{int(round(duration_s)):04d}_000_000______MOR_R_NT____.SEN3")


def write_sen3(path: str | os.PathLike[str], *, resolution: str,
               tie_points: Mapping[str, np.ndarray], counts: Any, flags: np.ndarray,
               detector_index: np.ndarray, pixel_geolocation: dict[str, np.ndarray],
               first_line_time: np.datetime64, line_interval_s: float,
               scaling: ScalingFactors | None = None,
               progress: ProgressCallback | None = None) -> Path:
    """Write a MERIS Level 1 ``.SEN3`` directory (``layout``) at ``path``.

    ``resolution`` "FR" or "RR"; ``counts``: 15 uint16 (H, W) arrays in the N1 column order
    (stored mirrored, west to east on a descending pass, as ESA's products);
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
    t_stop = t0 + np.timedelta64(int(stamps[-1] - t0_us), "us")
    common = {"Conventions": "CF-1.6",
              "title": f"MERIS Level 1b Product, {resolution} (simulated)",
              "product_name": out.name, "institution": "meris-ortho simulator",
              "absolute_orbit_number": np.uint16(0), "ac_subsampling_factor": np.uint16(dj),
              "al_subsampling_factor": np.uint16(df), "start_time": str(t0) + "Z",
              "stop_time": str(t_stop) + "Z", "source": "napari-meris-ortho"}
    with atomic_dir(out) as tmp:
        nc = NcWriter(tmp, common)
        _write_bands(nc, counts, scaling, progress)
        with nc.dataset(GEO_FILE, {"rows": height, "columns": width}) as ds:
            write_geo(nc.var, ds, ("rows", "columns"), pixel_geolocation)
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


class NcWriter:
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
        """A compressed variable holding ``data`` cast to ``dtype`` (raw, attributes as given);
        image and tie-point columns given in the N1 order are stored mirrored (``layout``)."""
        v = ds.createVariable(name, dtype, dims, zlib=True, complevel=1, fill_value=fill)
        v.set_auto_maskandscale(False)
        v.setncatts(attrs)
        values = np.asarray(data)
        if len(dims) >= 2 and dims[1] in ("columns", "tie_columns"):
            values = mirror_columns(values)
        v[...] = values.astype(v.dtype)
        return v


def _write_bands(nc: NcWriter, counts: Any, scaling: ScalingFactors,
                 progress: ProgressCallback | None) -> None:
    """``Mnn_radiance.nc``: the counts with the radiance factor as CF ``scale_factor``."""
    height, width = np.shape(counts[0])
    for b in range(1, NUM_BANDS + 1):
        with nc.dataset(radiance_file(b), {"rows": height, "columns": width}) as ds:
            nc.var(ds, radiance_variable(b), "u2", ("rows", "columns"),
                   np.asarray(counts[b - 1], np.uint16), RADIANCE_FILL,
                   scale_factor=np.float32(scaling.radiance[b - 1]),
                   add_offset=np.float32(0.0), units="mW.m-2.sr-1.nm-1",
                   standard_name="toa_upwelling_spectral_radiance",
                   long_name=f"TOA radiance for MERIS acquisition band M{b:02d}",
                   valid_min=np.uint16(0), valid_max=np.uint16(65534))
        if progress is not None:
            progress(b, NUM_BANDS + 1)


def _write_instrument(nc: NcWriter, detector_index: np.ndarray, flags: np.ndarray,
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
                   np.float32(-1.0), units=unit, long_name=long)  # SNAP: no-data -1
    with nc.dataset(QUALITY_FILE, img) as ds:
        nc.var(ds, "quality_flags", "u4", ("rows", "columns"), l1b_to_quality(flags), None,
               long_name="Classification and quality flags",
               flag_masks=np.array([1 << b for _, b in QUALITY_FLAGS], np.uint32),
               flag_meanings=" ".join(n for n, _ in QUALITY_FLAGS))


def _write_tie_points(nc: NcWriter, tie_points: Mapping[str, np.ndarray]) -> None:
    """``tie_geo_coordinates.nc``, ``tie_geometries.nc`` (azimuths on (-180, 180]) and
    ``tie_meteo.nc`` (ozone in kg m-2) from N1-named physical tie points."""
    tshape = np.shape(tie_points["latitude"])
    tdims = {"tie_rows": tshape[0], "tie_columns": tshape[1]}
    tie = ("tie_rows", "tie_columns")

    def get(key: str) -> np.ndarray:
        return np.asarray(tie_points.get(key, np.zeros(tshape)), np.float64)

    with nc.dataset(TIE_GEO_FILE, tdims) as ds:
        write_geo(nc.var, ds, tie, {"longitude": get("longitude"), "latitude": get("latitude"),
                                     "altitude": get("dem_alt")}, corrected=False)
    write_tie_angles_and_meteo(nc, tdims, get, ANGLE_LONG_NAMES,
                               "Horizontal wind vector at 10 m (east, north)", fills=False)


#: the tie-point angles (variable, N1 tie-point name) and their long names in MERIS's files
ANGLE_LONG_NAMES = {("SZA", "sun_zenith"): "Sun zenith angle",
                    ("SAA", "sun_azimuth"): "Sun azimuth angle",
                    ("OZA", "view_zenith"): "Observation zenith angle",
                    ("OAA", "view_azimuth"): "Observation azimuth angle"}


def write_tie_angles_and_meteo(nc: NcWriter, tdims: dict[str, int],
                               get: Callable[[str], np.ndarray],
                               long_names: Mapping[tuple[str, str], str], wind_long_name: str,
                               fills: bool) -> None:
    """``tie_geometries.nc`` (zeniths uint32, azimuths int32 on (-180, 180], x 1e-6 deg;
    ``fills``: with the integer fill values, as OLCI's files carry them) and ``tie_meteo.nc``
    (ozone in kg m-2) from the N1-named physical tie points ``get(name)`` gives; the long
    names as the sensor's files word them."""
    tie = ("tie_rows", "tie_columns")
    with nc.dataset(TIE_GEOMETRY_FILE, tdims) as ds:
        for (name, key), long in long_names.items():
            zenith = name[1] == "Z"
            deg = get(key) if zenith else 180.0 - (180.0 - get(key)) % 360.0
            fill = (np.uint32(4294967295) if zenith else np.int32(-2147483648)) if fills else None
            nc.var(ds, name, "u4" if zenith else "i4", tie, np.round(deg * 1e6), fill,
                   scale_factor=1e-6, units="degrees", long_name=long,
                   standard_name=("solar_" if name[0] == "S" else "sensor_")
                   + ("zenith_angle" if zenith else "azimuth_angle"))
    with nc.dataset(TIE_METEO_FILE, {**tdims, "wind_vectors": 2}) as ds:
        wind = np.stack([get("zonal_wind"), get("merid_wind")], axis=-1)
        nc.var(ds, "horizontal_wind", "f4", (*tie, "wind_vectors"), wind, None,
               units="m s-1", long_name=wind_long_name)
        for name, key, factor, unit in (("sea_level_pressure", "atm_pressure", 1.0, "hPa"),
                                        ("total_ozone", "ozone", DOBSON_KG_M2, "kg.m-2"),
                                        ("humidity", "rel_humidity", 1.0, "%")):
            nc.var(ds, name, "f4", tie, get(key) * factor, None, units=unit,
                   long_name=name.replace("_", " ").capitalize())


def write_geo(var, ds, dims: tuple[str, str], geo: dict[str, np.ndarray],
               corrected: bool = True) -> None:
    """Latitude, longitude (int32 x 1e-6) and altitude: the per-pixel ones terrain-corrected
    ("DEM corrected latitude"), the tie points' on the ellipsoid (SNAP: "Latitude"); the
    altitude is the DEM's in both ("DEM corrected altitude", SNAP's TP_altitude)."""
    for key, std, unit in (("latitude", "latitude", "degrees_north"),
                           ("longitude", "longitude", "degrees_east")):
        values = np.asarray(geo[key], np.float64)
        if key == "longitude":
            values = (values + 180.0) % 360.0 - 180.0
        limit = 90_000_000 if key == "latitude" else 180_000_000
        var(ds, key, "i4", dims, np.round(values * 1e6), np.int32(INT32_FILL),
            scale_factor=1e-6, add_offset=0.0, units=unit, standard_name=std,
            long_name=f"DEM corrected {key}" if corrected else key.capitalize(),
            valid_min=np.int32(-limit),
            valid_max=np.int32(limit))
    var(ds, "altitude", "i2", dims, np.round(np.asarray(geo["altitude"], np.float64)),
        np.int16(INT16_FILL), units="m", standard_name="height_above_reference_ellipsoid",
        long_name="DEM corrected altitude")


#: what SNAP, ocssw and ACOLITE recognise a MERIS 4th-reprocessing Level 1 product by: the
#: contentUnit text (ocssw: "MERIS", "ENVISAT", "Level 1"), the platform and instrument family
#: names (ACOLITE), the band descriptions (SNAP)
CONTENT_TEXT = "ENVISAT MERIS Level 1 Product"
PLATFORM = "Envisat"
INSTRUMENT = "MEdium Resolution Imaging Spectrometer"


def _manifest(name: str, resolution: str, height: int, width: int, df: int, dj: int,
              t0: np.datetime64, duration_us: int) -> str:
    """The XFDU manifest: the content unit, acquisition period, platform and instrument, the
    product information (name, type, image size, tie-point sampling, band descriptions) and
    the data objects (MER4RP-PFS-001-ACR; what SNAP's, ocssw's and ACOLITE's readers read)."""
    files = [MANIFEST, *required_files()[1:], TIE_METEO_FILE]
    stop = t0 + np.timedelta64(int(duration_us), "us")
    objects = "\n".join(
        f'    <dataObject ID="{Path(f).stem}Data"><byteStream mimeType="application/x-netcdf">'
        f'<fileLocation locatorType="URL" href="./{f}"/></byteStream></dataObject>'
        for f in files[1:])
    pointers = "\n".join(
        f'      <xfdu:contentUnit ID="{Path(f).stem}Unit" unitType="Measurement Data Unit">'
        f'<dataObjectPointer dataObjectID="{Path(f).stem}Data"/></xfdu:contentUnit>'
        for f in files[1:])
    bands = "\n".join(
        f'          <envisat:band name="M{b:02d}"><envisat:centralWavelength>{w:.3f}'
        f'</envisat:centralWavelength><envisat:bandWidth>{bw:.3f}</envisat:bandWidth>'
        f'</envisat:band>'
        for b, (w, bw) in enumerate(zip(APPENDIX_A_WAVELENGTHS, APPENDIX_A_BANDWIDTHS,
                                        strict=True), start=1))
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<xfdu:XFDU xmlns:xfdu="urn:ccsds:schema:xfdu:1" xmlns:sentinel-safe="http://www.esa.int/safe/sentinel/1.1" xmlns:envisat="http://www.esa.int/safe/sentinel/envisat/1.0" version="esa/safe/sentinel/1.0/envisat/meris/level1">
  <informationPackageMap>
    <xfdu:contentUnit ID="packageUnit" unitType="SAFE Archive Information Package" textInfo="{CONTENT_TEXT}" dmdID="acquisitionPeriod platform generalProductInformation merisProductInformation">
{pointers}
    </xfdu:contentUnit>
  </informationPackageMap>
  <metadataSection>
    <metadataObject ID="acquisitionPeriod" classification="DESCRIPTION" category="DMD"><metadataWrap mimeType="text/xml" vocabularyName="Sentinel-SAFE" textInfo="Acquisition Period"><xmlData><sentinel-safe:acquisitionPeriod>
      <sentinel-safe:startTime>{t0}Z</sentinel-safe:startTime>
      <sentinel-safe:stopTime>{stop}Z</sentinel-safe:stopTime>
    </sentinel-safe:acquisitionPeriod></xmlData></metadataWrap></metadataObject>
    <metadataObject ID="platform" classification="DESCRIPTION" category="DMD"><metadataWrap mimeType="text/xml" vocabularyName="Sentinel-SAFE" textInfo="Platform Description"><xmlData><sentinel-safe:platform>
      <sentinel-safe:nssdcIdentifier>2002-009A</sentinel-safe:nssdcIdentifier>
      <sentinel-safe:familyName>{PLATFORM}</sentinel-safe:familyName>
      <sentinel-safe:instrument><sentinel-safe:familyName abbreviation="MERIS">{INSTRUMENT}</sentinel-safe:familyName></sentinel-safe:instrument>
    </sentinel-safe:platform></xmlData></metadataWrap></metadataObject>
    <metadataObject ID="generalProductInformation" classification="DESCRIPTION" category="DMD"><metadataWrap mimeType="text/xml" vocabularyName="Envisat" textInfo="General Product Information"><xmlData>
      <envisat:generalProductInformation><envisat:productName>{name}.SEN3</envisat:productName>
      <envisat:productType>ME_1_{resolution}G___</envisat:productType>
      </envisat:generalProductInformation></xmlData></metadataWrap></metadataObject>
    <metadataObject ID="merisProductInformation" classification="DESCRIPTION" category="DMD"><metadataWrap mimeType="text/xml" vocabularyName="Envisat" textInfo="MERIS Product Information"><xmlData>
      <envisat:merisProductInformation>
        <envisat:imageSize><envisat:rows>{height}</envisat:rows><envisat:columns>{width}</envisat:columns></envisat:imageSize>
        <envisat:samplingParameters><envisat:rowsPerTiePoint>{df}</envisat:rowsPerTiePoint><envisat:columnsPerTiePoint>{dj}</envisat:columnsPerTiePoint></envisat:samplingParameters>
        <envisat:bandDescriptions>
{bands}
        </envisat:bandDescriptions>
      </envisat:merisProductInformation></xmlData></metadataWrap></metadataObject>
  </metadataSection>
  <dataObjectSection>
{objects}
  </dataObjectSection>
</xfdu:XFDU>
"""  # noqa: E501

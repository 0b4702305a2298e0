"""A ``.SEN3`` written from the documented facts of ESA's product
``ENV_ME_1_RRG____20120406T085654`` (as SNAP's Sentinel-3 reader test describes it, SNAP's
DDDB and ocssw's ``l1_safe``), with netCDF4 directly: not with our
writer, so that the reader is checked against the facts, not against ourselves.

Facts used: 1121 columns x 1617 rows, tie points every 16 x 16 (71 x 102); columns run west to
east on the descending pass (pixel x=483, y=869 at 35.920023 N 22.175995 E; x=832, y=1049 at
33.253976 N 25.440486 E); OAA about 102 deg in the western half; radiances uint16 with
``_FillValue`` 65535 and a per-band ``scale_factor`` (M01: 620.943 / 65535, SNAP's no-data value);
per-pixel lat/lon int32 x 1e-6 "DEM corrected latitude"; the full ``quality_flags`` coding
(uint32, ``flag_masks``/``flag_meanings``); tie-point meteo with total columnar water vapour;
dimensions rows/columns, tie_rows/tie_columns, bands/detectors. The geolocation between the two
known pixels is an affine field through them (a descending track heading SSW), the radiances a
smooth field: only the facts above are claims about the real product.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

NAME = ("ENV_ME_1_RRG____20120406T085654_20120406T094052_________________2518_113_122______"
        "ACR_R_NT____.SEN3")
WIDTH, HEIGHT, STEP = 1121, 1617, 16
#: SNAP's pixel (x, y) -> (lat, lon), file column order
KNOWN = {(483, 869): (35.920023, 22.175995), (832, 1049): (33.253976, 25.440486)}
#: M01 scale factor: SNAP's no-data value 620.943 is 65535 x this
M01_SCALE = 620.943 / 65535
#: ESA's quality_flags coding
CODING = [("land", 31), ("coastline", 30), ("fresh_inland_water", 29), ("tidal_region", 28),
          ("bright", 27), ("invalid", 25), ("cosmetic", 24), ("duplicated", 23),
          ("sun_glint_risk", 22), ("dubious", 21)] + [
          (f"saturated_M{b:02d}", 21 - b) for b in range(1, 22)]
#: file-order pixels with special content: (x, y)
FILL_PIXEL = (700, 900)       # M01 and M07 fill (65535)
SATURATED_PIXEL = (300, 400)  # land, saturated_M07

# the affine field through the two known pixels: lat/lon per column (a) and per row (b)
_B_ROW, _A_ROW = -0.0105, -0.0028


def _field() -> tuple[float, float, float, float, float, float]:
    (x1, y1), (x2, y2) = KNOWN
    (la1, lo1), (la2, lo2) = KNOWN[(x1, y1)], KNOWN[(x2, y2)]
    b_col = (la2 - la1 - _B_ROW * (y2 - y1)) / (x2 - x1)
    a_col = (lo2 - lo1 - _A_ROW * (y2 - y1)) / (x2 - x1)
    lat0 = la1 - b_col * x1 - _B_ROW * y1
    lon0 = lo1 - a_col * x1 - _A_ROW * y1
    return lat0, b_col, _B_ROW, lon0, a_col, _A_ROW


def geolocation(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lat, lon) of file-order pixel (x, y)."""
    lat0, bc, br, lon0, ac, ar = _field()
    return lat0 + bc * x + br * y, lon0 + ac * x + ar * y


def _nc(path: Path, dims: dict[str, int], product: str):
    import netCDF4

    ds = netCDF4.Dataset(path, "w", format="NETCDF4")
    ds.setncatts({"title": "MERIS Level 1b Product", "product_name": product,
                  "absolute_orbit_number": np.uint32(52627), "institution": "ACR",
                  "ac_subsampling_factor": np.uint32(STEP),
                  "al_subsampling_factor": np.uint32(STEP),
                  "start_time": "2012-04-06T08:56:54.000000Z",
                  "stop_time": "2012-04-06T09:40:52.000000Z"})
    for d, n in dims.items():
        ds.createDimension(d, n)
    return ds


def _var(ds, name, dtype, dims, data, fill=None, **attrs):
    v = ds.createVariable(name, dtype, dims, zlib=True, complevel=1, fill_value=fill)
    v.set_auto_maskandscale(False)
    v.setncatts(attrs)
    v[...] = data
    return v


def write_real_like(target: Path, *, name: str = NAME, manifest_type: str | None = "ME_1_RRG___",
                    meteo: tuple[str, ...] = ("horizontal_wind", "sea_level_pressure",
                                              "total_ozone", "humidity",
                                              "total_columnar_water_vapour")) -> Path:
    """Write the product under ``target`` (a directory); returns its path."""
    d = target / name
    d.mkdir(parents=True)
    img = {"rows": HEIGHT, "columns": WIDTH}
    x = np.arange(WIDTH, dtype=np.float64)[None, :]
    y = np.arange(HEIGHT, dtype=np.float64)[:, None]
    lat, lon = geolocation(x, y)
    fx, fy = FILL_PIXEL
    sx, sy = SATURATED_PIXEL
    for b in range(1, 16):
        scale = M01_SCALE if b == 1 else 0.01 * (1 + b / 30)
        radiance = 40.0 + 20.0 * np.sin(x / 97.0) * np.cos(y / 131.0) + b
        counts = np.round(radiance / scale).astype(np.uint16)
        if b in (1, 7):
            counts[fy, fx] = 65535
        with _nc(d / f"M{b:02d}_radiance.nc", img, name) as ds:
            _var(ds, f"M{b:02d}_radiance", "u2", ("rows", "columns"), counts, np.uint16(65535),
                 scale_factor=np.float32(scale), add_offset=np.float32(0.0),
                 units="mW.m-2.sr-1.nm-1",
                 long_name=f"TOA radiance for MERIS acquisition band M{b:02d}")
    with _nc(d / "geo_coordinates.nc", img, name) as ds:
        _var(ds, "latitude", "i4", ("rows", "columns"), np.round(lat * 1e6).astype(np.int32),
             scale_factor=1e-6, units="degrees_north", long_name="DEM corrected latitude")
        _var(ds, "longitude", "i4", ("rows", "columns"), np.round(lon * 1e6).astype(np.int32),
             scale_factor=1e-6, units="degrees_east", long_name="DEM corrected longitude")
        _var(ds, "altitude", "i2", ("rows", "columns"),
             np.zeros((HEIGHT, WIDTH), np.int16), units="m",
             long_name="DEM corrected altitude")
    quality = np.full((HEIGHT, WIDTH), np.uint32(1 << 31))
    quality[sy, sx] |= np.uint32(1 << (21 - 7))
    quality[fy, fx] |= np.uint32(1 << 25)
    with _nc(d / "qualityFlags.nc", img, name) as ds:
        _var(ds, "quality_flags", "u4", ("rows", "columns"), quality,
             long_name="Classification and quality flags",
             flag_masks=np.array([1 << bit for _, bit in CODING], np.uint32),
             flag_meanings=" ".join(n for n, _ in CODING))
    with _nc(d / "instrument_data.nc", {**img, "bands": 15, "detectors": 925}, name) as ds:
        det = np.broadcast_to(np.arange(WIDTH, dtype=np.int16)[None, :] % 925, (HEIGHT, WIDTH))
        _var(ds, "detector_index", "i2", ("rows", "columns"), det, np.int16(-1))
        _var(ds, "lambda0", "f4", ("bands", "detectors"),
             np.repeat(np.linspace(412.5, 900.0, 15, dtype=np.float32)[:, None], 925, 1))
        _var(ds, "FWHM", "f4", ("bands", "detectors"), np.full((15, 925), 10.0, np.float32))
        _var(ds, "solar_flux", "f4", ("bands", "detectors"),
             np.full((15, 925), 1500.0, np.float32))
    with _nc(d / "time_coordinates.nc", {"rows": HEIGHT}, name) as ds:
        t0 = 386931414_000_000  # 2012-04-06T08:56:54 in microseconds since 2000-01-01
        _var(ds, "time_stamp", "i8", ("rows",), t0 + np.arange(HEIGHT) * 176_000,
             units="microseconds since 2000-01-01 00:00:00 ")
    tdims = {"tie_rows": (HEIGHT - 1) // STEP + 1, "tie_columns": (WIDTH - 1) // STEP + 1}
    tie = ("tie_rows", "tie_columns")
    tx = np.arange(tdims["tie_columns"], dtype=np.float64)[None, :] * STEP
    ty = np.arange(tdims["tie_rows"], dtype=np.float64)[:, None] * STEP
    tlat, tlon = geolocation(tx, ty)
    tshape = tlat.shape
    with _nc(d / "tie_geo_coordinates.nc", tdims, name) as ds:
        _var(ds, "latitude", "i4", tie, np.round(tlat * 1e6).astype(np.int32), scale_factor=1e-6,
             units="degrees_north", long_name="Latitude")
        _var(ds, "longitude", "i4", tie, np.round(tlon * 1e6).astype(np.int32),
             scale_factor=1e-6, units="degrees_east", long_name="Longitude")
        _var(ds, "altitude", "i2", tie, np.zeros(tshape, np.int16), units="m",
             long_name="DEM corrected altitude")
    # nadir near column 560: the western half views the satellite towards the east (OAA ~102)
    west = tx < 560
    oza = np.abs(tx - 560) / 560 * 40.0 + 0 * ty
    oaa = np.where(west, 102.0, -78.0) + 0 * ty
    with _nc(d / "tie_geometries.nc", tdims, name) as ds:
        for n, v, dt in (("SZA", 35.0 + 0 * oza, "u4"), ("OZA", oza, "u4"),
                         ("SAA", 140.0 + 0 * oza, "i4"), ("OAA", oaa, "i4")):
            _var(ds, n, dt, tie, np.round(v * 1e6).astype({"u4": np.uint32, "i4": np.int32}[dt]),
                 scale_factor=1e-6, units="degrees")
    with _nc(d / "tie_meteo.nc", {**tdims, "wind_vectors": 2, "tie_pressure_levels": 20},
             name) as ds:
        if "horizontal_wind" in meteo:
            _var(ds, "horizontal_wind", "f4", (*tie, "wind_vectors"),
                 np.stack([np.full(tshape, 3.0), np.full(tshape, -1.0)], -1))
        for n, value in (("sea_level_pressure", 1013.0), ("total_ozone", 0.0068),
                         ("humidity", 55.0), ("total_columnar_water_vapour", 12.0)):
            if n in meteo:
                _var(ds, n, "f4", tie, np.full(tshape, value, np.float32))
        _var(ds, "atmospheric_temperature_profile", "f4", (*tie, "tie_pressure_levels"),
             np.full((*tshape, 20), 280.0, np.float32))
    type_element = (f"<envisat:productType>{manifest_type}</envisat:productType>"
                    if manifest_type else "")
    (d / "xfdumanifest.xml").write_text(f"""<?xml version="1.0" encoding="UTF-8"?>
<xfdu:XFDU xmlns:xfdu="urn:ccsds:schema:xfdu:1" xmlns:envisat="http://www.esa.int/safe/sentinel/envisat/1.0">
  <informationPackageMap><xfdu:contentUnit textInfo="ENVISAT MERIS Level 1 Product"/></informationPackageMap>
  <metadataSection><metadataObject ID="generalProductInformation"><metadataWrap><xmlData>
    <envisat:generalProductInformation><envisat:productName>{name}</envisat:productName>
    {type_element}</envisat:generalProductInformation></xmlData></metadataWrap></metadataObject>
  </metadataSection>
</xfdu:XFDU>
""")  # noqa: E501
    return d

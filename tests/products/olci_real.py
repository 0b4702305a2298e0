"""OLCI Level 1B products written from the documented facts of ESA's products, with netCDF4
directly: not with our writer, so that the reader is checked against the facts, not against
ourselves.

Facts used (the *Sentinel-3 OLCI Product Data Format Specification*, the manifests of
``S3A_OL_1_EFR____20240526`` and ``S3B_OL_1_ERR____20210831`` in public test resources, SNAP's
OLCI reader tests): member names ``OaNN_radiance.nc``, ``geo_coordinates.nc``,
``tie_geo_coordinates.nc``, ``tie_geometries.nc``, ``tie_meteo.nc``, ``instrument_data.nc``,
``qualityFlags.nc``, ``time_coordinates.nc`` (EFR: ``removed_pixels.nc``); dimensions
rows/columns, tie_rows/tie_columns, bands/detectors; EFR 4865 columns, ERR 1217, tie points on
every row and every 64 or 16 columns (77 tie columns), no tie-point altitude; radiances uint16 with
``_FillValue`` 65535 and their own ``scale_factor`` (Oa01 0.013946459628641605), no
``add_offset``; per-pixel latitude/longitude int32 x 1e-6 "DEM corrected", altitude int16;
angles SZA/OZA uint32 and SAA/OAA int32 x 1e-6; ``quality_flags`` uint32 with
``flag_masks``/``flag_meanings`` (per-band saturation before baseline 2.24); columns west to east
on the descending pass, OZA 56.6 deg at the west edge and 24.3 at the east edge; SNAP's pixels
EFR (x 2098, y 2199) -> 25.259381 N 137.931706 E, (3612, 2654) -> 23.302191 N 141.588296 E, ERR
(524, 8037) -> -6.576821 N 41.195532 E.

To stay small, a product holds the rows up to its last known pixel, and its variables are
chunked: the per-pixel geolocation is written on the rows around the known pixels only (the
others are the fill value), the other bands than Oa01 not at all (fill). The geolocation between
known pixels is an affine field through them; only the facts above are claims about the real
products. The 2.24 baseline's ``saturated``/``partially_saturated`` bits are not among the facts
at hand: the ERR product puts them on bits 0 and 1, not where our writer's table has them, so
that the reader is seen to take the file's coding.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

EFR_NAME = ("S3A_OL_1_EFR____20240526T011231_20240526T011531_20240527T083340_0179_112_302_"
            "2160_PS1_O_NT_004.SEN3")
ERR_NAME = ("S3B_OL_1_ERR____20210831T064316_20210831T072743_20210901T114422_2667_056_234_"
            "_____LN1_O_NT_002.SEN3")
EFR_WIDTH, ERR_WIDTH = 4865, 1217
#: rows written: up to the last known pixel
EFR_ROWS, ERR_ROWS = 2660, 8040
#: SNAP's pixel (x, y) in the file's column order -> (lat, lon)
EFR_KNOWN = {(2098, 2199): (25.259381, 137.931706), (3612, 2654): (23.302191, 141.588296)}
ERR_KNOWN = {(524, 8037): (-6.576821, 41.195532)}
OA01_SCALE = 0.013946459628641605
#: OZA at the west (tie column 0) and east (last tie column) edges
OZA_WEST, OZA_EAST = 56.6, 24.3
COMMON = [("land", 31), ("coastline", 30), ("fresh_inland_water", 29), ("tidal_region", 28),
          ("bright", 27), ("straylight_risk", 26), ("invalid", 25), ("cosmetic", 24),
          ("duplicated", 23), ("sun_glint_risk", 22), ("dubious", 21)]
#: quality_flags codings: before 2.24 (per band), since 2.24 (this fixture's bits)
CODING_PER_BAND = COMMON + [(f"saturated_Oa{b:02d}", 21 - b) for b in range(1, 22)]
CODING_2_24 = COMMON + [("saturated", 0), ("partially_saturated", 1)]
#: file-order pixels with special content (x, y)
EFR_FILL = (2100, 2199)          # Oa01 fill
EFR_SATURATED = (2097, 2199)     # land, saturated_Oa08
ERR_FILL = (525, 8037)
ERR_SATURATED = (523, 8037)      # bright, saturated (2.24)


def _affine(known: dict, row_step: float, lon_row: float, width: int):
    """(lat, lon) of file pixel (x, y): an affine field through the known pixels (a descending
    track: latitude falls with the row, longitude grows with the column)."""
    (x1, y1), (la1, lo1) = next(iter(known.items()))
    if len(known) > 1:
        (x2, y2), (la2, lo2) = list(known.items())[1]
        lat_col = (la2 - la1 - row_step * (y2 - y1)) / (x2 - x1)
        lon_col = (lo2 - lo1 - lon_row * (y2 - y1)) / (x2 - x1)
    else:  # ERR: 1080 m columns
        lat_col, lon_col = -0.0017, 1080.0 / (111_320.0 * np.cos(np.radians(la1)))

    def at(x, y):
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        return (la1 + lat_col * (x - x1) + row_step * (y - y1),
                lo1 + lon_col * (x - x1) + lon_row * (y - y1))
    return at


EFR_FIELD = _affine(EFR_KNOWN, -0.00264, -0.00178, EFR_WIDTH)
ERR_FIELD = _affine(ERR_KNOWN, -0.01058, -0.0067, ERR_WIDTH)


def _nc(path: Path, dims: dict[str, int | None], name: str, dj: int):
    import netCDF4

    ds = netCDF4.Dataset(path, "w", format="NETCDF4")
    ds.setncatts({"Conventions": "CF-1.6", "title": "OLCI Level 1b Product",
                  "product_name": name, "institution": "PS1", "source": "IPF-OL-1 06.17",
                  "absolute_orbit_number": np.uint32(42722),
                  "ac_subsampling_factor": np.uint16(dj), "al_subsampling_factor": np.uint16(1)})
    for d, n in dims.items():
        ds.createDimension(d, n)
    return ds


def _var(ds, name, dtype, dims, data=None, fill=None, chunks=None, **attrs):
    v = ds.createVariable(name, dtype, dims, zlib=True, complevel=1, fill_value=fill,
                          chunksizes=chunks)
    v.set_auto_maskandscale(False)
    v.setncatts(attrs)
    if data is not None:
        v[...] = data
    return v


def write_product(target: Path, kind: str = "EFR", *, name: str | None = None,
                  manifest_type: str | None = None) -> Path:
    """The ``EFR`` or ``ERR`` product (directory) in ``target``; ``name``/``manifest_type``
    replace the product name and the manifest's ``productType``."""
    efr = kind == "EFR"
    width, rows = (EFR_WIDTH, EFR_ROWS) if efr else (ERR_WIDTH, ERR_ROWS)
    dj = 64 if efr else 16
    known, field = (EFR_KNOWN, EFR_FIELD) if efr else (ERR_KNOWN, ERR_FIELD)
    name = name or (EFR_NAME if efr else ERR_NAME)
    coding = CODING_PER_BAND if efr else CODING_2_24
    fill_px, sat_px = (EFR_FILL, EFR_SATURATED) if efr else (ERR_FILL, ERR_SATURATED)
    d = target / name
    d.mkdir(parents=True)
    img = {"rows": rows, "columns": width}
    chunks = (min(rows, 256), min(width, 1024))
    written = sorted({y + k for (_, y) in known for k in (-1, 0, 1)})

    for b in range(1, 22):
        with _nc(d / f"Oa{b:02d}_radiance.nc", img, name, dj) as ds:
            data = None
            if b == 1:
                data = np.full((rows, width), 3000, np.uint16)
                data[fill_px[1], fill_px[0]] = 65535
            _var(ds, f"Oa{b:02d}_radiance", "u2", ("rows", "columns"), data,
                 np.uint16(65535), chunks, scale_factor=np.float32(OA01_SCALE * (1 + b / 100)
                                                                   if b > 1 else OA01_SCALE),
                 units="mW.m-2.sr-1.nm-1", standard_name="toa_upwelling_spectral_radiance",
                 long_name=f"TOA radiance for OLCI acquisition band Oa{b:02d}",
                 valid_max=np.uint16(65534), valid_min=np.uint16(0))
    with _nc(d / "geo_coordinates.nc", img, name, dj) as ds:
        lat = _var(ds, "latitude", "i4", ("rows", "columns"), None, np.int32(-2147483648),
                   chunks, scale_factor=1e-6, units="degrees_north", standard_name="latitude",
                   long_name="DEM corrected latitude", valid_min=np.int32(-90000000),
                   valid_max=np.int32(90000000))
        lon = _var(ds, "longitude", "i4", ("rows", "columns"), None, np.int32(-2147483648),
                   chunks, scale_factor=1e-6, units="degrees_east", standard_name="longitude",
                   long_name="DEM corrected longitude", valid_min=np.int32(-180000000),
                   valid_max=np.int32(180000000))
        x = np.arange(width)
        for y in written:
            la, lo = field(x, np.full(width, y))
            for (kx, ky), (kla, klo) in known.items():
                if ky == y:
                    la[kx], lo[kx] = kla, klo
            lat[y, :] = np.round(la * 1e6).astype(np.int32)
            lon[y, :] = np.round(lo * 1e6).astype(np.int32)
        _var(ds, "altitude", "i2", ("rows", "columns"), np.zeros((rows, width), np.int16),
             np.int16(-32768), chunks, units="m", standard_name="height_above_reference_"
             "ellipsoid", long_name="DEM corrected altitude")
    t = {"tie_rows": rows, "tie_columns": (width - 1) // dj + 1}
    tcols = np.arange(t["tie_columns"]) * dj
    yy, xx = np.meshgrid(np.arange(rows), tcols, indexing="ij")
    with _nc(d / "tie_geo_coordinates.nc", t, name, dj) as ds:
        la, lo = field(xx - 0.5, yy)  # ESA's tie points: half a pixel towards column 0
        _var(ds, "latitude", "i4", ("tie_rows", "tie_columns"), np.round(la * 1e6),
             np.int32(-2147483648), scale_factor=1e-6, units="degrees_north",
             long_name="Latitude")
        _var(ds, "longitude", "i4", ("tie_rows", "tie_columns"), np.round(lo * 1e6),
             np.int32(-2147483648), scale_factor=1e-6, units="degrees_east",
             long_name="Longitude")
    with _nc(d / "tie_geometries.nc", t, name, dj) as ds:
        x0 = (width - 1) * np.tan(np.radians(OZA_WEST)) / (
            np.tan(np.radians(OZA_WEST)) + np.tan(np.radians(OZA_EAST)))
        s = np.tan(np.radians(OZA_WEST)) / x0
        oza = np.degrees(np.arctan(np.abs(xx - x0) * s))
        oaa = np.where(xx < x0, 101.5, -78.5)
        for vn, val, dt, fill in (("SZA", np.full(xx.shape, 35.0), "u4", np.uint32(4294967295)),
                                  ("SAA", np.full(xx.shape, 140.0), "i4", np.int32(-2147483648)),
                                  ("OZA", oza, "u4", np.uint32(4294967295)),
                                  ("OAA", oaa, "i4", np.int32(-2147483648))):
            _var(ds, vn, dt, ("tie_rows", "tie_columns"), np.round(val * 1e6), fill,
                 scale_factor=1e-6, units="degrees")
    with _nc(d / "tie_meteo.nc", {**t, "wind_vectors": 2, "tie_pressure_levels": 25},
             name, dj) as ds:
        _var(ds, "horizontal_wind", "f4", ("tie_rows", "tie_columns", "wind_vectors"),
             np.full((rows, t["tie_columns"], 2), 3.0, np.float32), units="m s-1")
        _var(ds, "sea_level_pressure", "f4", ("tie_rows", "tie_columns"),
             np.full(xx.shape, 1013.0, np.float32), units="hPa")
        _var(ds, "total_ozone", "f4", ("tie_rows", "tie_columns"),
             np.full(xx.shape, 0.0064, np.float32), units="kg.m-2")
        _var(ds, "humidity", "f4", ("tie_rows", "tie_columns", "tie_pressure_levels"),
             None, units="%")
    with _nc(d / "instrument_data.nc", {**img, "bands": 21, "detectors": 3700}, name, dj) as ds:
        _var(ds, "detector_index", "i2", ("rows", "columns"),
             np.broadcast_to(np.arange(width, dtype=np.int16) % 3700, (rows, width)),
             np.int16(-1), chunks, long_name="Detector index")
        _var(ds, "frame_offset", "i1", ("rows", "columns"), None, np.int8(-128), chunks)
        for vn, val in (("lambda0", 400.0), ("FWHM", 10.0), ("solar_flux", 1500.0)):
            _var(ds, vn, "f4", ("bands", "detectors"), np.full((21, 3700), val, np.float32),
                 np.float32(-1.0))
    with _nc(d / "qualityFlags.nc", img, name, dj) as ds:
        q = np.zeros((rows, width), np.uint32)
        masks = dict(coding)
        x, y = sat_px
        q[y, x] = (1 << masks["land"]) | (1 << masks["saturated_Oa08" if efr else "saturated"])
        q[y, x + 5] = 1 << masks["bright"]
        q[y, x + 6] = 1 << masks["invalid"]
        _var(ds, "quality_flags", "u4", ("rows", "columns"), q, np.uint32(4294967295), chunks,
             flag_masks=np.array([1 << bit for _, bit in coding], np.uint32),
             flag_meanings=" ".join(n for n, _ in coding))
    with _nc(d / "time_coordinates.nc", {"rows": rows}, name, dj) as ds:
        t0 = 769_914_751_000_000 if efr else 683_620_996_000_000
        step = 44_000 if efr else 176_000
        _var(ds, "time_stamp", "i8", ("rows",), t0 + step * np.arange(rows, dtype=np.int64),
             units="microseconds since 2000-01-01 00:00:00", standard_name="time")
    if efr:
        with _nc(d / "removed_pixels.nc", {"removed_pixels": 12}, name, dj) as ds:
            _var(ds, "detector_index", "i2", ("removed_pixels",), np.zeros(12, np.int16))
    ptype = manifest_type if manifest_type is not None else f"OL_1_{kind}___"
    (d / "xfdumanifest.xml").write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n<xfdu:XFDU xmlns:xfdu="urn:ccsds:schema:'
        'xfdu:1" xmlns:sentinel3="http://www.esa.int/safe/sentinel/sentinel-3/1.0" '
        'xmlns:olci="http://www.esa.int/safe/sentinel/sentinel-3/olci/1.0"><metadataSection>'
        f'<sentinel3:generalProductInformation><sentinel3:productName>{name}'
        f'</sentinel3:productName><sentinel3:productType>{ptype}</sentinel3:productType>'
        '</sentinel3:generalProductInformation><olci:olciProductInformation>'
        f'<olci:samplingParameters><olci:rowsPerTiePoint>1</olci:rowsPerTiePoint>'
        f'<olci:columnsPerTiePoint>{dj}</olci:columnsPerTiePoint></olci:samplingParameters>'
        '</olci:olciProductInformation></metadataSection></xfdu:XFDU>\n')
    return d

"""Small synthetic MERIS products for the orthorectification tests (no simulator needed).

Band 1 holds the product line of each pixel and band 2 its column, so a nearest-neighbour
mapping shows the antecedent it used; the tie points come from ``analytic_swath``.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np

from napari_meris_ortho.geometry.tiepoints import analytic_swath
from napari_meris_ortho.products.n1 import write_product


def terrain(lon, lat):
    """Smooth mountains (300..2700 m) used for the test DEM."""
    lon = np.asarray(lon, dtype=np.float64)
    lat = np.asarray(lat, dtype=np.float64)
    return 1500.0 + 1200.0 * np.sin(np.radians(lon) * 40.0) * np.cos(np.radians(lat) * 30.0)


def make_product(path: Path, height: int = 200, width: int = 513, lon0: float = 11.0,
                 nadir_col: float = 0.0, first_line_time: dt.datetime | None = None) -> Path:
    """An FR product on the analytic swath; bands 1/2 = line/column, flags = (line+col) % 256."""
    g = analytic_swath(height=height, width=width, lon0=lon0, nadir_col=nadir_col)
    tp = dict(latitude=g.latitude, longitude=(g.longitude + 180.0) % 360.0 - 180.0,
              view_zenith=g.view_zenith, view_azimuth=g.view_azimuth,
              dem_alt=np.round(g.dem_alt))
    line = np.repeat(np.arange(height, dtype=np.uint16)[:, None], width, axis=1)
    col = np.repeat(np.arange(width, dtype=np.uint16)[None, :], height, axis=0)
    counts = [line, col] + [np.full((height, width), 100 * b, np.uint16) for b in range(3, 16)]
    flags = ((line.astype(np.int64) + col) % 256).astype(np.uint8)
    return write_product(path, product_type="MER_FR__1P", tie_points=tp, counts=counts,
                         flags=flags, detector_index=col.astype(np.int16),
                         first_line_time=first_line_time or dt.datetime(2003, 9, 21, 9, 23))


def make_dem(path: Path, lon0: float, lat0: float, lon1: float, lat1: float,
             res: float = 0.002) -> Path:
    """A GeoTIFF DEM (EPSG:4326) of ``terrain`` over the given box."""
    import rasterio
    from rasterio.transform import from_origin

    w = int(round((lon1 - lon0) / res))
    h = int(round((lat1 - lat0) / res))
    lon = lon0 + (np.arange(w) + 0.5) * res
    lat = lat1 - (np.arange(h) + 0.5) * res
    z = terrain(lon[None, :], lat[:, None]).astype(np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=w, height=h, count=1, dtype="float32",
                       crs="EPSG:4326", transform=from_origin(lon0, lat1, res, res),
                       nodata=-9999.0) as ds:
        ds.write(z, 1)
    return path


#: a 128 x 193 piece of fr-small (20-30 deg view zenith, up to ~4 km terrain) whose DEM is
#: also exported as Copernicus GLO-90 tiles with heights above the EGM96 geoid
COPERNICUS_SCENE = {"base": "fr-small", "lines": 128, "columns": 193,
                    "exports": {"copernicus": True, "getasse30": False, "getasse30_beam": False,
                                "srtm30": False, "geotiff_utm": False, "reference": False}}

"""Fixtures of the napari tests: a tiny MERIS FR product and a DEM GeoTIFF over it."""

from __future__ import annotations

import datetime as dt
import os

import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine

from napari_meris_ortho.products.n1 import tie_columns, tie_lines, write_product

# the Orthorectify widget would compile the numba kernels in a background thread
os.environ.setdefault("MERIS_ORTHO_NO_WARMUP", "1")

#: tiny FR product: 129 lines x 257 columns (3 x 5 tie points), Alps-like latitudes
TINY_H, TINY_W = 129, 257


def tiny_tie_points() -> dict[str, np.ndarray]:
    """Tie points of the tiny product: stored order east (nadir) to west, 64 px = 16.6 km."""
    nt, nc = tie_lines(TINY_H, 64), tie_columns(TINY_W, 64)
    i, k = np.mgrid[0:nt, 0:nc].astype(np.float64)
    return {
        "latitude": 45.9 - 0.17 * i - 0.01 * k,
        "longitude": 8.0 - 0.215 * k + 0.03 * i,
        "dem_alt": 300.0 + 200.0 * k,
        "view_zenith": np.linspace(2.0, 22.0, nc) + 0.0 * i,
        "view_azimuth": 100.0 + 0.0 * i,
        "sun_zenith": 48.0 + 0.0 * i,
        "sun_azimuth": 153.0 + 0.0 * i,
    }


@pytest.fixture(autouse=True)
def _nothing_left_frozen():
    """Each test ends with every object within the garbage collector's reach (a read or the
    widget freezes the objects alive then: ``_napari.memory``)."""
    yield
    from napari_meris_ortho._napari import memory

    memory.thaw()


@pytest.fixture(scope="session")
def tiny_n1(tmp_path_factory):
    """Path of the tiny product; its radiances are smooth ramps plus a checkerboard."""
    path = tmp_path_factory.mktemp("tiny") / "MER_FR__1PTINY.N1"
    rows, cols = np.mgrid[0:TINY_H, 0:TINY_W]
    checker = ((rows // 8 + cols // 8) % 2) * 400
    counts = [(1000 + 10 * b + rows * 2 + cols + checker).astype(np.uint16) for b in range(15)]
    write_product(path, product_type="MER_FR__1P", tie_points=tiny_tie_points(), counts=counts,
                  flags=np.zeros((TINY_H, TINY_W), np.uint8),
                  detector_index=(cols % 740).astype(np.int16),
                  first_line_time=dt.datetime(2003, 9, 21, 9, 23, 41))
    return path


@pytest.fixture(scope="session")
def tiny_dem(tmp_path_factory):
    """A lon/lat GeoTIFF DEM over the tiny product: 500..2500 m waves."""
    path = tmp_path_factory.mktemp("dem") / "dem.tif"
    lon0, lat0, step = 6.5, 46.2, 0.005
    n_lat, n_lon = 240, 360
    lat = lat0 - (np.arange(n_lat) + 0.5) * step
    lon = lon0 + (np.arange(n_lon) + 0.5) * step
    h = 1500 + 1000 * (np.sin(np.radians(lon[None, :] * 400))
                       * np.cos(np.radians(lat[:, None] * 300)))
    with rasterio.open(path, "w", driver="GTiff", width=n_lon, height=n_lat, count=1,
                       dtype="float32", crs="EPSG:4326",
                       transform=Affine(step, 0, lon0, 0, -step, lat0)) as ds:
        ds.write(h.astype(np.float32)[None])
    return path


@pytest.fixture(autouse=True)
def _plugin_settings_in_tmp(tmp_path_factory, monkeypatch):
    """Widget settings (napari plugin settings) are saved under a fresh directory per test, never
    in the user's napari config: a test's choices do not leak into the next test."""
    from napari import settings as napari_settings

    folder = tmp_path_factory.mktemp("napari-settings")
    napari_settings._clear_plugin_settings_cache()
    monkeypatch.setattr(napari_settings, "_CFG_PATH", str(folder / "settings.yaml"))
    yield folder
    napari_settings._clear_plugin_settings_cache()

"""Tie-point heights below 0 (bathymetry, as ESA stores it over sea) give no parallax in every
elevation mode that takes heights from the tie points."""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest

from napari_meris_ortho.geometry.tiepoints import TiePointGrid, analytic_swath
from napari_meris_ortho.ortho import orthorectify
from napari_meris_ortho.products.n1 import read_product, write_product

#: tie-point dem_alt of MER_RR__1PRACR20060116 over the open Pacific reach -5103 m
PACIFIC_DEPTH_M = -5103.0
#: a land strip of the same product (m)
LAND_M = 1200.0


@pytest.fixture(scope="module")
def pacific(tmp_path_factory):
    """An RR product over the sea (dem_alt -3000 .. -5103 m, the real figures) with a land strip
    in its last tie-point columns (+1200 m), up to ~24 deg view zenith."""
    height, width = 97, 321
    g = analytic_swath(height=height, width=width, df=16, dj=16, lat0=-12.0, lon0=-120.0,
                       pixel_m=1040.0, nadir_col=-80.0)
    n_lines, n_cols = g.latitude.shape
    k = np.arange(n_cols)[None, :] + 0.0 * np.arange(n_lines)[:, None]
    dem = np.round(PACIFIC_DEPTH_M + 2103.0 * k / (n_cols - 1))
    land = k >= n_cols - 4
    dem[land] = LAND_M
    tp = dict(latitude=g.latitude, longitude=g.longitude, view_zenith=g.view_zenith,
              view_azimuth=g.view_azimuth, dem_alt=dem)
    counts = [np.full((height, width), 100 * b, np.uint16) for b in range(1, 16)]
    path = write_product(tmp_path_factory.mktemp("pacific") / "rr.N1", product_type="MER_RR__1P",
                         tie_points=tp, counts=counts, flags=np.zeros((height, width), np.uint8),
                         detector_index=np.zeros((height, width), np.int16),
                         first_line_time=dt.datetime(2006, 1, 16, 18, 0))
    return path, land


def test_a_pacific_product_is_read_with_its_seabed(pacific):
    path, _ = pacific
    tp = read_product(path).tie_points
    assert tp["dem_alt"].min() == PACIFIC_DEPTH_M and tp["dem_alt"].max() == LAND_M


def test_seabed_gives_no_parallax_in_tiepoint_mode(pacific):
    """Over the sea the tie-point mode puts every output pixel where elevation "none" does
    (shift 0 m); over the land strip the parallax is there (hundreds of metres)."""
    path, land = pacific
    none = orthorectify(path, bands=[1], elevation="none", diagnostics=True)
    tie = orthorectify(path, grid=none.grid, bands=[1], elevation="tiepoints", diagnostics=True)
    d = tie.diagnostics
    col = d["col"]
    land_col = 16.0 * (land.shape[1] - 4)
    sea = tie.valid & none.valid & (col < land_col - 16.0)
    onshore = tie.valid & (col > land_col + 16.0)
    assert sea.sum() > 10_000 and onshore.sum() > 1_000
    shift = np.hypot(d["shift_east_m"], d["shift_north_m"])
    assert np.max(shift[sea]) == 0.0 and np.max(np.abs(d["elevation"][sea])) == 0.0
    np.testing.assert_array_equal(col[sea], none.diagnostics["col"][sea])
    np.testing.assert_array_equal(d["line"][sea], none.diagnostics["line"][sea])
    assert np.median(shift[onshore]) > 200.0


def test_seabed_gives_no_parallax_where_a_dem_falls_back_to_the_tie_points(pacific, tmp_path):
    """Elevation "dem" with a DEM that has no data over the sea (as SRTM): the tie points give
    the height there (source -1), and it is 0, not the seabed."""
    import rasterio
    from rasterio.transform import from_origin

    path, _ = pacific
    none = orthorectify(path, bands=[1], elevation="none", diagnostics=True)
    dem = tmp_path / "nodata.tif"
    with rasterio.open(dem, "w", driver="GTiff", width=400, height=300, count=1,
                       dtype="float32", crs="EPSG:4326", nodata=-32768.0,
                       transform=from_origin(-125.0, -8.0, 0.02, 0.02)) as ds:
        ds.write(np.full((1, 300, 400), -32768.0, np.float32))
    r = orthorectify(path, dems=[f"{dem}:ellipsoid"], grid=none.grid, bands=[1],
                     elevation="dem", diagnostics=True)
    d = r.diagnostics
    sea = r.valid & none.valid & (none.diagnostics["col"] < 240.0)
    assert sea.sum() > 10_000
    assert np.all(d["elevation_source"][sea] == -1)
    assert np.max(np.abs(d["elevation"][sea])) == 0.0
    np.testing.assert_array_equal(d["col"][sea], none.diagnostics["col"][sea])
    np.testing.assert_array_equal(d["line"][sea], none.diagnostics["line"][sea])


def test_the_location_models_take_no_height_below_zero():
    """``TiePointGrid`` (what every location kernel reads) holds the seabed as 0, land as is."""
    g = analytic_swath(height=65, width=129, df=16, dj=16)
    dem = np.where(np.arange(g.latitude.shape[1]) < 4, PACIFIC_DEPTH_M, 850.0)
    dem = np.broadcast_to(dem, g.latitude.shape)
    grid = TiePointGrid(g.latitude, g.longitude, g.view_zenith, g.view_azimuth, dem, 16, 16,
                        65, 129)
    np.testing.assert_array_equal(grid.dem_alt, np.where(dem < 0, 0.0, dem))

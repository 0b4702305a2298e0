"""Hostile DEMs: special files refused without hanging, invalid
georeferencing refused, implausible heights are no data, a half float32 GETASSE30 tile is not
read as the int16 variant, and a DEM that gives no height is reported by ``map``."""

from __future__ import annotations

import logging
import os

import numpy as np
import pytest
import rasterio
from affine import Affine
from rasterio.transform import from_origin

from napari_meris_ortho.cli import main
from napari_meris_ortho.dem.getasse import GETASSE_FLOAT_SIZE, getasse_tile_name
from napari_meris_ortho.dem.stack import open_dem
from napari_meris_ortho.errors import DemError
from napari_meris_ortho.products.n1 import read_product
from ortho_samples import make_dem, make_product


def write_tif(path, z, transform, crs="EPSG:4326", nodata=None):
    with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1,
                       dtype=z.dtype, crs=crs, transform=transform, nodata=nodata) as ds:
        ds.write(z, 1)
    return path


@pytest.mark.timeout(60)
@pytest.mark.parametrize("name", ["dem.tif", "45N015E.GETASSE30", "tile.DEM"])
def test_fifo_dem_is_refused_without_hanging(tmp_path, name):
    fifo = tmp_path / name
    os.mkfifo(fifo)
    with pytest.raises(DemError, match="not a regular file"):
        open_dem(fifo)


@pytest.mark.timeout(60)
def test_fifo_header_of_an_srtm_tile_is_refused(tmp_path):
    (tmp_path / "tile.DEM").write_bytes(bytes(8))
    os.mkfifo(tmp_path / "tile.HDR")
    with pytest.raises(DemError, match="tile.HDR: the DEM header is a FIFO, not a regular file"):
        open_dem(tmp_path / "tile.DEM")


def test_zero_pixel_size_is_refused(tmp_path):
    transform = Affine(0.01, 0, 10, 0, 0.0, 50)  # GDAL keeps a zero row height and the CRS
    path = write_tif(tmp_path / "flat.tif", np.ones((4, 4), np.float32), transform)
    with pytest.raises(DemError, match="invalid georeferencing: pixel size"):
        open_dem(path)


def test_implausible_heights_are_no_data(tmp_path):
    z = np.array([[3e38, -600.0, 9500.0, 8848.0], [-430.0, 0.0, 100.0, 1e4]], np.float32)
    path = write_tif(tmp_path / "dem.tif", z, from_origin(10.0, 50.0, 1.0, 1.0))
    dem = open_dem(path)
    lon = 10.5 + np.arange(4.0)
    h = dem.sample(np.r_[lon, lon], np.r_[[49.5] * 4, [48.5] * 4], method="nearest")
    np.testing.assert_array_equal(h, [np.nan, np.nan, np.nan, 8848.0,
                                      -430.0, 0.0, 100.0, np.nan])  # fmt: skip
    # bilinear: a post out of range makes the point no data (the next DEM is tried)
    assert np.isnan(dem.sample(11.0, 49.0))
    assert dem.sample(12.0, 48.2, method="bilinear") == pytest.approx(50.0)


def test_half_of_a_float_getasse_tile_is_not_read_as_int16(tmp_path):
    lat0, lon0 = 45, 15
    r, c = np.mgrid[0:1800, 0:1800].astype(np.float32)
    heights = 200.0 + 3.0 * r + 0.5 * c  # plausible alpine float heights
    raw = heights.astype("<f4").tobytes()
    assert len(raw) == GETASSE_FLOAT_SIZE
    (tmp_path / getasse_tile_name(lat0, lon0)).write_bytes(raw[: len(raw) // 2])
    dem = open_dem(tmp_path)
    with pytest.raises(DemError, match="not a BEAM int16 GETASSE30 tile"):
        dem.sample(17.0, 50.0)


def test_half_of_a_mostly_sea_float_getasse_tile_is_not_read_as_int16(tmp_path):
    """A float32 tile of sea (0) with a patch of land, cut at half its size (the BEAM int16
    size): the zero posts read as plausible int16 heights and hid the patch's implausible
    ones (2.5 % of the samples; 5 % refused): read as int16, every height was 0."""
    lat0, lon0 = 45, 0
    heights = np.zeros((1800, 1800), np.float32)
    heights[200:400, 500:700] = 850.25 + np.arange(200, dtype=np.float32)  # land, first half
    raw = heights.astype("<f4").tobytes()
    (tmp_path / getasse_tile_name(lat0, lon0)).write_bytes(raw[: len(raw) // 2])
    dem = open_dem(tmp_path)
    with pytest.raises(DemError, match="not a BEAM int16 GETASSE30 tile"):
        dem.sample(1.0, 46.0)


def test_map_warns_about_a_dem_that_gives_no_height(tmp_path, caplog):
    prod = make_product(tmp_path / "p.N1", height=130, width=321, lon0=15.0, nadir_col=-800.0)
    tp = read_product(prod).tie_points
    box = (tp["longitude"].min() - 0.3, tp["latitude"].min() - 0.3,
           tp["longitude"].max() + 0.3, tp["latitude"].max() + 0.3)  # fmt: skip
    good = make_dem(tmp_path / "good.tif", *box)
    wrong_crs = make_dem(tmp_path / "wrong.tif", *box)
    with rasterio.open(wrong_crs, "r+") as ds:
        ds.crs = "EPSG:3857"  # degrees tagged as metres: lies off the coast of Africa
    caplog.set_level(logging.INFO, logger="napari_meris_ortho")
    out = tmp_path / "out.tif"
    wrong_entry = f"{wrong_crs}:ellipsoid"  # (the datum named: no datum warning)
    code = main(["map", str(prod), "-o", str(out), "--bands", "1", "--dem", wrong_entry,
                 "--dem", f"{good}:ellipsoid"])  # fmt: skip
    assert code == 0 and out.exists()
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warnings == [f"warning: DEM {wrong_entry} contributed no height (outside the product, "
                        "wrong CRS, or only no data / heights outside -500..9000 m)"]


LOCAL_CS = ('LOCAL_CS["site grid",LOCAL_DATUM["site",0],UNIT["metre",1],AXIS["X",EAST],'
            'AXIS["Y",NORTH]]')
MARS_GEOGCS = ('GEOGCS["Mars 2000",DATUM["D_Mars_2000",SPHEROID["Mars_2000_IAU_IAG",3396190,'
               '169.8944472236118]],PRIMEM["Reference_Meridian",0],'
               'UNIT["degree",0.0174532925199433]]')


@pytest.mark.parametrize(("crs", "message"), [
    (LOCAL_CS, "'site grid' is an engineering (local) CRS, not tied to the Earth"),
    (MARS_GEOGCS, "'Mars 2000' is not on the Earth (ellipsoid 'Mars_2000_IAU_IAG', "
                  "semi-major axis 3396190 m)"),
    ("IAU_2015:49900", "is not on the Earth (ellipsoid 'Mars (2015) - Sphere', semi-major axis "
                       "3396190 m)"),
])
@pytest.mark.parametrize("ignore_body", ["", "YES"])
def test_dem_off_the_earth_is_one_message(tmp_path, capsys, monkeypatch, crs, message,
                                          ignore_body):
    """A DEM in an engineering CRS or on Mars: one message naming the DEM and its
    CRS, exit 2, no output, also when PROJ is told to ignore the celestial body."""
    import pyproj

    if ignore_body:
        monkeypatch.setenv("PROJ_IGNORE_CELESTIAL_BODY", ignore_body)
    prod = make_product(tmp_path / "p.N1", height=130, width=321, lon0=15.0, nadir_col=-800.0)
    dem = write_tif(tmp_path / "dem.tif", np.full((50, 50), 500.0, np.float32),
                    from_origin(14.0, 48.0, 0.05, 0.05),
                    crs=rasterio.crs.CRS.from_wkt(pyproj.CRS(crs).to_wkt("WKT1_GDAL")))
    out = tmp_path / "out.tif"
    assert main(["-q", "map", str(prod), "-o", str(out), "--bands", "1", "--dem", str(dem)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("meris-ortho: error: ")
    assert f"{dem}: the DEM's CRS " in err and message in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dem.tif", "p.N1"]
    with pytest.raises(DemError, match="not tied to the Earth|not on the Earth"):
        open_dem(dem)


def test_a_dem_masked_by_a_mask_band_has_no_data_there(tmp_path):
    """GDAL and QGIS write no data as an internal mask band (0 under it), not as a nodata
    value: the masked posts are no data, not 0 m heights."""
    z = np.full((4, 6), 1500.0, np.float32)
    z[1:3, 2:4] = 0.0  # under the mask
    path = tmp_path / "masked.tif"
    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):
        with rasterio.open(path, "w", driver="GTiff", width=6, height=4, count=1,
                           dtype="float32", crs="EPSG:4326",
                           transform=from_origin(10.0, 50.0, 1.0, 1.0)) as ds:
            ds.write(z, 1)
            mask = np.full((4, 6), 255, np.uint8)
            mask[1:3, 2:4] = 0
            ds.write_mask(mask)
    with rasterio.open(path) as ds:
        assert ds.nodata is None and ds.read_masks(1)[1, 2] == 0  # a mask, not a value
    dem = open_dem(f"{path}:ellipsoid")
    lon, lat = np.array([10.5, 12.5, 13.5, 15.5]), np.array([49.5, 48.5, 47.5, 46.5])
    np.testing.assert_array_equal(dem.sample(lon, lat, method="nearest"),
                                  [1500.0, np.nan, np.nan, 1500.0])


def test_a_copernicus_tile_given_as_a_file_is_above_the_geoid(tmp_path, caplog):
    """A Copernicus tile named as a file (not its directory) was taken as ellipsoidal with the
    "does not say its vertical datum" warning (46 m off): its name says EGM2008."""
    z = np.full((12, 12), 800.0, np.float32)
    path = write_tif(tmp_path / "Copernicus_DSM_COG_30_N46_00_E013_00_DEM.tif", z,
                     from_origin(13.0, 47.0, 1 / 12, 1 / 12))
    with caplog.at_level(logging.WARNING):
        dem = open_dem(path)
    assert "does not say its vertical datum" not in caplog.text
    h = dem.sample(np.array([13.5]), np.array([46.5]), method="nearest")[0]
    assert 840.0 < h < 860.0  # 800 m above the geoid: about 848 m above the ellipsoid here


def test_a_dem_in_a_national_height_datum_is_above_the_geoid(tmp_path, caplog):
    """EPSG:3035 + EVRF2007 height, as European DEMs are tagged: the heights are above the
    geoid and the warning names the datum (read as ellipsoidal heights, "does not say its
    vertical datum", they would be 31 m low on average, radiances off by up to 188)."""
    from rasterio.crs import CRS

    z = np.full((10, 10), 1000.0, np.float32)
    transform = from_origin(4_500_000.0, 2_600_000.0, 1000.0, 1000.0)
    path = write_tif(tmp_path / "evrf.tif", z, transform,
                     crs=CRS.from_user_input("EPSG:3035+5621"))
    with caplog.at_level(logging.WARNING):
        dem = open_dem(path)
    assert "EVRF2007 height" in caplog.text
    assert "does not say its vertical datum" not in caplog.text
    lon, lat = pyproj_lonlat(4_505_000.0, 2_595_000.0)
    h = dem.sample(np.array([lon]), np.array([lat]), method="nearest")[0]
    assert 1040.0 < h < 1060.0  # the geoid is 40-60 m above the ellipsoid in Europe


def pyproj_lonlat(x, y):
    import pyproj

    return pyproj.Transformer.from_crs("EPSG:3035", "EPSG:4326", always_xy=True).transform(x, y)


def test_a_dem_with_ground_control_points_only_says_so(tmp_path):
    """``gdal_translate -gcp`` makes a raster with a CRS on its ground control points and no
    geotransform: the message says so, not "the DEM has no coordinate reference system"."""
    from rasterio.control import GroundControlPoint
    from rasterio.crs import CRS

    points = [GroundControlPoint(r, c, 10.0 + c / 10, 46.0 - r / 10)
              for r, c in ((0, 0), (0, 6), (4, 0), (4, 6))]
    path = tmp_path / "gcp.tif"
    with rasterio.open(path, "w", driver="GTiff", width=6, height=4, count=1, dtype="float32",
                       gcps=points, crs=CRS.from_epsg(4326)) as ds:
        ds.write(np.full((4, 6), 500.0, np.float32), 1)
    with pytest.raises(DemError, match="ground control points only"):
        open_dem(path)


def test_an_n1_product_chosen_as_a_dem_is_named_as_such(tmp_path):
    """GDAL opens an N1 (its Envisat driver, ground control points): the message names it a
    product, not a DEM (and does not tell the user to warp it with gdalwarp)."""
    n1 = make_product(tmp_path / "MER_FR__1PNTEST.N1", height=64)
    with pytest.raises(DemError, match=r"an Envisat product \(N1\), not a DEM"):
        open_dem(n1)
    assert main(["map", str(n1), "-o", str(tmp_path / "out.tif"), "--elevation", "dem",
                 "--dem", str(n1)]) == 2
    assert not (tmp_path / "out.tif").exists()

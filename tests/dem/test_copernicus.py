"""Copernicus DEM GLO-30/GLO-90 tile directories (dem.copernicus)."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine

from napari_meris_ortho.dem.copernicus import (
    CopernicusSource,
    covering_tiles,
    lon_factor,
    parse_name,
    tile_name,
)
from napari_meris_ortho.dem.geoid import EGM96, ELLIPSOID, geoid_undulation
from napari_meris_ortho.dem.stack import open_dem
from napari_meris_ortho.errors import DemError
from ortho_samples import COPERNICUS_SCENE


@pytest.fixture(scope="module")
def scene():
    from napari_meris_ortho.simulate.scene import generate_scene

    return generate_scene(COPERNICUS_SCENE)


def test_names_and_zones():
    name = tile_name(46, 10, "10")
    assert name == "Copernicus_DSM_COG_10_N46_00_E010_00_DEM.tif"
    assert parse_name(name) == ("10", 46, 10)
    assert parse_name("Copernicus_DSM_30_S14_00_W172_00_DEM.dt2") == ("30", -14, -172)
    assert parse_name("Copernicus_DSM_COG_10_N46_00_E010_00_DEM.tif.aux.xml") is None
    assert [lon_factor(x) for x in (0, 49, -50, 50, 59, 60, 72, 80, 85, -90)] == [
        1, 1, 1, 1.5, 1.5, 2, 3, 5, 10, 10]
    assert covering_tiles((179.5, -0.5, 180.5, 0.2)) == [(-1, 179), (-1, -180), (0, 179),
                                                        (0, -180)]


def test_tile_directory_reads_the_truth_above_the_geoid(scene):
    """The exported tiles hold H = h - N; the source gives h back (float32 exact at the posts,
    bilinear across tile seams) and opens only the tiles under the points."""
    src = open_dem(scene.dem_paths["copernicus"])
    assert isinstance(src, CopernicusSource) and src.datum == EGM96
    assert src.resolution == "GLO-90" and len(src.tile_keys) >= 4
    # posts on both sides of the seams at 14 E and 46 N
    rng = np.random.default_rng(3)
    d = 3.0 / 3600.0
    c = np.round(rng.uniform(13.8, 14.2, 3000) / d)
    r = np.round(rng.uniform(45.975, 46.15, 3000) / d)  # the scene starts at 45.965 N
    lon, lat = c * d, r * d
    truth = scene.dem_height(lon, lat)
    h = src.sample(lon, lat)
    ok = np.isfinite(truth)
    assert ok.mean() > 0.9 and np.all(np.isfinite(h[ok]))
    assert np.max(np.abs(h[ok] - truth[ok])) < 2e-3
    # between posts, across the seams: bilinear between the four posts of any tiles
    lon2, lat2 = lon + 0.37 * d, lat - 0.61 * d
    expected = (0.63 * 0.39 * truth + 0.37 * 0.39 * scene.dem_height(lon + d, lat)
                + 0.63 * 0.61 * scene.dem_height(lon, lat - d)
                + 0.37 * 0.61 * scene.dem_height(lon + d, lat - d))
    ok2 = np.isfinite(expected)
    assert ok2.mean() > 0.9
    assert np.max(np.abs(src.sample(lon2, lat2)[ok2] - expected[ok2])) < 5e-3
    assert set(src.tiles_opened) == {(45, 13), (45, 14), (46, 13), (46, 14)}
    # stored heights are above the geoid: the same tiles read as ellipsoidal heights lack N
    raw = open_dem(f"{scene.dem_paths['copernicus']}:ellipsoid")
    assert raw.datum == ELLIPSOID
    n = geoid_undulation(lon[ok], lat[ok])
    assert 40 < n.min() and np.allclose(raw.sample(lon[ok], lat[ok]), h[ok] - n, atol=1e-3)
    src.close()


def test_vrt_of_the_tiles_is_one_entry(scene, tmp_path):
    gdalbuildvrt = shutil.which("gdalbuildvrt")
    assert gdalbuildvrt, "gdal-bin (scripts/setup.sh) provides gdalbuildvrt"
    tiles = sorted(str(p) for p in scene.dem_paths["copernicus"].glob("*.tif"))
    vrt = tmp_path / "copernicus.vrt"
    subprocess.run([gdalbuildvrt, "-q", str(vrt), *tiles], check=True)
    src = open_dem(vrt)
    assert src.datum == EGM96  # a VRT of Copernicus tiles: heights above the geoid
    lon = np.linspace(13.3, 14.6, 200)
    lat = np.linspace(45.7, 46.4, 200)
    a, b = src.sample(lon, lat), open_dem(scene.dem_paths["copernicus"]).sample(lon, lat)
    ok = np.isfinite(b)
    assert ok.sum() > 100 and np.allclose(a[ok], b[ok], atol=1e-3)


def _tile(path, lat0, lon0, value, dx=3 / 3600, dy=3 / 3600, shift=0.0):
    n, m = int(round(1 / dy)), int(round(1 / dx))
    t = Affine(dx, 0, lon0 - 0.5 * dx + shift, 0, -dy, lat0 + 1 + 0.5 * dy)
    with rasterio.open(path / tile_name(lat0, lon0), "w", driver="GTiff", width=m, height=n,
                       count=1, dtype="float32", crs="EPSG:4326", transform=t) as ds:
        ds.write(np.full((1, n, m), value, np.float32))


def test_bad_tile_directories(tmp_path):
    (tmp_path / "a" / "DEM").mkdir(parents=True)
    _tile(tmp_path / "a" / "DEM", 60, 20, 100.0, dx=4.5 / 3600)  # GLO-90 at 60-70 N: x1.5? x2
    with pytest.raises(DemError, match="not a Copernicus DEM tile"):
        open_dem(tmp_path / "a").sample(20.5, 60.5)
    (tmp_path / "b").mkdir()
    _tile(tmp_path / "b", 60, 20, 100.0, dx=6 / 3600)
    src = open_dem(f"{tmp_path / 'b'}:ellipsoid")
    assert src.sample(20.5, 60.5) == 100.0 and np.isnan(src.sample(21.5, 60.5))
    with pytest.raises(DemError, match="no Copernicus tile covers the product footprint"):
        src.check_covers((10.0, 45.0, 12.0, 47.0))
    src.check_covers((20.9, 58.0, 22.0, 60.1))
    (tmp_path / "b" / tile_name(61, 20, "10")).write_bytes(b"")
    with pytest.raises(DemError, match="mixes GLO-30 and GLO-90"):
        open_dem(tmp_path / "b")


@pytest.mark.slow
def test_a_missing_tile_under_the_footprint_is_reported(scene, tmp_path, caplog):
    """With one tile of the directory gone, the points under it (45 % here) take the tie
    points' heights, and that is said: the tiles under the footprint the directory lacks are in
    the run's statistics and warned about by ``map``; a complete directory gives no warning."""
    import logging

    from napari_meris_ortho.cli import main
    from napari_meris_ortho.ortho import orthorectify

    full = scene.dem_paths["copernicus"]
    assert open_dem(full).missing_tiles((13.2, 45.9, 14.6, 46.8)) == []
    holed = tmp_path / "holed"
    shutil.copytree(full, holed)
    (gone,) = list(holed.rglob("*N46_00_E013_00_DEM.tif"))
    gone.unlink()
    src = open_dem(holed)
    assert src.missing_tiles((13.2, 45.9, 14.6, 46.8)) == ["N46 E013"]
    src.close()
    res = orthorectify(scene.product_path, dems=[holed], bands=[7])
    assert res.stats.dem_gaps == {str(holed): ["N46 E013"]}
    assert res.stats.elevation_sources.get("tiepoints", 0) > 0
    complete = orthorectify(scene.product_path, dems=[full], bands=[7])
    assert complete.stats.dem_gaps == {}
    with caplog.at_level(logging.WARNING):
        assert main(["-q", "map", str(scene.product_path), "-o", str(tmp_path / "o.tif"),
                     "--dem", str(holed), "--bands", "7"]) == 0
    assert f"DEM {holed} has no tile N46 E013 under the footprint" in caplog.text


@pytest.mark.slow
def test_getasse30_names_its_missing_tiles(fr_small):
    """GETASSE30 covers the globe in 15-degree tiles: under a box across 15 E the scene's
    directory (one tile, 45N000E) lacks 45N015E."""
    src = open_dem(fr_small.dem_paths["getasse30"])
    assert src.missing_tiles((13.2, 45.9, 14.6, 46.8)) == []
    assert src.missing_tiles((14.5, 45.9, 15.5, 46.8)) == ["45N015E.GETASSE30"]
    assert src.missing_tiles((179.0, 44.0, 181.0, 46.0)) == ["30N165E.GETASSE30",
                                                              "30N180W.GETASSE30",
                                                              "45N165E.GETASSE30",
                                                              "45N180W.GETASSE30"]
    src.close()


def test_srtm30_names_its_missing_tiles(fr_small):
    """SRTM30/GTOPO30 cover the globe in 40 x 50 deg tiles (60 x 30 deg in the Antarctic): the
    scene's directory holds W020N90 (20 W to 20 E, 40 N to 90 N) only."""
    from napari_meris_ortho.dem.srtm import srtm30_tiles

    src = open_dem(fr_small.dem_paths["srtm30"].parent)
    assert src.missing_tiles((13.2, 45.9, 14.6, 46.8)) == []
    assert src.missing_tiles((19.0, 39.0, 21.0, 41.0)) == ["E020N90.DEM", "W020N40.DEM",
                                                            "E020N40.DEM"]
    src.close()
    assert srtm30_tiles((179.0, 60.0, 181.0, 61.0)) == ["E140N90", "W180N90"]
    assert srtm30_tiles((-5.0, -70.0, 5.0, -65.0)) == ["W060S60", "W000S60"]

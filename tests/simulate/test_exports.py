"""DEM and reference exports: GeoTIFF, GETASSE30, SRTM30 tiles and a UTM GeoTIFF like DEM
Italy, in the formats those DEMs are distributed in."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio

from napari_meris_ortho.dem.geoid import geoid_undulation
from napari_meris_ortho.simulate.exports import (
    getasse_tile_name,
    getasse_tiles,
    srtm30_tile_name,
    srtm30_tiles,
)


def test_tile_names_from_their_corners():
    assert getasse_tile_name(45, 15) == "45N015E.GETASSE30"
    assert getasse_tile_name(-90, -180) == "90S180W.GETASSE30"
    assert getasse_tiles((12.3, 45.6, 14.2, 46.9)) == [(45, 0)]
    assert sorted(getasse_tiles((178.0, 59.0, 182.0, 61.0))) == [
        (45, -180), (45, 165), (60, -180), (60, 165)]
    assert srtm30_tile_name(-20, 90) == "W020N90"
    assert srtm30_tile_name(140, -10) == "E140S10"
    assert srtm30_tiles((9.0, 39.9, 18.4, 47.0)) == [(-20, 90, 40, 50), (-20, 40, 40, 50)]
    assert srtm30_tiles((175.0, 60.0, 185.0, 65.0)) == [(-180, 90, 40, 50), (140, 90, 40, 50)]
    assert srtm30_tiles((-70.0, -73.0, -60.0, -70.0)) == [(-120, -60, 60, 30)]


@pytest.mark.slow
def test_geotiff_is_the_truth_dem(fr_small):
    with rasterio.open(fr_small.dem_paths["geotiff"]) as ds:
        z = ds.read(1)
        t = ds.transform
        assert ds.crs.to_epsg() == 4326 and ds.dtypes[0] == "float32"
    assert np.array_equal(z, fr_small.dem)
    g = fr_small.dem_grid
    assert (t.c, t.f, t.a, -t.e) == (g.lon0, g.lat0, g.spacing, g.spacing)
    # posts at pixel centres: dem_height at a pixel centre is the pixel value
    r, c = 100, 200
    lon, lat = rasterio.transform.xy(t, r, c)  # the pixel's centre
    assert abs(fr_small.dem_height(lon, lat) - z[r, c]) < 1e-3
    assert z.max() > 3500.0 and (z == 0).any()  # mountains and sea


def _posts(lat0, lon0, rows, cols, south_to_north):
    lon = lon0 + (cols + 0.5) / 120
    lat = lat0 + (rows + 0.5) / 120 if south_to_north else lat0 + 15 - (rows + 0.5) / 120
    return lon, lat


def test_getasse30_both_variants(fr_small):
    name = "45N000E.GETASSE30"
    hb = fr_small.dem_paths["getasse30"] / name
    beam = fr_small.dem_paths["getasse30_beam"] / name
    assert hb.stat().st_size == 12_960_000 and beam.stat().st_size == 6_480_000
    assert (fr_small.dem_paths["getasse30"] / f"{name}_flag").stat().st_size == 6_480_000
    a = np.fromfile(hb, "<f4").reshape(1800, 1800)
    b = np.fromfile(beam, ">i2").reshape(1800, 1800)
    flag = np.fromfile(fr_small.dem_paths["getasse30"] / f"{name}_flag", "<u2").reshape(1800, 1800)
    rng = np.random.default_rng(1)
    # posts of the tile inside the scene: around lon 13, lat 46.2
    rows_sn = rng.integers(int((46.0 - 45) * 120), int((46.5 - 45) * 120), 200)
    cols = rng.integers(int(12.8 * 120), int(13.6 * 120), 200)
    lon, lat = _posts(45, 0, rows_sn, cols, True)
    truth = fr_small.dem_height(lon, lat)
    assert np.allclose(a[rows_sn, cols], truth, atol=1e-3)
    assert np.all(flag[rows_sn, cols] == 1) and flag[0, 0] == 0
    assert np.all(np.abs(b[1799 - rows_sn, cols] - truth) <= 0.5)
    assert a[0, 0] == 0.0 and b[0, 0] == 0  # outside the scene


def test_srtm30_tile_and_header(fr_small):
    dem = fr_small.dem_paths["srtm30"]
    assert dem.name == "W020N90.DEM" and dem.stat().st_size == 6000 * 4800 * 2
    hdr = dict(line.split() for line in dem.with_suffix(".HDR").read_text().splitlines())
    assert hdr["BYTEORDER"] == "M" and hdr["NODATA"] == "-9999" and hdr["NBITS"] == "16"
    assert (hdr["NROWS"], hdr["NCOLS"]) == ("6000", "4800")
    assert abs(float(hdr["ULXMAP"]) - (-20 + 1 / 240)) < 1e-12
    assert abs(float(hdr["ULYMAP"]) - (90 - 1 / 240)) < 1e-12
    z = np.memmap(dem, ">i2", mode="r", shape=(6000, 4800))
    lon = np.linspace(12.6, 13.9, 300)
    lat = np.full(300, 45.9)
    c = np.round((lon + 20 - 1 / 240) * 120).astype(int)
    r = np.round((90 - 1 / 240 - lat) * 120).astype(int)
    lon_p, lat_p = -20 + (c + 0.5) / 120, 90 - (r + 0.5) / 120
    v = z[r, c]
    # heights above the EGM96 geoid, like real SRTM30
    truth = fr_small.dem_height(lon_p, lat_p) - geoid_undulation(lon_p, lat_p)
    land = v != -9999
    assert land.any() and (~land).any()  # the northern sea is no data, like SRTM30
    assert np.all(np.abs(v[land] - truth[land]) <= 0.5)
    assert np.all(truth[~land] < 20.0)  # sea (0 m) or the coast's first bilinear metres
    assert z[0, 0] == -9999


def test_utm_geotiff_like_dem_italy(fr_small):
    from pyproj import Transformer

    with rasterio.open(fr_small.dem_paths["geotiff_utm"]) as ds:
        assert ds.crs.to_epsg() == 32633 and ds.res == (500.0, 500.0)
        z = ds.read(1)
        r, c = ds.height // 2, ds.width // 2
        x, y = rasterio.transform.xy(ds.transform, r, c)
    lon, lat = Transformer.from_crs(32633, 4326, always_xy=True).transform(x, y)
    assert abs(z[r, c] - fr_small.dem_height(lon, lat)) < 1e-2


def test_reference_image_is_the_truth(fr_small):
    with rasterio.open(fr_small.reference_path) as ds:
        assert ds.count == 3 and ds.descriptions[1] == "band 7 radiance"
        img = ds.read()
        t = ds.transform
    r, c = 321, 456
    lon, lat = rasterio.transform.xy(t, r, c)  # the pixel's centre
    for k, band in enumerate((5, 7, 13)):
        assert abs(img[k, r, c] - fr_small.truth_radiance(lon, lat, band)) < 1e-3

"""DEM sources: GETASSE30 (both variants), SRTM30/GTOPO30, GeoTIFF in any CRS; DemStack."""

from __future__ import annotations

import logging
import zipfile

import numpy as np
import pyproj
import pytest
import rasterio
from rasterio.transform import from_origin

from napari_meris_ortho.dem.geoid import geoid_undulation
from napari_meris_ortho.dem.getasse import GetasseSource, getasse_tile_name
from napari_meris_ortho.dem.raster import RasterSource
from napari_meris_ortho.dem.stack import DemStack, heights_or_fallback, open_dem
from napari_meris_ortho.errors import DemError


def plane(lon, lat):
    """Integer at every 30" post of the tiles used here, so int16 tiles store it exactly
    (120 x a half-post offset is 0.5 in each term); 600..7800 m over lon 0..30, lat 30..60."""
    return 120.0 * np.asarray(lon) + 120.0 * np.asarray(lat) - 3000.0


def post_lonlat(lat0, lon0, south_to_north=True):
    r, c = np.mgrid[0:1800, 0:1800].astype(np.float64)
    lon = lon0 + (c + 0.5) / 120.0
    lat = lat0 + (r + 0.5) / 120.0 if south_to_north else lat0 + 15.0 - (r + 0.5) / 120.0
    return lon, lat


def write_handbook_tile(folder, lat0, lon0, order="<f4"):
    lon, lat = post_lonlat(lat0, lon0, True)
    path = folder / getasse_tile_name(lat0, lon0)
    plane(lon, lat).astype(order).tofile(path)
    return path


def beam_tile_bytes(lat0, lon0, nodata_post=None):
    lon, lat = post_lonlat(lat0, lon0, False)
    h = np.rint(plane(lon, lat)).astype(">i2")
    if nodata_post is not None:
        h[nodata_post] = -32768
    return h.tobytes()


@pytest.fixture(scope="module")
def getasse_dir(tmp_path_factory):
    """45N000E handbook float32 LE, 45N015E BEAM int16 in a zip, 30N000E BEAM int16 plain
    (post (row 0, col 100) of 30N000E, i.e. its north-west corner area, is no data),
    30N015E handbook float32 BE; 60N000E missing."""
    d = tmp_path_factory.mktemp("getasse")
    write_handbook_tile(d, 45, 0, "<f4")
    write_handbook_tile(d, 30, 15, ">f4")
    (d / "30N000E.GETASSE30").write_bytes(beam_tile_bytes(30, 0, nodata_post=(0, 100)))
    with zipfile.ZipFile(d / "45N015E.zip", "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("45N015E.GETASSE30", beam_tile_bytes(45, 15))
    (d / "README.txt").write_text("not a tile")
    return d


def test_tile_names_from_lower_left_corner():
    assert getasse_tile_name(45, 15) == "45N015E.GETASSE30"
    assert getasse_tile_name(30, 0) == "30N000E.GETASSE30"
    assert getasse_tile_name(-15, -30) == "15S030W.GETASSE30"
    assert getasse_tile_name(-90, -180) == "90S180W.GETASSE30"


def test_getasse_both_variants_reproduce_a_plane(getasse_dir):
    dem = open_dem(getasse_dir)
    assert isinstance(dem, GetasseSource)
    assert dem.bounds == (0.0, 30.0, 30.0, 60.0)
    kinds = sorted(t.kind for t in dem.tiles.values())
    assert kinds == ["float32", "float32", "int16", "int16"]
    rng = np.random.default_rng(0)
    lon = rng.uniform(0.01, 29.99, 4000)
    lat = rng.uniform(30.5, 59.99, 4000)
    h = dem.sample(lon, lat)
    np.testing.assert_allclose(h, plane(lon, lat), atol=1e-6)
    hc = dem.sample(lon, lat, method="bicubic")
    ok = lat < 59.98  # bicubic needs one more post row to the north
    np.testing.assert_allclose(hc[ok], plane(lon, lat)[ok], atol=1e-6)


def test_getasse_across_tile_edges_and_posts(getasse_dir):
    dem = open_dem(getasse_dir)
    # between the last post of one tile and the first of the next (lon 15, lat 45)
    lon = np.array([15.0, 15.0, 7.5, 14.999, 3.0])
    lat = np.array([50.0, 45.0, 45.0, 44.9999, 45.001])
    np.testing.assert_allclose(dem.sample(lon, lat), plane(lon, lat), atol=1e-6)
    # nearest: the value of the closest post, rows S->N and N->S alike
    post_lon = np.array([0.5 / 120, 15 + 1799.5 / 120, 3 + 0.5 / 120])
    post_lat = np.array([45 + 0.5 / 120, 30 + 0.5 / 120, 30 + 1799.5 / 120])
    near = dem.sample(post_lon + 0.3 / 120, post_lat - 0.4 / 120, method="nearest")
    np.testing.assert_allclose(near, plane(post_lon, post_lat), atol=1e-6)


def test_getasse_missing_tile_and_no_data_post(getasse_dir):
    dem = open_dem(getasse_dir)
    # 60N000E is missing: inside it, and above the last post row of 45N000E
    h = dem.sample(np.array([5.0, 5.0, 5.0, -5.0]), np.array([65.0, 59.999, 59.99, 50.0]))
    assert np.isnan(h[0]) and np.isnan(h[1]) and np.isfinite(h[2]) and np.isnan(h[3])
    # BEAM tile 30N000E row 0 (north) col 100 is -32768: the 4 surrounding cells are no data
    plon = 100.5 / 120
    plat = 45.0 - 0.5 / 120
    near = dem.sample(np.array([plon - 0.3 / 120, plon + 0.3 / 120, plon + 1.5 / 120]),
                      np.array([plat - 0.2 / 120, plat - 0.2 / 120, plat - 0.2 / 120]))
    assert np.isnan(near[0]) and np.isnan(near[1]) and np.isfinite(near[2])
    nn = dem.sample(np.array([plon + 0.4 / 120]), np.array([plat]), method="nearest")
    assert np.isnan(nn[0])


def test_single_tile_file_opens(getasse_dir):
    dem = open_dem(getasse_dir / "45N000E.GETASSE30")
    assert dem.bounds == (0.0, 45.0, 15.0, 60.0)
    assert np.isnan(dem.sample(np.array([16.0]), np.array([50.0]))[0])


def write_srtm(folder, name="W020N90", nodata_at=(5, 7)):
    n_rows, n_cols = 60, 40
    ulx, uly, step = -20.0 + 0.5 / 120, 90.0 - 0.5 / 120, 1 / 120
    r, c = np.mgrid[0:n_rows, 0:n_cols].astype(float)
    h = np.rint(plane(ulx + c * step, uly - r * step)).astype(">i2")
    h[nodata_at] = -9999
    h.tofile(folder / f"{name}.DEM")
    (folder / f"{name}.HDR").write_text(
        "BYTEORDER      M\nLAYOUT       BIL\nNROWS         60\nNCOLS         40\nNBANDS 1\n"
        "NBITS 16\nBANDROWBYTES 80\nTOTALROWBYTES 80\nBANDGAPBYTES 0\nNODATA -9999\n"
        f"ULXMAP {ulx!r}\nULYMAP {uly!r}\nXDIM {step!r}\nYDIM {step!r}\n")
    return folder / f"{name}.DEM"


def test_srtm30_tile(tmp_path):
    dem = open_dem(write_srtm(tmp_path))
    b = dem.bounds
    assert b == pytest.approx((-20.0, 90.0 - 0.5, -20.0 + 40 / 120, 90.0))
    rng = np.random.default_rng(5)
    lon = rng.uniform(-19.99, -19.7, 300)
    lat = rng.uniform(89.6, 89.99, 300)
    h = dem.sample(lon, lat)
    ok = np.isfinite(h)
    assert ok.mean() > 0.95
    # SRTM30 heights are above the EGM96 geoid: the source gives ellipsoidal ones (+ N)
    np.testing.assert_allclose(h[ok], plane(lon, lat)[ok] + geoid_undulation(lon, lat)[ok],
                               atol=1e-6)
    raw = open_dem(f"{tmp_path / 'W020N90.DEM'}:ellipsoid").sample(lon, lat)
    np.testing.assert_allclose(raw[ok], plane(lon, lat)[ok], atol=1e-6)
    # no-data post (row 5, col 7) and a point outside the tile
    plon, plat = -20 + 7.5 / 120, 90 - 5.5 / 120
    out = dem.sample(np.array([plon + 0.1 / 120, -25.0, plon]), np.array([plat, 89.9, 89.9]))
    assert np.isnan(out[0]) and np.isnan(out[1]) and np.isfinite(out[2])
    # a directory of tiles and the .HDR path also open
    assert np.isfinite(open_dem(tmp_path).sample(plon, 89.9))
    assert np.isfinite(open_dem(tmp_path / "W020N90.HDR").sample(plon, 89.9))


def write_geotiff_dem(path, crs, transform, data, nodata=None):
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0],
                       count=1, dtype=data.dtype.name, crs=crs, transform=transform,
                       nodata=nodata, tiled=True, blockxsize=64, blockysize=64) as ds:
        ds.write(data, 1)
    return path


def test_geotiff_geographic_posts_at_pixel_centres(tmp_path):
    t = from_origin(10.0, 47.0, 0.01, 0.01)
    r, c = np.mgrid[0:200, 0:300].astype(float)
    data = plane(10.0 + (c + 0.5) * 0.01, 47.0 - (r + 0.5) * 0.01)
    data[50, 60] = -32768.0
    dem = open_dem(write_geotiff_dem(tmp_path / "geo.tif", "EPSG:4326", t, data, -32768.0))
    assert isinstance(dem, RasterSource)
    lon = np.array([10.005, 12.3456, 12.99, 10.0, 9.99, 10.6051])
    lat = np.array([46.995, 46.1234, 45.01, 46.5, 46.5, 46.4951])
    h = dem.sample(lon, lat)
    np.testing.assert_allclose(h[:3], plane(lon[:3], lat[:3]), atol=1e-6)
    assert h[3] == pytest.approx(plane(10.005, 46.5))  # half a post beyond: edge clamped
    assert np.isnan(h[4]) and np.isnan(h[5])  # outside; next to the nodata post
    # only the window under the requested points is read
    local = open_dem(tmp_path / "geo.tif")
    local.sample(np.array([11.0, 11.05]), np.array([46.0, 46.03]))
    assert local._window is not None and local._window[2].shape == (5, 7)


def test_geotiff_utm_lookups_are_reprojected(tmp_path):
    t = from_origin(400000.0, 5200000.0, 1000.0, 1000.0)
    r, c = np.mgrid[0:100, 0:120].astype(float)
    x = 400000.0 + (c + 0.5) * 1000.0
    y = 5200000.0 - (r + 0.5) * 1000.0
    data = 0.01 * (x - 400000.0) - 0.02 * (y - 5100000.0) + 1500.0  # 0..3200 m
    dem = open_dem(write_geotiff_dem(tmp_path / "utm.tif", "EPSG:32633", t, data))
    rng = np.random.default_rng(6)
    px = rng.uniform(401000, 518000, 200)
    py = rng.uniform(5101000, 5199000, 200)
    lon, lat = pyproj.Transformer.from_crs(32633, 4326, always_xy=True).transform(px, py)
    h = dem.sample(lon, lat)
    np.testing.assert_allclose(h, 0.01 * (px - 400000) - 0.02 * (py - 5100000) + 1500,
                               atol=1e-6)
    assert dem.bounds[0] == pytest.approx(13.7, abs=0.1)
    for method in ("nearest", "bicubic"):
        assert np.all(np.isfinite(dem.sample(lon, lat, method=method)))


def test_dem_stack_tries_each_source_in_order(tmp_path, getasse_dir):
    t = from_origin(0.0, 47.0, 0.5, 0.5)
    tif = write_geotiff_dem(tmp_path / "flat.tif", "EPSG:4326", t, np.full((4, 4), 123.0))
    stack = DemStack([tif, getasse_dir])
    lon = np.array([1.0, 10.0, 5.0, -40.0])
    lat = np.array([46.0, 46.0, 65.0, 0.0])
    h, idx = stack.sample(lon, lat)
    assert idx.tolist() == [0, 1, -1, -1]
    assert h[0] == 123.0 and h[1] == pytest.approx(plane(10.0, 46.0))
    assert np.isnan(h[2]) and np.isnan(h[3])
    hf, idxf = heights_or_fallback(stack, lon, lat, np.array([1.0, 2.0, 3.0, 4.0]))
    assert hf.tolist()[2:] == [3.0, 4.0] and idxf.tolist() == [0, 1, -1, -1]
    h2, _ = stack.sample(lon.reshape(2, 2), lat.reshape(2, 2))
    assert h2.shape == (2, 2)


def test_unreadable_dems_raise_dem_error(tmp_path):
    with pytest.raises(DemError, match="not found"):
        open_dem(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DemError, match="no GETASSE30"):
        open_dem(tmp_path / "empty")
    (tmp_path / "junk.tif").write_bytes(b"this is not a tiff" * 10)
    with pytest.raises(DemError, match="cannot read DEM"):
        open_dem(tmp_path / "junk.tif")
    bad = tmp_path / "badtile"
    bad.mkdir()
    (bad / "45N015E.GETASSE30").write_bytes(b"\0" * 1000)
    with pytest.raises(DemError, match="1000 bytes"):
        open_dem(bad)
    srtm = tmp_path / "srtm"
    srtm.mkdir()
    write_srtm(srtm)
    (srtm / "W020N90.DEM").write_bytes(b"\0" * 10)
    with pytest.raises(DemError, match="bytes, expected"):
        open_dem(srtm / "W020N90.DEM")
    (srtm / "W020N90.HDR").write_text("NROWS 60\n")
    with pytest.raises(DemError, match="header"):
        open_dem(srtm / "W020N90.DEM")
    with pytest.raises(DemError, match="interpolation"):
        open_dem(write_srtm(tmp_path)).sample(0.0, 0.0, method="spline")


def test_reads_the_simulator_exports_at_their_posts():
    """Every DEM format the simulator exports reads back the scene's truth heights at the posts
    (float formats exactly, int16 formats to the 0.5 m rounding)."""
    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene({"base": "fr-small", "lines": 128, "columns": 193,
                            "first_column": 1150})
    b = open_dem(scene.dem_paths["geotiff"]).bounds
    rng = np.random.default_rng(7)
    c = np.floor(rng.uniform(b[0] + 0.02, b[2] - 0.02, 2000) * 120)
    r = np.floor(rng.uniform(b[1] + 0.02, b[3] - 0.02, 2000) * 120)
    lon, lat = (c + 0.5) / 120, (r + 0.5) / 120
    truth = scene.dem_height(lon, lat)
    tolerance = {"geotiff": 1e-6, "getasse30": 1e-3, "getasse30_beam": 0.5, "srtm30": 0.5}
    for key, tol in tolerance.items():
        h = open_dem(scene.dem_paths[key]).sample(lon, lat)
        ok = np.isfinite(h)
        assert ok.mean() > 0.9, key
        assert np.max(np.abs(h[ok] - truth[ok])) <= tol, key


def test_geotiff_prepared_window_read_once_same_heights(tmp_path):
    """``prepare`` reads the footprint window once; lookups give the generic kernel's numbers."""
    t = from_origin(10.0, 47.0, 0.01, 0.01)
    rng = np.random.default_rng(8)
    data = rng.uniform(0.0, 3000.0, (200, 300)).astype(np.float32)
    data[50, 60] = -32768.0
    path = write_geotiff_dem(tmp_path / "geo.tif", "EPSG:4326", t, data, -32768.0)
    lazy, ready = open_dem(path), open_dem(path)
    ready.prepare(10.5, 45.5, 12.5, 46.8)
    window = ready._window
    assert window[:2] == (17, 47) and window[2].shape == (136, 206)
    lon = rng.uniform(10.5, 12.5, 5000)
    lat = rng.uniform(45.5, 46.8, 5000)
    lon[:3], lat[:3] = 10.605, 46.495  # on the nodata post (60, 50)
    for method in ("bilinear", "nearest", "bicubic"):
        np.testing.assert_allclose(ready.sample(lon, lat, method), lazy.sample(lon, lat, method),
                                   rtol=1e-12, equal_nan=True)
    assert np.isnan(ready.sample(lon[:1], lat[:1])[0])
    assert ready._window is window  # nothing read again
    # a point beyond the footprint is still found, without replacing the footprint window
    far = ready.sample(np.array([10.015]), np.array([46.985]))
    assert far[0] == pytest.approx(lazy.sample(np.array([10.015]), np.array([46.985]))[0])
    assert ready._window is window
    stack = DemStack([path])
    stack.prepare(10.5, 45.5, 12.5, 46.8)
    assert stack.sources[0]._window[2].shape == (136, 206)


def test_geotiff_vertical_datum_from_its_crs_or_a_warning(tmp_path, caplog):
    """A compound EGM96-height CRS gives EGM96 heights (+ N), a plain 2-D CRS is
    taken as ellipsoidal with one warning per path, each tile of a directory keeps its own."""
    t = from_origin(10.0, 47.0, 0.01, 0.01)
    data = np.full((100, 100), 500.0)
    (tmp_path / "d").mkdir()
    geoid_tif = write_geotiff_dem(tmp_path / "d" / "a.tif", "EPSG:4326+5773", t, data)
    plain_tif = write_geotiff_dem(tmp_path / "d" / "b.tif", "EPSG:4326",
                                  from_origin(11.0, 47.0, 0.01, 0.01), data)
    lon, lat = np.array([10.5, 11.5]), np.array([46.5, 46.5])
    n = geoid_undulation(lon, lat)
    assert open_dem(geoid_tif).sample(lon[0], lat[0]) == pytest.approx(500.0 + n[0], abs=1e-6)
    caplog.set_level(logging.WARNING, logger="napari_meris_ortho")
    for _ in range(2):
        assert open_dem(plain_tif).sample(lon[1], lat[1]) == pytest.approx(500.0, abs=1e-6)
    assert caplog.text.count("does not say its vertical datum") == 1
    both = open_dem(tmp_path / "d")
    np.testing.assert_allclose(both.sample(lon, lat), [500.0 + n[0], 500.0], atol=1e-6)
    forced = open_dem(f"{tmp_path / 'd'}:egm96")
    np.testing.assert_allclose(forced.sample(lon, lat), 500.0 + n, atol=1e-6)


def test_multiband_raster_is_not_a_dem(tmp_path):
    """A 3-band radiance GeoTIFF (an orthorectified RGB) is refused as a DEM."""
    path = tmp_path / "radiance.tif"
    with rasterio.open(path, "w", driver="GTiff", width=8, height=6, count=3, dtype="float32",
                       crs="EPSG:4326", transform=from_origin(7.0, 46.0, 0.01, 0.01)) as ds:
        ds.write(np.full((3, 6, 8), 80.0, np.float32))
    with pytest.raises(DemError, match="3 bands, not a DEM"):
        open_dem(path)


def test_lattice_window_is_the_prepared_window_as_plain_data(tmp_path):
    """``lattice_window``: None before ``prepare``; then the float32 posts (no data NaN, an
    int16 raster read exactly), the inverse geotransform, the window's place in the lattice,
    the wrap centre of a geographic DEM and the transformation of a projected one."""
    data = np.arange(200 * 300, dtype=np.int16).reshape(200, 300) % 3000
    data[50, 60] = -9999
    data[52, 61] = 9500  # implausible: kept in the window, screened at lookup
    path = write_geotiff_dem(tmp_path / "geo.tif", "EPSG:4326",
                             from_origin(10.0, 47.0, 0.01, 0.01), data, -9999)
    dem = open_dem(f"{path}:ellipsoid")
    assert dem.lattice_window() is None
    dem.prepare(10.5, 45.5, 12.5, 46.8)
    w = dem.lattice_window()
    assert w is not None and w.data.dtype == np.float32 and w.data.flags.c_contiguous
    assert w.lattice.tolist() == [17, 47, 200, 300] and w.data.shape == (136, 206)
    expected = data[17:153, 47:253].astype(np.float32)
    expected[data[17:153, 47:253] == -9999] = np.nan
    np.testing.assert_array_equal(w.data, expected)
    np.testing.assert_allclose(w.inv, [100.0, 0.0, -1000.0, 0.0, -100.0, 4700.0], atol=1e-9)
    assert w.wrap_centre == pytest.approx(11.5) and w.transform is None
    assert w.datum == "ellipsoid"
    # the flat bilinear lookups of the prepared window still screen implausible posts
    assert np.isnan(dem.sample(10.615, 46.475)) and np.isfinite(dem.sample(10.65, 46.45))
    utm_path = write_geotiff_dem(tmp_path / "utm.tif", "EPSG:32633",
                                 from_origin(400000.0, 5200000.0, 1000.0, 1000.0),
                                 np.full((100, 120), 700.0, np.float32))
    utm = open_dem(f"{utm_path}:egm96")
    utm.prepare(13.8, 46.1, 14.9, 46.9)
    wu = utm.lattice_window()
    assert wu is not None and np.isnan(wu.wrap_centre) and wu.transform is not None
    assert wu.datum == "egm96"
    x, y = wu.transform(np.array([15.0]), np.array([46.5]))
    ref = pyproj.Transformer.from_crs(4326, 32633, always_xy=True).transform(15.0, 46.5)
    assert (x[0], y[0]) == ref and x[0] == pytest.approx(500000.0)

"""napari readers: N1 products (product geometry) and geocoded GeoTIFFs (world frame)."""

from __future__ import annotations

import datetime as dt
import warnings

import numpy as np
import pytest
import rasterio
from rasterio.errors import NotGeoreferencedWarning
from rasterio.transform import Affine

from napari_meris_ortho._napari.reader import get_reader, read_layers
from napari_meris_ortho._napari.world import layer_scale, layer_translate
from napari_meris_ortho.errors import MerisOrthoError, N1FormatError
from napari_meris_ortho.geometry.grid import OutputGrid
from napari_meris_ortho.products.n1 import tie_columns, tie_lines, write_product

H, W = 70, 2241


@pytest.fixture(scope="module")
def n1_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("n1") / "MER_FR__1PTEST.N1"
    nt, nc = tie_lines(H, 64), tie_columns(W, 64)
    i, k = np.mgrid[0:nt, 0:nc].astype(np.float64)
    tie_points = {"latitude": 45.9 - 0.16 * i + 0.03 * k, "longitude": 8.0 - 0.06 * i - 0.21 * k,
                  "dem_alt": 100.0 * k, "view_zenith": np.linspace(0, 40.7, nc) + 0 * i,
                  "view_azimuth": 99.6 + 0 * i}
    rows, cols = np.mgrid[0:H, 0:W]
    counts = [((rows * 3 + cols + 100 * b) % 4000).astype(np.uint16) for b in range(15)]
    flags = np.where(cols < 100, 16, 0).astype(np.uint8)
    write_product(path, product_type="MER_FR__1P", tie_points=tie_points, counts=counts,
                  flags=flags, detector_index=(cols % 740).astype(np.int16),
                  first_line_time=dt.datetime(2003, 9, 21, 9, 23, 41))
    return path


def test_reader_accepts_n1_and_geotiff_only(n1_path, tmp_path):
    geo = _write_tif(tmp_path / "out.tif", np.ones((4, 5), np.float32), "EPSG:32632",
                     Affine(260.0, 0, 400_000.0, 0, -260.0, 5_100_000.0))
    png = tmp_path / "image.png"
    png.write_bytes(b"\x89PNG")
    assert get_reader(str(n1_path)) is read_layers
    assert get_reader(str(geo)) is read_layers
    assert get_reader([str(geo), str(n1_path)]) is read_layers
    assert get_reader(str(png)) is None
    assert get_reader([str(geo), str(png)]) is None


def test_n1_reader_layers(n1_path):
    from napari_meris_ortho.products.n1 import read_product

    layers = read_layers(str(n1_path))
    assert [t for _, _, t in layers] == ["image", "image", "labels"]
    # only the RGB quick-look is drawn at first: the radiance stack under it (the RGB is opaque)
    # and the flags open hidden
    assert [kw.get("visible", True) for _, kw, _ in layers] == [False, True, False]
    # multiscale (2241 columns: levels of 2241, 1121 and 561 columns), level 0 read here
    assert all(kw["multiscale"] for _, kw, _ in layers)
    assert [level.shape for level in layers[0][0]] == [(15, H, W), (15, 35, 1121), (15, 18, 561)]
    radiance, rgb, flags = (np.asarray(d[0]) for d, _, _ in layers)
    assert radiance.shape == (15, H, W)
    product = read_product(n1_path)
    np.testing.assert_array_equal(np.asarray(radiance[6]), product.radiance(7))
    np.testing.assert_array_equal(np.asarray(radiance[0, 5, :10]), product.radiance(1)[5, :10])
    assert rgb.shape == (H, W, 3) and rgb.dtype == np.uint8 and layers[1][1]["rgb"]
    assert rgb.min() == 0 and rgb.max() == 255
    # the red channel is band 7: it follows band 7's ordering
    r7 = product.radiance(7)
    assert np.corrcoef(rgb[..., 0].ravel(), r7.ravel())[0, 1] > 0.95
    assert flags.shape == (H, W) and flags.dtype == np.uint8
    assert int(flags[0, 50]) == 16 and int(flags[0, 500]) == 0
    meta = layers[0][1]["metadata"]
    assert meta["tie_points"]["latitude"].shape == (tie_lines(H, 64), 36)
    assert meta["tie_points"]["latitude"][0, 0] == pytest.approx(45.9, abs=1e-6)
    assert meta["mph"]["PRODUCT"].startswith("MER_FR__1P")
    assert "FIRST_LINE_TIME" in meta["sph"]


def test_truncated_n1_is_a_clear_error(n1_path, tmp_path):
    bad = tmp_path / "bad.N1"
    bad.write_bytes(n1_path.read_bytes()[:5000])
    with pytest.raises(N1FormatError):
        read_layers(str(bad))


def _write_tif(path, data, crs, transform, descriptions=None):
    data = data[None] if data.ndim == 2 else data
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[2], height=data.shape[1],
                       count=data.shape[0], dtype=data.dtype, crs=crs, transform=transform,
                       nodata=0) as ds:
        ds.write(data)
        for k, d in enumerate(descriptions or []):
            ds.set_band_description(k + 1, d)
    return path


def test_geotiff_layers_in_world_frame(tmp_path):
    a = np.arange(1, 1 + 20 * 30, dtype=np.float32).reshape(1, 20, 30)
    path = _write_tif(tmp_path / "ortho.tif", np.concatenate([a, 2 * a]), "EPSG:32632",
                      Affine(300.0, 0, 400_000.0, 0, -300.0, 5_100_000.0), ["band_7", "band_5"])
    layers = read_layers(str(path))
    assert [kw["name"] for _, kw, _ in layers] == ["ortho band_7", "ortho band_5"]
    data, kw, kind = layers[0]
    assert kind == "image" and data.shape == (20, 30)
    assert kw["scale"] == (300.0, 300.0)
    # centre of pixel (0, 0): x = 400150, y = 5099850 -> world (-5099850, 400150)
    assert kw["translate"] == (-5_099_850.0, 400_150.0)
    frame = OutputGrid.from_transform(**{k: kw["metadata"]["geo"][k]
                                         for k in ("crs", "transform", "shape")})
    assert frame.x0 == 400_000.0 and frame.y0 == 5_100_000.0 and frame.width == 30
    np.testing.assert_array_equal(layers[1][0], 2 * a[0])


def test_geotiff_counts_with_scale_read_as_radiances(tmp_path):
    """``meris-ortho map`` writes uint16 counts with GDAL scale = sf_rad: layers hold radiances."""
    from napari_meris_ortho.engine.resample import overview_level
    from napari_meris_ortho.geometry.grid import OutputGrid
    from napari_meris_ortho.output.geotiff import write_cog

    g = OutputGrid("EPSG:32632", 400_000.0, 5_100_000.0, 300.0, 300.0, 30, 20)
    counts = np.arange(20 * 30, dtype=np.uint16).reshape(20, 30)  # 0 = background
    path = write_cog(tmp_path / "c.tif", [counts, counts], g, count=2, scales=[0.01, 0.5],
                     offsets=[0.0, 0.0], halve=overview_level)
    layers = read_layers(str(path))
    assert layers[0][0].dtype == np.float32
    np.testing.assert_allclose(layers[1][0], counts * np.float32(0.5))
    np.testing.assert_allclose(layers[0][0], counts * np.float32(0.01), rtol=1e-6)


def test_geotiff_other_crs_reprojected_onto_frame(tmp_path):
    # frame: UTM 32N, 1 km pixels; reference: lon/lat grid with a value = 1000 * column index
    frame = OutputGrid.from_transform(
        "EPSG:32632", (1000.0, 0, 300_000.0, 0, -1000.0, 5_000_000.0), (40, 50))
    lon0, lat0 = 5.0, 45.3
    ref = np.tile(np.arange(1, 301, dtype=np.float32), (200, 1))
    path = _write_tif(tmp_path / "ref.tif", ref, "EPSG:4326",
                      Affine(0.01, 0, lon0, 0, -0.01, lat0))
    from napari_meris_ortho._napari.reader import geotiff_layers

    (data, kw, _), = geotiff_layers(path, frame)
    assert kw["scale"] == layer_scale(frame) and kw["metadata"]["reprojected"]
    # on the frame's pixels, but the whole reference (3 x 2 degrees), not cut to the frame's
    # 50 x 40 km: a second raster is not cut to the first layer's extent
    offset = (np.array(kw["translate"]) - np.array(layer_translate(frame))) / np.array(
        layer_scale(frame))
    np.testing.assert_allclose(offset, np.round(offset), atol=1e-6)
    assert data.shape[0] > 200 and data.shape[1] > 200
    assert (data > 0).mean() > 0.7
    # check one pixel centre: its lon gives the expected column value of the reference
    from pyproj import Transformer

    x, y = 300_000.0 + 10.5 * 1000.0, 5_000_000.0 - 20.5 * 1000.0
    lon, lat = Transformer.from_crs("EPSG:32632", "EPSG:4326", always_xy=True).transform(x, y)
    expected = np.floor((lon - lon0) / 0.01) + 1
    row, col = (int(v) for v in np.round([20 - offset[0], 10 - offset[1]]))
    assert data[row, col] == pytest.approx(expected, abs=1.0)
    # a raster beside the frame, not over it, is all there
    east = _write_tif(tmp_path / "east.tif", np.full((20, 20), 5.0, np.float32), "EPSG:4326",
                      Affine(0.01, 0, 9.5, 0, -0.01, 45.0))
    (data, kw, _), = geotiff_layers(east, frame)
    assert (data == 5.0).sum() > 0.7 * data.size


def test_geotiff_same_crs_other_pixel_size_overlays(tmp_path):
    """Two rasters of the same CRS and different pixel sizes cover the same world area."""
    from napari_meris_ortho._napari.reader import geotiff_layers

    fine = _write_tif(tmp_path / "fine.tif", np.ones((40, 60), np.float32), "EPSG:32632",
                      Affine(250.0, 0, 500_000.0, 0, -250.0, 5_000_000.0))
    coarse = _write_tif(tmp_path / "coarse.tif", np.ones((10, 15), np.float32), "EPSG:32632",
                        Affine(1000.0, 0, 500_000.0, 0, -1000.0, 5_000_000.0))
    (d1, k1, _), = geotiff_layers(fine)
    (d2, k2, _), = geotiff_layers(coarse)
    # world extents (pixel edges) are identical
    for d, k in ((d1, k1), (d2, k2)):
        top = k["translate"][0] - k["scale"][0] / 2
        left = k["translate"][1] - k["scale"][1] / 2
        bottom = top + d.shape[0] * k["scale"][0]
        right = left + d.shape[1] * k["scale"][1]
        assert (top, left, bottom, right) == (-5_000_000.0, 500_000.0, -4_990_000.0, 515_000.0)


def test_geotiff_without_crs_is_refused(tmp_path):
    path = tmp_path / "plain.tif"
    with warnings.catch_warnings():  # written without georeferencing, as meant
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path, "w", driver="GTiff", width=4, height=4, count=1,
                           dtype="float32") as ds:
            ds.write(np.ones((1, 4, 4), np.float32))
    with pytest.raises(MerisOrthoError, match="no CRS"):
        read_layers(str(path))


def test_sparse_huge_geotiff_is_refused_before_reading(tmp_path):
    """A 200000 x 100000 float32 GeoTIFF with no block written (sparse: kB on disk) would
    need 80 GB per band: refused with the grid size instead of read."""
    path = tmp_path / "sparse.tif"
    with rasterio.open(path, "w", driver="GTiff", width=200_000, height=100_000, count=1,
                       dtype="float32", crs="EPSG:4326", tiled=True, sparse_ok=True,
                       BIGTIFF="YES", transform=Affine(0.0018, 0, -180, 0, -0.0018, 90)):
        pass
    assert path.stat().st_size < 10_000_000
    with pytest.raises(MerisOrthoError) as info:
        read_layers(str(path))
    assert "output grid of 200000 x 100000 pixels" in str(info.value)
    assert str(info.value).startswith(f"{path}: ")


@pytest.mark.slow
def test_reader_in_viewer_reprojects_onto_first_geocoded_layer(make_napari_viewer, tmp_path):
    viewer = make_napari_viewer()
    base = _write_tif(tmp_path / "base.tif", np.ones((30, 40), np.float32), "EPSG:32632",
                      Affine(1000.0, 0, 300_000.0, 0, -1000.0, 5_000_000.0))
    ref = _write_tif(tmp_path / "ref.tif", np.full((100, 200), 7.0, np.float32), "EPSG:4326",
                     Affine(0.01, 0, 6.0, 0, -0.01, 45.3))
    viewer.open(str(base), plugin="napari-meris-ortho")
    (layer,) = viewer.open(str(ref), plugin="napari-meris-ortho")
    base_layer = viewer.layers["base"]
    np.testing.assert_allclose(layer.scale, base_layer.scale)
    assert layer.metadata["reprojected"]
    # lon 6..8, lat 44.3..45.3 on the base's 1 km pixels: all of it (about 160 x 115 km), not
    # only the base's 40 x 30 km; the base's pixels are whole pixels of it
    assert layer.data.shape[0] > 110 and layer.data.shape[1] > 155
    offset = (np.array(base_layer.translate) - np.array(layer.translate)) / layer.scale
    np.testing.assert_allclose(offset, np.round(offset), atol=1e-6)
    r, c = (int(v) for v in np.round(offset))
    assert np.all(np.asarray(layer.data)[r:r + 30, c:c + 40] == pytest.approx(7.0))


@pytest.mark.slow
def test_a_geotiff_reprojected_onto_the_world_keeps_the_window_turning(make_napari_viewer,
                                                                         tmp_path, qtbot):
    """A GeoTIFF in another CRS than the viewer's world is reprojected inside napari's call of
    the reader, on the Qt thread: warping the fr-alps reference onto its N1's UTM world there
    would freeze the window for 2-3 s. The warp runs in a thread while the window's timers and
    paints go on (``_qt.waiting.responsively``), and the bands come back as pyramids (napari
    uploads the level that fits the canvas); ``viewer.open`` still returns the layers whole."""
    import time

    from qtpy.QtCore import QTimer

    from napari_meris_ortho import placement

    viewer = make_napari_viewer(show=True)
    base = _write_tif(tmp_path / "base.tif", np.ones((30, 40), np.float32), "EPSG:32632",
                      Affine(100.0, 0, 300_000.0, 0, -100.0, 5_000_000.0))
    # a warp of a quarter of a second or more: the waiting loop turns every ``TURN_MS`` plus
    # its paints, so the timer below ticks about four times meanwhile
    rows, cols = np.mgrid[0:3000, 0:6000]
    values = (1.0 + (rows + cols) / 2).astype(np.float32)
    ref = _write_tif(tmp_path / "ref.tif", values, "EPSG:4326",
                     Affine(0.0004, 0, 6.0, 0, -0.0004, 45.3))
    viewer.open(str(base), plugin="napari-meris-ortho")
    qtbot.wait(100)
    warps: list[tuple[float, float]] = []
    reproject = placement.reproject_onto

    def timed(*args, **kwargs):  # when the warp ran, to count the timer's ticks meanwhile
        t0 = time.perf_counter()
        try:
            return reproject(*args, **kwargs)
        finally:
            warps.append((t0, time.perf_counter()))

    ticks: list[float] = []
    timer = QTimer()
    timer.timeout.connect(lambda: ticks.append(time.perf_counter()))
    timer.start(10)
    placement.reproject_onto = timed
    try:
        (layer,) = viewer.open(str(ref), plugin="napari-meris-ortho")
    finally:
        placement.reproject_onto = reproject
        timer.stop()
    ((start, end),) = warps
    during = [t for t in ticks if start <= t <= end]
    # the window turned while the warp ran (a warp on the Qt thread: 0 ticks)
    assert end - start > 0.1 and len(during) >= 2, (end - start, len(during))
    assert layer.multiscale and layer.metadata["reprojected"]
    assert layer.data[0].shape[0] > 1024  # whole: about 120 x 200 km on 100 m pixels
    assert layer.data[-1].shape[0] <= 1024
    lo, hi = layer.contrast_limits
    assert 1.0 < lo < hi < 4500.0


def _rgb_tif(path, rgb, alpha=None, overviews=()):
    from rasterio.enums import ColorInterp, Resampling

    count = 3 if alpha is None else 4
    with rasterio.open(path, "w", driver="GTiff", width=rgb.shape[1], height=rgb.shape[0],
                       count=count, dtype="uint8", crs="EPSG:32632", photometric="RGB",
                       transform=Affine(260.0, 0, 400_000.0, 0, -260.0, 5_100_000.0)) as ds:
        ds.write(np.moveaxis(rgb, -1, 0), [1, 2, 3])
        if alpha is not None:
            ds.write(alpha, 4)
            ds.colorinterp = [ColorInterp.red, ColorInterp.green, ColorInterp.blue,
                              ColorInterp.alpha]
    if overviews:
        with rasterio.open(path, "r+") as ds:
            ds.build_overviews(list(overviews), Resampling.nearest)
    return path


@pytest.mark.parametrize("big", [False, True])
@pytest.mark.slow
def test_an_rgb_geotiff_opens_as_one_rgb_layer(make_napari_viewer, tmp_path, big):
    """A true-colour reference image (PHOTOMETRIC=RGB, with or without alpha), as GDAL, QGIS or
    a satellite's TCI write it, is one RGB layer, transparent where its alpha is 0 (not three or
    four grey layers, the alpha band an opaque one on top). A big one reads its levels on
    demand, from its overviews."""
    h, w = (2600, 2200) if big else (60, 80)
    rows, cols = np.mgrid[0:h, 0:w]
    rgb = np.stack([(rows % 256), (cols % 256), ((rows + cols) % 256)], -1).astype(np.uint8)
    alpha = np.full((h, w), 255, np.uint8)
    alpha[: h // 10] = 0
    path = _rgb_tif(tmp_path / "tci.tif", rgb, alpha, overviews=(2, 4, 8) if big else ())
    viewer = make_napari_viewer()
    (layer,) = viewer.open(str(path), plugin="napari-meris-ortho")
    assert layer.rgb and layer.multiscale == big
    full = layer.data[0] if big else layer.data
    assert full.shape == (h, w, 4)
    np.testing.assert_array_equal(np.asarray(full[h // 2:h // 2 + 5, 100:110]),
                                  np.dstack([rgb, alpha])[h // 2:h // 2 + 5, 100:110])
    if big:
        with rasterio.open(path, overview_level=0) as ds:
            overview = np.moveaxis(ds.read(), 0, -1)
        np.testing.assert_array_equal(np.asarray(layer.data[1]), overview)
    np.testing.assert_allclose(layer.scale, [260.0, 260.0])
    # without alpha: three channels
    (plain,) = viewer.open(str(_rgb_tif(tmp_path / "rgb.tif", rgb[:50, :60])),
                           plugin="napari-meris-ortho")
    assert plain.rgb and np.asarray(full_res(plain)).shape[-1] == 3


def full_res(layer):
    return layer.data[0] if layer.multiscale else layer.data


@pytest.mark.slow
def test_south_up_rotated_and_gcp_geotiffs_open_north_up(make_napari_viewer, tmp_path):
    """A south-up raster (positive y pixel size), a rotated geotransform and ground control
    points only (``gdal_translate -gcp``) are valid GDAL georeferencing: each opens north-up,
    warped by GDAL (nearest: the south-up pixels exactly, flipped), never refused as "not
    north-up" or with no reason."""
    from rasterio.control import GroundControlPoint
    from rasterio.crs import CRS

    z = np.arange(1, 1 + 40 * 50, dtype=np.float32).reshape(40, 50)
    south = _write_tif(tmp_path / "south.tif", z, "EPSG:4326",
                       Affine(0.01, 0, 10.0, 0, 0.01, 45.6))
    rotated = _write_tif(tmp_path / "rotated.tif", z, "EPSG:32632",
                         Affine(100.0, 20.0, 400_000.0, 20.0, -100.0, 5_000_000.0))
    gcp = tmp_path / "gcp.tif"
    points = [GroundControlPoint(r, c, 10.0 + c / 100, 46.0 - r / 100)
              for r, c in ((0, 0), (0, 50), (40, 0), (40, 50))]
    with rasterio.open(gcp, "w", driver="GTiff", width=50, height=40, count=1, dtype="float32",
                       gcps=points, crs=CRS.from_epsg(4326)) as ds:
        ds.write(z, 1)
    viewer = make_napari_viewer()
    north = _write_tif(tmp_path / "north.tif", z[::-1], "EPSG:4326",
                       Affine(0.01, 0, 10.0, 0, -0.01, 46.0))  # the same raster, north-up
    (twin,) = viewer.open(str(north), plugin="napari-meris-ortho")
    (layer,) = viewer.open(str(south), plugin="napari-meris-ortho")
    np.testing.assert_array_equal(np.asarray(layer.data), z[::-1])
    np.testing.assert_allclose(layer.translate, twin.translate, atol=1e-9)
    np.testing.assert_allclose(layer.scale, twin.scale, rtol=1e-9)
    viewer.layers.clear()
    (layer,) = viewer.open(str(gcp), plugin="napari-meris-ortho")
    np.testing.assert_array_equal(np.asarray(layer.data), z)
    viewer.layers.clear()
    (layer,) = viewer.open(str(rotated), plugin="napari-meris-ortho")
    data = np.asarray(layer.data)
    assert data.shape[0] > 40 and data.shape[1] > 50  # the rotated raster's north-up envelope
    assert set(np.unique(data[data > 0])) <= set(z.ravel())  # nearest: its own values


def test_longitudes_beyond_180_land_beside_the_same_ground(tmp_path):
    """A geographic raster in longitudes 190..193 opened into a world at -170..-167 (the same
    ground) overlays that ground, not a place 360 degrees away."""
    from napari_meris_ortho._napari.reader import geotiff_layers

    frame = OutputGrid.from_transform("EPSG:4326", (0.01, 0, -170.0, 0, -0.01, 10.0), (300, 300))
    path = _write_tif(tmp_path / "lon360.tif", np.full((200, 200), 3.0, np.float32),
                      "EPSG:4326", Affine(0.02, 0, 190.5, 0, -0.02, 9.5))
    (data, kw, _), = geotiff_layers(path, frame)
    lon0 = kw["translate"][1]  # the raster's west edge, 190.5 = -169.5 degrees
    assert -170.0 <= lon0 <= -169.0, lon0
    assert (np.asarray(data) == 3.0).mean() > 0.9


@pytest.mark.slow
def test_an_n1_is_read_off_the_qt_thread_while_the_window_turns(make_napari_viewer, n1_path,
                                                                 tmp_path, qtbot, monkeypatch):
    """napari calls the reader on its Qt thread: a session's first N1 (its readers' imports,
    reading, levels and placement, and napari's own import of xarray for its first layer) would
    hold the window for the whole of a first open (about 1 s on fr-alps). That runs in a
    thread while the window's timers go on; the coarse-placement warning is still given, from
    the Qt thread. Here xarray is loaded already: the first read is told it is pending."""
    import threading
    import time

    from qtpy.QtCore import QTimer

    from napari_meris_ortho._napari import reader
    from napari_meris_ortho.products import open as product_open

    viewer = make_napari_viewer(show=True)
    # a 10 m map first: the N1's affine placement is coarse on it, which warns
    base = _write_tif(tmp_path / "base.tif", np.ones((30, 40), np.float32), "EPSG:32632",
                      Affine(10.0, 0, 400_000.0, 0, -10.0, 5_100_000.0))
    viewer.open(str(base), plugin="napari-meris-ortho")
    qtbot.wait(100)
    calls: list[tuple[str, float, float]] = []
    read, first = product_open.read_product, reader._import_for_first_layer

    def slow_read(*args, **kwargs):  # a slow disk: 0.3 s more
        t0 = time.perf_counter()
        time.sleep(0.3)
        out = read(*args, **kwargs)
        calls.append((threading.current_thread().name, t0, time.perf_counter()))
        return out

    def imports():
        calls.append((threading.current_thread().name, 0.0, 0.0))
        first()

    ticks: list[float] = []
    timer = QTimer()
    timer.timeout.connect(lambda: ticks.append(time.perf_counter()))
    monkeypatch.setattr(product_open, "read_product", slow_read)
    monkeypatch.setattr(reader, "_import_for_first_layer", imports)
    monkeypatch.setattr(reader, "_imports_pending", lambda: True)
    timer.start(10)
    try:
        with pytest.warns(UserWarning, match="affine fit of its tie points"):
            layers = viewer.open(str(n1_path), plugin="napari-meris-ortho")
    finally:
        timer.stop()
    (name, start, end), (name2, _, _) = calls
    main = threading.main_thread().name
    assert name != main and name2 != main, (name, name2)
    during = [t for t in ticks if start <= t <= end]
    assert len(during) >= 3, len(during)  # the window turned in the 0.3 s
    assert [layer.name.split(" · ")[0] for layer in layers] == ["radiance", "RGB 7-5-2", "flags"]
    assert layers[0].multiscale and layers[0].data[0].shape == (15, H, W)


def test_only_a_sessions_first_product_is_read_in_a_thread(n1_path):
    """``_imports_pending`` is True in a new process until a product has been read (the
    thread costs more than a later product's 0.05 s read)."""
    import subprocess
    import sys

    code = ("from napari_meris_ortho._napari import reader as r; a = r._imports_pending(); "
            "r._n1_layer_data(%r, None); print(a, r._imports_pending())")
    out = subprocess.run([sys.executable, "-c", code % str(n1_path)],
                         capture_output=True, text=True, timeout=300)
    assert out.stdout.split() == ["True", "False"], out.stderr[-2000:]


@pytest.mark.slow
def test_a_big_geotiff_without_overviews_is_read_once_off_the_qt_thread(make_napari_viewer,
                                                                         tmp_path, monkeypatch):
    """A GeoTIFF with no overviews opened on its own grid is read once, in a thread, into
    in-memory levels: read on demand, each level's read (the contrast limits, napari's first
    slice of each band) would read the whole band on the Qt thread (the fr-alps reference, 3810
    x 2955, 3 bands, would hold the window about 2 s at every opening). A COG still opens on its
    own overviews (``test_lazy_layers``)."""
    import threading

    from napari_meris_ortho._napari import reader

    rows, cols = np.mgrid[0:1500, 0:2500]
    path = _write_tif(tmp_path / "plain.tif", (1.0 + rows + cols).astype(np.float32),
                      "EPSG:4326", Affine(0.0025, 0, 6.0, 0, -0.0025, 46.0))
    with rasterio.open(path) as ds:
        assert not ds.overviews(1)
    threads: list[str] = []
    physical = reader.physical_bands

    def recorded(ds):
        threads.append(threading.current_thread().name)
        return physical(ds)

    monkeypatch.setattr(reader, "physical_bands", recorded)
    viewer = make_napari_viewer(show=True)
    (layer,) = viewer.open(str(path), plugin="napari-meris-ortho")
    assert len(threads) == 1 and threads[0] != threading.main_thread().name, threads
    assert layer.multiscale and all(isinstance(level, np.ndarray) for level in layer.data)
    np.testing.assert_array_equal(layer.data[0], (1.0 + rows + cols).astype(np.float32))
    assert layer.data[-1].shape[0] <= 1024

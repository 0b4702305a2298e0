"""Lazy multiscale layers: an N1 or a COG opens as pyramids read on demand; napari shows the
level that fits the canvas and reads only that, not the whole product (four full float32 bands
for the contrast limits and the RGB quick-look: about 3 s for fr-alps) in full-resolution
textures.
"""

from __future__ import annotations

import datetime as dt
import tracemalloc

import numpy as np
import pytest
import rasterio

from napari_meris_ortho._napari.reader import read_layers
from napari_meris_ortho.display import contrast_limits, stretch_channel
from napari_meris_ortho.products.n1 import read_product, tie_columns, tie_lines, write_product

#: a full-width FR product (2241 columns), 1400 lines: levels 2241, 1121 and 561 columns wide
H, W = 1400, 2241


@pytest.fixture(scope="module")
def big_n1(tmp_path_factory):
    path = tmp_path_factory.mktemp("big") / "MER_FR__1PBIG.N1"
    nt, nc = tie_lines(H, 64), tie_columns(W, 64)
    i, k = np.mgrid[0:nt, 0:nc].astype(np.float64)
    tie_points = {"latitude": 46.0 - 0.16 * i + 0.03 * k, "longitude": 8.0 - 0.06 * i - 0.21 * k,
                  "dem_alt": 100.0 * k, "view_zenith": np.linspace(0, 40.7, nc) + 0 * i,
                  "view_azimuth": 99.6 + 0 * i}
    rows, cols = np.mgrid[0:H, 0:W]
    counts = [(500 + (rows * 3 + cols * (b + 1)) % 4000).astype(np.uint16) for b in range(15)]
    flags = np.where(cols < 100, 16, 0).astype(np.uint8)
    write_product(path, product_type="MER_FR__1P", tie_points=tie_points, counts=counts,
                  flags=flags, detector_index=(cols % 740).astype(np.int16),
                  first_line_time=dt.datetime(2003, 9, 21, 9, 23, 41))
    return path


def test_opening_reads_a_fraction_of_one_band(big_n1):
    """The reader reads the coarsest level only: it allocates less than one full float32 band
    (12.5 MB), not four full bands (band 7 for the contrast limits, 7, 5 and 2 for the
    quick-look) read and stretched."""
    read_product(big_n1)  # the headers' own allocations are not the reader's
    tracemalloc.start()
    try:
        layers = read_layers(str(big_n1))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < H * W * 4, f"peak {peak / 2**20:.1f} MB"
    shapes = [[level.shape for level in data] for data, _, _ in layers]
    assert shapes == [[(15, H, W), (15, 700, 1121), (15, 350, 561)],
                      [(H, W, 3), (700, 1121, 3), (350, 561, 3)],
                      [(H, W), (700, 1121), (350, 561)]]


def test_an_n1_selection_converts_only_its_own_pixels(big_n1):
    """A decimated level or a tile of an N1 band converts the selected columns of the selected
    lines to radiance, not the whole lines: every 4th line and column allocates what it returns
    (0.8 MB), a 512 x 512 tile too (1.0 MB), not whole lines as float32 twice, one of them
    kept alive by the returned view (6.3 MB and 9.2 MB at the peak)."""
    from napari_meris_ortho._napari.reader import radiance_reader

    product = read_product(big_n1)
    read = radiance_reader(product)
    for rows, cols in ((range(0, H, 4), range(0, W, 4)), (range(300, 812), range(900, 1412))):
        read(7, rows, cols)  # the first read's own allocations (memory map, caches)
        tracemalloc.start()
        try:
            out = read(7, rows, cols)
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        np.testing.assert_array_equal(out, product.radiance(7)[rows.start:rows.stop:rows.step,
                                                               cols.start:cols.stop:cols.step])
        assert peak < 1.5 * out.nbytes, f"{peak / 2**20:.1f} MB for {out.nbytes / 2**20:.1f} MB"


def test_levels_hold_the_product_values(big_n1):
    """Every level is the product decimated (every 2nd, 4th line and column): radiances, the
    quick-look stretched by the coarsest level's 1-99 % limits, the flags."""
    product = read_product(big_n1)
    (radiance, kw, _), (rgb, _, _), (flags, _, _) = read_layers(str(big_n1))
    r7 = product.radiance(7)
    np.testing.assert_array_equal(np.asarray(radiance[0][6, 100:140, 2000:2100]),
                                  r7[100:140, 2000:2100])
    np.testing.assert_array_equal(np.asarray(radiance[2][6]), r7[::4, ::4])
    np.testing.assert_array_equal(np.asarray(radiance[1][:, 5, 7]),
                                  [product.radiance(b)[10, 14] for b in range(1, 16)])
    # contrast limits of band 7 from the coarsest level: within 1 % of the full band's
    full = contrast_limits(r7, 0.0)
    np.testing.assert_allclose(kw["contrast_limits"], full, rtol=0.01)
    for c, b in enumerate((7, 5, 2)):
        limits = contrast_limits(product.radiance(b)[::4, ::4])
        np.testing.assert_array_equal(np.asarray(rgb[1][..., c]),
                                      stretch_channel(product.radiance(b)[::2, ::2], limits))
    np.testing.assert_array_equal(np.asarray(flags[1]), product.flags[::2, ::2])


@pytest.mark.slow
def test_viewer_shows_a_decimated_level_of_the_n1(make_napari_viewer, big_n1):
    viewer = make_napari_viewer(show=True)
    layers = viewer.open(str(big_n1), plugin="napari-meris-ortho")
    viewer.screenshot(canvas_only=True)  # a draw: napari picks the level for the canvas
    rgb = next(layer for layer in layers if layer.name.startswith("RGB"))
    assert all(layer.multiscale for layer in layers)
    assert rgb.data_level > 0
    shown = rgb._slice.image.raw  # the tile napari sends to the canvas
    assert shown.shape[0] * shown.shape[1] <= H * W / 4
    np.testing.assert_array_equal(shown, np.asarray(rgb.data[rgb.data_level])[
        tuple(slice(lo, hi + 1) for lo, hi in rgb.corner_pixels.T)])


def test_cog_opens_on_its_own_overviews(make_napari_viewer, tmp_path):
    """A COG as ``meris-ortho map`` writes it (uint16 counts x scale, overviews 2, 4, 8): one
    level per overview, each read from the file's overview, in radiances."""
    from napari_meris_ortho.engine.resample import overview_level
    from napari_meris_ortho.geometry.grid import OutputGrid
    from napari_meris_ortho.output.geotiff import write_cog

    h, w = 1300, 2500
    grid = OutputGrid("EPSG:32632", 400_000.0, 5_100_000.0, 300.0, 300.0, w, h)
    rows, cols = np.mgrid[0:h, 0:w]
    counts = ((rows * 7 + cols * 3) % 5000 + 1).astype(np.uint16)
    counts[:50] = 0  # background
    path = write_cog(tmp_path / "map.tif", [counts], grid, count=1, scales=[0.01],
                     offsets=[0.0], halve=overview_level)
    viewer = make_napari_viewer(show=True)
    (layer,) = viewer.open(str(path), plugin="napari-meris-ortho")
    viewer.screenshot(canvas_only=True)
    assert layer.multiscale and len(layer.data) == 4
    assert layer.data_level > 0
    np.testing.assert_allclose(np.asarray(layer.data[0][200:210, 300:320]),
                               counts[200:210, 300:320] * np.float32(0.01), rtol=1e-6)
    for k in range(3):
        with rasterio.open(path, overview_level=k) as ds:
            overview = ds.read(1) * np.float32(0.01)
            overview[ds.read_masks(1) == 0] = 0
        np.testing.assert_array_equal(np.asarray(layer.data[k + 1]), overview)
    assert np.asarray(layer.data[1][:20]).max() == 0  # background stays 0, not nodata x scale


@pytest.mark.slow
def test_a_cog_of_gdals_cog_driver_opens_with_its_odd_overviews(make_napari_viewer, tmp_path):
    """GDAL's COG driver rounds an overview's size down (627 lines: 313, 156), the pyramid's
    levels are ceil(n / f) (314, 157): the last line and column of a level repeat the
    overview's last ones: a view reaching them reads (no "cannot reshape array")."""
    import rasterio.shutil
    from rasterio.transform import from_origin

    h, w = 627, 1068
    values = (np.arange(h * w, dtype=np.float32).reshape(h, w) % 977.0) + 1.0
    plain = tmp_path / "plain.tif"
    with rasterio.open(plain, "w", driver="GTiff", width=w, height=h, count=1, dtype="float32",
                       crs="EPSG:4326", transform=from_origin(11.9, 47.0, 0.0025, 0.0025),
                       tiled=True, blockxsize=256, blockysize=256) as ds:
        ds.write(values, 1)
    path = tmp_path / "cog.tif"
    rasterio.shutil.copy(plain, path, driver="COG", blocksize=256, overview_resampling="nearest")
    with rasterio.open(path, overview_level=0) as ds:
        overview = ds.read(1)
    assert overview.shape == (313, 534)  # rounded down: the case of this test
    viewer = make_napari_viewer(show=True)
    (layer,) = viewer.open(str(path), plugin="napari-meris-ortho")
    viewer.screenshot(canvas_only=True)
    level = np.asarray(layer.data[1])
    assert level.shape == (314, 534)
    np.testing.assert_array_equal(level[:313], overview)
    np.testing.assert_array_equal(level[313], overview[312])  # the last line repeated
    np.testing.assert_array_equal(np.asarray(layer.data[0][620:, 1000:]), values[620:, 1000:])


@pytest.mark.slow
def test_multiscale_layer_saves_its_full_resolution(make_napari_viewer, tmp_path):
    """File > Save Selected Layers on a multiscale layer writes level 0 (the plugin's writer;
    np.asarray of napari's multiscale data would not even be an image)."""
    from napari_meris_ortho._napari.writer import write_geotiff_layer

    viewer = make_napari_viewer()
    (layer,) = viewer.open(str(_cog(tmp_path)), plugin="napari-meris-ortho")
    assert layer.multiscale
    data, meta, _ = layer.as_layer_data_tuple()
    (out,) = write_geotiff_layer(str(tmp_path / "saved.tif"), data, meta)
    with rasterio.open(out) as ds:
        assert ds.shape == (1300, 2500)
        np.testing.assert_array_equal(ds.read(1), np.asarray(layer.data[0]))


def _cog(tmp_path):
    from napari_meris_ortho.engine.resample import overview_level
    from napari_meris_ortho.geometry.grid import OutputGrid
    from napari_meris_ortho.output.geotiff import write_cog

    grid = OutputGrid("EPSG:32632", 400_000.0, 5_100_000.0, 300.0, 300.0, 2500, 1300)
    rows, cols = np.mgrid[0:1300, 0:2500]
    counts = ((rows * 7 + cols * 3) % 5000 + 1).astype(np.uint16)
    return write_cog(tmp_path / "cog.tif", [counts], grid, count=1, scales=[0.01],
                     offsets=[0.0], halve=overview_level)


@pytest.mark.slow
def test_an_n1_is_drawn_before_its_layers_controls_are_made(make_napari_viewer, qtbot, tiny_n1,
                                                             monkeypatch):
    """Opening an N1 inserts three layers in one napari call; their controls (and Qt's styling
    of them) were 0.1-0.2 s each of the time to the first pixels. The reader leaves them to the
    turns after the opening: a stand-in frame holds each place, the controls follow, and a
    layer inserted afterwards gets its own at once again."""
    from napari._qt.layer_controls import qt_layer_controls_container as qlc

    from napari_meris_ortho._napari._qt.insertion import CONTROLS_STAND_IN

    viewer = make_napari_viewer(show=True)
    container = viewer.window._qt_viewer.controls
    made: list[str] = []
    create = qlc.create_qt_layer_controls

    def spy(layer):
        made.append(layer.name)
        return create(layer)

    monkeypatch.setattr(qlc, "create_qt_layer_controls", spy)
    layers = viewer.open(tiny_n1, plugin="napari-meris-ortho")
    assert len(layers) == 3 and not made
    assert all(container.widgets[x].objectName() == CONTROLS_STAND_IN for x in layers)
    active = viewer.layers.selection.active
    assert container.currentWidget() is container.widgets[active]
    viewer.screenshot(canvas_only=True)  # drawn with stand-ins in the controls stack
    qtbot.waitUntil(lambda: len(made) == 3, timeout=5000)
    qtbot.wait(50)
    assert sorted(made) == sorted(x.name for x in layers)
    assert not any(container.widgets[x].objectName() == CONTROLS_STAND_IN for x in layers)
    assert container.currentWidget() is container.widgets[active]
    extra = viewer.add_image(np.zeros((4, 4), np.float32), name="extra")
    assert made[-1] == "extra" and container.widgets[extra].objectName() != CONTROLS_STAND_IN
    viewer.layers.clear()  # every stand-in is gone, no controls left behind
    assert container.widgets == {}


@pytest.mark.slow
def test_an_n1s_flags_overlays_are_built_after_its_first_frame(make_napari_viewer, qtbot,
                                                              tiny_n1):
    """napari builds a labels layer's polygon and brush overlays at its insertion (0.07-0.08 s
    of an N1's opening, 0.3 s at the session's first). The reader holds napari's scene graph
    for its hidden flags layer, the last one: the first frame is drawn without them, and they
    are built (and the flags layer joins the scene) in the turns after the opening."""
    viewer = make_napari_viewer(show=True)
    canvas = viewer.window._qt_viewer.canvas
    radiance, rgb, flags = viewer.open(tiny_n1, plugin="napari-meris-ortho")
    assert not canvas._layer_overlay_to_visual.get(flags)
    assert canvas._pause_scene_graph
    assert canvas.layer_to_visual[rgb].node.parent is canvas.view.scene  # in the first frame
    assert canvas.layer_to_visual[flags].node.parent is None
    viewer.screenshot(canvas_only=True)
    qtbot.waitUntil(lambda: not canvas._pause_scene_graph, timeout=5000)
    built = canvas._layer_overlay_to_visual[flags]
    assert {type(o).__name__ for o in built} == {"LabelsPolygonOverlay",
                                                "LabelsBrushStrokeOverlay"}
    assert canvas.layer_to_visual[flags].node.parent is canvas.view.scene
    flags.visible = True  # the scene graph follows the layers again
    flags.mode = "polygon"
    assert built[flags._overlays["polygon"]].node.visible
    extra = viewer.add_labels(np.zeros((4, 4), np.uint8), name="extra")
    assert len(canvas._layer_overlay_to_visual[extra]) == 2

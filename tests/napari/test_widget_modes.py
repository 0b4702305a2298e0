"""The Orthorectify widget offers the CLI's parallax and search options (through
``OrthoOptions.of``), updates an existing synthesis store (input-store field), and names what
Run will do before Run (remembered settings never switch the mode silently)."""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest

from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.options import Geolocation, Parallax, SearchMethod
from napari_meris_ortho.ortho import orthorectify
from napari_meris_ortho.products.n1 import read_product, write_product
from napari_meris_ortho.synthesis.reading import open_synthesis

pytestmark = pytest.mark.slow


def _widget(viewer):
    _, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    return widget


def _run(widget, qtbot):
    assert widget.start() is not None, widget.status.value
    qtbot.waitUntil(lambda: not widget.running, timeout=120_000)
    assert widget.status.value.startswith("done"), widget.status.value


def _copy(tiny_n1, path, when, gain):
    """The tiny product seen at another time, radiances times ``gain``."""
    first = read_product(tiny_n1)
    tie_points = {k: v for k, v in first.tie_points.items()
                  if k in ("latitude", "longitude", "dem_alt", "view_zenith", "view_azimuth",
                           "sun_zenith", "sun_azimuth")}
    rows, cols = np.mgrid[0:first.height, 0:first.width]
    base = 1000 + rows * 2 + cols + ((rows // 8 + cols // 8) % 2) * 400
    counts = [(gain * (base + 10 * b)).astype(np.uint16) for b in range(15)]
    write_product(path, product_type="MER_FR__1P", tie_points=tie_points, counts=counts,
                  flags=np.zeros(rows.shape, np.uint8),
                  detector_index=(cols % 740).astype(np.int16), first_line_time=when)
    return path


def _synthesis_widget(make_napari_viewer, tiny_n1, tmp_path):
    """The tiny product seen twice more (x 0.9, x 0.5) and a widget set for a one-band
    synthesis with the tie-point heights: (viewer, widget, second, third, store path)."""
    second = _copy(tiny_n1, tmp_path / "MER_FR__1PTWO.N1", dt.datetime(2003, 9, 24, 9, 41), 0.9)
    third = _copy(tiny_n1, tmp_path / "MER_FR__1PTHREE.N1", dt.datetime(2003, 9, 27, 9, 46),
                  0.5)
    viewer = make_napari_viewer()
    widget = _widget(viewer)
    widget.elevation.value = "tiepoints"
    widget.geometry.value = False
    widget.bands.value = "7"
    return viewer, widget, second, third, tmp_path / "store"


def test_parallax_and_search_reach_the_engine(make_napari_viewer, qtbot, tiny_n1, tiny_dem):
    viewer = make_napari_viewer()
    widget = _widget(viewer)
    widget.products.value = [tiny_n1]
    widget.add_dem(tiny_dem)
    widget.bands.value = "7"
    widget.geometry.value = False
    widget.parallax.value = "ellipsoid"
    widget.search.value = "handbook"
    opts = widget.settings().options()
    assert (opts.parallax, opts.method, opts.geolocation) == (
        Parallax.ELLIPSOID, SearchMethod.HANDBOOK, Geolocation.ECEF)
    _run(widget, qtbot)
    layer = next(x for x in viewer.layers if x.name.startswith("ortho b7"))
    grid = widget.last_run.items[0]["grid"]
    product = read_product(tiny_n1)
    ellipsoid = orthorectify(product, grid=grid, dems=[tiny_dem], bands=(7,),
                             parallax="ellipsoid", method="handbook")
    handbook = orthorectify(product, grid=grid, dems=[tiny_dem], bands=(7,))
    valid = ellipsoid.valid
    np.testing.assert_array_equal(layer.data[valid], ellipsoid.bands[7][valid])
    # the options changed the result: the handbook sphere maps other antecedents somewhere
    assert np.count_nonzero(handbook.bands[7][valid] != ellipsoid.bands[7][valid]) > 0


def test_synthesis_update_from_the_widget(make_napari_viewer, qtbot, tiny_n1, tmp_path):
    viewer, widget, second, third, store = _synthesis_widget(make_napari_viewer, tiny_n1,
                                                             tmp_path)
    widget.products.value = [tiny_n1, second]
    widget.algorithm.value = "min-radiance"
    widget.output.value = store
    assert widget.mode.value == "new synthesis (min-radiance) of 2 products"
    assert not widget.keep.native.isHidden() and widget.keep.value == 0  # synthesis: shown
    _run(widget, qtbot)

    widget.products.value = [third]
    widget.output.value = None
    widget.input_store.value = store
    assert widget.mode.value == "update synthesis store (min-radiance) with 1 product in place"
    widget.output.value = store  # the same store as output: in place too
    assert widget.mode.value == "update synthesis store (min-radiance) with 1 product in place"
    widget.output.value = store.parent / "copy"
    assert widget.mode.value == ("update synthesis store (min-radiance) with 1 product into a "
                                 f"copy at {store.parent / 'copy'}")
    widget.output.value = None
    _run(widget, qtbot)
    assert "updated synthesis (min-radiance) of 1 product" in widget.status.value
    assert "kept the store's newest" not in widget.status.value  # keep 0: every commit
    synthesis = open_synthesis(store)
    assert len(synthesis.history()) == 2
    names = set(synthesis.product_names().values())
    assert read_product(third).product_name in names and len(names) == 3
    # the darkest product (x 0.5) wins the minimum radiance where it sees the ground
    count = np.asarray(synthesis.read("count"))
    winner = np.asarray(synthesis.read("product"))
    third_index = next(k for k, v in synthesis.product_names().items()
                       if v == read_product(third).product_name)
    assert (count == 3).sum() > 1000
    assert np.mean(winner[count == 3] == third_index) > 0.99
    layer = next(x for x in viewer.layers if x.name == "synthesis min-radiance b7")
    np.testing.assert_allclose(layer.data, synthesis.band(7))
    # another rule than the store's, or a directory that is no store: one message before Run
    widget.algorithm.value = "max-ndvi"
    assert widget.start() is None
    assert widget.status.value.startswith(f"input synthesis {store}: is a min-radiance "
                                          "synthesis, cannot update it with max-ndvi")
    widget.input_store.value = tmp_path
    assert widget.start() is None
    assert widget.status.value == f"input synthesis {tmp_path}: not a synthesis store"
    assert len(open_synthesis(store).history()) == 2  # nothing written


def test_a_synthesis_run_keeps_the_newest_commits(make_napari_viewer, qtbot, tiny_n1,
                                                  tmp_path):
    """The widget's "keep commits" (the CLI's ``synthesize --keep``): after the update's commit
    the store keeps its newest N commits and frees what only older ones held; the field shows
    for syntheses only; a negative count is refused before Run."""
    _, widget, second, third, store = _synthesis_widget(make_napari_viewer, tiny_n1, tmp_path)
    widget.products.value = [tiny_n1]
    assert widget.keep.native.isHidden()  # mapping: nothing to keep
    widget.algorithm.value = "min-radiance"
    assert not widget.keep.native.isHidden()
    widget.output.value = store
    _run(widget, qtbot)
    for product in (second, third):
        widget.products.value = [product]
        widget.output.value = None
        widget.input_store.value = store
        _run(widget, qtbot)
    assert len(open_synthesis(store).history()) == 3
    before = open_synthesis(store).read("count")
    fourth = _copy(tiny_n1, tmp_path / "MER_FR__1PFOUR.N1", dt.datetime(2003, 9, 30, 9, 51), 0.7)
    widget.products.value = [fourth]
    widget.keep.value = 1
    _run(widget, qtbot)
    assert "kept the store's newest 1 commit," in widget.status.value, widget.status.value
    freed = float(widget.status.value.split("commit, ")[1].split(" MB freed")[0])
    assert freed >= 0.0  # a tiny store: kilobytes
    synthesis = open_synthesis(store)
    assert len(synthesis.history()) == 1  # the update's commit, older ones expired
    assert len(set(synthesis.product_names().values())) == 4
    np.testing.assert_array_equal(np.asarray(synthesis.read("count")), np.asarray(before) + (
        np.asarray(before) > 0))  # the fourth product sees what the others saw: count + 1
    settings = widget.settings()
    settings.keep = -1
    with pytest.raises(OptionsError, match="keep must be a number of commits"):
        settings.check()


def test_mode_label_and_remembered_selection(make_napari_viewer, tiny_n1, tiny_dem):
    viewer = make_napari_viewer()
    widget = _widget(viewer)
    widget.products.value = [tiny_n1]
    assert widget.mode.value == "mapping: orthorectify 1 product, one by one"
    widget.algorithm.value = "max-ndvi"
    assert widget.mode.value == "new synthesis (max-ndvi) of 1 product"
    # the next session opens with the remembered rule, and says so before any Run
    again = _widget(make_napari_viewer())
    assert again.algorithm.value == "max-ndvi"
    assert again.mode.value == "new synthesis (max-ndvi) of 0 products"
    assert "max-ndvi" in again.status.value and "last session" in again.status.value


def test_update_of_a_large_store_reads_only_what_the_products_changed(make_napari_viewer, qtbot,
                                                                      tiny_n1, tmp_path):
    """A store nine times the product's footprint (a Europe-size store, in small): the widget's
    update shows the part the product reached, read from the store, placed where it lies, and
    does not read every layer of the whole grid into memory (15 x 3.2e8 pixels for Europe)."""
    from napari_meris_ortho.geometry.grid import OutputGrid
    from napari_meris_ortho.ortho import product_grid
    from napari_meris_ortho.synthesis.api import synthesize
    from napari_meris_ortho.synthesis.tiling import products_window

    foot = product_grid(read_product(tiny_n1), "EPSG:4326")
    big = OutputGrid(foot.crs, foot.x0 - foot.width * foot.dx, foot.y0 + foot.height * foot.dy,
                     foot.dx, foot.dy, 3 * foot.width, 3 * foot.height)
    store = tmp_path / "store"
    synthesize([tiny_n1], store, grid=big, bands=(7,), algorithm="min-radiance",
               elevation="tiepoints")
    second = _copy(tiny_n1, tmp_path / "MER_FR__1PTWO.N1", dt.datetime(2003, 9, 24, 9, 41), 0.7)
    viewer = make_napari_viewer()
    widget = _widget(viewer)
    widget.elevation.value = "tiepoints"
    widget.geometry.value = False
    widget.products.value = [second]
    widget.algorithm.value = "min-radiance"
    widget.input_store.value = store
    _run(widget, qtbot)
    synthesis = open_synthesis(store)
    window = products_window(synthesis.grid, [read_product(second)])
    r0, r1, c0, c1 = window
    assert (r1 - r0) * (c1 - c0) < big.width * big.height / 4
    layer = next(x for x in viewer.layers if x.name == "synthesis min-radiance b7")
    np.testing.assert_allclose(np.asarray(layer.data), synthesis.band(7, window))
    assert layer.metadata["window"] == list(window)
    # placed where it lies: its first pixel's world position is the store's pixel (r0, c0)
    x, y = synthesis.grid.xy(r0, c0)
    np.testing.assert_allclose(layer.data_to_world((0, 0)), (-y, x), rtol=0, atol=1e-9)

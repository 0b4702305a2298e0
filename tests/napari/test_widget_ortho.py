"""Orthorectify widget end to end (thread worker) and the geometry layers it adds."""

from __future__ import annotations

import numpy as np
import pytest
from napari.layers import Image, Labels, Vectors
from pyproj import Transformer

from napari_meris_ortho._napari.widget_ortho import (
    CRS_EPSG,
    CRS_GEOGRAPHIC,
    OrthorectifyWidget,
    parse_bands,
    run_orthorectify,
)
from napari_meris_ortho.engine.boundary import segment_boundary
from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.geometry.grid import OutputGrid, default_grid
from napari_meris_ortho.products.n1 import read_product
from qt_paints import paints_of

STAMP = " · 09-21 09:23"  # first line time of the tiny product


def _run(widget, qtbot, timeout=60_000):
    worker = widget.start()
    assert worker is not None, widget.status.value
    assert widget.running
    qtbot.waitUntil(lambda: not widget.running, timeout=timeout)
    return worker


def test_widget_runs_end_to_end(make_napari_viewer, qtbot, tiny_n1, tiny_dem):
    viewer = make_napari_viewer()
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [tiny_n1]
    widget.add_dem(tiny_dem)
    widget.vector_step.value = 8
    _run(widget, qtbot)
    assert widget.status.value.startswith("done"), widget.status.value
    names = [layer.name for layer in viewer.layers]
    for name in ("ortho RGB 7-5-2", "ortho b2", "ortho b5", "ortho b7", "iterations",
                 "elevation", "elevation source", "facets", "footprint", "parallax ×10"):
        assert f"{name}{STAMP}" in names, name
    rgb = viewer.layers[f"ortho RGB 7-5-2{STAMP}"]
    assert isinstance(rgb, Image) and rgb.rgb

    # the grid: UTM 32N (footprint centre ~7.6 E), smallest rectangle holding the boundary
    product = read_product(tiny_n1)
    tp = product.tie_points
    expected = default_grid(segment_boundary(tp["latitude"], tp["longitude"]),
                            crs="EPSG:32632", pixel_size=260.0)
    frame = OutputGrid.from_transform(**rgb.metadata["geo"])
    assert frame.same_grid(expected)
    assert (frame.x0, frame.y0, frame.width, frame.height) == pytest.approx(
        (expected.x0, expected.y0, expected.width, expected.height))
    # world extent of the pixel corners = the grid bounds, north up
    top_left = np.asarray(rgb.translate) - np.asarray(rgb.scale) / 2
    assert top_left == pytest.approx([-expected.y0, expected.x0])
    bottom_right = top_left + np.asarray(rgb.scale) * rgb.data.shape[:2]
    x_min, y_min, x_max, y_max = expected.bounds
    assert bottom_right == pytest.approx([-y_min, x_max])
    band7 = viewer.layers[f"ortho b7{STAMP}"]
    assert band7.data.shape == (expected.height, expected.width)
    assert np.count_nonzero(band7.data) > 0.5 * band7.data.size

    assert widget.last_run.items[0]["valid"] is None  # the run keeps no arrays
    item = run_orthorectify(widget.settings()).items[0]  # the same run, without Qt
    # elevation source: the DEM (label 1) everywhere it was valid
    src = viewer.layers[f"elevation source{STAMP}"]
    assert isinstance(src, Labels)
    assert set(np.unique(src.data[item["valid"]])) == {1}
    it = viewer.layers[f"iterations{STAMP}"].data
    # no antecedent: transparent (NaN), not a colour of the iterations' scale
    assert it[item["valid"]].min() >= 1 and np.isnan(it[~item["valid"]]).all()


@pytest.mark.slow
def test_footprint_and_facets_match_engine_boundary(make_napari_viewer, qtbot, tiny_n1):
    viewer = make_napari_viewer()
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"
    _run(widget, qtbot)
    tp = read_product(tiny_n1).tie_points
    lat, lon = tp["latitude"], tp["longitude"]
    to_utm = Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True)

    footprint = viewer.layers[f"footprint{STAMP}"]
    assert isinstance(footprint, Vectors) and footprint.vector_style == "line"
    boundary = segment_boundary(lat, lon)
    bx, by = to_utm.transform(boundary.lon, boundary.lat)
    vertices = footprint.data[:, 0]  # the edges' starts: the polygon's vertices, in order
    ends = footprint.data[:, 0] + footprint.data[:, 1]
    np.testing.assert_allclose(ends, np.roll(vertices, -1, axis=0), atol=1.0)  # closed ring
    # every boundary vertex (border tie point) is a footprint vertex: world = (-northing, easting)
    for x, y in zip(bx, by, strict=True):
        d = np.hypot(vertices[:, 0] + y, vertices[:, 1] - x)
        assert d.min() < 1.0  # napari keeps vectors in float32: 0.5 m steps at 5000 km
    n_border = 2 * (lat.shape[0] - 1) + 2 * (lat.shape[1] - 1)
    assert len(vertices) in (n_border * 4, n_border * 4 + 1)  # densified x4

    facets = viewer.layers[f"facets{STAMP}"]
    n_lines, n_cols = lat.shape
    assert isinstance(facets, Vectors)
    # every edge of the tie-point grid once: along the lines, then along the columns
    assert len(facets.data) == n_lines * (n_cols - 1) + (n_lines - 1) * n_cols
    x, y = to_utm.transform(lon, lat)
    np.testing.assert_allclose(facets.data[0], [[-y[0, 0], x[0, 0]],
                                                [-y[0, 1] + y[0, 0], x[0, 1] - x[0, 0]]],
                               atol=1.0)
    last = facets.data[-1]
    np.testing.assert_allclose(last[0] + last[1], [-y[-1, -1], x[-1, -1]], atol=1.0)
    # the status bar names the facet under the cursor (section 3.4): the centre of a facet
    i, k = n_lines - 2, n_cols // 2
    row = -(y[i, k] + y[i, k + 1] + y[i + 1, k + 1] + y[i + 1, k]) / 4
    col = (x[i, k] + x[i, k + 1] + x[i + 1, k + 1] + x[i + 1, k]) / 4
    status = facets.get_status((row, col), view_direction=None, dims_displayed=[0, 1],
                               world=True)
    assert status["coordinates"].endswith(f"; facet of tie line {i}, tie column {k}"), status
    far = facets.get_status((row - 1e6, col), view_direction=None, dims_displayed=[0, 1],
                            world=True)
    assert "facet" not in far["coordinates"]


@pytest.mark.slow
def test_parallax_vectors_count_and_direction(make_napari_viewer, qtbot, tiny_n1):
    viewer = make_napari_viewer()
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"
    widget.vector_step.value = 10
    widget.exaggeration.value = 5.0
    _run(widget, qtbot)
    item = run_orthorectify(widget.settings()).items[0]  # the widget's run, without Qt
    diag, valid, grid = item["diagnostics"], item["valid"], item["grid"]
    vec = viewer.layers[f"parallax ×5{STAMP}"]
    assert isinstance(vec, Vectors)
    rows = np.arange(5, grid.height, 10)
    cols = np.arange(5, grid.width, 10)
    sub = (valid & np.isfinite(diag["shift_east_m"]))[np.ix_(rows, cols)]
    assert len(vec.data) == int(sub.sum()) > 20
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    rr, cc = rr[sub], cc[sub]
    east, north = diag["shift_east_m"][rr, cc], diag["shift_north_m"][rr, cc]
    # direction = shift x 5 in world (row = -north, col = east); ends on the pixel centre
    np.testing.assert_allclose(vec.data[:, 1, 0], -5.0 * north, rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(vec.data[:, 1, 1], 5.0 * east, rtol=1e-5, atol=1e-3)
    x_c, y_c = grid.xy(rr, cc)
    np.testing.assert_allclose(vec.data[:, 0] + vec.data[:, 1], np.c_[-y_c, x_c], atol=1e-3)
    # the satellite is east (view azimuth 100 deg): terrain points move east, more with height
    assert np.all(east >= 0) and east.max() > 50.0
    np.testing.assert_allclose(vec.features["height"], diag["elevation"][rr, cc])


@pytest.mark.slow
def test_geographic_and_epsg_output(make_napari_viewer, qtbot, tiny_n1, tmp_path):
    viewer = make_napari_viewer()
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "none"
    widget.geometry.value = False
    widget.crs.value = CRS_GEOGRAPHIC
    widget.bands.value = "13"
    out = tmp_path / "ortho.tif"
    widget.output.value = out
    _run(widget, qtbot)
    layer = viewer.layers[f"ortho b13{STAMP}"]
    frame = OutputGrid.from_transform(**layer.metadata["geo"])
    assert frame.is_geographic
    assert frame.dx == pytest.approx(np.degrees(260.0 / 6_370_997.0))
    assert out.is_file()
    from napari_meris_ortho._napari.reader import read_layers

    (data, kwargs, _), = read_layers(str(out))
    np.testing.assert_array_equal(data, layer.data)
    assert kwargs["scale"] == pytest.approx(tuple(layer.scale))
    assert kwargs["translate"] == pytest.approx(tuple(layer.translate))
    assert len(viewer.layers) == 1

    widget.crs.value = CRS_EPSG
    widget.epsg.value = 3035
    widget.output.value = None
    widget.pixel_size.value = 1000.0
    _run(widget, qtbot)
    assert widget.status.value.startswith("done"), widget.status.value

    grid = widget.last_run.items[0]["grid"]
    assert grid.dx == 1000.0 and grid.crs.to_epsg() == 3035
    # the viewer's world frame is geographic: the LAEA result is reprojected onto it
    second = viewer.layers[-1]
    assert second.metadata["reprojected_from"]["transform"][0] == 1000.0
    frame2 = OutputGrid.from_transform(**second.metadata["geo"])
    assert frame2 == frame and frame2.crs.to_epsg() == 4326
    both = (layer.data > 0) & (second.data > 0)
    assert both.sum() > 0.5 * (layer.data > 0).sum()
    # same radiances, 1 km pixels against 260 m ones: close on average
    ratio = np.median(second.data[both] / layer.data[both])
    assert ratio == pytest.approx(1.0, abs=0.05)


@pytest.mark.slow
def test_dem_list_order(make_napari_viewer, tiny_dem, tmp_path):
    import shutil

    viewer = make_napari_viewer()
    widget = OrthorectifyWidget(viewer)
    second = tmp_path / "dem2.tif"
    shutil.copy(tiny_dem, second)
    widget.add_dem(tiny_dem)
    widget.add_dem(second)
    widget.add_dem(tmp_path / "missing.tif")
    assert widget.dems == [tiny_dem, second]
    assert "not found" in widget.status.value
    widget.move_dem(second, -1)
    assert widget.dems == [second, tiny_dem]
    widget.dem_list.value = [second]
    widget._move_selected(+1)
    assert widget.dems == [tiny_dem, second]
    widget.dem_list.value = [tiny_dem]
    widget._remove_selected()
    assert widget.dems == [second]
    assert widget.dem_list.choices == (second,)


@pytest.mark.slow
def test_bad_options_are_reported(make_napari_viewer, qtbot, tiny_n1, tiny_dem):
    viewer = make_napari_viewer()
    widget = OrthorectifyWidget(viewer)
    assert widget.start() is None
    assert "at least one N1 product" in widget.status.value
    widget.products.value = [tiny_n1]
    widget.bands.value = "7,16"
    assert widget.start() is None and "1..15" in widget.status.value
    widget.bands.value = "7"
    widget.add_dem(tiny_dem)
    widget.elevation.value = "none"
    assert widget.start() is None
    assert "only used with elevation 'dem'" in widget.status.value
    assert len(viewer.layers) == 0
    assert widget.run_button.enabled and not widget.cancel_button.enabled


def test_cancel_stops_the_worker(make_napari_viewer, qtbot, tiny_n1):
    viewer = make_napari_viewer()
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [tiny_n1, tiny_n1]
    widget.elevation.value = "tiepoints"
    widget.cancel()  # a cancel before the start is forgotten
    widget._cancel.set()
    assert widget.start() is not None
    assert not widget._cancel.is_set()
    widget.cancel()
    qtbot.waitUntil(lambda: not widget.running, timeout=60_000)
    assert widget.status.value == "cancelled by the user"
    assert len(viewer.layers) == 0


@pytest.mark.slow
def test_closing_the_dock_mid_run_cancels_the_job(make_napari_viewer, qtbot, tiny_n1):
    """Closing the Orthorectify dock (its title bar's close button: napari takes the widget out
    of the window) while a run runs cancels the job as if Cancel had been pressed: nothing left
    running with nothing on screen to follow or cancel it, no layers coming in later."""
    viewer = make_napari_viewer(show=True)
    dock, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    widget.products.value = [tiny_n1] * 40
    widget.elevation.value = "tiepoints"
    widget.bands.value = "all"
    assert widget.start() is not None, widget.status.value
    thread = widget._job.thread
    qtbot.waitUntil(lambda: widget.progress_state[0] > 0, timeout=60_000)
    done, total = widget.progress_state
    assert done < total
    viewer.window.remove_dock_widget(dock)
    qtbot.waitUntil(lambda: not thread.is_alive(), timeout=5_000)
    qtbot.wait(300)  # a (wrongly) finished job's layers would go in now
    assert widget.progress_state[0] < total
    assert len(viewer.layers) == 0
    assert not widget.running


@pytest.mark.slow
def test_closing_the_dock_while_the_layers_go_in_leaves_the_viewer_as_before(
        make_napari_viewer, qtbot, tiny_n1):
    """Closed between a rerun's layer changes, the widget undoes them as Cancel does: the
    viewer keeps its layers and its canvas repaints (it does not while layers go in)."""
    viewer = make_napari_viewer(show=True)
    dock, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"
    _run(widget, qtbot)
    before = list(viewer.layers)
    assert widget.start() is not None
    qtbot.waitUntil(lambda: len(widget._removed) >= 3, timeout=60_000)
    canvas = viewer.window._qt_viewer.canvas.native
    assert not canvas.updatesEnabled()  # in the middle of the insertions
    viewer.window.remove_dock_widget(dock)
    qtbot.waitUntil(lambda: not widget.running, timeout=10_000)
    assert list(viewer.layers) == before
    assert canvas.updatesEnabled()


def test_parse_bands():
    assert parse_bands("7, 5,2") == (7, 5, 2)
    assert parse_bands("all") is None and parse_bands("") is None
    with pytest.raises(OptionsError):
        parse_bands("0")
    with pytest.raises(OptionsError):
        parse_bands("x")


@pytest.mark.slow
def test_widgets_dock_through_the_manifest(make_napari_viewer, qtbot, tiny_n1):
    from napari_meris_ortho._napari.widget_flicker import FlickerWidget

    viewer = make_napari_viewer()
    _, ortho = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    _, flicker = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Flicker")
    assert isinstance(ortho, OrthorectifyWidget) and isinstance(flicker, FlickerWidget)
    ortho.products.value = [tiny_n1]
    ortho.elevation.value = "none"
    ortho.geometry.value = False
    _run(ortho, qtbot)
    assert ortho.status.value.startswith("done"), ortho.status.value
    # the flicker widget sees the new layers (two top-most images pre-selected)
    assert flicker.layer_a.value is not None and flicker.layer_b.value is not None
    assert flicker.layer_a.value.name != flicker.layer_b.value.name


@pytest.mark.slow
def test_a_rerun_replaces_all_its_layers_and_shows_a_band(make_napari_viewer, qtbot, tiny_n1,
                                                          tmp_path):
    """A rerun with fewer bands removes every layer an earlier run made of the same product
    (the first run's RGB and other bands left beside the new layers can crash Mesa's software GL
    drawing them). A run without bands 7, 5 and 2 shows its first band, not no image. Two
    products of one sensing time get distinct names."""
    viewer = make_napari_viewer(show=True)
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"
    _run(widget, qtbot)
    assert f"ortho RGB 7-5-2{STAMP}" in [x.name for x in viewer.layers]
    widget.bands.value = "7"
    widget.geometry.value = False
    _run(widget, qtbot)
    assert widget.status.value.startswith("done"), widget.status.value
    assert [x.name for x in viewer.layers] == [f"ortho b7{STAMP}"]
    assert viewer.layers[0].visible
    # two products of one sensing time: distinct names, and a rerun replaces both sets
    twin = tmp_path / "MER_FR__1PTWIN.N1"
    twin.write_bytes(tiny_n1.read_bytes())
    widget.products.value = [tiny_n1, twin]
    for _ in range(2):
        _run(widget, qtbot)
        names = [x.name for x in viewer.layers]
        assert sorted(names) == sorted([f"ortho b7{STAMP} {tiny_n1.name}",
                                        f"ortho b7{STAMP} {twin.name}"]), names


@pytest.mark.slow
def test_cancel_while_the_layers_go_in_leaves_the_viewer_as_before(make_napari_viewer, qtbot,
                                                                   tiny_n1):
    """A Cancel between a rerun's layer changes undoes the changes made, not leaving the old
    layers partly removed and none of the new ones in."""
    viewer = make_napari_viewer(show=True)
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"
    _run(widget, qtbot)
    before = list(viewer.layers)
    visible = [layer.visible for layer in before]
    assert len(before) > 5 and any(visible) and not all(visible)
    assert widget.start() is not None
    qtbot.waitUntil(lambda: len(widget._removed) >= 3, timeout=60_000)  # in the middle
    widget.cancel()
    qtbot.waitUntil(lambda: not widget.running, timeout=10_000)
    assert widget.status.value.startswith("cancelled by the user: the viewer is as before")
    assert list(viewer.layers) == before  # the same layer objects, in the same order
    assert [layer.visible for layer in viewer.layers] == visible
    assert widget._removed == [] and widget._appended == []
    assert widget.run_button.enabled


@pytest.mark.slow
def test_hidden_layers_get_their_thumbnails(make_napari_viewer, qtbot, tiny_n1):
    """napari makes a thumbnail when it slices a layer, and slices visible layers only (and
    empties an image layer's slice when it inserts it): a run's single bands and diagnostics,
    and an opened product's radiances, all hidden, would show black squares in the layer list.
    They are sliced once, shown and hidden again in a turn of their own each: after the
    run has ended, after the product's first pixels. Not the labels layers (napari's first
    slicing of one builds its colour textures: 0.28-0.30 s after a session's first open)."""
    viewer = make_napari_viewer(show=True)
    layers = viewer.open(tiny_n1, plugin="napari-meris-ortho")
    radiance = next(x for x in layers if x.name.startswith("radiance"))
    assert not radiance.visible and not radiance.thumbnail[..., :3].any()  # not sliced yet
    qtbot.waitUntil(lambda: radiance.thumbnail[..., :3].any(), timeout=5000)
    assert not radiance.visible
    # opened again: napari renames the copy ("... [1]"), whose thumbnail is made too
    copy = next(x for x in viewer.open(tiny_n1, plugin="napari-meris-ortho")
                if x.name.startswith("radiance"))
    assert copy.name.endswith(" [1]") and not copy.thumbnail[..., :3].any()
    qtbot.waitUntil(lambda: copy.thumbnail[..., :3].any(), timeout=5000)
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"
    _run(widget, qtbot)
    hidden = [viewer.layers[f"{name}{STAMP}"] for name in
              ("ortho b2", "ortho b5", "ortho b7", "iterations", "elevation")]
    assert not any(x.visible for x in hidden)
    qtbot.waitUntil(lambda: all(x.thumbnail[..., :3].any() for x in hidden), timeout=5000)
    assert not any(x.visible for x in hidden)
    # a band's thumbnail is its image, not a flat square
    thumb = viewer.layers[f"ortho b7{STAMP}"].thumbnail[..., 0]
    assert len(np.unique(thumb)) > 10


@pytest.mark.slow
def test_the_running_state_is_painted_before_the_job_starts(make_napari_viewer, qtbot,
                                                            tiny_n1):
    """The widget's "running..." state is on screen before the job's thread starts: a first
    run's job loads its modules and numba's kernels holding the GIL, and the paint waited for
    it (the first run's longest stall, 0.19-0.21 s on fr-alps). A widget closed before its job
    starts starts none."""

    viewer = make_napari_viewer(show=True)
    widget = OrthorectifyWidget(viewer)
    viewer.window.add_dock_widget(widget)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"

    def state() -> tuple[str, bool] | None:  # the status painted, and whether the job runs
        job = widget._job
        return None if job is None else (widget.status.value, job.thread.ident is not None)

    with paints_of(widget.status.native, state) as seen:
        _run(widget, qtbot)
    painted = [paint for paint in seen if paint is not None]
    running = [started for text, started in painted if text == "running..."]
    assert running and not running[0], painted
    assert widget.status.value.startswith("done"), widget.status.value

    assert widget.start() is not None
    job = widget._job
    widget._shutdown()
    qtbot.wait(200)
    assert job.thread.ident is None and not widget.running


def test_output_like_a_layer_takes_its_grid(make_napari_viewer, qtbot, tiny_n1, tmp_path):
    """Output CRS "like a layer": the run's output has the chosen layer's CRS, transform and
    size (as the CLI's ``--like``), so both align pixel for pixel."""
    import rasterio

    from napari_meris_ortho._napari.widget_ortho import CRS_LIKE

    reference = OutputGrid("EPSG:3035", 4_080_000.0, 2_560_000.0, 500.0, 500.0, 200, 160)
    ref = tmp_path / "reference.tif"
    with rasterio.open(ref, "w", driver="GTiff", width=reference.width,
                       height=reference.height, count=1, dtype="uint8",
                       crs=reference.crs.to_wkt(), transform=reference.transform) as ds:
        ds.write(np.ones((1, reference.height, reference.width), np.uint8))
    viewer = make_napari_viewer()
    viewer.open(str(ref), plugin="napari-meris-ortho")
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "none"
    widget.geometry.value = False
    widget.bands.value = "13"
    widget.crs.value = CRS_LIKE
    assert not widget.like.native.isHidden() and not widget.pixel_size.enabled
    assert viewer.layers[0].name in [c for c in widget.like.choices]
    widget.like.value = viewer.layers[0].name
    out = tmp_path / "aligned.tif"
    widget.output.value = out
    _run(widget, qtbot)
    assert widget.status.value.startswith("done"), widget.status.value
    assert widget.last_run.items[0]["grid"] == reference
    with rasterio.open(out) as ds:
        assert (ds.width, ds.height) == (reference.width, reference.height)
        assert tuple(ds.transform)[:6] == pytest.approx(tuple(reference.transform)[:6])
        assert ds.crs.to_epsg() == 3035
        assert (ds.read(1) > 0).sum() > 1000  # the product lies on the reference's grid


def test_like_a_layer_without_a_layer_is_refused(make_napari_viewer, tiny_n1):
    from napari_meris_ortho._napari.widget_ortho import CRS_LIKE

    widget = OrthorectifyWidget(make_napari_viewer())
    widget.products.value = [tiny_n1]
    widget.elevation.value = "none"
    widget.crs.value = CRS_LIKE
    assert widget.start() is None
    assert "'like a layer' needs a layer" in widget.status.value

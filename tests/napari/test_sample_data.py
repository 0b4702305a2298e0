"""Sample data "fr-small": layers in one world frame; the orthorectified mapping matches the
reference image far better than the uncorrected one (handbook section 4.4)."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho._napari.layout import camera_of
from napari_meris_ortho.geometry.grid import OutputGrid


def test_sample_small_in_viewer(make_napari_viewer):
    viewer = make_napari_viewer()
    layers = viewer.open_sample("napari-meris-ortho", "fr-small")
    names = [layer.name for layer in layers]
    for name in ("reference b7", "DEM", "uncorrected RGB 7-5-2", "ortho RGB 7-5-2",
                 "uncorrected b7", "ortho b7", "footprint",
                 "facets"):
        assert name in names, name
    # the automatic spacing and exaggeration keep the arrows apart; the name says which
    vec, = [layer for layer in layers if layer.name.startswith("parallax ×")]
    exaggeration = vec.metadata["exaggeration"]
    assert vec.name == f"parallax ×{exaggeration:g}" and 1 <= exaggeration <= 10
    ref = viewer.layers["reference b7"]
    frame = OutputGrid.from_transform(**ref.metadata["geo"])

    assert frame.crs.to_epsg() == 32633  # UTM zone of the footprint (~15 E)
    assert frame.dx == 260.0
    for name in ("DEM", "uncorrected b7", "ortho b7", "ortho RGB 7-5-2"):
        layer = viewer.layers[name]
        assert OutputGrid.from_transform(**layer.metadata["geo"]) == frame
        np.testing.assert_allclose(layer.scale[-2:], ref.scale)
        np.testing.assert_allclose(layer.translate[-2:], ref.translate)
    r = ref.data
    o = viewer.layers["ortho b7"].data
    u = viewer.layers["uncorrected b7"].data
    m = (r > 0) & (o > 0) & (u > 0)
    assert m.sum() > 100_000
    corr_ortho = np.corrcoef(r[m], o[m])[0, 1]
    corr_flat = np.corrcoef(r[m], u[m])[0, 1]
    assert corr_ortho > 0.95 and corr_flat < 0.7
    dem = viewer.layers["DEM"].data
    assert dem[m].max() > 2000.0  # the high range is in the small scene
    assert len(vec.data) >= 50  # a readable field: about ten arrows across the scene
    # shift lengths (exaggerated) against heights: higher points move further
    length = np.hypot(vec.data[:, 1, 0], vec.data[:, 1, 1])
    h = vec.features["height"].to_numpy()
    assert np.corrcoef(length, h)[0, 1] > 0.8
    assert length.max() == pytest.approx(exaggeration * h.max() * np.tan(np.radians(30)),
                                         rel=0.4)


@pytest.mark.slow
def test_disparity_of_sample_ortho_against_reference(make_napari_viewer):
    from napari_meris_ortho._napari.widget_flicker import FlickerWidget

    viewer = make_napari_viewer()
    viewer.open_sample("napari-meris-ortho", "fr-small")
    widget = FlickerWidget(viewer)
    widget.layer_a.value = viewer.layers["reference b7"]
    widget.layer_b.value = viewer.layers["ortho b7"]
    result = widget.measure_disparity()
    dx, dy = result.global_displacement
    n = int(np.count_nonzero(result.candidate))
    assert n > 500
    assert abs(dx) < 0.25 and abs(dy) < 0.25  # orthorectified: superimposable
    vec = viewer.layers["disparity ×10 reference b7"]
    assert 0 < len(vec.data) < n / 4  # thinned to a readable density
    np.testing.assert_allclose(vec.scale, viewer.layers["reference b7"].scale)
    widget.layer_b.value = viewer.layers["uncorrected b7"]
    flat = widget.measure_disparity()
    # uncorrected: features sit at their ellipsoid position, west of the true one (the
    # satellite is east): B is displaced by -dX, several pixels on the high range
    assert np.nanpercentile(flat.dx[flat.candidate], 5) < -2.0
    assert flat.global_displacement[0] < dx - 0.2


#: longest event-loop gap while a sample loads (one napari layer insertion on a loaded machine)
MAX_GAP_S = 2.0


@pytest.mark.slow
def test_sample_from_the_menu_loads_in_the_background(make_napari_viewer, qtbot, tmp_path,
                                                      monkeypatch):
    """File > Open Sample (inside the running event loop) returns at once and simulates the
    scene in another process, maps it off the GUI thread and adds one layer per turn
    (simulated and mapped on the GUI thread, fr-small would freeze napari for about 20 s)."""
    import time

    from qtpy.QtCore import QTimer

    from napari_meris_ortho._napari import sample_data

    monkeypatch.setenv("MERIS_ORTHO_CACHE", str(tmp_path))  # simulated afresh
    viewer = make_napari_viewer(show=True)
    # napari's first layer of each kind sets up GL (up to 2 s on Xvfb): not the sample's
    viewer.add_image(np.zeros((2, 2), np.float32))
    viewer.add_shapes([np.array([[0.0, 0.0], [0.0, 1.0], [1.0, 1.0]])], shape_type="polygon")
    viewer.add_vectors(np.zeros((1, 2, 2)))
    viewer.add_labels(np.zeros((2, 2), np.uint8))
    qtbot.wait(100)
    viewer.layers.clear()
    stamps: list[float] = []
    timer = QTimer()
    timer.timeout.connect(lambda: stamps.append(time.perf_counter()))
    timer.start(10)
    took: list[float] = []
    from napari.utils.notifications import notification_manager

    told = len(notification_manager.records)

    def open_sample() -> None:
        t0 = time.perf_counter()
        viewer.open_sample("napari-meris-ortho", "fr-small")
        took.append(time.perf_counter() - t0)

    shown_at_draw: list[int] = []
    viewer.window._qt_viewer.canvas._scene_canvas.events.draw.connect(
        lambda _e=None: shown_at_draw.append(sum(layer.visible for layer in viewer.layers)))
    import gc

    frozen_before = gc.get_freeze_count()
    QTimer.singleShot(0, open_sample)
    qtbot.waitUntil(lambda: "footprint" in viewer.layers and not sample_data.loading(),
                    timeout=120_000)
    timer.stop()
    # the sample's visible layers appear one per frame (vispy builds each one's shaders at
    # its first draw), after the placeholder has gone
    steps = np.diff(shown_at_draw)
    assert shown_at_draw[-1] == sum(layer.visible for layer in viewer.layers) >= 4
    assert steps.max() == 1, shown_at_draw
    names = [layer.name for layer in viewer.layers]
    assert "reference b7" in names and "ortho b7" in names
    assert not any(name.startswith("MERIS sample") for name in names)  # placeholder gone
    # each layer's controls came in turns after its insertion, in place of a stand-in
    from napari_meris_ortho._napari._qt.insertion import CONTROLS_STAND_IN

    stack = viewer.window._qt_viewer.controls
    assert all(stack.widgets[x].objectName() != CONTROLS_STAND_IN for x in viewer.layers)
    assert took[0] < 1.0  # main: the whole simulation and both mappings (11 s)
    assert float(np.diff(stamps).max()) < MAX_GAP_S
    # the scene graph, held while the layers went in, is napari's again; nothing stays
    # frozen out of the garbage collector after the placeholder's removal (when nothing was)
    assert viewer.window._qt_viewer.canvas._pause_scene_graph is False
    assert gc.get_freeze_count() == 0 or frozen_before > 0
    # the camera on the sample, not on the 1-pixel placeholder napari framed (zoom ~900 on
    # (0, 0): a black canvas); no "Inconsistent units" (the placeholder in pixels beside the
    # sample in metres); the status bar not left at "generating..."
    ref = viewer.layers["reference b7"]
    (low, high) = np.asarray(ref.extent.world)[:, -2:]
    assert np.all((low <= camera_of(viewer).center[-2:]) & (camera_of(viewer).center[-2:] <= high))
    canvas = np.asarray(viewer.canvas.size, np.float64)
    assert camera_of(viewer).zoom < 2 * np.min(canvas / (high - low))  # the whole sample in view
    units = [str(n.message) for n in notification_manager.records[told:]
             if "units" in str(n.message)]
    assert not units, units
    assert "generating" not in str(viewer.status)


def test_sample_rasters_bigger_than_a_level_are_pyramids(monkeypatch):
    """A sample's rasters go in as pyramids like a run's (``ortho_run.multiscale_layer``): with
    levels of at most 256 pixels, fr-small's rasters get levels, full resolution first and
    unchanged; geometry layers stay as they are."""
    from napari_meris_ortho import pyramid
    from napari_meris_ortho._napari.sample_data import build_sample, sample_layers

    sample = build_sample("fr-small", None)
    flat = {kw["name"]: (data, kind) for data, kw, kind in sample_layers(sample)}
    monkeypatch.setattr(pyramid, "MAX_LEVEL_SIDE", 256)
    layers = sample_layers(sample)
    rasters = [(data, kw) for data, kw, kind in layers if kind in ("image", "labels")]
    assert len(rasters) >= 5
    for data, kw in rasters:
        assert kw.get("multiscale"), kw["name"]
        assert len(data) >= 2 and max(data[-1].shape[:2]) <= 256
        np.testing.assert_array_equal(np.asarray(data[0]), np.asarray(flat[kw["name"]][0]))
    geometry = [kw for _, kw, kind in layers if kind in ("shapes", "vectors")]
    assert len(geometry) == 3 and not any(kw.get("multiscale") for kw in geometry)

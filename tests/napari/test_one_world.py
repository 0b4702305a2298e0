"""One world. Product layers (an N1 opened with the reader) and the map layers
of a run share the output CRS and its unit, so napari keeps units (no "Inconsistent units"
warning, scale bar in metres); an N1 opened first founds the world where it lies, and a run in
another CRS is moved into that world with its geometry sized in the world's units."""

from __future__ import annotations

import numpy as np
import pytest
from napari.utils.notifications import notification_manager

from napari_meris_ortho._napari.layout import camera_of
from napari_meris_ortho._napari.widget_ortho import CRS_GEOGRAPHIC, OrthorectifyWidget

pytestmark = pytest.mark.slow

STAMP = " · 09-21 09:23"


def _run(widget, qtbot):
    assert widget.start() is not None, widget.status.value
    qtbot.waitUntil(lambda: not widget.running, timeout=60_000)
    assert widget.status.value.startswith("done"), widget.status.value


def _widget(viewer, n1, crs=None):
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [n1]
    widget.elevation.value = "tiepoints"
    if crs is not None:
        widget.crs.value = crs
    return widget


def _centre(layer):
    """World (row, col) centre of a layer's extent."""
    return np.asarray(layer.extent.world, np.float64)[:, -2:].mean(axis=0)


@pytest.fixture
def messages():
    """napari notifications (show_warning) raised during the test."""
    seen = []
    notification_manager.notification_ready.connect(seen.append)
    yield seen
    notification_manager.notification_ready.disconnect(seen.append)


def test_product_and_map_layers_share_units(make_napari_viewer, qtbot, tiny_n1, messages):
    viewer = make_napari_viewer()
    viewer.open(str(tiny_n1), plugin="napari-meris-ortho")
    viewer.canvas.overlays.scale_bar.visible = True
    _run(_widget(viewer, tiny_n1), qtbot)
    viewer.screenshot(canvas_only=True)  # a draw: napari checks the units there
    texts = [str(m.message) for m in messages]
    assert not [t for t in texts if "Inconsistent units" in t], texts
    units = viewer.layers.extent.units
    assert units is not None and [str(u) for u in units[-2:]] == ["meter", "meter"]

    # the N1 lies where its orthorectification lies: centres within 10 km (not 5000 km)
    n1_rgb = viewer.layers[f"RGB 7-5-2{STAMP}"]
    ortho_rgb = viewer.layers[f"ortho RGB 7-5-2{STAMP}"]
    gap = np.hypot(*(_centre(n1_rgb) - _centre(ortho_rgb)))
    assert gap < 10_000.0, gap
    # the camera frames the result (napari's fit_to_view(layers=) fails over a 3-D band stack)
    assert np.hypot(*(np.asarray(camera_of(viewer).center)[-2:] - _centre(ortho_rgb))) < 10_000.0
    # the band axis in front of the same world
    radiance = viewer.layers[f"radiance{STAMP}"]
    assert [str(u) for u in radiance.units[-2:]] == ["meter", "meter"]
    assert np.hypot(*(_centre(radiance) - _centre(ortho_rgb))) < 10_000.0


def test_geographic_run_into_utm_world(make_napari_viewer, qtbot, tiny_n1, messages):
    viewer = make_napari_viewer()
    _run(_widget(viewer, tiny_n1), qtbot)  # the world: UTM 32N, metres
    utm_footprint = viewer.layers[f"footprint{STAMP}"]
    widget = _widget(viewer, tiny_n1, CRS_GEOGRAPHIC)
    _run(widget, qtbot)  # replaces the layers of the same names, moved into the UTM world
    viewer.screenshot(canvas_only=True)
    assert not [m for m in messages if "Inconsistent units" in str(m.message)]
    footprint = viewer.layers[f"footprint{STAMP}"]
    parallax, = [x for x in viewer.layers if x.name.startswith("parallax ×")]
    for layer in (footprint, parallax, viewer.layers[f"facets{STAMP}"]):
        assert [str(u) for u in layer.units] == ["meter", "meter"], layer.name
    # edge widths in metres, as the UTM run's (degrees would be ~1e-3: invisible)
    width = float(np.asarray(footprint.edge_width).max())
    assert width == pytest.approx(float(np.asarray(utm_footprint.edge_width).max()), rel=0.1)
    assert 50.0 < float(np.asarray(parallax.edge_width).max()) < 5000.0

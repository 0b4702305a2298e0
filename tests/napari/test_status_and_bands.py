"""Status-bar coordinates right whatever layer is selected (after a run, a
vectors layer), the band slider of an N1 naming the MERIS band (1-15, not the step 0-14), and
distinct names for the per-pixel geolocation results within what the layer list shows."""

from __future__ import annotations

import pytest
from napari.layers import Vectors

from napari_meris_ortho.products.n1 import read_product

STAMP = " · 09-21 09:23"


def _widget(viewer, n1):
    _, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    widget.products.value = [n1]
    widget.elevation.value = "tiepoints"
    return widget


def _run(widget, qtbot):
    assert widget.start() is not None, widget.status.value
    qtbot.waitUntil(lambda: not widget.running, timeout=60_000)
    assert widget.status.value.startswith("done"), widget.status.value


@pytest.mark.slow
def test_status_bar_over_the_geometry_layers(make_napari_viewer, qtbot, tiny_n1):
    viewer = make_napari_viewer()
    widget = _widget(viewer, tiny_n1)
    _run(widget, qtbot)
    active = viewer.layers.selection.active
    assert isinstance(active, Vectors)  # what napari selects after a run
    grid = widget.last_run.items[0]["grid"]
    x, y = grid.xy(40, 60)
    footprint = viewer.layers[f"footprint{STAMP}"]
    assert isinstance(footprint, Vectors)
    for layer in (active, footprint, viewer.layers[f"facets{STAMP}"]):
        status = layer.get_status((-y, x), view_direction=None, dims_displayed=[0, 1],
                                  world=True)
        coords = status["coords"]
        assert f"E {x:.0f} m" in coords and f"N {y:.0f} m" in coords, (layer.name, coords)
        assert "EPSG:32632" in coords and "-" not in coords.split("(")[0], coords


def test_band_slider_names_the_band(make_napari_viewer, tiny_n1):
    viewer = make_napari_viewer()
    viewer.open(str(tiny_n1), plugin="napari-meris-ortho")
    radiance = viewer.layers[f"radiance{STAMP}"]
    product = read_product(tiny_n1)
    for step, band in ((6, 7), (0, 1), (14, 15)):
        viewer.dims.set_current_step(0, step)
        assert viewer.dims.point[0] == pytest.approx(band)
        assert viewer.dims.axis_labels[0] == radiance.metadata["band_names"][band - 1].replace(
            "band", "MERIS band"), viewer.dims.axis_labels
        # the world band axis is the band number: data index band - 1 is shown
        assert radiance.world_to_data(viewer.dims.point)[0] == pytest.approx(band - 1)
        assert product.wavelengths[band - 1] > 400.0
    assert viewer.dims.axis_labels[0] == "MERIS band 15 (900 nm)"


@pytest.mark.slow
def test_pixel_geolocation_names_are_distinct(make_napari_viewer, qtbot, geolocated):
    viewer = make_napari_viewer()
    widget = _widget(viewer, geolocated["fsg"])
    widget.elevation.value = "none"
    widget.geolocation.value = "pixel"
    widget.geometry.value = False
    _run(widget, qtbot)
    names = [layer.name for layer in viewer.layers]
    assert len(names) == 4 and all("(pixel geolocation) · " in n for n in names), names
    # distinct within the 16 characters a narrow layer list shows
    assert len({n[:16] for n in names}) == 4, names
    assert {n.split(" (")[0] for n in names} == {"ortho RGB 7-5-2", "ortho b7", "ortho b5",
                                                  "ortho b2"}

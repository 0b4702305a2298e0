"""The Orthorectify widget says what is wrong."""

from __future__ import annotations

import numpy as np
import pytest


def _ortho_widget(viewer):
    _, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    return widget


def _run(widget, qtbot):
    worker = widget.start()
    if worker is not None:
        qtbot.waitUntil(lambda: not widget.running, timeout=120_000)
    return worker


def test_missing_product_is_named(make_napari_viewer, qtbot, tiny_n1, tmp_path):
    viewer = make_napari_viewer()
    widget = _ortho_widget(viewer)
    missing = tmp_path / "MER_FR__1PGONE.N1"
    widget.products.value = [tiny_n1, missing]
    widget.elevation.value = "tiepoints"
    assert _run(widget, qtbot) is None
    assert "not found" in widget.status.value and str(missing) in widget.status.value
    assert len(viewer.layers) == 0


@pytest.mark.slow
def test_dem_elevation_without_dem_is_refused(make_napari_viewer, qtbot, tiny_n1):
    viewer = make_napari_viewer()
    widget = _ortho_widget(viewer)
    widget.products.value = [tiny_n1]
    assert widget.elevation.value == "dem" and widget.dems == []
    assert _run(widget, qtbot) is None
    assert "DEM" in widget.status.value and "tiepoints" in widget.status.value
    assert len(viewer.layers) == 0


@pytest.mark.slow
def test_radiance_geotiff_is_not_a_dem(make_napari_viewer, qtbot, tiny_n1, tiny_dem, tmp_path):
    viewer = make_napari_viewer()
    widget = _ortho_widget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "none"
    widget.bands.value = "7,5,2"
    widget.output.value = tmp_path / "radiance.tif"
    _run(widget, qtbot)
    assert widget.status.value.startswith("done"), widget.status.value
    widget.add_dem(tmp_path / "radiance.tif")
    assert widget.dems == []
    assert "3 bands" in widget.status.value, widget.status.value
    widget.add_dem(tiny_dem)
    assert widget.dems == [tiny_dem]


@pytest.mark.slow
def test_success_clears_an_old_error(make_napari_viewer, qtbot, tiny_n1, tiny_dem):
    viewer = make_napari_viewer()
    widget = _ortho_widget(viewer)
    widget.add_dem(tiny_dem.parent / "absent.tif")
    assert "not found" in widget.status.value
    widget.add_dem(tiny_dem)  # a success replaces the old error
    assert "not found" not in widget.status.value
    assert tiny_dem.name in widget.status.value
    widget.products.value = [tiny_n1]
    widget.elevation.value = "none"  # DEMs with elevation "none": refused
    _run(widget, qtbot)
    assert "only used with elevation 'dem'" in widget.status.value
    widget.elevation.value = "dem"
    widget.bands.value = "7"
    _run(widget, qtbot)
    assert widget.status.value.startswith("done"), widget.status.value
    assert "only used" not in widget.status.value
    assert np.count_nonzero(viewer.layers[-1].data) > 0


@pytest.mark.slow
def test_an_output_a_layer_reads_from_is_refused(make_napari_viewer, qtbot, tiny_n1, tmp_path):
    """The widget does not write over a GeoTIFF the viewer shows (File > Save refuses it too: a
    lazy layer reads its file as the view moves). One message; the file is unchanged."""
    viewer = make_napari_viewer()
    widget = _ortho_widget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "none"
    widget.bands.value = "7"
    shown = tmp_path / "shown.tif"
    widget.output.value = shown
    _run(widget, qtbot)
    assert widget.status.value.startswith("done"), widget.status.value
    (layer,) = viewer.open(shown, plugin="napari-meris-ortho")
    before = shown.read_bytes()
    assert _run(widget, qtbot) is None
    assert widget.status.value == (f"output {shown}: layer {layer.name!r} reads from this "
                                   "file; choose another output")
    assert shown.read_bytes() == before
    viewer.layers.remove(layer)
    assert _run(widget, qtbot) is not None  # once no layer reads it
    assert widget.status.value.startswith("done"), widget.status.value


@pytest.mark.slow
def test_an_output_in_a_directory_that_takes_no_file_is_refused_before_the_run(
        make_napari_viewer, qtbot, tiny_n1):
    """An output under /proc looks writable to root (``os.access``), and would be refused only
    after the run had computed. The checks make (and remove) a file there: refused before the
    run, in one line."""
    import os

    if not os.access("/proc", os.W_OK):
        pytest.skip("needs /proc to look writable (root)")
    viewer = make_napari_viewer()
    widget = _ortho_widget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "none"
    widget.bands.value = "7"
    widget.output.value = "/proc/out.tif"
    assert widget.start() is None  # no run started
    assert widget.status.value.startswith("/proc/out.tif: cannot write in /proc ("), (
        widget.status.value)

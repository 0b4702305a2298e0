"""The Orthorectify widget's DEM list survives napari's reset_choices and runs."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

pytestmark = pytest.mark.slow


def _ortho_widget(viewer):
    _, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    return widget


def _shown(widget):
    """The DEM paths the list shows, in order."""
    return [str(p) for p in widget.dem_list.choices]


def test_dem_list_survives_layer_changes_and_runs(make_napari_viewer, qtbot, tiny_n1, tiny_dem,
                                                  tmp_path):
    viewer = make_napari_viewer()
    widget = _ortho_widget(viewer)
    second = tmp_path / "dem2.tif"
    shutil.copy(tiny_dem, second)
    widget.add_dem(tiny_dem)
    widget.add_dem(second)
    assert _shown(widget) == [str(tiny_dem), str(second)]
    # napari calls reset_choices on docked magicgui widgets at every layer change
    layer = viewer.add_image(np.zeros((4, 4), np.float32), name="scratch")
    assert _shown(widget) == [str(tiny_dem), str(second)]
    viewer.layers.remove(layer)
    widget.reset_choices()
    assert _shown(widget) == [str(tiny_dem), str(second)]
    # what is shown is what runs: remove the second DEM through the list
    widget.dem_list.value = [second]
    widget.dem_remove.clicked.emit()
    assert _shown(widget) == [str(tiny_dem)]
    widget.products.value = [tiny_n1]
    widget.bands.value = "7"
    worker = widget.start()
    assert worker is not None, widget.status.value
    qtbot.waitUntil(lambda: not widget.running, timeout=120_000)
    assert widget.status.value.startswith("done"), widget.status.value
    assert [str(p) for p in widget.last_run.options.dems] == [str(tiny_dem)]
    # the list is still there after the run (layers were added: reset_choices again)
    assert _shown(widget) == [str(tiny_dem)]

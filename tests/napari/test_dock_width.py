"""The plugin's docks keep their width under long text (issue 24, item 7): a long status
message, path or layer name widened the dock from 477 to 1066 px and shrank the canvas."""

from __future__ import annotations

import numpy as np

#: a 500-character status message: words, then a long path without a space
LONG_PATH = "/data/" + "a_very_long_directory_name/" * 8 + "MER_FR__1PNSIM20030921.N1"
MESSAGE = ("N1 product not found: " + " ".join(["word"] * 60) + " " + LONG_PATH)[:500]


def _widths(viewer, dock):
    return dock.width(), viewer.window._qt_viewer.canvas.native.width()


def test_orthorectify_dock_keeps_its_width(make_napari_viewer, qtbot):
    viewer = make_napari_viewer(show=True)
    dock, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    qtbot.wait(200)
    before = _widths(viewer, dock)
    assert len(MESSAGE) == 500
    widget.status.value = MESSAGE
    widget.products.value = [LONG_PATH, LONG_PATH]
    widget.output.value = LONG_PATH
    qtbot.wait(200)
    assert _widths(viewer, dock) == before
    assert widget.status.native.toolTip() == MESSAGE  # the full text, even where clipped
    assert widget.status.native.height() > 3 * widget.status.native.fontMetrics().height()


def test_flicker_dock_keeps_its_width(make_napari_viewer, qtbot):
    viewer = make_napari_viewer(show=True)
    dock, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Flicker")
    qtbot.wait(200)
    before = _widths(viewer, dock)
    for k in range(2):
        viewer.add_image(np.zeros((8, 8), np.float32), name=f"{k} {MESSAGE[:200]}")
    widget.status.value = MESSAGE
    qtbot.wait(200)
    assert dock.width() == before[0]  # (napari's own layer list widens with the names)

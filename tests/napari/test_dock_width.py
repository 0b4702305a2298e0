"""The plugin's docks keep their width under long text: a long status message, path or layer
name must not widen the dock (and shrink the canvas)."""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.slow

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


def test_the_form_scrolls_and_run_stays_in_view(make_napari_viewer, qtbot):
    """The Orthorectify dock does not ask for its whole height (812 px; 1181 px with the
    Flicker dock below it), which would grow napari's window past a 1080-line screen and put the
    rows at the bottom out of reach. The form scrolls above its action rows (Run, Cancel,
    progress, status), which stay in view, and claims at most ``FORM_SCREEN_SHARE`` of the
    screen's height."""
    from qtpy.QtWidgets import QApplication, QDockWidget

    from napari_meris_ortho._napari.layout import FORM_SCREEN_SHARE

    viewer = make_napari_viewer(show=True)
    dock, ortho = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Flicker")
    qtbot.wait(300)
    screen = QApplication.primaryScreen().availableGeometry().height()
    footer = ortho.footer.native.minimumSizeHint().height()
    title = 40  # the dock's title bar and margins
    assert isinstance(dock, QDockWidget)
    assert dock.minimumSizeHint().height() <= FORM_SCREEN_SHARE * screen + footer + title, (
        dock.minimumSizeHint().height(), screen, footer)
    for row in (ortho.run_button, ortho.cancel_button, ortho.progress_bar, ortho.status):
        assert not row.native.visibleRegion().isEmpty(), row.name
    ortho.status.value = "done: " + "word " * 80  # a long message: Run stays in view
    qtbot.wait(100)
    assert not ortho.run_button.native.visibleRegion().isEmpty()

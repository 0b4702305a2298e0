"""The flicker key (Shift-F) is declared in the manifest, works through a real key event on the
canvas and is unbound when the Flicker widget closes."""

from __future__ import annotations

import numpy as np
from npe2 import PluginManifest
from qtpy.QtCore import Qt


def _press_shift_f(viewer, qtbot):
    canvas = viewer.window._qt_viewer.canvas.native
    canvas.setFocus()
    qtbot.keyClick(canvas, Qt.Key_F, Qt.ShiftModifier)


def test_shift_f_toggles_flicker_and_is_unbound_on_close(make_napari_viewer, qtbot):
    manifest = PluginManifest.from_distribution("napari-meris-ortho")
    (binding,) = manifest.contributions.keybindings
    assert binding.key == "Shift+F"
    assert binding.command in {c.id for c in manifest.contributions.commands}

    viewer = make_napari_viewer(show=True)
    a = viewer.add_image(np.zeros((8, 8), np.float32), name="A")
    b = viewer.add_image(np.ones((8, 8), np.float32), name="B")
    dock, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Flicker")
    widget.layer_a.value, widget.layer_b.value = a, b
    _press_shift_f(viewer, qtbot)
    qtbot.waitUntil(lambda: widget.running, timeout=5000)
    _press_shift_f(viewer, qtbot)
    qtbot.waitUntil(lambda: not widget.running, timeout=5000)
    assert a.visible and b.visible
    viewer.window.remove_dock_widget(dock)
    assert widget._toggle_key not in list(viewer.keymap.values())
    _press_shift_f(viewer, qtbot)  # nothing happens, nothing raises
    qtbot.wait(100)  # let a (wrongly) bound handler run, if any
    assert not widget.running

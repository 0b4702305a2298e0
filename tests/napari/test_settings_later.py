"""The Orthorectify dock opens without waiting for napari's plugin settings (built once a
session in a thread): the last session's values come into the form when they are there, and a
value the user changed before is kept and saved."""

from __future__ import annotations

import threading

import pytest

pytestmark = pytest.mark.gui


def test_the_dock_opens_before_the_settings_and_keeps_what_the_user_typed(
        make_napari_viewer, qtbot, monkeypatch):
    from napari_meris_ortho._napari import settings

    viewer = make_napari_viewer()
    built = settings._all_settings()
    assert built is not None
    built.orthorectify.sampling = "bilinear"  # the last session's choices
    built.orthorectify.bands = "13,7,3"
    gate = threading.Event()

    def slow_build():  # napari's settings, ready only when the test says so
        gate.wait(30)
        return built

    monkeypatch.setattr(settings, "_FETCH", None)
    monkeypatch.setattr(settings, "_PENDING", [])
    monkeypatch.setattr(settings, "_all_settings", slow_build)
    _, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    # the form is open, the settings not there yet: the defaults, and the user types bands
    assert widget.sampling.value == "nearest"
    assert len(settings._PENDING) == 1
    widget.bands.value = "8,6,3"
    gate.set()
    qtbot.waitUntil(lambda: not settings._PENDING, timeout=10_000)
    assert widget.sampling.value == "bilinear"  # restored when the settings came
    assert widget.bands.value == "8,6,3"  # the user's value kept...
    assert built.orthorectify.bands == "8,6,3"  # ...and saved
    widget.sampling.value = "bicubic"  # later changes saved as before
    assert built.orthorectify.sampling == "bicubic"
    # a second dock of the session: the settings at once
    _, again = make_napari_viewer().window.add_plugin_dock_widget("napari-meris-ortho",
                                                                 "Orthorectify")
    assert again.sampling.value == "bicubic" and again.bands.value == "8,6,3"

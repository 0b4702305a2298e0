"""The parallax colour legend is on the canvas (text overlay naming the height
range of the colours) while a parallax layer is visible, and the widget's own warm-up DEM says
its vertical datum (no warning at every opening of the widget)."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from qt_paints import paints_of

STAMP = " · 09-21 09:23"


@pytest.mark.slow
def test_parallax_legend_on_the_canvas(make_napari_viewer, qtbot, tiny_n1, tiny_dem):
    viewer = make_napari_viewer(show=True)  # a hidden canvas draws no overlays
    _, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    widget.products.value = [tiny_n1]
    widget.add_dem(tiny_dem)
    widget.bands.value = "7"
    assert widget.start() is not None, widget.status.value
    qtbot.waitUntil(lambda: not widget.running, timeout=60_000)
    vectors, = [x for x in viewer.layers if x.name.startswith("parallax ×")]
    viewer.layers.selection.active = vectors  # the key follows the selected layer
    lo, hi = vectors.edge_contrast_limits
    heights = np.asarray(vectors.features["height"])
    assert (lo, hi) == (heights.min(), heights.max()) and hi - lo > 500  # the DEM's relief
    overlay = viewer.canvas.overlays.text
    # a run started as the widget opens: its legend waits for the glyphs' preparation
    qtbot.waitUntil(lambda: overlay.text.startswith("parallax"), timeout=10_000)
    assert overlay.visible
    assert overlay.text == (f"{vectors.name}: colour = height, purple {lo:.0f} m → "
                            f"yellow {hi:.0f} m")
    shown = viewer.screenshot(canvas_only=True)
    vectors.visible = False  # no parallax on screen: no legend
    assert not overlay.visible and overlay.text == ""
    hidden = viewer.screenshot(canvas_only=True)
    # the legend is drawn: the top-left corner changes when it goes (napari's notifications
    # come up in the bottom right)
    corner = (slice(0, shown.shape[0] // 4), slice(0, shown.shape[1] // 2))
    assert np.count_nonzero(np.any(shown[corner] != hidden[corner], axis=-1)) > 50
    vectors.visible = True
    assert overlay.visible


def test_warm_up_dem_states_its_datum(tmp_path, caplog):
    from napari_meris_ortho.dem.stack import open_dem
    from napari_meris_ortho.warmup import _tiny_product

    _, dem = _tiny_product(tmp_path)
    with caplog.at_level(logging.WARNING):
        open_dem(dem).close()
    assert not [r for r in caplog.records if "vertical datum" in r.getMessage()], caplog.text


def _overlay_font(viewer):
    """vispy's font of the canvas text overlay, as napari's canvas holds it."""
    visuals = viewer.window._qt_viewer.canvas._viewer_overlay_to_visual
    visual = visuals[viewer.canvas.overlays.text][0]
    return visual.node._font_manager.get_font(visual.node.face)


def _glyphs_rendered(viewer) -> int:
    """How many glyphs vispy has rendered into the font the overlay draws with (napari's
    canvas font of its face, before the overlay's visual is made)."""
    canvas = viewer.window._qt_viewer.canvas
    if viewer.canvas.overlays.text in canvas._viewer_overlay_to_visual:
        return len(_overlay_font(viewer)._glyphs)
    info = canvas._font_info
    return len(info.font_manager.get_font(info.face)._glyphs)


@pytest.mark.slow
def test_legend_glyphs_are_rendered_before_a_run(make_napari_viewer, qtbot):
    """The widget has the overlay's font render the legend's characters beforehand, a few per
    turn: the first legend of a session does not render them (0.2-0.6 s under software GL) in
    the frame that shows the run's layers. No frame is drawn for them but the overlay's first
    (its shaders, in the widget's opening: transparent text, whose glyphs came before) and its
    last (the overlay hidden and emptied): a frame drawn at each turn would cost 0.13-0.16 s
    over a run's layers."""
    from napari_meris_ortho._napari.legend import ALIGNMENT_GLYPHS, GLYPHS, GLYPHS_PER_TURN

    viewer = make_napari_viewer(show=True)
    qtbot.wait(100)
    overlay = viewer.canvas.overlays.text
    color = np.asarray(overlay.color).copy()
    seen: list[tuple[str, float]] = []

    rendered_at_first_show: list[int] = []

    def record(_event=None):
        color = overlay.color
        seen.append((overlay.text, 1.0 if color is None else float(np.asarray(color)[3])))

    def shown(event=None):
        if overlay.visible and not rendered_at_first_show:
            rendered_at_first_show.append(_glyphs_rendered(viewer))

    overlay.events.text.connect(record)
    overlay.events.visible.connect(shown)
    with paints_of(viewer.window._qt_viewer.canvas.native) as paints:
        viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
        qtbot.waitUntil(lambda: bool(seen) and seen[-1][0] == "", timeout=10_000)
        qtbot.wait(100)
    assert not overlay.visible and overlay.text == ""
    assert all(alpha == 0.0 for text, alpha in seen if text)  # never visible text
    assert np.array_equal(np.asarray(overlay.color), color)  # napari's own colour back
    font = _overlay_font(viewer)
    assert set(GLYPHS) - {" "} <= set(font._glyphs)
    assert len(paints) <= 4, len(paints)  # not one frame per turn of glyphs (24 turns)
    # the overlay's first draw renders no glyph of its own text in its frame: they came before
    first = set(ALIGNMENT_GLYPHS + GLYPHS[:GLYPHS_PER_TURN]) - {" "}
    assert rendered_at_first_show[0] >= len(first), rendered_at_first_show


@pytest.mark.slow
def test_legend_glyphs_wait_while_a_run_runs(make_napari_viewer, qtbot, tiny_n1, tiny_dem):
    """A run started as the widget opens: the glyphs' preparation waits while it runs (its
    job's thread holds the GIL for most of a glyph's rendering: 0.07-0.11 s turns against
    0.01-0.03 s, fr-alps), and the run's legend shows once they are ready."""
    from qtpy.QtCore import QTimer

    viewer = make_napari_viewer(show=True)
    _, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    widget.products.value = [tiny_n1]
    widget.add_dem(tiny_dem)
    widget.bands.value = "7"
    samples: list[tuple[bool, int]] = []
    timer = QTimer()
    timer.timeout.connect(lambda: samples.append((widget.running, _glyphs_rendered(viewer))))
    timer.start(5)
    assert widget.start() is not None, widget.status.value
    qtbot.waitUntil(lambda: not widget.running, timeout=60_000)
    overlay = viewer.canvas.overlays.text
    qtbot.waitUntil(lambda: overlay.text.startswith("parallax"), timeout=10_000)
    timer.stop()
    during = {count for running, count in samples if running}
    assert len(during) == 1, sorted(during)  # not one glyph rendered while the run ran
    assert _glyphs_rendered(viewer) > max(during)  # the rest came after it
    assert overlay.visible and overlay.color[-1] == 1.0  # seen


@pytest.mark.slow
def test_text_put_in_the_overlay_during_the_preparation_is_seen(make_napari_viewer, qtbot):
    """A user's own text in the canvas overlay while the glyphs are being prepared stops the
    preparation and is seen: the preparation's transparent colour goes back (it stayed)."""
    viewer = make_napari_viewer(show=True)
    overlay = viewer.canvas.overlays.text
    color = np.asarray(overlay.color).copy()  # napari's default: None
    viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    qtbot.waitUntil(lambda: overlay.visible, timeout=10_000)  # its first draw, a few turns in
    assert float(np.asarray(overlay.color)[-1]) == 0.0  # preparing
    overlay.text, overlay.visible = "my annotation", True
    qtbot.wait(300)
    assert overlay.text == "my annotation" and overlay.visible
    assert np.array_equal(np.asarray(overlay.color), color)


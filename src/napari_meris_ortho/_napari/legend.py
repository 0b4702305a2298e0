"""The colour key of the selected layer on the canvas.

Every coloured layer of the plugin carries its key in ``metadata["legend"]``: the parallax
vectors (height, viridis; ``geometry_layers.parallax_layer_data``), iterations, elevation and
elevation source (``product_layers.diagnostic_layers``), a synthesis's NDVI and count. The key
of the selected layer, while it is visible, is napari's canvas text overlay in the top left
corner (napari's notifications come up in the bottom right):
"parallax ×10 · 09-21 09:23: colour = height, purple 412 m → yellow 2391 m".
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from typing import Any

import numpy as np

from ._qt.insertion import draw_now, text_overlay_font

_WATCHED: weakref.WeakSet[Any] = weakref.WeakSet()
#: viewers whose text overlay shows a legend of ours
_SHOWING: weakref.WeakSet[Any] = weakref.WeakSet()
#: viewers whose canvas still renders the legend's glyphs (``prepare_glyphs``): their legend
#: waits for it
_PREPARING: weakref.WeakSet[Any] = weakref.WeakSet()
#: where the key is drawn: clear of napari's notifications (bottom right)
LEGEND_POSITION = "top_left"
#: the ends of napari's viridis colormap, in words
VIRIDIS_ENDS = ("purple", "yellow")


def legend_line(layer: Any) -> str | None:
    """The colour key of a layer of ours ("<name>: <key>"), None for a layer without one; a
    parallax layer's from its colour limits as they are now."""
    meta = getattr(layer, "metadata", {}) or {}
    if "legend" not in meta:
        return None
    if "exaggeration" not in meta:
        return f"{layer.name}: {meta['legend']}"
    lo, hi = (float(v) for v in layer.edge_contrast_limits)
    low, high = VIRIDIS_ENDS
    return f"{layer.name}: colour = height, {low} {lo:.0f} m → {high} {hi:.0f} m"


def update_legend(viewer: Any) -> None:
    """Show the key of the selected layer, when it is visible and has one, in the canvas text
    overlay (hide it when there is none and it shows ours); after the glyphs are ready
    (``prepare_glyphs``)."""
    if viewer in _PREPARING:
        return  # shown at the end of the preparation
    active = viewer.layers.selection.active
    line = legend_line(active) if active is not None and active.visible else None
    overlay = viewer.canvas.overlays.text
    if line is not None:
        overlay.text = line
        overlay.position = LEGEND_POSITION
        overlay.font_size = 10
        overlay.color = "white"
        overlay.visible = True
        _SHOWING.add(viewer)
    elif viewer in _SHOWING:
        overlay.text, overlay.visible = "", False
        _SHOWING.discard(viewer)


#: the characters of a legend line (``legend_line``: "parallax ×10 · 09-21 09:23: colour =
#: height, purple 412 m → yellow 2391 m")
GLYPHS = "0123456789 abcdefghijklmnopqrstuvwxyz:=,.-×·→()+/NDVIEMR"
#: glyphs rendered per turn of the event loop (10-20 ms each)
GLYPHS_PER_TURN = 2


def prepare_glyphs(viewer: Any, step_ms: int = 40,
                   paused: Callable[[], bool] | None = None) -> None:
    """Have the canvas render the legend's glyphs beforehand, so that the first legend of a
    run does not render them all in the frame that shows the run (vispy renders each new
    character into its atlas at its first draw: 0.2-0.6 s for a legend line under software
    GL). The overlay's first draw (its shaders and nine glyphs vispy always renders:
    0.15-0.2 s), with transparent text, is made at once (the widget calls this in a turn of
    its own right after its opening, before a user reaches Run); then a few glyphs per turn
    into the overlay's font (``text_overlay_font``), no frame drawn (drawing the canvas in
    each turn would cost 0.07-0.11 s during a run's job, 0.13-0.16 s over a run's fr-alps
    layers), none while ``paused()`` (a run). A legend asked for meanwhile shows at the end.
    Stops when the overlay is in use by another; no-op when it is in use or nothing is
    drawn."""
    from qtpy.QtCore import QTimer

    overlay = viewer.canvas.overlays.text
    if overlay.visible or viewer in _SHOWING or viewer in _PREPARING:
        return
    ref = weakref.ref(viewer)
    chunks = [GLYPHS[k:k + GLYPHS_PER_TURN] for k in range(0, len(GLYPHS), GLYPHS_PER_TURN)]
    state: dict[str, str | None] = {"text": None}
    # the overlay's colour as it was: the first draw's text is transparent (napari's box
    # behind it is not: a transparent box colour still draws it, and turning the box off and
    # on again crashes Mesa's software GL in a later draw)
    color = overlay.color

    def restore(text: Any) -> None:
        """The colour back, unless someone set it meanwhile."""
        if text.color is not None and float(np.asarray(text.color)[-1]) == 0.0:
            text.color = color

    def step() -> None:
        alive = ref()
        if alive is None:
            return
        if paused is not None and paused():
            QTimer.singleShot(step_ms, step)
            return
        text = alive.canvas.overlays.text
        if state["text"] is not None and text.text != state["text"]:
            restore(text)  # someone else uses the overlay: their text is seen
            _PREPARING.discard(alive)
            return
        if not chunks:
            text.text, text.visible = "", False
            restore(text)
            _PREPARING.discard(alive)
            update_legend(alive)  # one asked for meanwhile
            return
        chunk = chunks.pop(0)
        font = None if state["text"] is None else text_overlay_font(alive)
        if font is not None:
            for char in chunk:
                font[char]  # vispy renders the glyph when it is first indexed
        else:  # the first step, drawn now; or no font within reach: drawn by the canvas
            state["text"] = chunk
            text.color, text.font_size = (0.0, 0.0, 0.0, 0.0), 10  # before the text: unseen
            text.text, text.visible = chunk, True
        QTimer.singleShot(step_ms, step)

    _PREPARING.add(viewer)
    step()
    draw_now(viewer)


def show_legends(viewer: Any) -> None:
    """Keep the selected layer's key on the canvas as layers are selected, come, go, show and
    hide."""
    if viewer is None or viewer in _WATCHED:
        return
    _WATCHED.add(viewer)
    ref = weakref.ref(viewer)

    def update(_event: Any = None) -> None:
        alive = ref()
        if alive is not None:
            update_legend(alive)

    def watch(event: Any) -> None:
        if legend_line(event.value) is not None:
            event.value.events.visible.connect(update)
        update()

    viewer.layers.events.inserted.connect(watch)
    viewer.layers.events.removed.connect(update)
    viewer.layers.selection.events.active.connect(update)
    for layer in viewer.layers:
        if legend_line(layer) is not None:
            layer.events.visible.connect(update)
    update()

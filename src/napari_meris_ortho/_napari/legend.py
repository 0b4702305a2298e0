"""The colour legend of the parallax vectors on the canvas (issue 24 item 4).

A vectors layer of parallax shifts (``geometry_layers.parallax_layer_data``) is coloured by the
terrain height (viridis); its legend (``metadata["legend"]``, the height range) is shown as
napari's canvas text overlay while such a layer is visible, one line per visible layer:
"parallax ×10 · 2003-09-21 09:23: colour = height, purple 412 m → yellow 2391 m".
"""

from __future__ import annotations

import weakref
from typing import Any

from ._qt.insertion import draw_now

_WATCHED: weakref.WeakSet[Any] = weakref.WeakSet()
#: viewers whose text overlay shows a legend of ours
_SHOWING: weakref.WeakSet[Any] = weakref.WeakSet()
#: the ends of napari's viridis colormap, in words
VIRIDIS_ENDS = ("purple", "yellow")


def legend_line(layer: Any) -> str | None:
    """The legend line of a height-coloured vectors layer, None for any other layer."""
    meta = getattr(layer, "metadata", {}) or {}
    if "legend" not in meta or "exaggeration" not in meta:
        return None
    lo, hi = (float(v) for v in layer.edge_contrast_limits)
    low, high = VIRIDIS_ENDS
    return f"{layer.name}: colour = height, {low} {lo:.0f} m → {high} {hi:.0f} m"


def update_legend(viewer: Any) -> None:
    """Show the legends of the visible parallax layers in the canvas text overlay (hide it when
    there is none and it shows ours)."""
    lines = [line for layer in viewer.layers if layer.visible
             for line in [legend_line(layer)] if line is not None]
    overlay = viewer.canvas.overlays.text
    if lines:
        overlay.text = "\n".join(lines)
        overlay.position = "bottom_left"
        overlay.font_size = 10
        overlay.color = "white"
        overlay.visible = True
        _SHOWING.add(viewer)
    elif viewer in _SHOWING:
        overlay.text, overlay.visible = "", False
        _SHOWING.discard(viewer)


#: the characters of a legend line (``legend_line``: "parallax ×10 · 2003-09-21 09:23: colour =
#: height, purple 412 m → yellow 2391 m")
GLYPHS = "0123456789 abcdefghijklmnopqrstuvwxyz:=,.-×·→"
#: glyphs rendered per turn of the event loop (about 10-30 ms each under software GL)
GLYPHS_PER_TURN = 2


def prepare_glyphs(viewer: Any, step_ms: int = 40) -> None:
    """Have the canvas render the legend's glyphs beforehand, invisibly (transparent text), so
    that the first legend of a run does not render them all in the frame that shows the run
    (vispy renders each new character into its atlas at its first draw: 0.2-0.6 s for a legend
    line under software GL). The overlay's first draw (its shaders and nine glyphs vispy always
    renders: 0.15-0.2 s) is made at once, within the widget's opening, not in a turn of a run
    started right after; then a few glyphs per turn. Stops when a legend is shown; no-op when
    the overlay is in use or nothing is drawn."""
    from qtpy.QtCore import QTimer

    overlay = viewer.canvas.overlays.text
    if overlay.visible or viewer in _SHOWING:
        return
    ref = weakref.ref(viewer)
    chunks = [GLYPHS[k:k + GLYPHS_PER_TURN] for k in range(0, len(GLYPHS), GLYPHS_PER_TURN)]
    state: dict[str, str | None] = {"text": None}

    def step() -> None:
        alive = ref()
        if alive is None or alive in _SHOWING:
            return
        text = alive.canvas.overlays.text
        if state["text"] is not None and text.text != state["text"]:
            return  # someone else uses the overlay
        if not chunks:
            text.text, text.visible, text.color = "", False, "white"
            return
        state["text"] = chunks.pop(0)
        text.color, text.font_size = (0.0, 0.0, 0.0, 0.0), 10  # before the text: never seen
        text.text, text.visible = state["text"], True
        QTimer.singleShot(step_ms, step)

    step()
    draw_now(viewer)


def show_legends(viewer: Any) -> None:
    """Keep the parallax legend on the canvas as parallax layers come, go, show and hide."""
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
    for layer in viewer.layers:
        if legend_line(layer) is not None:
            layer.events.visible.connect(update)
    update()

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
#: viewers whose canvas still renders the legend's glyphs (``glyph_steps``): their legend
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
    (``glyph_steps``)."""
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
#: the glyphs vispy renders for every text, to align it vertically (``_text_to_vbo``)
ALIGNMENT_GLYPHS = "ÅÉÑŐjgpqy"
#: glyphs rendered per turn of the event loop (10-20 ms each)
GLYPHS_PER_TURN = 2
#: glyphs of the overlay's first text rendered per step before its first draw
FIRST_GLYPHS_PER_STEP = 4


def glyph_steps(viewer: Any, step_ms: int = 40,
                paused: Callable[[], bool] | None = None) -> list[Callable[[], None]]:
    """The steps that have the canvas render the legend's glyphs beforehand, each for a turn
    of the event loop of its own (``in_turns``), so that the first legend of a run does not
    render them all in the frame that shows the run (vispy renders each new character into
    its atlas at its first draw: 0.2-0.6 s for a legend line under software GL).

    The glyphs of the overlay's first text (and the nine vispy aligns every text by) go into
    the text overlay's font (``text_overlay_font``: 10-20 ms each) a few per step, no frame
    drawn; the last step is the overlay's first draw (its shaders: about 0.2 s; transparent
    text), right after the dock's opening, before a user reaches Run. From there the other
    glyphs follow a few per turn (every ``step_ms``), and the overlay is hidden again; a
    legend asked for meanwhile shows at the end. Nothing is rendered or drawn while
    ``paused()`` (a run): the first text's glyphs left then come before the first draw.
    Stops when the overlay is in use by another; nothing is done when it is in use or
    nothing is drawn."""
    from qtpy.QtCore import QTimer

    ref = weakref.ref(viewer)
    first_text = GLYPHS[:GLYPHS_PER_TURN]

    def chunked(glyphs: str, size: int) -> list[str]:
        return [glyphs[k:k + size] for k in range(0, len(glyphs), size)]

    after = chunked(GLYPHS[GLYPHS_PER_TURN:], GLYPHS_PER_TURN)
    state: dict[str, Any] = {"on": False, "text": None, "color": None}

    def render_next(font: Any, chunks: list[str]) -> None:
        for char in chunks.pop(0):
            font[char]  # vispy renders the glyph when it is first indexed

    def restore(text: Any) -> None:
        """The overlay's colour as it was, unless someone set it meanwhile (the first draw's
        text is transparent; napari's box behind it is not: a transparent box colour still
        draws it, and turning the box off and on again crashes Mesa's software GL later)."""
        if text.color is not None and float(np.asarray(text.color)[-1]) == 0.0:
            text.color = state["color"]

    def render(first: bool) -> Callable[[], None]:
        def step() -> None:
            alive = ref()
            if alive is None:
                return
            if first:
                overlay = alive.canvas.overlays.text
                if overlay.visible or alive in _SHOWING or alive in _PREPARING:
                    return  # in use: the preparation does nothing
                state["on"], state["color"] = True, overlay.color
                _PREPARING.add(alive)
            if not state["on"] or alive.canvas.overlays.text.visible or not before:
                return
            if paused is not None and paused():
                return  # this step's glyphs come before the first draw (``go_on``)
            font = text_overlay_font(alive)
            if font is not None:
                render_next(font, before)
        return step

    def go_on() -> None:
        alive = ref()
        if alive is None or not state["on"]:
            return
        if paused is not None and paused():
            QTimer.singleShot(step_ms, go_on)
            return
        text = alive.canvas.overlays.text
        if state["text"] is None and text.visible or (state["text"] is not None
                                                      and text.text != state["text"]):
            restore(text)  # someone else uses the overlay: their text is seen
            _PREPARING.discard(alive)
            return
        font = text_overlay_font(alive)
        if state["text"] is None and before and font is not None:  # left while a run ran
            render_next(font, before)
        elif state["text"] is None:  # the first draw (with no font within reach: its glyphs)
            state["text"] = first_text
            text.color, text.font_size = (0.0, 0.0, 0.0, 0.0), 10  # before the text: unseen
            text.text, text.visible = first_text, True
            draw_now(alive)
        elif after and font is not None:
            render_next(font, after)
        else:  # every glyph ready: hidden again, a legend asked for meanwhile shown
            text.text, text.visible = "", False
            restore(text)
            _PREPARING.discard(alive)
            update_legend(alive)
            return
        QTimer.singleShot(step_ms, go_on)

    before = chunked(ALIGNMENT_GLYPHS + first_text, FIRST_GLYPHS_PER_STEP)
    return [*(render(k == 0) for k in range(len(before))), go_on]


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

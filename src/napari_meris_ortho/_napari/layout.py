"""Layout of the plugin's widgets: docks of a fixed width, text never widens them (issue 24,
item 7); the canvas held still while layers go in (``canvas_updates``), layers inserted without
switching the layer controls each time (``append_inactive``), so that no event-loop turn does
much (item 1).

A QLabel without word wrap asks for the width of its whole text, and a QComboBox for its
longest item: a long status message, path or layer name widened the dock from 477 to 1066 px.
Labels wrap at spaces and ignore their text width (the full text is also their tooltip);
combo boxes ask for ``COMBO_CHARS`` characters and elide the rest.
"""

from __future__ import annotations

import contextlib
from typing import Any

from magicgui.widgets import Label

#: characters a combo box asks room for (longer layer names are elided)
COMBO_CHARS = 24


class StatusLabel(Label):
    """A magicgui ``Label`` that wraps its text and never asks for more width than the dock
    has; its tooltip is the full text (an unbroken path may be clipped, the tooltip shows it)."""

    def __init__(self, **kwargs: Any) -> None:
        from qtpy.QtWidgets import QSizePolicy

        super().__init__(**kwargs)
        native = self.native
        native.setWordWrap(True)
        policy = QSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)
        policy.setHeightForWidth(True)
        native.setSizePolicy(policy)
        native.setMinimumWidth(1)
        native.setToolTip(str(self.value))

    @property
    def value(self) -> Any:
        return Label.value.fget(self)  # type: ignore[attr-defined]

    @value.setter
    def value(self, value: Any) -> None:
        Label.value.fset(self, value)  # type: ignore[attr-defined]
        self.native.setToolTip(str(value))
        self.fit()

    def fit(self) -> None:
        """Ask for the height of the wrapped text at the label's width (the dock's scroll
        area does not pass height-for-width on)."""
        native = self.native
        native.setMinimumHeight(max(native.heightForWidth(max(native.width(), 100)), 0))


def compact_combo(combo: Any) -> Any:
    """A magicgui ``ComboBox`` asking room for ``COMBO_CHARS`` characters, not its longest item."""
    from qtpy.QtCore import Qt
    from qtpy.QtWidgets import QComboBox

    native = combo.native
    native.setSizeAdjustPolicy(QComboBox.SizeAdjustPolicy.AdjustToMinimumContentsLengthWithIcon)
    native.setMinimumContentsLength(COMBO_CHARS)
    native.view().setTextElideMode(Qt.TextElideMode.ElideMiddle)
    return combo


#: ms between showing two new layers (a run's, a sample's), one per frame: vispy builds a new
#: visual's shaders at its first draw, so a frame drawing them all was the longest stall. Each
#: is drawn in the turn after the one that shows it (canvas updates off while it is shown)
SHOW_STEP_MS = 40


def hide_for_now(layers: list[Any]) -> list[Any]:
    """Hide the visible ones of ``layers`` (shown one per frame later); returns them."""
    shown = [layer for layer in layers if layer.visible]
    for layer in shown:
        layer.visible = False
    return shown


def show_in(viewer: Any, layers: list[Any]) -> None:
    """Show those of ``layers`` that are in the viewer."""
    for layer in layers:
        if layer in viewer.layers:
            layer.visible = True


def prepare_dash_patterns() -> None:
    """vispy's line dash patterns built now (it keeps them): every labels layer's polygon
    overlay builds them, 0.08 s in the session's first labels layer insertion (measured)."""
    with contextlib.suppress(ImportError):  # a vispy without it: nothing to prepare
        from vispy.visuals.line.dash_atlas import DashAtlas

        DashAtlas()


def _canvas(viewer: Any) -> Any:
    """The canvas's Qt widget (None without a Qt window)."""
    window = getattr(getattr(viewer, "__wrapped__", viewer), "window", None)  # not the proxy
    return getattr(getattr(getattr(window, "_qt_viewer", None), "canvas", None), "native", None)


def draw_now(viewer: Any) -> None:
    """Draw the canvas at once, if it is shown."""
    native = _canvas(viewer)
    if native is not None and native.isVisible():
        native.repaint()


def canvas_updates(viewer: Any, enabled: bool) -> None:
    """Stop (and restart) the canvas repainting while a run's or a sample's layers go in one per
    event-loop turn: a draw between two insertions crashed Mesa's software GL under Xvfb
    (segmentation fault in glDrawArrays); the rest of the window (progress bar, Cancel, the
    layer list) keeps responding. No-op without a Qt window."""
    native = _canvas(viewer)
    if native is None:
        return
    with contextlib.suppress(RuntimeError):  # the Qt object is already deleted
        native.setUpdatesEnabled(enabled)
        if enabled:
            native.update()


def scene_graph_paused(viewer: Any, paused: bool) -> None:
    """Hold (``paused``) or rebuild napari's scene graph while a run's layers go in, one per
    turn: every insertion otherwise rebuilds it for all the layers of the viewer (their order,
    their overlays, a pass of the canvas's draw hook): 0.01-0.02 s per image layer, 0.07-0.08 s
    for a labels layer, whose polygon overlay is built there (measured, software GL). The
    rebuild of ``paused=False`` then takes a turn of its own. napari's own switch (the one its
    batched layer changes use, without their garbage collection); no-op without it."""
    window = getattr(getattr(viewer, "__wrapped__", viewer), "window", None)
    canvas = getattr(getattr(window, "_qt_viewer", None), "canvas", None)
    if canvas is None or not isinstance(getattr(canvas, "_pause_scene_graph", None), bool):
        return
    if canvas._pause_scene_graph == paused:
        return
    canvas._pause_scene_graph = paused
    if not paused:
        with contextlib.suppress(RuntimeError):  # the Qt objects are already deleted
            canvas._update_scenegraph()


def build_overlays(viewer: Any, layer: Any) -> None:
    """Have napari build the canvas overlays of ``layer`` now, in a turn of their own, while the
    scene graph is held (``scene_graph_paused``): a labels layer's polygon and brush overlays
    took 0.08-0.14 s of the rebuild's turn (fr-alps, software GL). No-op without them."""
    window = getattr(getattr(viewer, "__wrapped__", viewer), "window", None)
    canvas = getattr(getattr(window, "_qt_viewer", None), "canvas", None)
    update = getattr(canvas, "_update_layer_overlays", None)
    if callable(update) and layer in getattr(canvas, "layer_to_visual", {}):
        with contextlib.suppress(RuntimeError):  # the Qt objects are already deleted
            update(layer)


def _controls_container(viewer: Any) -> Any:
    """napari's stack of layer controls, if the window has made it (None otherwise)."""
    window = getattr(getattr(viewer, "__wrapped__", viewer), "window", None)
    container = getattr(getattr(window, "_qt_viewer", None), "_controls", None)
    ok = callable(getattr(container, "_add", None)) and isinstance(
        getattr(container, "widgets", None), dict)
    return container if ok else None


#: object name of the empty frame that holds a layer's place in napari's controls stack until
#: ``add_controls`` makes its controls
CONTROLS_STAND_IN = "meris_ortho_controls_stand_in"


def append_inactive(viewer: Any, layer: Any, controls_later: bool = False) -> bool:
    """Append ``layer`` to the viewer without making it the active layer: activating (the
    controls switch to it, the list updates its selection) is a third of an insertion's time,
    paid at each turn of a run's insertions; the caller activates one layer at the end.
    napari's own switch (``_activate_on_insert``); without it (a future napari), activated.

    ``controls_later``: napari's controls of the layer are not made in this insertion but by
    :func:`add_controls`, in a turn of their own (making them and Qt's styling of their
    widgets were 0.1-0.2 s of the 0.2-0.3 s an insertion's turn took, measured on fr-alps
    under software GL); an empty frame holds their place meanwhile (napari finds it if the
    layer is selected or removed first). Returns whether they are still to be made."""
    layers = getattr(viewer, "__wrapped__", viewer).layers  # the plugin's public-only proxy
    layers = getattr(layers, "__wrapped__", layers)
    container = _controls_container(viewer) if controls_later else None
    previous = getattr(layers, "_activate_on_insert", True)
    layers._activate_on_insert = False
    try:
        if container is None:
            layers.append(layer)
            return False
        with layers.events.inserted.blocker(container._add):
            layers.append(layer)
    finally:
        layers._activate_on_insert = previous
    if layer in container.widgets or layer not in layers:
        return False
    from qtpy.QtWidgets import QFrame

    stand_in = QFrame()
    stand_in.setObjectName(CONTROLS_STAND_IN)
    container.addWidget(stand_in)
    container.widgets[layer] = stand_in
    return True


def make_controls(viewer: Any, layer: Any) -> None:
    """Make napari's controls of ``layer`` (appended with ``controls_later``) without putting
    them in the controls stack yet (:func:`add_controls` does, in a later turn): making them
    and Qt's styling of their widgets once in the stack were 0.06-0.08 s and 0.06-0.1 s of one
    turn (fr-alps, software GL)."""
    container = _controls_container(viewer)
    stand_in = None if container is None else container.widgets.get(layer)
    if (stand_in is None or stand_in.objectName() != CONTROLS_STAND_IN
            or layer not in viewer.layers or getattr(stand_in, "controls", None) is not None):
        return
    try:
        from napari._qt.layer_controls.qt_layer_controls_container import (
            create_qt_layer_controls,
        )
    except ImportError:  # a napari without it: add_controls makes them
        return
    stand_in.controls = create_qt_layer_controls(layer)


def add_controls(viewer: Any, layers: Any) -> None:
    """Put napari's controls of those of ``layers`` that ``append_inactive`` appended with
    ``controls_later`` in place of their stand-in (made by :func:`make_controls` or now), as
    napari's own insertion would."""
    from types import SimpleNamespace

    container = _controls_container(viewer)
    if container is None:
        return
    for layer in layers:
        stand_in = container.widgets.get(layer)
        if (layer not in viewer.layers or stand_in is None
                or stand_in.objectName() != CONTROLS_STAND_IN):
            continue
        shown = container.currentWidget() is stand_in
        made = getattr(stand_in, "controls", None)
        del container.widgets[layer]
        container.removeWidget(stand_in)
        stand_in.controls = None
        stand_in.deleteLater()
        if made is None:
            container._add(SimpleNamespace(value=layer))
        else:  # what napari's insertion does with the controls it makes
            made.ndisplay = viewer.dims.ndisplay
            container.addWidget(made)
            container.widgets[layer] = made
        if shown and layer in container.widgets:
            container.setCurrentWidget(container.widgets[layer])


def frame_extent(viewer: Any, low: Any, high: Any) -> None:
    """Point the camera at the world box ``low``..``high`` (its last two axes: row, column),
    the box filling 95 % of the canvas."""
    import numpy as np

    low, high = np.asarray(low, np.float64)[-2:], np.asarray(high, np.float64)[-2:]
    size = np.where(np.isclose(high - low, 0.0), 1.0, high - low)
    viewer.camera.center = tuple(float(v) for v in (low + high) / 2.0)
    canvas = np.asarray(viewer.canvas.size, np.float64)
    viewer.camera.zoom = float(0.95 * np.min(canvas / size))


def frame_later(viewer: Any, low: Any, high: Any) -> None:
    """:func:`frame_extent` at the next turn of the event loop: after napari has added the
    layers a reader returned (and reset its view to all of them). No-op without Qt."""
    try:
        from qtpy.QtCore import QTimer
    except ImportError:  # pragma: no cover - napari always has Qt
        return
    QTimer.singleShot(0, lambda: frame_extent(viewer, low, high))

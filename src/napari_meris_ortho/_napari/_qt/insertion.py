"""How a run's, a sample's and a reader's layers go into a live napari viewer without a long
turn of the Qt event loop: the canvas held still while they go in
(``canvas_updates``), one layer per turn without switching the layer controls to it
(``append_inactive``), napari's controls of a layer made and styled in later turns
(``controls_later``, ``make_controls``, ``polish_controls``, ``add_controls``,
``defer_controls``), napari's scene graph rebuilt once and a labels layer's overlays built in
a turn of their own (``scene_graph_paused``, ``build_overlays``), new layers shown one per
frame (``hide_for_now``, ``show_in``).

Some of this leans on napari's Qt internals (its canvas, its controls stack, its scene graph
switch); each is checked before use, and a napari without it gets napari's plain insertion.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

from .idle import in_viewer_open

#: ms between showing two new layers (a run's, a sample's), one per frame: vispy builds a new
#: visual's shaders at its first draw, so a frame drawing them all is the longest stall. Each
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


def thumbnail_while_hidden(layer: Any) -> None:
    """Have napari make the thumbnail of a hidden ``layer``: napari makes a thumbnail when it
    slices a layer, and it slices visible layers only, so a layer that comes hidden (a run's
    single bands under its RGB, its diagnostics; a product's radiances under its quick-look)
    shows a black square in the layer list. Shown and hidden again at once, it is sliced once
    (a multiscale layer at the level napari picks: 0.04-0.05 s for fr-alps' radiances)
    and keeps its thumbnail; no frame draws it in between. No-op for a visible layer. In a
    viewer: napari empties an image layer's slice, and so its thumbnail, when it inserts it.

    The layer's ``visible`` and ``set_data`` events are held meanwhile: its visibility is the
    same after as before, and the canvas does not rebuild its scene graph and redraw at each
    of the two changes, as it otherwise would (0.04 s and 0.08 s a thumbnail after a fr-alps
    run, software GL);
    its vispy layer gets the slice when the layer is shown (napari slices it again then)."""
    if layer.visible:
        return
    events = layer.events
    with events.visible.blocker(), events.set_data.blocker():
        layer.visible = True
        layer.visible = False


def thumbnails_later(viewer: Any, names: Sequence[str]) -> None:
    """``thumbnail_while_hidden`` for the viewer's layers of these ``names``, one per turn of
    the event loop once napari's opening is over (a reader's layers: after their first pixels;
    a run's: after it has ended), the first ``SHOW_STEP_MS`` after the call: not in the turn
    of the paint the caller's last change brings."""
    def step(name: str) -> None:  # the newest of that name: napari renames a second copy
        layer = next((x for x in reversed(viewer.layers) if _named(x.name, name)), None)
        if layer is not None:
            thumbnail_while_hidden(layer)

    if names:
        in_turns([partial(step, name) for name in names], first_ms=SHOW_STEP_MS)


def _named(name: str, asked: str) -> bool:
    """Whether a layer named ``name`` is the layer a reader named ``asked``: the same, or as
    napari renames a layer whose name is taken ("radiance [1]")."""
    if name == asked:
        return True
    tail = name[len(asked):]
    return name.startswith(asked) and tail.startswith(" [") and tail[2:-1].isdigit() \
        and tail.endswith("]")


def dash_pattern_steps() -> list[Callable[[], Any]]:
    """vispy's line dash patterns built beforehand, one call each (every labels layer's polygon
    overlay builds them, 0.08 s in the session's first labels layer insertion; all at once
    they would be a turn of 0.18-0.21 s after an N1's first opening of a session): vispy
    keeps each pattern it makes; its atlas, made at every line visual, finds them made. The
    patterns are those its atlas asks for (recorded, not made); none without vispy's atlas."""
    try:
        from vispy.visuals.line import dash_atlas
    except ImportError:  # a vispy without it: nothing to prepare
        return []
    make = getattr(dash_atlas, "_make_pattern", None)
    if not callable(make):
        return [dash_atlas.DashAtlas]
    asked: list[tuple[Any, ...]] = []

    class Recorder(dash_atlas.DashAtlas):
        def make_pattern(self, pattern: Any, caps: Any = (1, 1)) -> Any:
            asked.append((self._data.shape[1], pattern, caps))
            return 0.0, 1.0

    Recorder()  # its default shape: the length of its patterns
    return [partial(make, *args) for args in asked]


def _qt_viewer(viewer: Any) -> Any:
    """napari's QtViewer of ``viewer`` (None without a Qt window), reached through the viewer,
    not the plugin's public-only proxy of it."""
    window = getattr(getattr(viewer, "__wrapped__", viewer), "window", None)
    return getattr(window, "_qt_viewer", None)


def _canvas(viewer: Any) -> Any:
    """The canvas's Qt widget (None without a Qt window)."""
    return getattr(getattr(_qt_viewer(viewer), "canvas", None), "native", None)


def text_overlay_font(viewer: Any) -> Any:
    """vispy's font of the canvas text overlay (None without napari's Qt internals): the
    overlay's visual's once the canvas has made it, before that the canvas's font of the same
    face, which the visual will take (napari's font manager keeps one font per face).
    Indexing it by a character renders the glyph into the font's atlas, without drawing a
    frame."""
    canvas = getattr(_qt_viewer(viewer), "canvas", None)
    visuals = getattr(canvas, "_viewer_overlay_to_visual", {}).get(viewer.canvas.overlays.text)
    node: Any = getattr(visuals[0], "node", None) if visuals else None
    manager: Any
    if node is not None:
        manager, face = getattr(node, "_font_manager", None), getattr(node, "face", None)
    else:
        info = getattr(canvas, "_font_info", None)
        manager, face = getattr(info, "font_manager", None), getattr(info, "face", None)
    get_font = getattr(manager, "get_font", None)
    if face is None or not callable(get_font):
        return None
    return get_font(face)


def draw_now(viewer: Any) -> None:
    """Draw the canvas at once, if it is shown."""
    native = _canvas(viewer)
    if native is not None and native.isVisible():
        native.repaint()


def canvas_updates(viewer: Any, enabled: bool) -> None:
    """Stop (and restart) the canvas repainting while a run's or a sample's layers go in one per
    event-loop turn: a draw between two insertions crashes Mesa's software GL under Xvfb
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
    for a labels layer, whose polygon overlay is built there (software GL). The
    rebuild of ``paused=False`` then takes a turn of its own. napari's own switch (the one its
    batched layer changes use, without their garbage collection); no-op without it."""
    canvas = getattr(_qt_viewer(viewer), "canvas", None)
    if canvas is None or not isinstance(getattr(canvas, "_pause_scene_graph", None), bool):
        return
    if canvas._pause_scene_graph == paused:
        return
    canvas._pause_scene_graph = paused
    if not paused:
        with contextlib.suppress(RuntimeError):  # the Qt objects are already deleted
            canvas._update_scenegraph()


def scene_graph_is_paused(viewer: Any) -> bool:
    """True while ``scene_graph_paused`` holds napari's scene graph."""
    canvas = getattr(_qt_viewer(viewer), "canvas", None)
    return getattr(canvas, "_pause_scene_graph", False) is True


def build_overlays(viewer: Any, layer: Any) -> None:
    """Have napari build the canvas overlays of ``layer`` now, in a turn of their own, while the
    scene graph is held (``scene_graph_paused``): a labels layer's polygon and brush overlays
    take 0.08-0.14 s of the rebuild's turn (fr-alps, software GL). No-op without them."""
    canvas = getattr(_qt_viewer(viewer), "canvas", None)
    update = getattr(canvas, "_update_layer_overlays", None)
    if callable(update) and layer in getattr(canvas, "layer_to_visual", {}):
        with contextlib.suppress(RuntimeError):  # the Qt objects are already deleted
            update(layer)


def _controls_container(viewer: Any) -> Any:
    """napari's stack of layer controls, if the window has made it (None otherwise)."""
    container = getattr(_qt_viewer(viewer), "_controls", None)
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
    widgets are 0.1-0.2 s of the 0.2-0.3 s an insertion's turn takes, on fr-alps under
    software GL); an empty frame holds their place meanwhile (napari finds it if the
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
    _put_stand_in(container, layer)
    return True


#: ms after a reader's last layer went in before their controls are made, and again while
#: napari's opening still runs (its progress bar processes events, painting the first frame)
CONTROLS_AFTER_OPEN_MS = 50
#: ms after a reader returned when its deferral ends anyway (napari inserted fewer layers)
CONTROLS_FALLBACK_MS = 2000


def defer_controls(viewer: Any, kinds: Sequence[str]) -> None:
    """Leave napari's controls of the next ``len(kinds)`` layers inserted into ``viewer`` (those
    a reader returns, which napari inserts right after, in the same call; ``kinds``: their
    napari layer types, in that order) to later turns, as
    ``append_inactive(controls_later=True)`` does: a stand-in frame at their insertion, the
    controls made and put in napari's stack two turns per layer once the opening has returned.
    The canvas shows the layers first: making the controls and Qt's styling of them are
    0.1-0.2 s per layer of an N1's opening under software GL. A layer selected or removed
    meanwhile finds its stand-in.

    From the first labels layer on, napari's scene graph is held (``scene_graph_paused``): its
    insertion would build the labels' polygon and brush overlays, 0.07-0.08 s of an N1's
    opening and 0.3 s at the session's first (fr-alps, software GL). They are built
    after the controls, in a turn of their own (``build_overlays``, after one for vispy's dash
    patterns, 0.17 s of the session's first), and the scene graph rebuilt in the next; layers
    inserted after a labels layer are not in the first frame (the readers put their hidden
    labels last). No-op without napari's controls stack or Qt."""
    count = len(kinds)
    container = _controls_container(viewer)
    if container is None or count < 1:
        return
    try:
        from qtpy.QtCore import QTimer
    except ImportError:
        return
    events = getattr(getattr(viewer, "__wrapped__", viewer).layers, "events", None)
    inserted = getattr(events, "inserted", None)
    if inserted is None:
        return
    pending: list[Any] = []
    labels = [k for k, kind in enumerate(kinds) if kind == "labels"]
    held = labels[0] if labels else count  # the first insertion with the scene graph held
    inserted_labels: list[Any] = []
    state = {"blocked": True, "seen": 0}

    def stop() -> None:
        if state["blocked"]:
            state["blocked"] = False
            inserted.unblock(container._add)
            inserted.disconnect(stand_in)

    def then() -> None:  # vispy's dash patterns, each labels layer's overlays, then the
        built = inserted_labels[:]  # scene graph, a turn each
        inserted_labels.clear()
        if held < count:
            in_turns([*dash_pattern_steps(),
                      *(partial(build_overlays, viewer, layer) for layer in built),
                      partial(scene_graph_paused, viewer, False)])

    def hand_over() -> None:  # the layers leave these closures as they go to their turns: a
        layers = pending[:]   # timer's callable outlives its call (PyQt frees it later; the
        pending.clear()       # layers of an N1 opened, then removed, would stay alive)
        controls_in_turns(viewer, layers, then)

    def stand_in(event: Any) -> None:
        layer = event.value
        if state["seen"] in labels:
            inserted_labels.append(layer)
        state["seen"] += 1
        if state["seen"] == held < count:  # the next one is a labels layer
            scene_graph_paused(viewer, True)
        if layer not in container.widgets:
            _put_stand_in(container, layer)
            pending.append(layer)
        if len(pending) >= count:
            stop()
            QTimer.singleShot(CONTROLS_AFTER_OPEN_MS, hand_over)

    def fallback() -> None:  # fewer layers came (an error): napari makes any others' itself
        if state["blocked"]:
            stop()
            hand_over()

    if held == 0:
        scene_graph_paused(viewer, True)
    inserted.block(container._add)
    inserted.connect(stand_in)
    QTimer.singleShot(CONTROLS_FALLBACK_MS, fallback)


#: ms between two looks at whether ``in_turns``'s ``hold`` still holds its steps back
HOLD_RETRY_MS = 50


def in_turns(steps: list[Callable[[], Any]], first_ms: int = 1,
             hold: Callable[[], bool] | None = None) -> None:
    """Call each of ``steps`` in a turn of the Qt event loop of its own, from the next one on
    (the first ``first_ms`` from now), never inside napari's opening nor while ``hold()``."""
    from qtpy.QtCore import QTimer

    pending = list(steps)

    def step() -> None:
        if not pending:
            return
        if in_viewer_open():  # napari processes events before its opening returns
            QTimer.singleShot(CONTROLS_AFTER_OPEN_MS, step)
            return
        if hold is not None and hold():
            QTimer.singleShot(HOLD_RETRY_MS, step)
            return
        pending.pop(0)()
        QTimer.singleShot(1, step)

    QTimer.singleShot(first_ms, step)


#: ms between a worker's start being asked and the worker starting: the widget's "running"
#: state (buttons, status, progress bar) is painted first, without a job thread holding the GIL
#: for its first imports and numba's kernels (a first run's longest stall, 0.14-0.20 s)
START_AFTER_PAINT_MS = 30


def start_after_paint(worker: Any, cancelled: Callable[[], bool]) -> None:
    """Start ``worker`` (a napari thread worker) once the widget that asked for it has been
    painted, unless ``cancelled()`` says its widget has gone by then."""
    from qtpy.QtCore import QTimer

    def start() -> None:
        if not cancelled():
            worker.start()

    QTimer.singleShot(START_AFTER_PAINT_MS, start)


def controls_in_turns(viewer: Any, layers: list[Any], then: Any = None) -> None:
    """Make napari's controls of ``layers`` (appended with a stand-in), style them and put them
    in its stack, each in a turn of its own from the next one on (``make_controls``,
    ``polish_controls``, ``add_controls``), never inside napari's opening; then call
    ``then()``."""
    steps: list[Callable[[], Any]] = []
    for layer in layers:
        steps += [partial(make_controls, viewer, layer), partial(polish_controls, viewer, layer),
                  partial(add_controls, viewer, [layer])]
    in_turns(steps if then is None else [*steps, then])


def _put_stand_in(container: Any, layer: Any) -> None:
    """An empty frame in napari's controls stack in place of ``layer``'s controls."""
    from qtpy.QtWidgets import QFrame

    stand_in = QFrame()
    stand_in.setObjectName(CONTROLS_STAND_IN)
    container.addWidget(stand_in)
    container.widgets[layer] = stand_in


def make_controls(viewer: Any, layer: Any) -> None:
    """Make napari's controls of ``layer`` (appended with ``controls_later``) without putting
    them in the controls stack yet (:func:`add_controls` does, in a later turn): making them
    and Qt's styling of their widgets once in the stack are 0.06-0.08 s and 0.06-0.1 s of one
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


def polish_controls(viewer: Any, layer: Any) -> None:
    """Have Qt style the controls :func:`make_controls` made for ``layer``, in a turn of its
    own: put in napari's stack, they would be styled there (napari's style sheet applied to
    each of their widgets: 0.045 s of the 0.05 s of putting them in). They are styled as
    children of their stand-in (in the window, so under its style sheet, hidden; gone with it
    if the layer goes first); :func:`add_controls` moves them into the stack."""
    from qtpy.QtWidgets import QWidget

    container = _controls_container(viewer)
    stand_in = None if container is None else container.widgets.get(layer)
    made = getattr(stand_in, "controls", None)
    if made is None or layer not in viewer.layers:
        return
    with contextlib.suppress(RuntimeError):  # the Qt objects are already deleted
        made.setParent(stand_in)
        for widget in (made, *made.findChildren(QWidget)):
            widget.ensurePolished()


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

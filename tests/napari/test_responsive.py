"""The Orthorectify widget never blocks the Qt event loop and lets go of a finished run.

The longest gap between two turns of the event loop is measured with a 10 ms QTimer recording
timestamps. The result layers are built (contrast limits, RGB stretch, geometry) in the job, off
the Qt thread: built and added in one turn, they would freeze the viewer for seconds on
fr-small. The Qt thread inserts one ready layer per turn, without making it the active layer;
the layers a rerun replaces go one per turn inside one napari batch, so napari collects garbage
once, in a turn of its own. The longest turn left is one napari insertion (vispy visual, layer
controls) or that collection.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from qtpy.QtCore import QTimer

from napari_meris_ortho._napari.layout import camera_of
from napari_meris_ortho._napari.widget_ortho import OrthorectifyWidget
from napari_meris_ortho.simulate.scene import generate_scene
from qt_paints import paints_of

pytestmark = pytest.mark.slow

#: longest event-loop gap allowed during a run: one napari layer insertion or napari's one
#: garbage collection after the replaced layers went (about 0.5-0.8 s on a busy 2-core
#: machine), with room to spare. Collecting garbage at each removal, switching the layer
#: controls at each insertion or running two steps in one turn would exceed it.
MAX_GAP_S = 1.5


@pytest.fixture(scope="module")
def fr_small():
    """The fr-small scene (cached by the simulator)."""
    return generate_scene("fr-small")


class LoopTurns:
    """Timestamps of a 10 ms QTimer: the event loop's turns while the block runs."""

    def __enter__(self) -> LoopTurns:
        self.stamps: list[float] = []
        self.timer = QTimer()
        self.timer.timeout.connect(lambda: self.stamps.append(time.perf_counter()))
        self.timer.start(10)
        return self

    def __exit__(self, *exc: object) -> None:
        self.timer.stop()

    @property
    def longest_gap(self) -> float:
        return float(np.diff(self.stamps).max())


def _run(widget, qtbot):
    assert widget.start() is not None, widget.status.value
    qtbot.waitUntil(lambda: not widget.running, timeout=120_000)
    assert widget.status.value.startswith("done"), widget.status.value


def test_event_loop_keeps_turning_during_a_run(make_napari_viewer, qtbot, tiny_n1, fr_small,
                                               monkeypatch):
    from napari_meris_ortho._napari import widget_ortho

    # the widget's opening ends with a full garbage collection before ``freeze_long_lived``; it
    # waits while a run goes on, so a run started at once would push it into the measured run's
    # last turns (over a second in this pytest process's heap, the suite's earlier tests, where
    # a napari session's takes 0.1 s). The runs start after it, as a user's would.
    frozen: list[bool] = []
    freeze = widget_ortho.freeze_long_lived
    monkeypatch.setattr(widget_ortho, "freeze_long_lived",
                        lambda *a, **k: (freeze(*a, **k), frozen.append(True)))
    viewer = make_napari_viewer(show=True)
    widget = OrthorectifyWidget(viewer)
    qtbot.waitUntil(lambda: bool(frozen), timeout=30_000)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"
    _run(widget, qtbot)  # warm-up: numba kernels loaded, napari's first layers of each kind
    widget.products.value = [fr_small.product_path]
    widget.elevation.value = "dem"
    widget.add_dem(fr_small.dem_paths["geotiff"])
    with LoopTurns() as turns:
        _run(widget, qtbot)
        qtbot.wait(50)
    ortho = [layer for layer in viewer.layers if layer.name.startswith("ortho")]
    assert len(ortho) == 4  # RGB, 3 bands: same names as the tiny run's, which they replaced
    assert {layer.metadata["path"] for layer in ortho} == {str(fr_small.product_path)}
    assert turns.longest_gap < MAX_GAP_S, f"event loop blocked {turns.longest_gap:.2f} s"


def test_cancel_acts_within_half_a_second(make_napari_viewer, qtbot, fr_small):
    viewer = make_napari_viewer()
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [fr_small.product_path] * 4
    widget.add_dem(fr_small.dem_paths["geotiff"])
    widget.bands.value = "all"
    assert widget.start() is not None, widget.status.value
    qtbot.waitUntil(lambda: widget.progress_state[0] > 0, timeout=120_000)
    t0 = time.perf_counter()
    widget.cancel()
    qtbot.waitUntil(lambda: not widget.running, timeout=10_000)
    assert time.perf_counter() - t0 < 0.5
    assert "cancelled" in widget.status.value
    assert len(viewer.layers) == 0
    assert widget.run_button.enabled and not widget.cancel_button.enabled


def test_finished_runs_keep_nothing_but_their_layers(fr_small, tmp_path):
    """Four runs, all layers removed: resident memory within 10 % of before them. Measured in a
    fresh process (``memory_probe.py``: one warm-up run, then the four), on the test's display:
    in the pytest process the earlier tests' allocations would move the figure by 10 %."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    probe = Path(__file__).with_name("memory_probe.py")
    done = subprocess.run([sys.executable, str(probe), str(fr_small.product_path),
                           str(tmp_path / "settings.yaml")], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    figures = json.loads(done.stdout.strip().splitlines()[-1])
    before, after = figures["before"], figures["after"]
    assert figures["run_mb"] > 40
    assert after < 1.10 * before, f"{before / 2**20:.0f} MB -> {after / 2**20:.0f} MB"


def test_camera_frames_the_result(make_napari_viewer, qtbot, tiny_n1):
    """After a run the camera frames the result, not the whole viewer (where the result would
    show as a small patch in a mostly black canvas)."""
    from napari_meris_ortho._napari.world import geo_image_kwargs
    from napari_meris_ortho.geometry.grid import OutputGrid

    viewer = make_napari_viewer(show=True)
    # a map 20 x 20 times the size of the result, in the same UTM zone, already in the viewer
    big = OutputGrid.from_transform("EPSG:32632", (5000.0, 0, 0.0, 0, -5000.0, 5.6e6),
                                    (400, 400))
    viewer.add_image(np.ones((400, 400), np.float32), **geo_image_kwargs(big, name="map"))
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"
    _run(widget, qtbot)
    rgb = next(layer for layer in viewer.layers if layer.name.startswith("ortho RGB"))
    (top, left), (bottom, right) = np.asarray(rgb.extent.world)[:, -2:]
    centre = np.asarray(camera_of(viewer).center)[-2:]
    np.testing.assert_allclose(centre, [(top + bottom) / 2, (left + right) / 2],
                               atol=0.05 * (right - left))
    zoom_result = camera_of(viewer).zoom
    viewer.fit_to_view()
    assert zoom_result > 5 * camera_of(viewer).zoom  # framed on the result, not on the map


def test_a_run_shows_its_layers_one_per_frame(make_napari_viewer, qtbot, tiny_n1):
    """vispy builds a new visual's shaders at its first draw: a frame that drew every new layer
    of a run at once would be the longest stall of a run (up to about 0.6 s on fr-alps). The
    run's visible layers are shown one at a time, each in a frame of its own, once all are
    in (the canvas draws nothing while they go in: ``insertion.canvas_updates``)."""
    viewer = make_napari_viewer(show=True)
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"
    widget.bands.value = "7,5,2"
    widget.geometry.value = True
    scene_canvas = viewer.window._qt_viewer.canvas._scene_canvas
    shown_at_draw: list[int] = []

    def count(_event=None):
        new = [layer for layer in viewer.layers if layer.name.startswith(
            ("ortho", "footprint", "facets", "parallax")) and layer.visible]
        shown_at_draw.append(len(new))

    native = viewer.window._qt_viewer.canvas.native
    painting_when_shown: dict[str, bool] = {}

    def watch(event):  # each new layer, as it goes in: is the canvas painting when shown?
        layer = event.value
        layer.events.visible.connect(
            lambda e, name=layer.name: painting_when_shown.setdefault(
                name, bool(e.source.visible and native.updatesEnabled())))

    viewer.layers.events.inserted.connect(watch)
    scene_canvas.events.draw.connect(count)
    _run(widget, qtbot)
    qtbot.wait(200)
    scene_canvas.events.draw.disconnect(count)
    visible = [layer for layer in viewer.layers if layer.visible]
    assert len(visible) >= 4  # RGB, footprint, facets, parallax (bands hidden)
    assert shown_at_draw and shown_at_draw[-1] == len(visible)
    steps = np.diff([0, *shown_at_draw])
    assert steps.max() == 1, f"new layers per frame: {shown_at_draw}"
    # the first draw of a shown layer is in a turn after the one that showed it (its slicing
    # and thumbnail, 0.01-0.04 s, and its first draw, 0.03-0.09 s, would make one stall)
    shown = {layer.name for layer in visible}
    assert set(painting_when_shown) >= shown
    assert not any(painting_when_shown[name] for name in shown), painting_when_shown
    assert native.updatesEnabled()


def test_a_rerun_removes_the_replaced_layers_top_first(make_napari_viewer, qtbot, tiny_n1):
    """Removing a layer that widens the world (the footprint and facets reach past the rasters)
    makes napari slice again every layer left; the parallax vectors, on top, then redrew their
    thumbnail in Python (fr-alps: 0.09 s, the removal turn 0.12-0.19 s). The replaced layers
    go top first, so the vectors are gone before; the rasters left redraw theirs cheaply."""
    viewer = make_napari_viewer()
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"
    widget.geometry.value = True
    _run(widget, qtbot)
    old = list(viewer.layers)
    removed: list[str] = []
    viewer.layers.events.removed.connect(lambda e: removed.append(e.value.name))
    thumbnails: list[str] = []
    for layer in old:
        layer.events.thumbnail.connect(lambda e, name=layer.name: thumbnails.append(name))
    _run(widget, qtbot)
    assert removed == [layer.name for layer in old[::-1]]
    assert removed[0].startswith("parallax")
    assert not [name for name in thumbnails if name.startswith("parallax")], thumbnails


def test_a_labels_layer_after_the_widget_builds_no_dash_pattern(make_napari_viewer, qtbot):
    """Every napari labels layer has a polygon overlay whose vispy line builds the dash patterns
    (0.08 s, at the session's first labels layer: a run's "elevation source"). The widget has
    vispy build them as it opens (one per turn); a labels layer inserted later builds none."""
    from vispy.visuals.line.dash_atlas import _make_pattern

    _make_pattern.cache_clear()
    viewer = make_napari_viewer(show=True)
    OrthorectifyWidget(viewer)
    qtbot.waitUntil(lambda: _make_pattern.cache_info().misses >= 10, timeout=2000)
    qtbot.wait(200)
    built = _make_pattern.cache_info().misses
    viewer.add_labels(np.zeros((16, 16), np.uint8), name="elevation source")
    assert _make_pattern.cache_info().misses == built


def test_an_n1_opening_builds_the_dash_patterns_one_per_turn(make_napari_viewer, qtbot, tiny_n1):
    """An N1 opens with hidden labels (its flags): their insertion waits for vispy's dash
    patterns (about 0.2 s of work after a session's first opening of fr-alps, if built in one
    turn). They are built one pattern per turn, and a labels layer then builds none."""
    from qtpy.QtCore import QTimer
    from vispy.visuals.line.dash_atlas import _make_pattern

    _make_pattern.cache_clear()
    viewer = make_napari_viewer(show=True)
    turns: list[int] = []
    timer = QTimer()
    timer.timeout.connect(lambda: turns.append(_make_pattern.cache_info().misses))
    timer.start(0)
    viewer.open(tiny_n1, plugin="napari-meris-ortho")
    qtbot.waitUntil(lambda: _make_pattern.cache_info().misses >= 10, timeout=10_000)
    qtbot.wait(200)
    timer.stop()
    built = _make_pattern.cache_info().misses
    assert max(np.diff(turns)) == 1, sorted(set(np.diff(turns)))  # never two in one turn
    viewer.add_labels(np.zeros((16, 16), np.uint8), name="elevation source")
    assert _make_pattern.cache_info().misses == built


def test_the_widget_opens_in_turns_of_its_own(make_napari_viewer, qtbot):
    """Opening the dock in one turn of the event loop would take 0.4-0.5 s (warm disk cache;
    up to 1.2 s cold): the widget, the glyphs of the text overlay's first text and the nine
    vispy always renders (0.15 s), the overlay's first draw (its shaders, 0.2 s), a garbage
    collection before freezing what napari holds and vispy's dash patterns (0.04 s). The
    constructor makes the widget only; the patterns, the glyphs a few at a time, the overlay's
    first draw (transparent text) and the freeze come in turns of their own right after,
    before a user can fill the form and reach Run."""
    import gc

    from napari_meris_ortho._napari import memory

    viewer = make_napari_viewer(show=True)
    qtbot.wait(100)
    memory.thaw()
    native = viewer.window._qt_viewer.canvas.native
    with paints_of(native, lambda: (viewer.canvas.overlays.text.text,
                                    gc.get_freeze_count())) as paints:
        OrthorectifyWidget(viewer)
        opened, frozen = list(paints), gc.get_freeze_count()
        qtbot.waitUntil(lambda: gc.get_freeze_count() > 50_000, timeout=2000)
        seen = list(paints)
    assert not opened and frozen == 0  # neither within the constructor's turn
    first = [k for k, (text, _) in enumerate(seen) if text]
    assert first, seen  # the overlay was drawn with the first glyphs ...
    assert seen[first[0]][1] == 0  # ... before the freeze, in another turn
    assert not viewer.canvas.overlays.text.color[-1]  # transparent: never seen


def test_the_opening_steps_wait_after_a_users_open(make_napari_viewer, qtbot, monkeypatch):
    """A layer that goes in while the dock opens (a user's open) holds the opening's steps
    for ``SETTLE_AFTER_INSERT_S``: the legend's first draw and the collection before the
    freeze (0.2-0.35 s each) do not fall in the frames the user waits for."""
    from napari_meris_ortho._napari import memory, widget_ortho

    steps: list[float] = []
    freeze = widget_ortho.freeze_long_lived
    monkeypatch.setattr(widget_ortho, "freeze_long_lived",
                        lambda *a, **k: (steps.append(time.perf_counter()), freeze(*a, **k)))
    viewer = make_napari_viewer(show=True)
    qtbot.wait(100)
    memory.thaw()
    overlay = viewer.canvas.overlays.text
    drawn: list[float] = []
    overlay.events.visible.connect(lambda _e=None: drawn.append(time.perf_counter()))
    OrthorectifyWidget(viewer)
    viewer.add_image(np.zeros((8, 8), np.float32), name="a user's image")
    inserted = time.perf_counter()
    qtbot.waitUntil(lambda: bool(steps), timeout=10_000)
    assert steps[0] - inserted >= widget_ortho.SETTLE_AFTER_INSERT_S
    assert drawn and drawn[0] - inserted >= widget_ortho.SETTLE_AFTER_INSERT_S


def test_a_run_collects_its_garbage_off_the_qt_thread(make_napari_viewer, tiny_n1):
    """Building a run's layers makes tens of thousands of objects; Python's next full collection
    would then fall in one of their insertion turns on the Qt thread (0.04-0.09 s more in that
    turn). The worker's job (``build_layers``) ends with that
    collection: the layers come to the Qt thread with every generation's count at zero."""
    import gc

    from napari_meris_ortho._napari.widget_ortho import build_layers

    viewer = make_napari_viewer()
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"
    widget.geometry.value = True
    for _ in range(3):
        run, layers = build_layers(widget.settings(), lambda done, total: None, lambda: None, None)
        counts = gc.get_count()
        assert len(layers) >= 8 and counts[1:] == (0, 0), counts
        del run, layers


def test_a_job_makes_one_full_collection_and_none_when_it_replaces_layers(make_napari_viewer,
                                                                         tiny_n1):
    """A full collection holds the GIL for as long as it walks (0.1-0.2 s with a session's
    layers), so the Qt thread stalls whichever thread runs it. The job pauses Python's automatic
    collections while it makes the layers and collects once; a job whose layers replace the
    viewer's collects not at all (napari collects after removing the replaced layers, before the
    insertions)."""
    import gc
    import threading

    from napari_meris_ortho._napari.widget_ortho import build_layers

    viewer = make_napari_viewer()
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"
    widget.geometry.value = True
    full: list[str] = []

    def count(phase, info):
        if phase == "start" and info["generation"] == 2:
            full.append(threading.current_thread().name)

    threshold = gc.get_threshold()
    gc.set_threshold(50, 1, 1)  # Python's full collections as often as they can come
    gc.callbacks.append(count)
    try:
        _, layers = build_layers(widget.settings(), lambda done, total: None, lambda: None, None)
        first = len(full)
        names = frozenset(layer.name for layer in layers)
        del layers
        _, layers = build_layers(widget.settings(), lambda done, total: None, lambda: None, None,
                                 names)
        rerun = len(full) - first
    finally:
        gc.callbacks.remove(count)
        gc.set_threshold(*threshold)
    assert gc.isenabled()
    assert first == 1, full
    assert rerun == 0, full


def test_a_runs_removed_layers_are_collected(make_napari_viewer, qtbot, tiny_n1):
    """Every layer of a run is freed once removed. The footprint and facets are Vectors, not
    napari Shapes, which napari keeps alive through their mode buttons after removal
    (https://github.com/napari/napari/issues/2027: 9 MB more at each run and clear of fr-small).
    A weak reference to each of a run's layers is dead after the viewer is cleared."""
    import gc
    import weakref

    viewer = make_napari_viewer(show=True)
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"
    for _ in range(2):
        assert widget.start() is not None
        qtbot.waitUntil(lambda: not widget.running, timeout=60_000)
        kinds = {layer.name.split(" ")[0]: layer._type_string for layer in viewer.layers}
        assert kinds["facets"] == kinds["footprint"] == "vectors"
        refs = [weakref.ref(layer) for layer in viewer.layers]
        viewer.layers.clear()
        qtbot.wait(300)  # napari's deferred deletions of the layer controls
        gc.collect()
        alive = [r().name for r in refs if r() is not None]
        assert alive == [], alive


def test_an_opened_products_removed_layers_are_collected(make_napari_viewer, qtbot, tiny_n1):
    """An N1's layers, opened then removed, are freed. The timer's callable that hands their
    controls to later turns holds a list of them, and PyQt frees a single shot's callable only
    later, so the layers leave that list as they go to their turns."""
    import gc
    import weakref

    viewer = make_napari_viewer(show=True)
    for _ in range(2):
        viewer.open(tiny_n1, plugin="napari-meris-ortho")
        qtbot.wait(2500)  # the controls, overlays and thumbnails made in later turns
        refs = [weakref.ref(layer) for layer in viewer.layers]
        assert len(refs) == 3
        viewer.layers.clear()
        qtbot.wait(300)
        gc.unfreeze()  # the plugin's freeze of what napari holds at its first read
        gc.collect()
        alive = [r().name for r in refs if r() is not None]
        assert alive == [], alive


def test_removing_layers_hands_the_heap_back(make_napari_viewer, qtbot):
    """Once layers leave the viewer the widget has glibc return the freed heap to the system
    (``memory.trim_after_removals``), in a thread of its own a second after the last removal:
    resident memory goes back without the user doing anything."""
    import gc

    import psutil

    from napari_meris_ortho import _process

    viewer = make_napari_viewer()
    OrthorectifyWidget(viewer)
    qtbot.waitUntil(lambda: gc.get_freeze_count() > 0, timeout=2000)  # the opening's turns
    # many small blocks (the Python objects of removed layers are such): freed, they stay in
    # the heap until trimmed
    blocks = [bytearray(2000) for _ in range(150_000)]
    viewer.add_image(np.zeros((8, 8), np.float32), name="x", metadata={"blocks": blocks})
    del blocks
    before_removal = psutil.Process().memory_info().rss
    viewer.layers.clear()
    gc.collect()
    freed = psutil.Process().memory_info().rss
    qtbot.waitUntil(lambda: "timer" in _process._pending, timeout=5_000)
    _process._pending["timer"].join(10)
    qtbot.wait(50)
    trimmed = psutil.Process().memory_info().rss
    assert before_removal - trimmed > 200 * 2**20, (before_removal, freed, trimmed)
    assert freed - trimmed > 100 * 2**20  # the trim, not the removal, gave it back


def test_long_lived_objects_are_frozen_until_a_held_layer_goes(make_napari_viewer, qtbot):
    """napari collects garbage after removing layers (a full collection: 0.23-0.27 s at every
    rerun on fr-alps); the widget freezes the objects alive when it opens (napari, Qt, modules)
    so that collection sees only what came since. A layer held then that leaves the viewer, or
    the widget closing, unfreezes everything: nothing frozen is kept from collection."""
    import gc

    from napari_meris_ortho._napari import memory

    memory.thaw()
    viewer = make_napari_viewer()
    held = viewer.add_image(np.zeros((8, 8), np.float32), name="held")
    widget = OrthorectifyWidget(viewer)
    qtbot.waitUntil(lambda: gc.get_freeze_count() > 50_000, timeout=2000)  # in a turn after
    new = viewer.add_image(np.zeros((8, 8), np.float32), name="new")
    viewer.layers.remove(new)  # made after the freeze: collected as usual
    assert gc.get_freeze_count() > 50_000
    viewer.layers.remove(held)
    assert gc.get_freeze_count() == 0  # all objects within the collector's reach again
    memory.freeze_long_lived(viewer)  # no layer held: nothing to watch
    assert gc.get_freeze_count() > 50_000
    widget._shutdown()
    assert gc.get_freeze_count() == 0


def test_the_first_read_freezes_what_napari_holds(make_napari_viewer, tiny_n1):
    """napari makes the first layers of a session slowly (importing xarray and pandas: their
    objects fill the collector's oldest generation, and a full collection walks everything:
    about 0.15 s of a 1.1 s fr-alps open). The plugin's first read freezes the objects
    alive then, without a collection of its own, so later full passes walk only the new
    objects. Once per process: a later read freezes nothing."""
    import gc

    from napari_meris_ortho._napari import memory

    memory.thaw()
    memory._first_read[:] = [True]
    viewer = make_napari_viewer()
    started = []

    def watch(phase: str, info: dict) -> None:
        if phase == "start" and info["generation"] == 2:
            started.append(gc.get_freeze_count())

    alive = len(gc.get_objects())
    gc.callbacks.append(watch)
    try:
        viewer.open(str(tiny_n1), plugin="napari-meris-ortho")
    finally:
        gc.callbacks.remove(watch)
    frozen = gc.get_freeze_count()
    assert frozen >= 0.95 * alive > 50_000
    assert all(n >= 0.95 * alive for n in started)  # no full pass walked them
    memory.thaw()
    viewer.layers.clear()
    viewer.open(str(tiny_n1), plugin="napari-meris-ortho")
    assert gc.get_freeze_count() == 0


def test_the_widget_collects_what_the_first_read_froze(make_napari_viewer, qtbot, tiny_n1):
    """The first read freezes without collecting. The widget, when it opens, collects every
    object, frozen ones included, then freezes again: garbage frozen at the first read is
    reclaimed, and Python times its next full collections by all the survivors (a pass over
    the unfrozen few alone makes them frequent enough to stall runs by about 0.3 s)."""
    import gc
    import weakref

    from napari_meris_ortho._napari import memory

    class Cycle:
        me: object

    memory.thaw()
    memory._first_read[:] = [True]
    viewer = make_napari_viewer()
    gc.disable()  # the cycle is still garbage to collect when the reader freezes it
    try:
        cycle = Cycle()
        cycle.me = cycle
        ref = weakref.ref(cycle)
        del cycle
        viewer.open(str(tiny_n1), plugin="napari-meris-ortho")
    finally:
        gc.enable()
    gc.collect()
    assert ref() is not None and gc.get_freeze_count() > 50_000  # frozen, out of reach
    OrthorectifyWidget(viewer)
    qtbot.waitUntil(lambda: ref() is None, timeout=2000)  # in a turn after its opening
    assert gc.get_freeze_count() > 50_000


def test_freeze_undone_when_a_held_layer_goes_from_the_docked_widget(make_napari_viewer, qtbot):
    """As napari docks it (the widget gets the plugin's public-only proxy of the viewer), a
    layer held when the widget opened still undoes the freeze when it leaves."""
    import gc

    from napari_meris_ortho._napari import memory

    memory.thaw()
    viewer = make_napari_viewer()
    held = viewer.add_image(np.zeros((8, 8), np.float32), name="held")
    viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    qtbot.waitUntil(lambda: gc.get_freeze_count() > 50_000, timeout=2000)
    viewer.layers.remove(held)
    assert gc.get_freeze_count() == 0


def test_a_docked_widget_holds_the_canvas_without_napari_privates(make_napari_viewer):
    """Docked, the widget holds napari's public-only proxy of the viewer. Holding the canvas
    still through it (``insertion.canvas_updates``, at every run) reached ``Window._qt_viewer``
    through the proxy: a FutureWarning at each run, and no hold at all once napari 0.10 blocks
    such access (then Mesa's crash between insertions is back)."""
    import warnings

    from napari_meris_ortho._napari._qt.insertion import canvas_updates

    viewer = make_napari_viewer(show=True)
    _, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    assert type(widget.viewer).__name__ == "PublicOnlyProxy"
    native = viewer.window._qt_viewer.canvas.native
    with warnings.catch_warnings():
        warnings.simplefilter("error", FutureWarning)
        canvas_updates(widget.viewer, False)
        assert not native.updatesEnabled()
        canvas_updates(widget.viewer, True)
    assert native.updatesEnabled()


def test_a_layers_controls_are_made_in_a_turn_of_their_own(make_napari_viewer, qtbot, tiny_n1,
                                                            monkeypatch):
    """Making napari's controls of a new layer (and Qt's styling of their widgets after) is
    0.1-0.2 s of the 0.2-0.3 s an insertion takes (fr-alps, software GL): the widget
    appends a layer with a stand-in in napari's controls stack and makes its controls in the
    next turn. After the run every layer has its own controls, selecting one shows them, no
    stand-in is left, and the scene graph held during the insertions is rebuilt in order."""
    from napari._qt.layer_controls import qt_layer_controls_container as qlc

    from napari_meris_ortho._napari._qt.insertion import CONTROLS_STAND_IN

    viewer = make_napari_viewer(show=True)
    _, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"
    widget.geometry.value = True
    container = viewer.window._qt_viewer.controls
    appending: list[bool] = [False]
    made_while_appending: list[str] = []
    made: list[str] = []
    create = qlc.create_qt_layer_controls

    def spy(layer):
        made.append(layer.name)
        if appending[0]:
            made_while_appending.append(layer.name)
        return create(layer)

    monkeypatch.setattr(qlc, "create_qt_layer_controls", spy)
    from napari_meris_ortho._napari import widget_ortho

    original = widget_ortho.append_inactive

    def append(*args, **kwargs):
        appending[0] = True
        try:
            return original(*args, **kwargs)
        finally:
            appending[0] = False

    monkeypatch.setattr(widget_ortho, "append_inactive", append)
    _run(widget, qtbot)
    names = [layer.name for layer in viewer.layers]
    assert len(names) >= 6
    assert not made_while_appending, made_while_appending
    assert sorted(made) == sorted(names)
    stack = [container.widget(i) for i in range(container.count())]
    assert not [w for w in stack if w.objectName() == CONTROLS_STAND_IN]
    for layer in viewer.layers:
        controls = container.widgets[layer]
        assert type(controls).__name__.endswith("Controls"), type(controls)
        viewer.layers.selection.active = layer
        assert container.currentWidget() is controls and controls.isVisible()
    canvas = viewer.window._qt_viewer.canvas
    assert not canvas._pause_scene_graph
    orders = [canvas.layer_to_visual[layer].order for layer in viewer.layers]
    assert orders == sorted(orders) and len(set(orders)) == len(orders), orders
    labels = [layer for layer in viewer.layers if type(layer).__name__ == "Labels"]
    assert labels  # the elevation source; its overlays built in a turn of their own
    for layer in labels:
        built = {type(o).__name__ for o in canvas._layer_overlay_to_visual[layer]}
        assert {"LabelsPolygonOverlay", "LabelsBrushStrokeOverlay"} <= built, built


def test_a_layer_selected_or_removed_before_its_controls_are_made(make_napari_viewer):
    """In the turn between a layer's insertion and its controls, napari finds the stand-in:
    selecting the layer shows it (then its controls once made), removing the layer removes it
    (napari looked the controls up and failed with a KeyError without one)."""
    from napari_meris_ortho._napari._qt.insertion import (
        CONTROLS_STAND_IN,
        add_controls,
        append_inactive,
        make_controls,
    )

    viewer = make_napari_viewer(show=True)
    container = viewer.window._qt_viewer.controls
    first, second = (napari_image(name) for name in ("first", "second"))
    assert append_inactive(viewer, first, controls_later=True)
    assert append_inactive(viewer, second, controls_later=True)
    assert container.widgets[first].objectName() == CONTROLS_STAND_IN
    count = container.count()
    viewer.layers.selection.active = first
    assert container.currentWidget() is container.widgets[first]
    viewer.layers.remove(second)  # its stand-in goes with it
    assert second not in container.widgets and container.count() == count - 1
    # made in one turn, put in napari's stack in a later one (Qt styles them there)
    make_controls(viewer, first)
    made = container.widgets[first].controls
    assert container.widgets[first].objectName() == CONTROLS_STAND_IN
    assert container.indexOf(made) == -1
    add_controls(viewer, [first, second])  # the removed one: nothing to make
    controls = container.widgets[first]
    assert controls is made and container.indexOf(made) >= 0
    assert container.currentWidget() is controls  # the selected layer shows its controls
    viewer.layers.selection.active = None
    viewer.layers.selection.active = first
    assert container.currentWidget() is controls
    # without controls_later: napari makes them in the insertion, as ever
    third = napari_image("third")
    assert not append_inactive(viewer, third)
    assert container.widgets[third].objectName() != CONTROLS_STAND_IN


def napari_image(name: str):
    from napari.layers import Image

    return Image(np.zeros((8, 8), np.float32), name=name)


def test_a_hidden_layers_thumbnail_draws_no_frame(make_napari_viewer, qtbot):
    """A run's hidden bands get their thumbnails shown and hidden again at once: each of the
    two changes would rebuild the canvas's scene graph and redraw the canvas (0.04 s and 0.08 s
    a thumbnail after a fr-alps run). Neither happens; the layer's pixels are on the canvas when
    it is shown."""
    from napari_meris_ortho._napari._qt.insertion import thumbnail_while_hidden

    viewer = make_napari_viewer(show=True)
    ramp = np.tile(np.linspace(0.0, 1.0, 64, dtype=np.float32), (64, 1))
    layer = viewer.add_image(ramp, name="band", visible=False, contrast_limits=(0.0, 1.0))
    qtbot.wait(200)
    assert not layer.thumbnail[..., :3].any()  # never sliced
    changes: list[object] = []
    layer.events.visible.connect(changes.append)
    with paints_of(viewer.window._qt_viewer.canvas.native) as paints:
        thumbnail_while_hidden(layer)
        qtbot.wait(200)
    assert layer.thumbnail[..., :3].any() and not layer.visible
    assert not changes and not paints, (len(changes), len(paints))
    layer.visible = True
    shot = viewer.screenshot(canvas_only=True)[..., 0].astype(float)
    row = shot[shot.shape[0] // 2]
    lit = row[row > 0]
    assert lit.size > 10 and lit[-5:].mean() > lit[:5].mean() + 100  # the ramp, drawn


def test_a_layers_controls_are_styled_before_they_go_in(make_napari_viewer, qtbot):
    """Putting a layer's controls in napari's stack has Qt apply napari's style sheet to each
    of their widgets (0.045 s of the 0.05 s it takes): they are styled beforehand, in a turn of
    their own (``polish_controls``), as children of their stand-in; those of a layer removed
    before they go in go with the stand-in."""
    from qtpy.QtCore import Qt
    from qtpy.QtWidgets import QWidget

    from napari_meris_ortho._napari._qt import insertion

    viewer = make_napari_viewer(show=True)
    container = viewer.window._qt_viewer.controls
    kept, removed = napari_image("kept"), napari_image("gone")
    made = {}
    for layer in (kept, removed):
        assert insertion.append_inactive(viewer, layer, controls_later=True)
        insertion.make_controls(viewer, layer)
        made[layer.name] = container.widgets[layer].controls
        tree = [made[layer.name], *made[layer.name].findChildren(QWidget)]
        assert not all(w.testAttribute(Qt.WidgetAttribute.WA_WState_Polished) for w in tree)
        insertion.polish_controls(viewer, layer)
        assert all(w.testAttribute(Qt.WidgetAttribute.WA_WState_Polished) for w in tree)
    insertion.add_controls(viewer, [kept])
    assert container.widgets[kept] is made["kept"]
    viewer.layers.selection.active = kept
    assert container.currentWidget() is made["kept"]
    qtbot.waitUntil(lambda: made["kept"].isVisible(), timeout=2000)  # shown, styled
    destroyed: list[bool] = []
    made["gone"].destroyed.connect(lambda *_: destroyed.append(True))
    viewer.layers.remove(removed)
    qtbot.waitUntil(lambda: bool(destroyed), timeout=2000)

"""Memory of the viewer: the heap handed back once layers are removed, and the objects that
live as long as napari kept out of Python's full garbage collections.

glibc keeps the freed small-object heap for reuse: after four fr-alps runs with every layer
removed, a viewer that held 625 MB before the runs holds 861 MB resident, and 671 MB once
``malloc_trim`` has returned that heap.
``trim_after_removals`` calls it a second after the last removal, in a thread (no-op off glibc),
and has glibc hand big blocks back as they are freed (``_process.return_freed_memory``): the
heap of the thread that made a run's arrays is out of ``malloc_trim``'s reach.
``freeze_long_lived`` keeps napari's own collection after a removal short (its docstring).
"""

from __future__ import annotations

import contextlib
import gc
import weakref
from collections.abc import Iterator
from typing import Any

from .._process import return_freed_memory, schedule_trim

_WATCHED: weakref.WeakSet[Any] = weakref.WeakSet()


def trim_after_removals(viewer: Any) -> None:
    """Big blocks handed back when freed, the heap trimmed after layers leave ``viewer``
    (idempotent)."""
    if viewer is None or viewer in _WATCHED:
        return
    return_freed_memory()
    _WATCHED.add(viewer)
    viewer.layers.events.removed.connect(lambda _event=None: schedule_trim())


def freeze_long_lived(viewer: Any, collect: bool = True) -> None:
    """Move the objects alive now (napari, Qt, vispy, modules: 350 000 of them) out of reach of
    Python's garbage collector (``gc.freeze``, cumulative), so that napari's full collection
    after removing layers (``VispyCanvas._clean_and_update_scenegraph`` calls ``gc.collect()``:
    0.23-0.27 s at every rerun of the widget) traverses only what was made since: a run's
    layers (0.13-0.15 s then). Frozen objects are never collected as cyclic
    garbage, so this is undone (``thaw``) when one of the layers the viewer holds now leaves
    it, and when the widget goes (viewer closed). ``collect``: first a full collection of every
    object, frozen ones included: Python times its next full collections by the survivors of
    the last one (a quarter more), and a pass over the unfrozen few alone would make them
    frequent enough to fall in a run's insertions (0.26-0.29 s stalls)."""
    if collect:
        gc.unfreeze()
        gc.collect()
    gc.freeze()
    _frozen[0] = True
    # the layers themselves, not the plugin's public-only proxies of them (made at each access)
    layers = getattr(viewer, "__wrapped__", viewer).layers
    layers = getattr(layers, "__wrapped__", layers)
    held = weakref.WeakSet(layers)

    def removed(event: Any = None) -> None:
        layer = getattr(event, "value", None)
        if layer is not None and layer in held:
            held.clear()
            thaw()

    if len(held):
        layers.events.removed.connect(removed)


def freeze_at_first_read(viewer: Any) -> None:
    """``freeze_long_lived`` at the plugin's first read of the process, without the full
    collection: the session's garbage-collector pauses while napari makes the first layers
    (importing xarray and pandas, 0.15 s) then walk only what is new. At that moment the
    collection finds nothing (0 objects) and would cost the 0.1-0.15 s it saves."""
    if not _first_read:
        return
    _first_read.clear()
    if not frozen():
        freeze_long_lived(viewer, collect=False)


def thaw() -> None:
    """Undo ``freeze_long_lived``: every object back within the collector's reach."""
    gc.unfreeze()
    _frozen[0] = False


def frozen() -> bool:
    """Whether ``freeze_long_lived`` holds objects frozen (not undone by ``thaw``). Python's
    ``gc.get_freeze_count`` walks every frozen object: 0.03 s with napari's."""
    return _frozen[0]


_first_read = [True]
_frozen = [False]

__all__ = ["collections_paused", "freeze_at_first_read", "freeze_long_lived", "frozen",
           "short_collections", "thaw", "trim_after_removals"]


@contextlib.contextmanager
def short_collections() -> Iterator[None]:
    """For the block, the objects alive now out of napari's full collections (``gc.freeze``),
    so that a layer's removal collects only what was made since; given back after, unless
    objects were frozen before (``freeze_long_lived``: its ``thaw`` gives these back too)."""
    frozen_before = frozen()
    gc.freeze()
    try:
        yield
    finally:
        if not frozen_before:
            gc.unfreeze()


@contextlib.contextmanager
def collections_paused() -> Iterator[None]:
    """Python's automatic collections off for the block (napari layers being made off the Qt
    thread), as they were after: the caller then collects once, in its own thread, so that no
    full collection falls in one of the layers' insertion turns on the Qt thread."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()

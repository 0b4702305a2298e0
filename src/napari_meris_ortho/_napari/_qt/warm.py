"""The Orthorectify dock's warm-up, in pieces that never compete with the user.

What a user's first open and first Run would otherwise pay, prepared while they choose:

- napari's own first-layer set-up: the modules napari imports at its first image layer
  (xarray, pandas, scipy.ndimage for its thumbnails: about 1 s), one import per piece;
- the engine's numba kernels: compiled out of the process (``warmup.kernels_out_of_process``:
  a child at the lowest priority fills numba's on-disk cache, or reads it when warm); numba's
  CPU target started one module per piece (``_process.numba_start_pieces``), then the kernels
  loaded from the cache one specialisation per piece (``warmup.load_kernel``).

The pieces run through ``idle.IdlePieces``: one per idle turn of the event loop, none
while napari opens a file or a run is under way. napari's first-layer imports come first (a
user opens a product before a run); the dock's other opening steps wait for them, and the
kernels for those steps (``WarmUp``).
"""

from __future__ import annotations

import functools
import importlib
import os
import threading
from collections.abc import Callable
from typing import Any

from .idle import IdlePieces, run_when_idle

#: modules napari imports at its first image layer, leaves first (each import a piece; a
#: missing one is skipped)
FIRST_LAYER_IMPORTS = (
    "dateutil.parser", "dateutil.tz", "pandas._libs.tslibs", "pandas._libs",
    "pandas.core.dtypes.common", "pandas.core.arrays", "pandas.core.frame", "pandas",
    "cftime", "xarray.core.dataarray", "xarray", "scipy.special", "scipy.ndimage._filters",
    "scipy.ndimage._interpolation", "scipy.ndimage._measurements", "scipy.ndimage",
)


def _import(name: str) -> Callable[[], None]:
    def piece() -> None:
        try:
            importlib.import_module(name)
        except ImportError:  # another napari, another set of modules
            pass
    piece.__qualname__ = piece.__name__ = f"import {name}"
    return piece


#: s the kernels' pieces wait at most for the dock's other opening steps (``steps_done``)
STEPS_WAIT_S = 30.0


def warm_up_pieces(first_layer: threading.Event | None = None,
                   steps_done: threading.Event | None = None) -> list[Callable[[], Any]]:
    """The pieces of the warm-up: the child process started, napari's first-layer imports
    (what a first open needs: ``first_layer`` set after them), then, once ``steps_done`` is
    set (the dock's other opening steps, in the Qt thread: no piece shares the GIL with
    them) or after ``STEPS_WAIT_S``, the child's kernels waited for and loaded one per piece
    (appended to the list as the child answers: ``IdlePieces`` runs them in order)."""
    from ... import warmup

    pieces: list[Callable[[], Any]] = []
    found: list[Any] = []
    child = threading.Thread(target=lambda: found.extend(warmup.kernels_out_of_process()),
                             name="meris-ortho-kernels", daemon=True)

    def wait_for_kernels() -> None:
        if steps_done is not None:
            steps_done.wait(STEPS_WAIT_S)  # (no GIL held while waiting)
        child.join()  # no GIL held while the child process works
        from ..._process import numba_start_pieces

        pieces.extend(numba_start_pieces())
        pieces.extend(functools.partial(warmup.load_kernel, s) for s in found)

    pieces.append(child.start)
    pieces.extend(_import(name) for name in FIRST_LAYER_IMPORTS)
    if first_layer is not None:
        pieces.append(first_layer.set)
    pieces.append(wait_for_kernels)
    return pieces


class WarmUp:
    """The dock's warm-up under way: ``first_layer_ready()`` once napari's first-layer
    imports are done (or when there is no warm-up); ``steps_done()`` to say the dock's other
    opening steps are, so that the kernels' pieces follow."""

    def __init__(self, paused: Callable[[], bool], owner: Any) -> None:
        self._first_layer = threading.Event()
        self._steps = threading.Event()
        self.pieces: IdlePieces | None = None
        global _STARTED
        if os.environ.get("MERIS_ORTHO_NO_WARMUP") or _STARTED is not None:
            self._first_layer.set()
            return
        pieces = warm_up_pieces(self._first_layer, self._steps)
        self.pieces = _STARTED = run_when_idle(pieces, paused, owner, name="meris-ortho-warmup")

    def first_layer_ready(self) -> bool:
        """Whether napari's first-layer imports are done (or not to be done here)."""
        return self._first_layer.is_set() or (self.pieces is not None
                                              and self.pieces.done.is_set())

    def steps_done(self) -> None:
        """The dock's other opening steps are done: the kernels' pieces may start."""
        self._steps.set()


def start_warm_up(paused: Callable[[], bool], owner: Any) -> WarmUp:
    """Start the dock's warm-up (``warm_up_pieces`` in idle turns), unless
    ``MERIS_ORTHO_NO_WARMUP`` is set or it already ran in this process (a ``WarmUp`` with no
    pieces then)."""
    return WarmUp(paused, owner)


_STARTED: IdlePieces | None = None

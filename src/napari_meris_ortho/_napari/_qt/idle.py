"""Work done in small pieces while the window is idle, yielding to whatever the user does.

``IdlePieces`` runs a list of pieces (callables of a few milliseconds each: an import, one
numba kernel loaded from the cache) in a thread of its own, one piece only right after the Qt
event loop has turned twice in a row within ``IDLE_TICK_MS`` of each other: while napari opens
a file, inserts layers or draws a long frame, the loop does not turn, no tick comes and no
piece starts, so the user's action never shares the GIL with more than the piece under way.
After a piece that took no time (a module its predecessor imported) the next one starts at
once, if the last idle tick is still fresh.
Inside napari's opening of a file (whose reading may turn the loop) no piece starts either.
A piece may also wait for something outside the process (a child process): waiting holds no
GIL. ``paused()`` (a run under way) holds the pieces back too; they resume after it.
"""

from __future__ import annotations

import threading
import time
import weakref
from collections.abc import Callable, Iterable
from typing import Any

#: ms between two ticks of the Qt event loop that the pieces wait for
IDLE_TICK_MS = 20
#: a tick counts as idle when the previous one came at most this late (s): the loop turned
#: freely between them
IDLE_SLACK_S = 0.015
#: s the thread sleeps after each piece (no GIL held): the Qt thread takes it at once
PIECE_REST_S = 0.005
#: a piece that took less than this (s: a module already imported by the one before) lets the
#: next one start without a new idle tick, while the last one is at most ``IDLE_TICK_MS`` old
QUICK_PIECE_S = 0.002

#: the runs under way, kept alive until their last piece
_RUNNING: set[IdlePieces] = set()


def in_viewer_open() -> bool:
    """Whether this runs inside napari's ``ViewerModel.open`` (its progress bar processes the
    Qt events before the opening returns)."""
    import sys

    frame: Any = sys._getframe(1)
    while frame is not None:
        code = frame.f_code
        if code.co_name == "open" and code.co_filename.endswith("viewer_model.py"):
            return True
        frame = frame.f_back
    return False


class IdlePieces:
    """Pieces run in a thread, one per idle tick of the Qt event loop (module docstring)."""

    def __init__(self, pieces: Iterable[Callable[[], Any]],
                 paused: Callable[[], bool] | None = None, name: str = "idle-pieces") -> None:
        from qtpy.QtCore import QTimer

        #: the list itself, not a copy: a piece may append further pieces to it
        self.pieces = pieces if isinstance(pieces, list) else list(pieces)
        self.paused = paused or (lambda: False)
        #: seconds each piece took, in order (what the warm-up measured of itself)
        self.durations: list[float] = []
        #: when each piece started (``time.perf_counter``)
        self.starts: list[float] = []
        self.done = threading.Event()
        self._idle = threading.Event()
        self._stop = threading.Event()
        self._last_tick = time.perf_counter()
        #: when the last idle tick came (``time.perf_counter``)
        self._idle_at = 0.0
        self._timer = QTimer()
        self._timer.timeout.connect(self._tick)
        self._thread = threading.Thread(target=self._work, name=name, daemon=True)

    def start(self) -> IdlePieces:
        _RUNNING.add(self)
        self._timer.start(IDLE_TICK_MS)
        self._thread.start()
        return self

    def stop(self) -> None:
        """No further piece starts (the one under way ends)."""
        self._stop.set()
        self._idle.set()

    def _tick(self) -> None:
        """Qt thread: an idle tick when the loop turned freely since the last one."""
        now = time.perf_counter()
        free = now - self._last_tick <= IDLE_TICK_MS / 1000.0 + IDLE_SLACK_S
        self._last_tick = now
        if self.done.is_set():
            self._timer.stop()
            _RUNNING.discard(self)
        elif free and not self.paused() and not in_viewer_open():
            self._idle_at = now
            self._idle.set()

    def _work(self) -> None:
        try:
            quick = False
            for piece in self.pieces:
                recent = time.perf_counter() - self._idle_at <= IDLE_TICK_MS / 1000.0
                self._idle.clear()
                while not (quick and recent) and not self._idle.wait(0.5):
                    if self._stop.is_set():
                        return
                if self._stop.is_set():
                    return
                t0 = time.perf_counter()
                self.starts.append(t0)
                try:
                    piece()
                except Exception:  # best effort: a piece that fails only costs time later
                    pass
                self.durations.append(time.perf_counter() - t0)
                quick = self.durations[-1] < QUICK_PIECE_S
                if not quick:
                    time.sleep(PIECE_REST_S)
        finally:
            self.done.set()


def run_when_idle(pieces: Iterable[Callable[[], Any]], paused: Callable[[], bool] | None = None,
                  owner: Any = None, name: str = "idle-pieces") -> IdlePieces:
    """Start ``IdlePieces``; stopped when ``owner`` (a Qt widget) is destroyed."""
    run = IdlePieces(pieces, paused, name).start()
    if owner is not None:
        ref = weakref.ref(run)

        def stop(*_args: Any) -> None:
            alive = ref()
            if alive is not None:
                alive.stop()

        owner.destroyed.connect(stop)
    return run

"""Heavy work that napari makes the plugin do on the Qt thread (a reader's call inside
``viewer.open``), done in a thread while the Qt event loop keeps turning.

napari calls a reader on its Qt thread and adds the layers it returns; a GeoTIFF in another
CRS than the viewer's world is reprojected there (GDAL's warp: 2.2 s for the 3-band fr-alps
reference onto its N1's UTM world, a 3.2 s stall). ``responsively`` runs such work
in a thread (GDAL's warp releases the GIL) and processes the window's events meanwhile: it
repaints, timers and progress bars go on; the user's input waits until the work is done (it is
kept, not lost), so nothing re-enters the reader in the middle. The caller still gets the
result synchronously: ``viewer.open`` returns the finished layers.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")

#: ms the Qt thread waits for the work between two passes over the window's events: 25 passes a
#: second keep it responsive, and its Python (napari's paints) takes the GIL from a work in
#: Python less often: a first fr-alps N1 reads in 0.62-0.71 s at 50 ms, in 0.82-0.93 s at
#: 10 ms
TURN_MS = 40


def _qt_thread_app() -> Any:
    """The running QApplication, when this is its thread; else None."""
    try:
        from qtpy.QtCore import QThread
        from qtpy.QtWidgets import QApplication
    except ImportError:  # no Qt binding: nothing to keep turning
        return None
    app = QApplication.instance()
    if app is None or QThread.currentThread() is not app.thread():
        return None
    return app


class ThreadCall:
    """``func(*args, **kwargs)`` in a plain Python thread of its own (``start``), its value or
    exception handed over once (``outcome``: the call keeps nothing of the result).

    A plain thread, not one of napari's workers: those run on QThreadPool threads whose Python
    thread state is dropped after every job; pyproj's per-thread PROJ context goes with it and
    the next job on a pooled thread crashes inside PROJ (segmentation fault in ``proj_create``,
    also with a bare QRunnable). A Python thread keeps one thread state for the whole
    call, and can be joined (``thread``)."""

    def __init__(self, func: Callable[..., Any], *args: Any, name: str = "meris-ortho",
                 **kwargs: Any) -> None:
        self._outcome: dict[str, Any] = {}
        self.thread = threading.Thread(target=self._target, args=(func, args, kwargs),
                                       name=name, daemon=True)

    def _target(self, func: Callable[..., Any], args: tuple[Any, ...],
                kwargs: dict[str, Any]) -> None:
        try:
            self._outcome["value"] = func(*args, **kwargs)
        except BaseException as exc:  # raised again by ``outcome``, in the caller's thread
            self._outcome["error"] = exc

    def start(self) -> ThreadCall:
        self.thread.start()
        return self

    def outcome(self) -> Any:
        """The call's value, or its exception raised here (after the thread has ended)."""
        if "error" in self._outcome:
            raise self._outcome.pop("error")
        return self._outcome.pop("value")


def responsively(func: Callable[..., T], *args: Any, **kwargs: Any) -> T:
    """``func(*args, **kwargs)``; on the Qt thread, run in a thread of its own (``ThreadCall``)
    while the window's events (all but the user's input) are processed every ``TURN_MS``. Its
    exception, if any, is raised here. ``func`` must not touch Qt, and should make no pyproj
    object that outlives it (a PROJ context belongs to the thread that made it)."""
    app = _qt_thread_app()
    if app is None:
        return func(*args, **kwargs)
    from qtpy.QtCore import QEventLoop

    call = ThreadCall(func, *args, name="meris-ortho-read", **kwargs).start()
    flags = QEventLoop.ProcessEventsFlag.ExcludeUserInputEvents
    while call.thread.is_alive():
        app.processEvents(flags)
        call.thread.join(TURN_MS / 1000)
    return call.outcome()

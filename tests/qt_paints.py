"""What a test sees at each paint of a Qt widget (napari's canvas, a label of the widget)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any


@contextlib.contextmanager
def paints_of(native: Any, value: Callable[[], Any] = lambda: True) -> Iterator[list[Any]]:
    """The list of ``value()`` at each paint of the Qt widget ``native`` while the block runs
    (an event filter, removed at its end)."""
    from qtpy.QtCore import QEvent, QObject

    seen: list[Any] = []

    class Paints(QObject):
        def eventFilter(self, obj: Any, event: Any) -> bool:  # Qt calls it by this name
            if event.type() == QEvent.Type.Paint:
                seen.append(value())
            return False

    counter = Paints()
    native.installEventFilter(counter)
    try:
        yield seen
    finally:
        native.removeEventFilter(counter)

"""A dock widget's end: taken out of the window (its dock's close button) or destroyed."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from qtpy.QtCore import QEvent, QObject


class OnClose(QObject):
    """Calls back when its widget loses its parent (napari's ``remove_dock_widget``: the
    dock's close button) or, unless told not to, is destroyed (the viewer closed)."""

    def __init__(self, widget: Any, callback: Callable[[], None],
                 destroyed: bool = True) -> None:
        super().__init__()
        self._callback = callback
        widget.installEventFilter(self)
        if destroyed:
            widget.destroyed.connect(lambda _=None: callback())

    def eventFilter(self, obj: Any, event: Any) -> bool:
        if event.type() == QEvent.Type.ParentChange and obj.parent() is None:
            self._callback()
        return False

"""Widget settings remembered between sessions: napari plugin settings declared in the
manifest (``contributions.configurations``), saved by napari whenever a value changes.

napari builds the plugin settings once a session, rediscovering every plugin's manifest
(about 0.5 s of parsing): the first dock of a session has them built in a thread and applied
when they are there, so that its opening does not wait for them."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

PLUGIN = "napari-meris-ortho"
#: ms between two looks at the settings being built
POLL_MS = 20

_FETCH: Future[Any] | None = None
#: what waits for the settings: applied in order once they are built (Qt thread)
_PENDING: list[Callable[[Any], None]] = []


def _all_settings() -> Any | None:
    try:
        from napari.settings import get_plugin_settings

        return get_plugin_settings(PLUGIN)
    except (ImportError, KeyError, AttributeError):
        return None


def _fetch() -> Future[Any]:
    """This plugin's settings, built once a session in a thread."""
    global _FETCH
    if _FETCH is None:
        future: Future[Any] = Future()

        def build() -> None:
            try:
                future.set_result(_all_settings())
            except Exception:  # a broken settings file: nothing remembered
                future.set_result(None)

        _FETCH = future
        threading.Thread(target=build, name="meris-ortho-settings", daemon=True).start()
    return _FETCH


def _section(settings: Any, section: str) -> Any | None:
    return None if settings is None else getattr(settings, section, None)


def _flush() -> Any:
    """The settings as napari has them now (built once, kept by napari), after whatever
    waited for the first build (waited for) is applied."""
    if _FETCH is not None:
        first = _FETCH.result()
        while _PENDING:
            _PENDING.pop(0)(first)
    return _all_settings()


def plugin_section(section: str) -> Any | None:
    """The settings section ``section`` of this plugin (None when napari has none)."""
    return _section(_flush(), section)


def _restore(widget: Any, saved: Any) -> None:
    choices = getattr(widget, "choices", None)
    if choices is not None:  # a ComboBox: the choice equal to the saved value (str enums)
        saved = next((c for c in choices if c == saved), None)
        if saved is None:
            return
    with contextlib.suppress(ValueError, TypeError):
        widget.value = saved


def remember(section: str, widgets: dict[str, Any],
             restored: Callable[[], None] | None = None) -> None:
    """Give ``widgets`` (setting key -> magicgui value widget) their saved values, and save
    every later change; then call ``restored``. The first time in a session, when napari
    builds the settings in a thread meanwhile: a widget the user changes before they are
    there keeps its value (saved, not overwritten)."""
    if _FETCH is not None:  # built, or being built for another dock: wait
        _apply(_section(_flush(), section), widgets, set())
        if restored is not None:
            restored()
        return
    from qtpy.QtCore import QTimer

    future = _fetch()
    touched: set[str] = set()
    marks = {key: (lambda _v=None, key=key: touched.add(key)) for key in widgets}
    for key, widget in widgets.items():
        widget.changed.connect(marks[key])

    def apply(settings: Any) -> None:
        for key, widget in widgets.items():
            with contextlib.suppress(RuntimeError, TypeError, ValueError):
                widget.changed.disconnect(marks[key])
        _apply(_section(settings, section), widgets, touched)
        if restored is not None:
            restored()

    _PENDING.append(apply)

    def look() -> None:
        if future.done():
            first = future.result()
            while _PENDING:
                _PENDING.pop(0)(first)
        else:
            QTimer.singleShot(POLL_MS, look)

    QTimer.singleShot(POLL_MS, look)


def _apply(settings: Any | None, widgets: dict[str, Any], touched: set[str]) -> None:
    """The saved values into ``widgets`` but those the user ``touched`` (theirs saved), each
    later change saved."""
    if settings is None:
        return
    for key, widget in widgets.items():
        with contextlib.suppress(RuntimeError):  # a widget closed meanwhile
            if key in touched:
                _save(settings, key, widget.value)
            else:
                saved = getattr(settings, key, None)
                if saved is not None:
                    _restore(widget, saved)
            widget.changed.connect(lambda value, key=key: _save(settings, key, value))


def _save(settings: Any, key: str, value: Any) -> None:
    with contextlib.suppress(ValueError, TypeError):  # pydantic validation errors included
        setattr(settings, key, value.value if hasattr(value, "value") else value)

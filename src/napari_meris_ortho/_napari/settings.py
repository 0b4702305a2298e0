"""Widget settings remembered between sessions: napari plugin settings declared in the
manifest (``contributions.configurations``), saved by napari whenever a value changes."""

from __future__ import annotations

import contextlib
from typing import Any

PLUGIN = "napari-meris-ortho"


def plugin_section(section: str) -> Any | None:
    """The settings section ``section`` of this plugin (None when napari has none)."""
    try:
        from napari.settings import get_plugin_settings

        return getattr(get_plugin_settings(PLUGIN), section)
    except (ImportError, KeyError, AttributeError):
        return None


def _restore(widget: Any, saved: Any) -> None:
    choices = getattr(widget, "choices", None)
    if choices is not None:  # a ComboBox: the choice equal to the saved value (str enums)
        saved = next((c for c in choices if c == saved), None)
        if saved is None:
            return
    with contextlib.suppress(ValueError, TypeError):
        widget.value = saved


def remember(section: str, widgets: dict[str, Any]) -> None:
    """Give ``widgets`` (setting key -> magicgui value widget) their saved values, and save
    every later change."""
    settings = plugin_section(section)
    if settings is None:
        return
    for key, widget in widgets.items():
        saved = getattr(settings, key, None)
        if saved is not None:
            _restore(widget, saved)
        widget.changed.connect(lambda value, key=key: _save(settings, key, value))


def _save(settings: Any, key: str, value: Any) -> None:
    with contextlib.suppress(ValueError, TypeError):  # pydantic validation errors included
        setattr(settings, key, value.value if hasattr(value, "value") else value)

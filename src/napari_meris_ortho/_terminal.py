"""Terminal hygiene shared by the CLI: escaped text and progress bars only on a terminal."""

from __future__ import annotations

import sys


def printable(text: str) -> str:
    """``text`` with control and other non-printable characters escaped (``\\x1b``, ``\\r``), so
    that header text or file names cannot move the cursor or recolour the terminal."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode() for c in text)


def stderr_is_terminal() -> bool:
    """True when stderr is a terminal (progress bars are drawn only there)."""
    try:
        return sys.stderr is not None and sys.stderr.isatty()
    except (AttributeError, ValueError):  # closed or replaced stream
        return False

"""Resident pages of a product's file maps (an N1 file, the bands a ``.SEN3`` keeps for a run)."""

from __future__ import annotations

import contextlib
import mmap
from typing import Any


def drop_resident_pages(raw: Any) -> None:
    """Drop the pages of the file map ``raw`` that this process has read from its resident
    memory (``madvise(MADV_DONTNEED)``; the kernel's page cache keeps them, so a later read maps
    them again without a disk read or a decode): a product's ``release_pages``. Nothing when
    ``raw`` is not an ``mmap``, is closed, or the platform lacks ``MADV_DONTNEED``."""
    if isinstance(raw, mmap.mmap) and hasattr(mmap, "MADV_DONTNEED"):
        with contextlib.suppress(OSError, ValueError):  # closed meanwhile
            raw.madvise(mmap.MADV_DONTNEED)

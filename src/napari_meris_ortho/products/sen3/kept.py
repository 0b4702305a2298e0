"""Decoded ``.SEN3`` bands kept for the tasks of a run, in file maps as an N1's bands are.

A band of a ``.SEN3`` is a netCDF-4 variable, zlib-compressed: reading any of its lines decodes
the whole chunk, and ESA's chunking is not ours to choose. An N1 band is a memory map, read line by
line for free. Every tile task of a synthesis reads every band of each product it covers, so a
``.SEN3`` was decoded once per tile (an fr-alps product, 12 tiles: 180 band decodes, 7.3 s of a
14 s synthesis).

While :func:`keep_decoded_bands` is in force, a product keeps each band it decodes
(``MerisSen3Product.counts``) in a map of a temporary file (unlinked at once: nothing is left
behind, whatever ends the process), so that later calls read it as an N1's map is read, and
``release_pages`` drops the pages a task read from the process's resident memory, as an N1's
(the kernel's page cache keeps them). At most :data:`BUDGET_BYTES` for every product of the
process together, and at most a quarter of the space the temporary directory had free for them;
bands beyond that are decoded at each call, as before. :func:`release_decoded_bands` (the end of
a run: ``synthesis.run.engine``, on every worker) frees them.
"""

from __future__ import annotations

import mmap
import shutil
import tempfile
import threading
import weakref
from typing import Any

import numpy as np

from ..pages import drop_resident_pages

#: decoded bytes a process keeps at most, every product together: 26 FR products of 15 bands
#: (2241 x 2241 x 2 bytes a band)
BUDGET_BYTES = 4 * 2**30

_lock = threading.Lock()
_state = {"on": False, "bytes": 0}
_holders: weakref.WeakSet[KeptBands] = weakref.WeakSet()


class KeptBands:
    """The bands one product keeps (band -> read-only counts in a file map), freed with the
    product or by :func:`release_decoded_bands`."""

    def __init__(self, owner: Any) -> None:
        self.bands: dict[int, np.ndarray] = {}
        self.maps: list[mmap.mmap] = []
        weakref.finalize(owner, _forget, self)

    def get(self, band: int) -> np.ndarray | None:
        return self.bands.get(band)

    def keep(self, band: int, counts: np.ndarray) -> np.ndarray:
        """``counts`` of ``band``, read-only: kept in a file map when keeping is on and the
        budget allows (the map is returned then), else as they are."""
        counts.flags.writeable = False
        with _lock:
            fits = (_state["on"] and band not in self.bands
                    and _state["bytes"] + counts.nbytes <= BUDGET_BYTES)
            if fits:
                _state["bytes"] += counts.nbytes  # claimed before the copy, outside the lock
                total = _state["bytes"]
        if not fits:
            return counts
        mapped = _file_map(counts, total)
        with _lock:
            if mapped is None or not _state["on"]:  # no room on disk; or released meanwhile
                _state["bytes"] -= counts.nbytes
                return counts
            raw, array = mapped
            self.bands[band] = array
            self.maps.append(raw)
            _holders.add(self)
        return array

    def release_pages(self) -> None:
        """Drop the pages of the kept maps from this process's resident memory
        (``madvise(MADV_DONTNEED)``; the page cache keeps them, so a later read is no decode)."""
        for raw in list(self.maps):
            drop_resident_pages(raw)


def _file_map(counts: np.ndarray, total: int) -> tuple[mmap.mmap, np.ndarray] | None:
    """A copy of ``counts`` in a map of an unlinked temporary file, and the read-only array on
    it; None when the temporary directory refuses, or when ``total`` (the bytes kept with this
    band) would pass a quarter of its free space plus what is kept already (the space it had
    for them)."""
    directory = tempfile.gettempdir()
    try:
        if 4 * total > shutil.disk_usage(directory).free + total - counts.nbytes:
            return None
        with tempfile.TemporaryFile(dir=directory) as fh:  # unlinked: freed with the map
            fh.truncate(counts.nbytes)
            raw = mmap.mmap(fh.fileno(), counts.nbytes)
    except (OSError, ValueError):
        return None
    array = np.frombuffer(raw, dtype=counts.dtype).reshape(counts.shape)
    array[...] = counts
    view = array.view()
    view.flags.writeable = False
    return raw, view


def _forget(kept: KeptBands) -> None:
    with _lock:
        _state["bytes"] -= sum(array.nbytes for array in kept.bands.values())
        kept.bands.clear()
        kept.maps.clear()  # each map closes with its last array


def keep_decoded_bands() -> None:
    """From now on (until :func:`release_decoded_bands`), products keep the bands they decode."""
    with _lock:
        _state["on"] = True


def release_decoded_bands() -> int:
    """Stop keeping decoded bands and free those kept; returns the bytes freed."""
    with _lock:
        _state["on"] = False
        freed = int(_state["bytes"])
        holders = list(_holders)
        _holders.clear()
    for kept in holders:
        _forget(kept)
    return freed


def kept_bytes() -> int:
    """Decoded bytes kept now, every product of the process together."""
    with _lock:
        return int(_state["bytes"])

"""Decoded ``.SEN3`` bands kept for the tasks of a run, in file maps as an N1's bands are.

A band of a ``.SEN3`` is a netCDF-4 variable, zlib-compressed: reading any of its lines decodes
the whole chunk, and ESA's chunking is not ours to choose. An N1 band is a memory map, read line by
line for free. Every tile task of a synthesis reads every band of each product it covers, so a
``.SEN3`` would be decoded once per tile (an fr-alps product, 12 tiles: 180 band decodes, 7.3 s
of a 14 s synthesis).

While :func:`keep_decoded_bands` is in force, a product keeps each band it decodes
(``MerisSen3Product.counts``) in a file map, so that later calls read it as an N1's map is read,
and ``release_pages`` drops the pages a task read from the process's resident memory, as an N1's
(the kernel's page cache keeps them). At most :data:`BUDGET_BYTES` for every product of the
process together, and at most a quarter of the space the temporary directory had free for them;
bands beyond that are decoded at each call. :func:`release_decoded_bands` (the end of
a run: ``synthesis.run.engine``, on every worker) frees them.

Given the run's name, the processes of the run on one host (the workers of a LocalCluster, or of
``dask worker --nworkers N``) share the bands: each band is decoded by one of them into a file of
the run's directory (``meris-ortho-bands-*`` in the temporary directory; written aside, then
renamed) and mapped by the others, and ``prepare_bands`` decodes first the bands no other
process is decoding (a lock per band), so that N processes decode a product's bands N times
faster instead of each decoding all of them. The last process to leave the run removes the
directory; one left by a killed run is removed by the next run on the host. Without a name (or
without ``fcntl``), a process keeps its bands in unlinked temporary files, nothing to remove.
"""

from __future__ import annotations

import contextlib
import hashlib
import mmap
import os
import shutil
import stat
import tempfile
import threading
import time
import weakref
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from ...cores import usable_threads
from ..pages import drop_resident_pages

try:
    import fcntl
except ImportError:  # not POSIX: every process keeps its own bands
    fcntl = None  # type: ignore[assignment]

#: decoded bytes a process keeps at most, every product together: 26 FR products of 15 bands
#: (2241 x 2241 x 2 bytes a band)
BUDGET_BYTES = 4 * 2**30
#: a run's directory of shared bands, in the temporary directory: this prefix and a hash of its name
RUN_PREFIX = "meris-ortho-bands-"
#: the file of a run's directory every process of the run holds a shared lock on
USERS = ".users"
#: a run's directory nobody holds, untouched this long (s), is left over by a killed run
STALE_S = 60.0

_lock = threading.Lock()
#: "run": the run's name; "directory": its directory, made at the first band to share
_state: dict[str, Any] = {"on": False, "bytes": 0, "run": "", "directory": None}
_holders: weakref.WeakSet[KeptBands] = weakref.WeakSet()

Decode = Callable[[], np.ndarray]


class KeptBands:
    """The bands one product keeps (band -> read-only counts in a file map), freed with the
    product or by :func:`release_decoded_bands`; ``key``: the product's name in a run's
    directory (its path), ``shape``: a band's (lines, columns) (both needed to share bands)."""

    def __init__(self, owner: Any, key: str = "", shape: tuple[int, int] | None = None) -> None:
        self.bands: dict[int, np.ndarray] = {}
        self.maps: dict[int, mmap.mmap] = {}
        self.key = hashlib.sha1(key.encode()).hexdigest()[:16] if key and shape else ""
        self.shape: tuple[int, int] = shape or (0, 0)
        weakref.finalize(owner, _forget, self)

    def get(self, band: int) -> np.ndarray | None:
        return self.bands.get(band)

    def keep(self, band: int, counts: np.ndarray) -> np.ndarray:
        """``counts`` of ``band``, read-only: kept in a file map when keeping is on and the
        budget allows (the map is returned then; in the run's directory when it has one, where
        the other processes of the run find it), else as they are."""
        counts.flags.writeable = False
        total = self._claim(counts.nbytes, band)
        if total is None:
            return counts
        run = _run_directory()
        mapped = None
        if run is not None and self.key:
            mapped = run.publish(self._name(band), counts, total)
        if mapped is None:
            mapped = _file_map(counts, total)
        held = self._hold(band, mapped, counts.nbytes)
        return counts if held is None else held

    def fetch(self, band: int, decode: Decode) -> np.ndarray:
        """``band``'s counts: kept already; or in the run's directory (mapped); or decoded by
        ``decode`` and kept (:meth:`keep`), the other processes of the run waiting for it."""
        counts = self._fetch(band, decode, wait=True)
        assert counts is not None  # None only without waiting
        return counts

    def _fetch(self, band: int, decode: Decode, wait: bool) -> np.ndarray | None:
        """:meth:`fetch`; None when ``wait`` is False and another process is decoding it."""
        held = self.get(band)
        if held is not None:
            return held
        run = _run_directory() if self.key else None
        if run is None:
            return self.keep(band, decode())
        name = self._name(band)
        with run.band_lock(name, wait) as locked:
            if not locked:
                return None
            held = self.get(band)  # another thread of this process, meanwhile
            if held is not None:
                return held
            found = run.open(name, self.shape)
            if found is None:
                return self.keep(band, decode())
        held = None
        if self._claim(found[1].nbytes, band) is not None:
            held = self._hold(band, found, found[1].nbytes)
        if held is None:  # off, over the budget, or kept by another thread: not this map
            held = self.get(band)
        return found[1].copy() if held is None else held

    def prepare(self, bands: Sequence[int], decode: Callable[[int], np.ndarray]) -> None:
        """Decode ``bands`` now, ``usable_threads()`` at a time (``chunks``: a band inflates
        outside the GIL), and keep them (``MerisSen3Product.prepare_bands``). In a run's
        directory, those no other process of the run is decoding first, then wait for the
        others. Nothing while keeping is off, and no more than the budget holds."""
        nbytes = 2 * self.shape[0] * self.shape[1]
        todo = [b for b in dict.fromkeys(int(b) for b in bands) if self.get(b) is None]
        if not (todo and nbytes and _state["on"]):
            return
        todo = todo[:max((BUDGET_BYTES - _state["bytes"]) // nbytes, 0)]
        threads = usable_threads()
        if not self.key or _run_directory() is None:
            _each(todo, lambda b: self.fetch(b, partial(decode, b)), threads)
            return
        while todo and _state["on"]:
            got = _each(todo, lambda b: self._fetch(b, partial(decode, b), wait=False), threads)
            later = [b for b, counts in zip(todo, got, strict=True) if counts is None]
            if later:  # each is being decoded elsewhere: wait for one
                self.fetch(later[0], partial(decode, later[0]))
                later = later[1:]
            todo = later

    def release_pages(self) -> None:
        """Drop the pages of the kept maps from this process's resident memory
        (``madvise(MADV_DONTNEED)``; the page cache keeps them, so a later read is no decode)."""
        for raw in list(self.maps.values()):
            drop_resident_pages(raw)

    def release_band_pages(self, band: int) -> None:
        """:meth:`release_pages` of one band (a band read ahead waits for its task so)."""
        raw = self.maps.get(band)
        if raw is not None:
            drop_resident_pages(raw)

    def _name(self, band: int) -> str:
        return f"{self.key}-{band:02d}.u16"

    def _claim(self, nbytes: int, band: int) -> int | None:
        """The process's kept bytes with ``nbytes`` more, claimed; None when keeping is off,
        ``band`` is kept or the budget does not allow."""
        with _lock:
            if not (_state["on"] and band not in self.bands
                    and _state["bytes"] + nbytes <= BUDGET_BYTES):
                return None
            _state["bytes"] += nbytes  # claimed before the copy, outside the lock
            return int(_state["bytes"])

    def _hold(self, band: int, mapped: tuple[mmap.mmap, np.ndarray] | None,
              nbytes: int) -> np.ndarray | None:
        """Keep the map of ``band`` (``nbytes`` claimed) and return its array; None, the claim
        given back, when there is none (no room on disk) or the run was released meanwhile."""
        with _lock:
            if mapped is None or not _state["on"]:
                _state["bytes"] -= nbytes
                return None
            raw, array = mapped
            self.bands[band] = array
            self.maps[band] = raw
            _holders.add(self)
        return array


class _RunDirectory:
    """The directory the processes of one run on this host share decoded bands in: each holds a
    shared lock on its :data:`USERS` file while in the run."""

    def __init__(self, name: str) -> None:
        digest = hashlib.sha1(name.encode()).hexdigest()[:16]
        self.path = Path(tempfile.gettempdir()) / f"{RUN_PREFIX}{digest}"
        self.path.mkdir(mode=0o700, exist_ok=True)
        found = os.lstat(self.path)
        if not stat.S_ISDIR(found.st_mode) or found.st_uid != os.getuid():
            raise OSError(f"{self.path} is not a directory of this user's")
        self._users = os.open(self.path / USERS, os.O_RDWR | os.O_CREAT, 0o600)
        fcntl.flock(self._users, fcntl.LOCK_SH)
        os.utime(self._users)  # in use: not a left-over for a sweep

    def publish(self, name: str, counts: np.ndarray, total: int
                ) -> tuple[mmap.mmap, np.ndarray] | None:
        """Write ``counts`` as file ``name`` (aside, then renamed) and map it; None when the
        disk refuses or lacks room (``total``: the bytes kept with these, as ``_file_map``)."""
        final = self.path / name
        aside = self.path / f".{name}.{os.getpid()}.{threading.get_ident()}"
        try:
            if not _fits(self.path, total, counts.nbytes):
                return None
            with open(aside, "wb") as fh:
                np.ascontiguousarray(counts).tofile(fh)
            os.replace(aside, final)
        except OSError:
            with contextlib.suppress(OSError):
                aside.unlink()
            return None
        return self.open(name, counts.shape)

    def open(self, name: str, shape: tuple[int, ...]) -> tuple[mmap.mmap, np.ndarray] | None:
        """The map of file ``name`` and the read-only uint16 array of ``shape`` on it; None when
        there is none (or not of that size)."""
        try:
            with open(self.path / name, "rb") as fh:
                size = 2 * int(np.prod(shape))
                if size == 0 or os.fstat(fh.fileno()).st_size != size:
                    return None
                raw = mmap.mmap(fh.fileno(), size, access=mmap.ACCESS_READ)
        except (OSError, ValueError):
            return None
        return raw, np.frombuffer(raw, dtype=np.uint16).reshape(shape)

    @contextlib.contextmanager
    def band_lock(self, name: str, wait: bool) -> Any:
        """Hold the lock of file ``name`` (yields True), or, when ``wait`` is False and another
        process holds it, yield False; True without a lock when the lock cannot be made."""
        try:
            fd = os.open(self.path / f".{name}.lock", os.O_RDWR | os.O_CREAT, 0o600)
        except OSError:
            yield True
            return
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
            except BlockingIOError:
                yield False
                return
            yield True
        finally:
            os.close(fd)  # and its lock

    def close(self) -> None:
        """Leave the run; the last process to leave removes the directory."""
        fcntl.flock(self._users, fcntl.LOCK_UN)
        try:
            fcntl.flock(self._users, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:  # others are still in it
            os.close(self._users)
            return
        shutil.rmtree(self.path, ignore_errors=True)
        os.close(self._users)


def sweep_left_over_runs(keep: Path | None = None) -> int:
    """Remove the run directories no process holds that were untouched for :data:`STALE_S`
    (left by killed runs), but ``keep``; returns how many."""
    if fcntl is None:
        return 0
    removed = 0
    for path in Path(tempfile.gettempdir()).glob(f"{RUN_PREFIX}*"):
        if path == keep:
            continue
        try:
            fd = os.open(path / USERS, os.O_RDWR)
        except OSError:
            continue
        try:
            if time.time() - os.fstat(fd).st_mtime < STALE_S:
                continue
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:  # in use
                continue
            shutil.rmtree(path, ignore_errors=True)
            removed += 1
        finally:
            os.close(fd)
    return removed


def _each(bands: list[int], call: Callable[[int], np.ndarray | None], threads: int
          ) -> list[np.ndarray | None]:
    """``call`` of every band, ``threads`` at a time (in order when 1)."""
    if threads <= 1 or len(bands) <= 1:
        return [call(b) for b in bands]
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(min(threads, len(bands)), thread_name_prefix="sen3-decode") as pool:
        return list(pool.map(call, bands))


def _file_map(counts: np.ndarray, total: int) -> tuple[mmap.mmap, np.ndarray] | None:
    """A copy of ``counts`` in a map of an unlinked temporary file, and the read-only array on
    it; None when the temporary directory refuses, or when ``total`` (the bytes kept with this
    band) would pass a quarter of its free space plus what is kept already (the space it had
    for them)."""
    directory = tempfile.gettempdir()
    try:
        if not _fits(directory, total, counts.nbytes):
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


def _fits(directory: str | os.PathLike[str], total: int, nbytes: int) -> bool:
    """Whether ``total`` (the bytes kept with a band of ``nbytes``) stays within a quarter of
    the free space of ``directory`` plus what is kept already (the space it had for them);
    OSError when the directory cannot be asked."""
    return 4 * total <= shutil.disk_usage(directory).free + total - nbytes


def _forget(kept: KeptBands) -> None:
    with _lock:
        _state["bytes"] -= sum(array.nbytes for array in kept.bands.values())
        kept.bands.clear()
        kept.maps.clear()  # each map closes with its last array


def keep_decoded_bands(run: str = "") -> None:
    """From now on (until :func:`release_decoded_bands`), products keep the bands they decode;
    ``run``: the run's name, the same in all its processes (they share the bands on a host)."""
    with _lock:
        _state["on"] = True
        if run == _state["run"]:
            return
        _state["run"] = run
        left, _state["directory"] = _state["directory"], None
    if left is not None:  # a run left without its release
        left.close()


def _run_directory() -> _RunDirectory | None:
    """The directory of the run this process is in (made or joined now), None without a
    name, without ``fcntl``, or when it cannot be made."""
    with _lock:
        if _state["directory"] is not None or not _state["run"] or not _state["on"] \
                or fcntl is None:
            return _state["directory"]
        run = _state["run"]
    try:
        joined = _RunDirectory(run)
    except OSError:  # no shared directory: the bands of this process only
        with _lock:
            _state["run"] = ""
        return None
    with _lock:
        first = _state["directory"] is None and _state["run"] == run
        if first:
            _state["directory"] = joined
        current = _state["directory"]
    if not first:  # another thread joined first, or the run ended meanwhile
        joined.close()
    else:
        sweep_left_over_runs(keep=joined.path)
    return current


def release_decoded_bands() -> int:
    """Stop keeping decoded bands and free those kept (leave the run's directory); returns the
    bytes freed."""
    with _lock:
        _state["on"] = False
        freed = int(_state["bytes"])
        holders = list(_holders)
        _holders.clear()
        run, _state["directory"], _state["run"] = _state["directory"], None, ""
    for kept in holders:
        _forget(kept)
    if run is not None:
        run.close()
    return freed


def kept_bytes() -> int:
    """Decoded bytes kept now, every product of the process together."""
    with _lock:
        return int(_state["bytes"])

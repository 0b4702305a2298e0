"""Decoded .SEN3 bands kept for a run (``products.sen3.kept``): in a map of an unlinked
temporary file, read-only, the same values; their pages leave the resident memory on
``release_pages``; nothing is kept outside a run, beyond the budget, or after the release."""

from __future__ import annotations

import os
import resource

import numpy as np
import pytest

from napari_meris_ortho.products.sen3 import kept


class _Product:
    """An owner of kept bands, as ``MerisSen3Product`` is."""

    def __init__(self, key: str = "", shape: tuple[int, int] | None = None) -> None:
        self.kept = kept.KeptBands(self, key, shape)


def _resident_bytes() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * resource.getpagesize()


@pytest.fixture
def keeping():
    kept.keep_decoded_bands()
    yield
    kept.release_decoded_bands()
    assert kept.kept_bytes() == 0


def test_a_kept_band_is_a_file_map_whose_pages_can_leave(keeping) -> None:
    product = _Product()
    band = np.arange(64 * 2**20 // 2, dtype=np.uint16).reshape(4096, -1)  # 64 MiB
    before_files = set(os.listdir(kept.tempfile.gettempdir()))
    held = product.kept.keep(7, band)
    assert held is not band and np.array_equal(held, band) and not held.flags.writeable
    assert product.kept.get(7) is held and kept.kept_bytes() == band.nbytes
    assert set(os.listdir(kept.tempfile.gettempdir())) == before_files  # unlinked at once
    del band
    assert int(held[::16, ::16].sum(dtype=np.int64)) > 0  # its pages read back in
    resident = _resident_bytes()
    product.kept.release_pages()
    assert resident - _resident_bytes() > 48 * 2**20  # dropped from this process
    assert int(held[-1, -1]) == (64 * 2**20 // 2 - 1) % 65536  # still there (page cache)
    assert kept.release_decoded_bands() == 64 * 2**20
    assert kept.kept_bytes() == 0 and product.kept.get(7) is None


def test_nothing_is_kept_outside_a_run_or_beyond_the_budget(monkeypatch) -> None:
    product = _Product()
    band = np.ones((300, 200), np.uint16)
    assert product.kept.keep(1, band) is band and kept.kept_bytes() == 0  # off
    kept.keep_decoded_bands()
    try:
        monkeypatch.setattr(kept, "BUDGET_BYTES", band.nbytes)
        assert product.kept.keep(1, band) is not band
        other = np.ones((300, 200), np.uint16)
        assert product.kept.keep(2, other) is other  # over the budget: as it is
        assert kept.kept_bytes() == band.nbytes
        del product  # a product gone frees its bands
        assert kept.kept_bytes() == 0
    finally:
        kept.release_decoded_bands()


def test_a_band_is_kept_only_within_a_quarter_of_the_free_space(monkeypatch, keeping) -> None:
    import types

    product = _Product()
    band = np.ones((300, 200), np.uint16)
    free = {"bytes": 3 * band.nbytes}  # the band would be a third of it
    monkeypatch.setattr(kept.shutil, "disk_usage",
                        lambda directory: types.SimpleNamespace(free=free["bytes"]))
    assert product.kept.keep(1, band) is band and kept.kept_bytes() == 0
    free["bytes"] = 4 * band.nbytes
    assert product.kept.keep(1, band) is not band
    assert kept.kept_bytes() == band.nbytes
    second = band.copy()  # 2 bands kept would pass (4 free + 1 kept) / 4
    assert product.kept.keep(2, second) is second
    assert kept.kept_bytes() == band.nbytes


# ---- the processes of a run share a host's decoded bands (a lock per band, a run directory)

SHAPE = (300, 200)


class _Decoder:
    """Decodes band b as b everywhere, recording which bands it decoded, in order."""

    def __init__(self) -> None:
        self.done: list[int] = []

    def __call__(self, band: int) -> np.ndarray:
        self.done.append(band)
        return np.full(SHAPE, band, np.uint16)


@pytest.fixture
def run_dir(tmp_path, monkeypatch):
    """A run named "run-a" in a temporary directory of the test's own."""
    monkeypatch.setattr(kept.tempfile, "tempdir", str(tmp_path))
    kept.keep_decoded_bands("run-a")
    yield tmp_path
    kept.release_decoded_bands()
    assert kept.kept_bytes() == 0


def _run_directories(tmp_path) -> list[str]:
    return sorted(p.name for p in tmp_path.glob(f"{kept.RUN_PREFIX}*"))


def test_a_band_decoded_by_one_process_of_a_run_is_mapped_by_the_others(run_dir) -> None:
    """Two products of one path (as in two workers of a host): the second maps the band the
    first decoded; the run's directory goes with the last process to leave it."""
    first, second = _Decoder(), _Decoder()
    pa, pb = _Product("/data/P.SEN3", SHAPE), _Product("/data/P.SEN3", SHAPE)
    a, b = pa.kept, pb.kept
    held = a.fetch(7, lambda: first(7))
    assert first.done == [7] and np.all(held == 7) and not held.flags.writeable
    (directory,) = _run_directories(run_dir)
    mapped = b.fetch(7, lambda: second(7))
    assert second.done == [] and mapped.shape == SHAPE and np.all(mapped == 7)
    assert not mapped.flags.writeable and b.get(7) is mapped
    other = _Product("/data/Q.SEN3", SHAPE)  # another product
    other.kept.fetch(7, lambda: second(7))
    assert second.done == [7]
    assert kept.release_decoded_bands() == 3 * held.nbytes
    assert _run_directories(run_dir) == [] and int(mapped[0, 0]) == 7  # maps outlive the files


def test_a_process_decodes_first_the_bands_no_other_one_is_decoding(run_dir) -> None:
    """``prepare``: the band another process holds the lock of is taken last, and mapped once
    that process has written it, not decoded twice."""
    import threading
    import time

    order: list[tuple[str, int]] = []
    pa, pb = _Product("/data/P.SEN3", SHAPE), _Product("/data/P.SEN3", SHAPE)
    a, b = pa.kept, pb.kept
    directory = kept._run_directory()
    locked = threading.Event()

    def mine(band: int) -> np.ndarray:
        order.append(("mine", band))
        return np.full(SHAPE, band, np.uint16)

    def other_process() -> None:  # decodes band 1, done once this process took the others
        with directory.band_lock(b._name(1), wait=True):
            locked.set()
            for _ in range(100):
                if len(order) == 2:
                    break
                time.sleep(0.05)
            order.append(("theirs", 1))
            b.keep(1, np.full(SHAPE, 1, np.uint16))

    thread = threading.Thread(target=other_process)
    thread.start()
    locked.wait(10)
    a.prepare([1, 2, 3], mine)
    thread.join()
    # 2 and 3 in either order: several at a time on several cores (``usable_threads``)
    assert sorted(order[:2]) == [("mine", 2), ("mine", 3)] and order[2:] == [("theirs", 1)]
    assert [int(a.get(k)[0, 0]) for k in (1, 2, 3)] == [1, 2, 3]


def test_a_run_directory_left_by_a_killed_run_is_removed_by_the_next(tmp_path,
                                                                      monkeypatch) -> None:
    import fcntl

    monkeypatch.setattr(kept.tempfile, "tempdir", str(tmp_path))
    old = kept.time.time() - 2 * kept.STALE_S
    for name in ("killed", "in-use", "young"):
        (tmp_path / f"{kept.RUN_PREFIX}{name}").mkdir()
        users = tmp_path / f"{kept.RUN_PREFIX}{name}" / kept.USERS
        users.write_bytes(b"")
        if name != "young":
            os.utime(users, (old, old))
    holder = os.open(tmp_path / f"{kept.RUN_PREFIX}in-use" / kept.USERS, os.O_RDWR)
    fcntl.flock(holder, fcntl.LOCK_SH)  # a live process of that run
    try:
        kept.keep_decoded_bands("run-b")
        product = _Product("/data/P.SEN3", SHAPE)
        product.kept.fetch(
            1, lambda: np.ones(SHAPE, np.uint16))
        names = _run_directories(tmp_path)
        assert len(names) == 3 and f"{kept.RUN_PREFIX}killed" not in names
        assert {f"{kept.RUN_PREFIX}in-use", f"{kept.RUN_PREFIX}young"} < set(names)
    finally:
        kept.release_decoded_bands()
        os.close(holder)
    assert len(_run_directories(tmp_path)) == 2  # its own directory went with it


def test_nothing_is_shared_without_a_run_name(tmp_path, monkeypatch, keeping) -> None:
    """Without a run's name (a run in one process), ``prepare`` decodes the bands into this
    process's own maps (unlinked files: nothing in the temporary directory), each once."""
    monkeypatch.setattr(kept.tempfile, "tempdir", str(tmp_path))
    product = _Product("/data/P.SEN3", SHAPE)
    decoder = _Decoder()
    product.kept.prepare([1, 2, 1], decoder)
    assert sorted(decoder.done) == [1, 2]
    assert [int(product.kept.get(b)[0, 0]) for b in (1, 2)] == [1, 2]
    assert np.all(product.kept.fetch(1, lambda: np.zeros(SHAPE, np.uint16)) == 1)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not hasattr(os, "getuid") or os.getuid() != 0,
                    reason="making a directory of another user's takes root")
def test_a_run_directory_of_another_users_is_not_used(tmp_path, monkeypatch) -> None:
    """A directory of the run's name that another user made in the shared temporary directory
    is left alone: the bands are this process's own."""
    import hashlib

    monkeypatch.setattr(kept.tempfile, "tempdir", str(tmp_path))
    digest = hashlib.sha1(b"run-c").hexdigest()[:16]
    theirs = tmp_path / f"{kept.RUN_PREFIX}{digest}"
    theirs.mkdir(mode=0o777)
    os.chown(theirs, 65534, 65534)
    kept.keep_decoded_bands("run-c")
    try:
        product = _Product("/data/P.SEN3", SHAPE)
        held = product.kept.fetch(1, lambda: np.ones(SHAPE, np.uint16))
        assert np.all(held == 1) and product.kept.get(1) is held
        assert list(theirs.iterdir()) == []
    finally:
        kept.release_decoded_bands()
    assert theirs.is_dir()

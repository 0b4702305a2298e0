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

    def __init__(self) -> None:
        self.kept = kept.KeptBands(self)


def _resident_bytes() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * resource.getpagesize()


@pytest.fixture
def keeping():
    kept.keep_decoded_bands()
    yield
    kept.release_decoded_bands()


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

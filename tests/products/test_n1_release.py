"""An N1's file pages leave the process's resident memory on ``release_pages`` (synthesis
workers call it after each task, so a worker holds the lines of the task at hand only)."""

from __future__ import annotations

import os
import sys

import pytest

from napari_meris_ortho.products.n1 import read_product

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="reads /proc/self/smaps")


def _mapped_rss_kb(path: str) -> int:
    """Resident kB of every mapping of ``path`` in this process (/proc/self/smaps)."""
    real = os.path.realpath(path)
    total, inside = 0, False
    with open("/proc/self/smaps") as f:
        for line in f:
            head = line.split()
            if len(head) >= 5 and "-" in head[0] and ":" in head[3]:  # a mapping's header
                inside = len(head) >= 6 and head[-1] == real
            elif inside and line.startswith("Rss:"):
                total += int(head[1])
    return total


def test_release_pages_drops_the_read_lines_from_the_resident_set(fr_small) -> None:
    prod = read_product(fr_small.product_path)
    for band in (1, 7, 13):
        prod.radiance(band).sum()  # touches every line of three bands
    before = _mapped_rss_kb(fr_small.product_path)
    assert before > 1000  # three bands of fr-small are resident: several MB
    prod.release_pages()
    after = _mapped_rss_kb(fr_small.product_path)
    assert after < 0.05 * before
    assert prod.radiance(7).shape == (fr_small.geometry.lines, fr_small.geometry.columns)
    prod.release_pages()  # twice is harmless


def test_release_pages_before_any_read_does_nothing(fr_small) -> None:
    prod = read_product(fr_small.product_path)
    prod.release_pages()
    assert "_file_map" not in prod.__dict__  # nothing mapped by it

"""Fuzz test: thousands of mutations of a small valid product (truncations, random bytes in the
headers, the DSDs and the records) never raise anything but N1FormatError, and never hang."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from n1_samples import sample_inputs

from napari_meris_ortho.errors import N1FormatError
from napari_meris_ortho.products.n1 import read_product, write_product
from napari_meris_ortho.products.n1.format import DSD_SIZE, MPH_SIZE, SPH_TEXT_SIZE

pytestmark = pytest.mark.slow

MUTATIONS = 3000


def _exercise(path) -> None:
    """Open and touch everything a user of the product touches."""
    product = read_product(path)
    for values in product.tie_points.values():
        assert values.dtype == np.float64
    for band in (1, 8, 15):
        product.counts(band).sum()
    product.radiance(1)
    product.flags.sum()
    product.detector_index.sum()
    product.line_times.sum()
    assert len(product.wavelengths) == 15
    repr(product)


HEADER_END = MPH_SIZE + SPH_TEXT_SIZE + 30 * DSD_SIZE


def _mutate(data: bytes, rng: np.random.Generator, records_end: int, digits: list[int]) -> bytes:
    buf = bytearray(data)
    n = len(buf)
    header_end = HEADER_END
    kind = rng.integers(0, 7)
    if kind == 0:  # truncation
        return bytes(buf[: rng.integers(0, n)])
    if kind == 1:  # random bytes in the MPH and SPH text
        lo, hi = 0, MPH_SIZE + SPH_TEXT_SIZE
    elif kind == 2:  # random bytes in the DSDs
        lo, hi = MPH_SIZE + SPH_TEXT_SIZE, header_end
    elif kind == 3:  # random bytes in the annotation records (quality, GADS, tie points)
        lo, hi = header_end, records_end
    elif kind == 4:  # random bytes anywhere
        lo, hi = 0, n
    elif kind == 5:  # digits swapped for digits in the headers: plausible, deeper damage
        for i in rng.choice(digits, size=rng.integers(1, 4)):
            buf[i] = 48 + int(rng.integers(0, 10))
        return bytes(buf)
    else:  # a header line deleted or duplicated (sizes shift)
        lines = bytes(buf[:header_end]).split(b"\n")
        j = int(rng.integers(0, len(lines)))
        lines.insert(j, lines[j]) if rng.random() < 0.5 else lines.pop(j)
        return b"\n".join(lines) + bytes(buf[header_end:])
    for _ in range(int(rng.integers(1, 9))):
        buf[int(rng.integers(lo, hi))] = int(rng.integers(0, 256))
    return bytes(buf)


@pytest.mark.timeout(120)
def test_mutations_only_raise_n1formaterror(tmp_path):
    good = write_product(tmp_path / "good.N1", **sample_inputs("MER_RR__1P", height=40, width=33))
    data = good.read_bytes()
    records_end = read_product(good).dsd("Radiance MDS(1)").offset
    digits = [i for i in range(HEADER_END) if 48 <= data[i] <= 57]
    _exercise(good)
    rng = np.random.default_rng(20030921)
    path = tmp_path / "mutant.N1"
    outcomes = {"ok": 0, "error": 0}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning (overflow, invalid value) either
        for i in range(MUTATIONS):
            mutant = _mutate(data, rng, records_end, digits)
            path.write_bytes(mutant)
            try:
                _exercise(path)
            except N1FormatError as exc:
                assert str(exc).startswith(str(path)), exc
                outcomes["error"] += 1
            except Exception as exc:  # the point of the test: nothing else may escape
                raise AssertionError(f"mutation {i} raised {exc!r}") from exc
            else:
                outcomes["ok"] += 1
    assert outcomes["error"] > MUTATIONS // 4 and outcomes["ok"] > MUTATIONS // 10, outcomes

"""Hostile N1 files built from a valid product: physically impossible tie points and scaling
factors, widened header fields, huge record counts in sparse files (tests/io/test_n1_checks.py
and the plausibility-aware fuzz test)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from napari_meris_ortho.products.n1 import MerisL1bProduct
from napari_meris_ortho.products.n1.format import (
    DSD_SIZE,
    GADS_DTYPE,
    MPH_SIZE,
    SPH_TEXT_SIZE,
    tie_point_dtype,
)
from napari_meris_ortho.products.n1.writer import format_dsd


def patch_text(data: bytes, old: bytes, new: bytes) -> bytes:
    """Replace the one occurrence of ``old`` (same length keeps every offset)."""
    assert data.count(old) == 1, old
    return data.replace(old, new)


def patch_dsds(data: bytes, product: MerisL1bProduct, **by_name: dict) -> bytes:
    """Rewrite the DSDs named in ``by_name`` with the given field changes."""
    buf = bytearray(data)
    for index, d in enumerate(product.dsds):
        if d.name in by_name:
            start = MPH_SIZE + SPH_TEXT_SIZE + index * DSD_SIZE
            buf[start : start + DSD_SIZE] = format_dsd(dataclasses.replace(d, **by_name[d.name]))
    return bytes(buf)


def patch_dsd(data: bytes, product: MerisL1bProduct, name: str, **changes) -> bytes:
    return patch_dsds(data, product, **{name: changes})


def tie_records(data: bytes, product: MerisL1bProduct) -> tuple[np.ndarray, int]:
    """A writable copy of the Tie points ADS records (raw integers) and their offset."""
    d = product.dsd("Tie points ADS")
    dtype = tie_point_dtype(product.n_tie_columns)
    return np.frombuffer(data, dtype, d.num_dsr, d.offset).copy(), d.offset


def with_records(data: bytes, records: np.ndarray, offset: int) -> bytes:
    raw = records.tobytes()
    return data[:offset] + raw + data[offset + len(raw) :]


def set_tie_point(data: bytes, product: MerisL1bProduct, name: str, raw, where=None) -> bytes:
    """Set raw tie-point field ``name`` (all tie points, or ``where`` = (i, k)) to ``raw``."""
    records, offset = tie_records(data, product)
    if where is None:
        records[name] = raw
    else:
        records[name][where] = raw
    return with_records(data, records, offset)


def set_scaling(data: bytes, product: MerisL1bProduct, name: str, value, index=None) -> bytes:
    """Set a Scaling Factor GADS field (``radiance`` takes ``index``) to ``value``."""
    offset = product.dsd("Scaling Factor GADS").offset
    rec = np.frombuffer(data, GADS_DTYPE, 1, offset).copy()
    if index is None:
        rec[name] = value
    else:
        rec[name][0, index] = value
    return with_records(data, rec, offset)


def sparse_with_counts(
    path: Path, data: bytes, product: MerisL1bProduct, tie_lines: int | None = None,
    height: int | None = None,
) -> Path:
    """Write a file whose DSDs claim ``tie_lines`` tie-point records and/or ``height`` product
    lines, sizes consistent, the claimed data sets laid out after the real ones in a sparse
    file (a few MB on disk whatever the counts)."""
    changes: dict[str, dict] = {}
    end = len(data)
    claims = []
    if tie_lines is not None:
        claims.append(("Tie points ADS", tie_lines))
    if height is not None:
        names = [f"Radiance MDS({b})" for b in range(1, 16)] + ["Flags MDS(16)"]
        claims += [(n, height) for n in names]
    for name, num in claims:
        d = product.dsd(name)
        changes[name] = {"offset": end, "num_dsr": num, "size": num * d.dsr_size}
        end += num * d.dsr_size
    bad = patch_dsds(data, product, **changes)
    with open(path, "wb") as f:
        f.write(bad)
        f.truncate(end)  # a hole: no disk blocks
    return path

"""napari sample data (filled in below)."""

from __future__ import annotations


def make_sample_alps():
    raise NotImplementedError


def make_sample_small():
    raise NotImplementedError

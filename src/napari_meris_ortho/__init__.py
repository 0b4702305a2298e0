"""Orthorectification and synthesis of Envisat MERIS Level 1b products.

The public API is imported lazily so that ``import napari_meris_ortho`` stays cheap
(no numba compilation, no Qt).
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

__version__ = "0.1.0"

_LAZY = {
    "read_product": "napari_meris_ortho.products.open",
    "MerisL1bProduct": "napari_meris_ortho.products.n1",
    "N1FormatError": "napari_meris_ortho.errors",
    "Sen3FormatError": "napari_meris_ortho.errors",
    "MerisOrthoError": "napari_meris_ortho.errors",
    "orthorectify": "napari_meris_ortho.ortho",
    "precompute": "napari_meris_ortho.ortho",
    "OrthoResult": "napari_meris_ortho.ortho",
    "geodetic_correction": "napari_meris_ortho.engine.location",
    "synthesize": "napari_meris_ortho.synthesis.api",
    "open_synthesis": "napari_meris_ortho.synthesis.reading",
    "disparity": "napari_meris_ortho.analysis.disparity",
    "demcheck": "napari_meris_ortho.analysis.demcheck",
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'napari_meris_ortho' has no attribute {name!r}")

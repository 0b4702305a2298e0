"""One entry point for every MERIS Level 1 product the project reads.

``read_product(path)``: an N1 file (``MER_FR__1P``, ``MER_RR__1P``, ``MER_FRS_1P`` and the
AMORGOS ``MER_FRG_1P``/``MER_FSG_1P``) -> ``products.n1.MerisL1bProduct``; a fourth-reprocessing
``.SEN3`` directory (or its ``xfdumanifest.xml``, or a ``.zip`` archive of it; ESA's
``EN1_MDSI_*`` names too) -> ``products.sen3.MerisSen3Product``. Both
give the same product interface (tie points, bands, flags); FRG/FSG and SEN3 products add the
per-pixel geolocation (``has_pixel_geolocation``, ``pixel_longitude()``, ``pixel_latitude()``,
``pixel_altitude()``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from . import n1, sen3
from .protocol import MerisProduct


def read_product(path: str | os.PathLike[str]) -> MerisProduct:
    """Open a MERIS Level 1 product: N1 file or ``.SEN3`` directory (see module docstring)."""
    p = Path(path)
    if sen3.is_sen3(p) or p.suffix.upper() in (".SEN3", ".ZIP"):
        return sen3.read_sen3(p)
    return n1.read_product(p)


def is_product_path(path: str | os.PathLike[str]) -> bool:
    """True for paths :func:`read_product` may open (``.N1`` files, ``.SEN3`` directories and
    their zip archives)."""
    p = Path(path)
    return p.suffix.upper() == ".N1" or sen3.is_sen3(p)


def has_pixel_geolocation(product: Any) -> bool:
    """True for products with a per-pixel geolocation (FRG/FSG N1, SEN3); False for anything
    else (a foreign object)."""
    return bool(getattr(product, "has_pixel_geolocation", False))

"""One entry point for every Level 1 product the project reads: MERIS and OLCI.

``read_product(path)``: an N1 file (``MER_FR__1P``, ``MER_RR__1P``, ``MER_FRS_1P`` and the
AMORGOS ``MER_FRG_1P``/``MER_FSG_1P``) -> ``products.n1.MerisL1bProduct``; a fourth-reprocessing
``.SEN3`` directory (or its ``xfdumanifest.xml``, or a ``.zip`` archive of it; ESA's
``EN1_MDSI_*`` names too) -> ``products.sen3.MerisSen3Product``; a Sentinel-3 OLCI Level 1B
``.SEN3`` (``S3A_OL_1_EFR____...``, ``..._ERR_...``; directory or zip) ->
``products.olci.OlciL1bProduct``; another Sentinel-3 product (OLCI Level 2, SYNERGY,
SLSTR...) -> ``OlciFormatError``. All give the same product interface (tie points, bands,
flags, ``sensor``, ``n_bands``); FRG/FSG and SEN3 products add the
per-pixel geolocation (``has_pixel_geolocation``, ``pixel_longitude()``, ``pixel_latitude()``,
``pixel_altitude()``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from ..errors import Sen3FormatError
from . import n1, olci, sen3
from .protocol import MerisProduct
from .sen3.layout import MANIFEST
from .sen3.layout import product_type_of as meris_type_of
from .sen3.members import Members


def read_product(path: str | os.PathLike[str]) -> MerisProduct:
    """Open a Level 1 product: MERIS N1 file or ``.SEN3``, OLCI Level 1B ``.SEN3`` (see
    module docstring)."""
    p = Path(path)
    if sen3.is_sen3(p) or p.suffix.upper() in (".SEN3", ".ZIP"):
        if is_sentinel3(p):
            return olci.read_olci(p)
        return sen3.read_sen3(p)
    return n1.read_product(p)


def is_sentinel3(path: Path) -> bool:
    """True for a SAFE product of Sentinel-3 (OLCI Level 1B or another kind, which
    ``read_olci`` names in its error): by its name, else its manifest's product type; a
    MERIS name (``ME_1_``, ``MER_``) is not read further."""
    p = path.parent if path.name == MANIFEST else path
    name = p.name
    if meris_type_of(name) is not None:
        return False
    if olci.product_type_of(name) or olci.foreign_type_of(name):
        return True
    try:
        members = Members(p)
    except Sen3FormatError:
        return False
    found = olci.sentinel3_type(members)
    return found is not None and meris_type_of(found) is None


def is_product_path(path: str | os.PathLike[str]) -> bool:
    """True for paths :func:`read_product` may open (``.N1`` files, ``.SEN3`` directories and
    their zip archives, MERIS or OLCI)."""
    p = Path(path)
    return p.suffix.upper() == ".N1" or sen3.is_sen3(p)


def has_pixel_geolocation(product: Any) -> bool:
    """True for products with a per-pixel geolocation (FRG/FSG N1, SEN3); False for anything
    else (a foreign object)."""
    return bool(getattr(product, "has_pixel_geolocation", False))

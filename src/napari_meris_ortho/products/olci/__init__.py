"""Sentinel-3 OLCI Level 1B products (``S3A_OL_1_EFR____...SEN3``, ``S3B_OL_1_ERR____...``):
the SAFE layout of the MERIS ``.SEN3`` (``products.sen3``, whose machinery they share) with 21
bands ``Oa01``..``Oa21``, tie points on every row, and two quality-flag codings.

Rooms: ``layout`` (names, sizes, flag codings, tie-point positions), ``reader``
(:func:`read_olci`), ``writer`` (:func:`write_olci`).
"""

from .layout import (
    EFR,
    ERR,
    OLCI_TYPES,
    QUALITY_FLAGS,
    TIE_COLUMN_SHIFT,
    FlagBaseline,
    flag_table,
    foreign_type_of,
    product_type_of,
    radiance_file,
    radiance_variable,
    required_files,
    tie_points_as_esa,
    tie_points_on_pixels,
)
from .reader import OlciL1bProduct, read_olci, sentinel3_type
from .writer import default_olci_name, quality_flags_of, write_olci

__all__ = [
    "EFR", "ERR", "OLCI_TYPES", "QUALITY_FLAGS", "TIE_COLUMN_SHIFT", "FlagBaseline",
    "OlciL1bProduct", "default_olci_name", "flag_table", "foreign_type_of", "product_type_of",
    "quality_flags_of", "radiance_file", "radiance_variable", "read_olci", "required_files",
    "sentinel3_type", "tie_points_as_esa", "tie_points_on_pixels", "write_olci",
]

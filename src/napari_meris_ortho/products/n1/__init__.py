"""ENVISAT N1 products of MERIS Level 1b: reader, writer and scaling factors.

Public entry points (the ``products.n1`` contract of ``docs/ARCHITECTURE.md``):

- :func:`read_product` -> :class:`MerisL1bProduct` (``n1_reader``);
- :func:`write_product` (``n1_writer``);
- :class:`ScalingFactors` (``.appendix_a()``: the values printed in Appendix A);
- :func:`west_to_east`: the mirrored (BEAM/EPR) view of stored-order arrays;
- the L1b flag bits ``FLAG_*`` (Flags MDS(16), defined in ``flags``).

Byte layouts live in ``n1_format``.
"""

from __future__ import annotations

from ...flags import (
    FLAG_BRIGHT,
    FLAG_COASTLINE,
    FLAG_COSMETIC,
    FLAG_DUPLICATED,
    FLAG_GLINT_RISK,
    FLAG_INVALID,
    FLAG_LAND_OCEAN,
    FLAG_NAMES,
    FLAG_SUSPECT,
)
from .format import (
    FR,
    NUM_BANDS,
    PRODUCT_TYPES,
    RR,
    TIE_POINT_NAMES,
    Dsd,
    ScalingFactors,
    plan_layout,
    tie_columns,
    tie_lines,
)
from .reader import MerisL1bProduct, read_product, west_to_east
from .writer import write_product

__all__ = [
    "FLAG_BRIGHT",
    "FLAG_COASTLINE",
    "FLAG_COSMETIC",
    "FLAG_DUPLICATED",
    "FLAG_GLINT_RISK",
    "FLAG_INVALID",
    "FLAG_LAND_OCEAN",
    "FLAG_NAMES",
    "FLAG_SUSPECT",
    "FR",
    "NUM_BANDS",
    "PRODUCT_TYPES",
    "RR",
    "TIE_POINT_NAMES",
    "Dsd",
    "MerisL1bProduct",
    "ScalingFactors",
    "plan_layout",
    "read_product",
    "tie_columns",
    "tie_lines",
    "west_to_east",
    "write_product",
]

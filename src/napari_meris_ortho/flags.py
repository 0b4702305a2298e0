"""L1b flag bits of MERIS Flags MDS(16) (EPR's ``MER_RR__1P_flags``), one definition for the
reader (``products.n1``), the synthesis rules (``engine.synthesis``) and the simulator. A bottom
room: imports nothing."""

from __future__ import annotations

FLAG_COSMETIC = 1
FLAG_DUPLICATED = 2
FLAG_GLINT_RISK = 4
FLAG_SUSPECT = 8
FLAG_LAND_OCEAN = 16
FLAG_BRIGHT = 32
FLAG_COASTLINE = 64
FLAG_INVALID = 128
#: names of the flag bits, lowest bit first
FLAG_NAMES = (
    "COSMETIC", "DUPLICATED", "GLINT_RISK", "SUSPECT", "LAND_OCEAN", "BRIGHT", "COASTLINE",
    "INVALID",
)  # fmt: skip

"""Synthesis of many MERIS and OLCI products (MERSYN use cases 1 and 2, handbook section 3.1,
Appendix C).

A synthesis is an Icechunk repository holding Zarr v3 arrays chunked inside the output tile
(:mod:`.store`). The work is split into one task per output tile: each product's piece of the
tile is orthorectified and made a contribution (:func:`engine.synthesis.segment_state`), one
after the other, and merged into the stored tile as it comes with the associative, commutative
rule of :func:`engine.synthesis.combine` (ties: sensing time, then name); then the tile is
written. Tasks run in this process (``workers=0``), on an
embedded ``distributed.LocalCluster`` or on an existing dask cluster (``scheduler``); each tile
task writes into its own fork of the Icechunk session, the forks are merged and the run ends in
one commit listing the products. Only the tiles the products touch are read, and only the
chunks whose values change are written.

A run killed or failed before its commit leaves the store at its previous commit. A product
already in the synthesis (same product name and sensing time) is reported and skipped.

A store holds the bands of one sensor, MERIS or OLCI; OLCI products feed a store of MERIS
bands with their matching bands (``bandsets``).

Rooms: ``store`` (the Icechunk/Zarr layout, tile read/write, lock, history), ``bandsets`` (the
band set of a store, the product bands feeding it), ``tiling`` (grid
and tile arithmetic), ``reports`` (Appendix B statistics), ``reading`` (``open_synthesis``),
``run`` (one run: tasks in process or on dask.distributed), ``api`` (``synthesize``),
``export`` (``export_cog``).
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

#: the room's public names and the module of each, imported on first use (``import
#: napari_meris_ortho.synthesis.store`` stays cheap)
_LAZY = {
    "synthesize": "api", "ALGORITHMS": "api", "prune_synthesis": "api",
    "open_synthesis": "reading", "is_synthesis": "reading", "SynthesisStore": "reading",
    "export_cog": "export",
    "ProductReport": "reports", "SynthesisResult": "reports",
    "tiles": "tiling", "terrain_margin_px": "tiling", "footprint_window": "tiling",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = sorted(_LAZY)

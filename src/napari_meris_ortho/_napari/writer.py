"""npe2 writer: a geocoded image layer saved as a GeoTIFF with its CRS and transform.

The georeference is the layer's ``metadata["geo"]`` (``world`` module doc); the file is written
through ``output.geotiff.write_geotiff`` (temporary name, then rename). A layer without one (a
product-geometry N1 layer, a plain image) is refused with a message naming it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import OutputError
from ..pyramid import full_resolution
from .world import layer_frame


class _Meta:
    """The ``metadata`` of the layer state napari hands to a writer, as ``layer_frame`` reads."""

    def __init__(self, meta: dict[str, Any]) -> None:
        self.metadata = meta.get("metadata") or {}


def write_geotiff_layer(path: str, data: Any, meta: dict[str, Any]) -> list[str]:
    """npe2 single-layer writer: ``data`` of an image layer as a GeoTIFF at ``path``."""
    from ..output.geotiff import meris_band_description, write_geotiff

    name = meta.get("name", "layer")
    grid = layer_frame(_Meta(meta))
    if grid is None:
        raise OutputError(f"layer {name!r} has no georeference (metadata 'geo'): save it with "
                          "napari's own TIFF writer, or orthorectify it first")
    arr = np.asarray(full_resolution(data))  # a multiscale layer: its full resolution
    bands = list(np.moveaxis(arr, -1, 0)) if meta.get("rgb") else (
        [arr] if arr.ndim == 2 else list(arr))
    info = meta.get("metadata") or {}
    band = info.get("band")
    descriptions = [meris_band_description(int(band))] if band and len(bands) == 1 else None
    return [str(write_geotiff(path, bands, grid, nodata=0, descriptions=descriptions,
                              metadata={"layer": name}))]

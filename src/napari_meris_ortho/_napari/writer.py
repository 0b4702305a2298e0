"""npe2 writer: a geocoded image or labels layer (elevation source, a synthesis's winning
product; its class 0, napari's background, as no data) saved as a GeoTIFF with its CRS and
transform.

The georeference is the layer's ``metadata["geo"]`` (``world`` module doc); the file is written
through ``output.geotiff.write_geotiff`` (temporary name, then rename), with the layer's own
no-data value (``metadata["nodata"]``: a GeoTIFF's, as the reader keeps it; 0 for a run's layers).
A layer without one (a product-geometry N1 layer, a plain image) is refused with a message naming
it, and so is a path a layer of the viewer reads from (napari's lazy layers read their file as the
view moves: replacing it under them crashes the viewer).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._atomic import same_file
from ..errors import OutputError
from ..pyramid import full_resolution
from .world import current_viewer, layer_frame


class _Meta:
    """The ``metadata`` of the layer state napari hands to a writer, as ``layer_frame`` reads."""

    def __init__(self, meta: dict[str, Any]) -> None:
        self.metadata = meta.get("metadata") or {}


def write_geotiff_layer(path: str, data: Any, meta: dict[str, Any]) -> list[str]:
    """npe2 single-layer writer: ``data`` of an image or labels layer as a GeoTIFF at
    ``path``."""
    from ..output.geotiff import meris_band_description, write_geotiff

    name = meta.get("name", "layer")
    grid = layer_frame(_Meta(meta))
    if grid is None:
        raise OutputError(f"layer {name!r} has no georeference (metadata 'geo'): save it with "
                          "napari's own TIFF writer, or orthorectify it first")
    readers = layers_reading(current_viewer(), path)
    if readers:
        raise OutputError(f"{path}: layer {readers[0]!r} reads from this file; save under "
                          "another name")
    arr = np.asarray(full_resolution(data))  # a multiscale layer: its full resolution
    bands = list(np.moveaxis(arr, -1, 0)) if meta.get("rgb") else (
        [arr] if arr.ndim == 2 else list(arr))
    info = meta.get("metadata") or {}
    band = info.get("band")
    descriptions = [meris_band_description(int(band))] if band and len(bands) == 1 else None
    nodata = 0 if meta.get("rgb") else info.get("nodata", 0)
    return [str(write_geotiff(path, bands, grid, nodata=nodata, descriptions=descriptions,
                              metadata={"layer": name}))]


def layers_reading(viewer: Any, path: Any) -> list[str]:
    """Names of the layers of ``viewer`` (None: none) whose source is the file ``path``."""
    if viewer is None:
        return []
    names = []
    for layer in viewer.layers:
        source = getattr(layer.source, "path", None) or (layer.metadata or {}).get("path")
        if source and same_file(source, path):
            names.append(layer.name)
    return names

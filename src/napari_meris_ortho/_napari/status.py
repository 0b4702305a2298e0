"""The status bar over geocoded layers: positive northing and easting (or latitude and
longitude) and the CRS, instead of napari's world (row, col) = (-northing, easting); and the
band slider of a product's radiance stack naming the band shown (MERIS or OLCI).

napari builds the status text from the selected layer's ``get_status``;
``show_map_coordinates(viewer)`` wraps it for every layer of the viewer that lives in the world
(``world.world_crs``: rasters, products, footprint/facet and parallax vectors), now and
when added, so that the coordinates are right whatever layer is selected (after a run, a
vectors layer). napari's slider shows the step index (0-14); the axis label of a radiance stack
names the band at the dims point instead ("MERIS band 7 (665 nm)", "OLCI Oa08 (665 nm)"; world
band axis = 1..n_bands).
"""

from __future__ import annotations

import weakref
from typing import Any

import numpy as np

from ..display import fixed
from ..geometry.grid import crs_facts
from .geometry_layers import facet_at
from .world import GEO_KEY, TIE_GRID_KEY, world_crs

_WATCHED: weakref.WeakSet[Any] = weakref.WeakSet()
_WRAPPED = "_meris_ortho_status"


def map_position(world_row: float, world_col: float, geographic: bool, label: str) -> str:
    """World (row, col) as map coordinates: 'E 412345 m, N 5087123 m (EPSG:32632)' or
    '46.12345° N, 7.54321° E (EPSG:4326)'."""
    x, y = float(world_col), -float(world_row)
    if geographic:
        return (f"{abs(y):.5f}° {'N' if y >= 0 else 'S'}, "
                f"{abs(x):.5f}° {'E' if x >= 0 else 'W'} ({label})")
    return f"E {fixed(x, 0)} m, N {fixed(y, 0)} m ({label})"


def source_text(layer: Any) -> str:
    """The layer list's tooltip of a layer of ours: its name, then the product (or store) it
    shows and when that was acquired, which the short name leaves out."""
    meta = getattr(layer, "metadata", None) or {}
    lines = [str(layer.name)]
    what = meta.get("product") or meta.get("synthesis") or meta.get("path")
    if what:
        lines.append(str(what))
    if meta.get("acquired"):
        lines.append(f"acquired {meta['acquired']}")
    return "\n".join(lines)


def wrap_tooltip(layer: Any) -> None:
    """The layer list's tooltip of ``layer`` (napari's ``get_source_str``): ``source_text``
    when the layer names a product or store; napari's own otherwise."""
    meta = getattr(layer, "metadata", None) or {}
    if any(meta.get(key) for key in ("product", "synthesis", "acquired")):
        layer.get_source_str = lambda: source_text(layer)


def wrap_status(layer: Any) -> None:
    """Replace ``layer.get_status`` by one reporting map coordinates (world layers only).
    Cheap and thread-free: a run wraps its layers in its worker, before their insertion."""
    if getattr(layer, _WRAPPED, False):
        return
    crs = world_crs(layer)
    if crs is None:
        return
    label, geographic = crs_facts(str(crs))
    original = layer.get_status

    def get_status(position: Any = None, **kwargs: Any) -> dict[str, str]:
        status = original(position, **kwargs)
        if position is None or not kwargs.get("world"):
            return status
        row, col = np.asarray(position, dtype=np.float64)[-2:]
        coords = map_position(row, col, geographic, label)
        old = status.get("coords", "")
        status["coordinates"] = (status.get("coordinates", "").replace(old, coords, 1)
                                 if old else coords)
        status["coords"] = coords
        grid = (getattr(layer, "metadata", None) or {}).get(TIE_GRID_KEY)
        if grid is not None:  # the facets layer: the facet under the cursor (section 3.4)
            facet = facet_at(grid, row, col)
            if facet is not None:
                status["coordinates"] += (f"; facet of tie line {facet[0]}, tie column "
                                          f"{facet[1]}")
        return status

    layer.get_status = get_status
    setattr(layer, _WRAPPED, True)


def show_map_coordinates(viewer: Any) -> None:
    """Map coordinates in the status bar for the viewer's geocoded layers (idempotent)."""
    if viewer is None or viewer in _WATCHED:
        return
    _WATCHED.add(viewer)
    for layer in viewer.layers:
        wrap_status(layer)
    viewer.layers.events.inserted.connect(lambda event: wrap_status(event.value))
    ref = weakref.ref(viewer)

    def bands(_event: Any = None) -> None:
        alive = ref()
        if alive is not None:
            label_bands(alive)

    viewer.dims.events.current_step.connect(bands)
    viewer.layers.events.inserted.connect(bands)
    bands()


#: axis label of the band axis of a MERIS radiance stack (``reader.n1_layers``)
BAND_AXIS = "MERIS band"


def band_axis_name(sensor: str) -> str:
    """The axis label of the band axis of a radiance stack of ``sensor``: 'MERIS band',
    'OLCI band'."""
    return f"{sensor} band"


def label_bands(viewer: Any) -> None:
    """Name the band at the dims point on the band axis of every radiance stack (a layer with
    ``metadata["band_names"]`` whose first axis is the band axis, world band = 1..n_bands):
    'MERIS band 7 (665 nm)', 'OLCI Oa08 (665 nm)'."""
    for layer in viewer.layers:
        meta = getattr(layer, "metadata", {}) or {}
        names = meta.get("band_names")
        sensor = str(meta.get("sensor", "MERIS"))
        labels = tuple(layer.axis_labels)
        if not names or layer.ndim != 3 or not labels[0].startswith(sensor):
            continue
        axis = viewer.dims.ndim - layer.ndim
        band = int(round(float(viewer.dims.point[axis])))
        text = (f"{sensor} {names[band - 1]}" if 1 <= band <= len(names)
                else band_axis_name(sensor))
        if labels[0] != text:
            layer.axis_labels = (text, *labels[1:])


__all__ = ["BAND_AXIS", "GEO_KEY", "band_axis_name", "label_bands", "map_position",
           "show_map_coordinates", "wrap_status"]

"""The status bar over geocoded layers: positive northing and easting (or latitude and
longitude) and the CRS, instead of napari's world (row, col) = (-northing, easting).

napari builds the status text from ``layer.get_status``; ``show_map_coordinates(viewer)``
wraps it for every geocoded layer of the viewer (``metadata["geo"]``), now and when added.
"""

from __future__ import annotations

import weakref
from typing import Any

import numpy as np

from .world import GEO_KEY, layer_frame

_WATCHED: weakref.WeakSet[Any] = weakref.WeakSet()
_WRAPPED = "_meris_ortho_status"


def crs_label(crs: Any) -> str:
    """'EPSG:32632' when the CRS has an EPSG code, else its name."""
    from pyproj import CRS

    crs = CRS.from_user_input(crs)
    epsg = crs.to_epsg()
    return f"EPSG:{epsg}" if epsg else str(crs.name)


def map_position(world_row: float, world_col: float, geographic: bool, label: str) -> str:
    """World (row, col) as map coordinates: 'E 412345 m, N 5087123 m (EPSG:32632)' or
    '46.12345° N, 7.54321° E (EPSG:4326)'."""
    x, y = float(world_col), -float(world_row)
    if geographic:
        return (f"{abs(y):.5f}° {'N' if y >= 0 else 'S'}, "
                f"{abs(x):.5f}° {'E' if x >= 0 else 'W'} ({label})")
    return f"E {x:.0f} m, N {y:.0f} m ({label})"


def _wrap(layer: Any) -> None:
    """Replace ``layer.get_status`` by one reporting map coordinates (geocoded layers only)."""
    grid = layer_frame(layer)
    if grid is None or getattr(layer, _WRAPPED, False):
        return
    label, geographic = crs_label(grid.crs), bool(grid.is_geographic)
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
        return status

    layer.get_status = get_status
    setattr(layer, _WRAPPED, True)


def show_map_coordinates(viewer: Any) -> None:
    """Map coordinates in the status bar for the viewer's geocoded layers (idempotent)."""
    if viewer is None or viewer in _WATCHED:
        return
    _WATCHED.add(viewer)
    for layer in viewer.layers:
        _wrap(layer)
    viewer.layers.events.inserted.connect(lambda event: _wrap(event.value))


__all__ = ["GEO_KEY", "crs_label", "map_position", "show_map_coordinates"]

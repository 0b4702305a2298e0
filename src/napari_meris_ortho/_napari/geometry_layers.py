"""Geometry layers of the napari front end (section 3.1, 3.4, eq. 2): the segment boundary
(footprint), the tie-point facets and the parallax shift vectors, built directly in world
coordinates (no scale/translate, see ``world``) from lon/lat projected into the frame's CRS.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ..engine.boundary import segment_boundary
from ..geometry.earth import MEAN_EARTH_RADIUS
from ..geometry.grid import OutputGrid, crs_wkt, lonlat_to_crs
from .world import WORLD_KEY, geo_metadata, to_world, world_axes


def footprint_polygons(tp_lat: np.ndarray, tp_lon: np.ndarray, crs: Any,
                       densify: int = 4) -> list[np.ndarray]:
    """World (row, col) vertices of the segment boundary (section 3.1, fig. 19) in ``crs``.

    The boundary is ``engine.boundary.segment_boundary`` of the tie points; one polygon, or
    several when it is cut at the antimeridian (fig. 20).
    """
    boundary = segment_boundary(tp_lat, tp_lon)
    return [to_world(x, y) for x, y in boundary.polygons(crs_wkt(crs), densify=densify)]


def footprint_layer_data(tp_lat: np.ndarray, tp_lon: np.ndarray, crs: Any,
                         name: str = "footprint") -> tuple[list[np.ndarray], dict, str]:
    """A Shapes layer tuple: the footprint boundary polygon(s) with a transparent face."""
    polys = footprint_polygons(tp_lat, tp_lon, crs)
    kwargs = {
        "shape_type": "polygon", "name": name, "face_color": "transparent",
        "edge_color": "yellow", "edge_width": _edge_width(np.concatenate(polys)), "opacity": 1.0,
        "metadata": {"crs": crs_wkt(crs)}, **world_axes(crs),
    }
    return polys, kwargs, "shapes"


def facet_polygons(lat: np.ndarray, lon: np.ndarray, crs: Any) -> np.ndarray:
    """World vertices (n_facets, 4, 2) of the tie-point facets (quads of 4 tie points, 3.4)."""
    x, y = lonlat_to_crs(np.asarray(lon), np.asarray(lat), crs)
    w = to_world(x, y)  # (n_lines, n_cols, 2)
    quads = np.stack([w[:-1, :-1], w[:-1, 1:], w[1:, 1:], w[1:, :-1]], axis=2)
    return quads.reshape(-1, 4, 2)


def facets_layer_data(lat: np.ndarray, lon: np.ndarray, crs: Any,
                      name: str = "facets") -> tuple[list[np.ndarray], dict, str]:
    """A Shapes layer tuple: the grid of tie-point facets (transparent quads)."""
    quads = facet_polygons(lat, lon, crs)
    n_lines, n_cols = np.asarray(lat).shape
    kwargs = {
        "shape_type": "polygon", "name": name, "face_color": "transparent",
        "edge_color": "cyan", "edge_width": _edge_width(quads) * 0.6, "opacity": 0.6,
        "visible": True, **world_axes(crs),
        "features": {
            "tie_line": np.repeat(np.arange(n_lines - 1), n_cols - 1),
            "tie_column": np.tile(np.arange(n_cols - 1), n_lines - 1),
        },
    }
    return list(quads), kwargs, "shapes"


def _edge_width(poly: np.ndarray) -> float:
    """An edge width of about 1/400 of the polygon's extent (world units)."""
    extent = np.ptp(np.asarray(poly).reshape(-1, 2), axis=0).max()
    return float(max(extent / 400.0, 1e-9))


def _pixel_centres(frame: OutputGrid, step: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rows, cols and CRS (x, y) of the pixel centres on a regular subsample of ``step``."""
    rr, cc = np.meshgrid(np.arange(step // 2, frame.height, step),
                         np.arange(step // 2, frame.width, step), indexing="ij")
    x, y = frame.xy(rr, cc)
    return rr.ravel(), cc.ravel(), x.ravel(), y.ravel()


def parallax_vectors(frame: OutputGrid, shift_east: np.ndarray, shift_north: np.ndarray,
                     height: np.ndarray | None = None, *, step: int = 16,
                     exaggeration: float = 1.0, valid: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Parallax shift vectors on a regular subsample of output points (eq. 2, section 2.4).

    Each vector goes from the uncorrected position (ellipsoid point of the tie-point
    interpolation) to the corrected (terrain) position, i.e. along the shift (east, north) in
    metres, times ``exaggeration``. Returns (vectors (n, 2, 2) in world coords, heights (n,)).
    """
    rows, cols, x, y = _pixel_centres(frame, step)
    east = np.asarray(shift_east, np.float64)[rows, cols]
    north = np.asarray(shift_north, np.float64)[rows, cols]
    keep = np.isfinite(east) & np.isfinite(north)
    if valid is not None:
        keep &= np.asarray(valid, bool)[rows, cols]
    rows, cols, x, y, east, north = (a[keep] for a in (rows, cols, x, y, east, north))
    if frame.is_geographic:
        lat = np.deg2rad(y)
        dx = np.rad2deg(east / (MEAN_EARTH_RADIUS * np.cos(lat)))
        dy = np.rad2deg(north / MEAN_EARTH_RADIUS)
    else:
        dx, dy = east, north
    dx, dy = dx * exaggeration, dy * exaggeration
    start = to_world(x - dx, y - dy)
    direction = to_world(dx, dy)
    vectors = np.stack([start, direction], axis=1)
    h = np.zeros(len(x)) if height is None else np.asarray(height, np.float64)[rows, cols]
    return vectors, h


def parallax_name(exaggeration: float) -> str:
    """'parallax ×10': the layer name carries the exaggeration of the vectors."""
    return f"parallax ×{exaggeration:g}"


def parallax_layer_data(frame: OutputGrid, shift_east: np.ndarray, shift_north: np.ndarray,
                        height: np.ndarray | None = None, *, step: int = 16,
                        exaggeration: float = 10.0, valid: np.ndarray | None = None,
                        name: str | None = None) -> tuple[np.ndarray, dict, str]:
    """A Vectors layer tuple of the parallax shifts, one every ``step`` pixels, coloured by
    height (viridis; the legend is in ``metadata["legend"]``, heights in the features)."""
    vectors, h = parallax_vectors(frame, shift_east, shift_north, height, step=step,
                                  exaggeration=exaggeration, valid=valid)
    lo, hi = (float(h.min()), float(h.max())) if len(h) else (0.0, 1.0)
    hi = hi if hi > lo else lo + 1.0
    pixel = max(frame.dx, frame.dy)
    kwargs = {
        "name": name or parallax_name(exaggeration), "edge_width": pixel * step / 5.0,
        "features": {"height": h}, "edge_color": "height", "edge_colormap": "viridis",
        "edge_contrast_limits": (lo, hi), "vector_style": "arrow", "length": 1.0,
        "metadata": {"exaggeration": exaggeration, "step": step, "pixel_size": pixel,
                     "legend": f"colour: height {lo:.0f}–{hi:.0f} m (viridis)"},
        **world_axes(frame.crs),
    }
    return vectors, kwargs, "vectors"


def geometry_layers(tie_points: Mapping[str, np.ndarray], frame: OutputGrid, suffix: str = "",
                    diagnostics: dict[str, np.ndarray] | None = None, *,
                    valid: np.ndarray | None = None, exaggeration: float = 10.0,
                    step: int = 16) -> list[tuple[Any, dict, str]]:
    """Footprint boundary, tie-point facets and (with diagnostics) parallax shift vectors,
    named "footprint", "facets", "parallax ×10" followed by ``suffix``."""
    lat, lon = tie_points["latitude"], tie_points["longitude"]
    layers: list[tuple[Any, dict, str]] = [
        facets_layer_data(lat, lon, frame.crs, name=f"facets{suffix}"),
        footprint_layer_data(lat, lon, frame.crs, name=f"footprint{suffix}")]
    if diagnostics and "shift_east_m" in diagnostics:
        layers.append(parallax_layer_data(
            frame, diagnostics["shift_east_m"], diagnostics["shift_north_m"],
            diagnostics.get("elevation"), step=step, exaggeration=exaggeration, valid=valid,
            name=f"{parallax_name(exaggeration)}{suffix}"))
    for _, kwargs, _ in layers:  # the world they live in (status bar, the viewer's frame)
        kwargs["metadata"] = {**(kwargs.get("metadata") or {}), WORLD_KEY: geo_metadata(frame)}
    return layers

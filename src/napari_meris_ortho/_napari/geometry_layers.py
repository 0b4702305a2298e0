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
from ..placement import to_world
from .product_layers import category_colormap
from .world import TIE_GRID_KEY, WORLD_KEY, geo_image_kwargs, geo_metadata, world_axes

#: colour of the ground hidden from the sensor by the relief (labels layer, semi-transparent)
HIDDEN_COLOUR = "magenta"
HIDDEN_OPACITY = 0.6


def footprint_polygons(tp_lat: np.ndarray, tp_lon: np.ndarray, crs: Any,
                       densify: int = 4) -> list[np.ndarray]:
    """World (row, col) vertices of the segment boundary (section 3.1, fig. 19) in ``crs``.

    The boundary is ``engine.boundary.segment_boundary`` of the tie points; one polygon, or
    several when it is cut at the antimeridian (fig. 20).
    """
    boundary = segment_boundary(tp_lat, tp_lon)
    return [to_world(x, y) for x, y in boundary.polygons(crs_wkt(crs), densify=densify)]


def polygon_edges(polygons: list[np.ndarray]) -> np.ndarray:
    """Napari vectors (n, 2, 2) = (start, direction) of the closed ``polygons``' edges."""
    edges = []
    for poly in polygons:
        p = np.asarray(poly, np.float64)
        edges.append(np.stack([p, np.roll(p, -1, axis=0) - p], axis=1))
    return np.concatenate(edges) if edges else np.zeros((0, 2, 2))


def footprint_layer_data(tp_lat: np.ndarray, tp_lon: np.ndarray, crs: Any,
                         name: str = "footprint") -> tuple[np.ndarray, dict, str]:
    """A Vectors layer tuple: the edges of the footprint boundary polygon(s), drawn as lines.

    Vectors, not Shapes: napari keeps every removed Shapes layer alive through its mode
    buttons (https://github.com/napari/napari/issues/2027: a run's two shapes layers, about
    9 MB, would stay in memory after their removal, run after run) and builds four shader
    programs at its first draw (the longest stall of a run)."""
    polys = footprint_polygons(tp_lat, tp_lon, crs)
    kwargs = {
        "name": name, "edge_color": "yellow", "vector_style": "line", "length": 1.0,
        "edge_width": _edge_width(np.concatenate(polys)), "opacity": 1.0,
        "metadata": {"crs": crs_wkt(crs)}, **world_axes(crs),
    }
    return polygon_edges(polys), kwargs, "vectors"


def tie_grid_world(lat: np.ndarray, lon: np.ndarray, crs: Any) -> np.ndarray:
    """World (row, col) of every tie point (n_lines, n_cols, 2) in ``crs``."""
    x, y = lonlat_to_crs(np.asarray(lon), np.asarray(lat), crs)
    return to_world(x, y)


def grid_edges(grid: np.ndarray) -> np.ndarray:
    """Napari vectors of the edges of a (n_lines, n_cols, 2) grid: along its lines, then along
    its columns (each edge once)."""
    along = np.stack([grid[:, :-1], grid[:, 1:] - grid[:, :-1]], axis=-2).reshape(-1, 2, 2)
    across = np.stack([grid[:-1, :], grid[1:, :] - grid[:-1, :]], axis=-2).reshape(-1, 2, 2)
    return np.concatenate([along, across])


def facets_layer_data(lat: np.ndarray, lon: np.ndarray, crs: Any,
                      name: str = "facets") -> tuple[np.ndarray, dict, str]:
    """A Vectors layer tuple: the edges of the tie-point facets (section 3.4), drawn as lines;
    the tie-point grid in world coordinates in its metadata, so that the status bar names the
    facet under the cursor (tie line, tie column: ``facet_at``)."""
    grid = tie_grid_world(lat, lon, crs)
    kwargs = {
        "name": name, "edge_color": "cyan", "vector_style": "line", "length": 1.0,
        "edge_width": min(_edge_width(grid) * 0.6, 0.25 * _shortest_side(grid)),
        "opacity": 0.6, "visible": True,
        "metadata": {TIE_GRID_KEY: grid}, **world_axes(crs),
    }
    return grid_edges(grid), kwargs, "vectors"


def facet_at(grid: np.ndarray, row: float, col: float) -> tuple[int, int] | None:
    """(tie line, tie column) of the facet of the world tie-point ``grid`` (n_lines, n_cols, 2)
    holding the world point (row, col): the quad of tie points (i, k), (i, k+1), (i+1, k+1),
    (i+1, k) whose four edges all keep it on one side (facets are convex); None outside."""
    g = np.asarray(grid, np.float64)
    if g.ndim != 3 or g.shape[0] < 2 or g.shape[1] < 2:
        return None
    corners = [g[:-1, :-1], g[:-1, 1:], g[1:, 1:], g[1:, :-1]]
    signs = []
    for a, b in zip(corners, corners[1:] + corners[:1], strict=True):
        cross = ((b[..., 0] - a[..., 0]) * (col - a[..., 1])
                 - (b[..., 1] - a[..., 1]) * (row - a[..., 0]))
        signs.append(cross)
    s = np.stack(signs)
    inside = np.all(s >= 0, axis=0) | np.all(s <= 0, axis=0)
    hits = np.argwhere(inside)
    return None if hits.size == 0 else (int(hits[0][0]), int(hits[0][1]))


def _shortest_side(grid: np.ndarray) -> float:
    """The median length of a facet's shorter sides (world units): between tie lines, or
    between tie columns when those are closer. An OLCI product's tie points are on every row
    (1.2 km apart in ERR): its edges stay thinner than that, not one solid fill."""
    g = np.asarray(grid, np.float64)
    sides = [np.hypot(*np.moveaxis(np.diff(g, axis=axis), -1, 0)).ravel()
             for axis in (0, 1) if g.shape[axis] > 1]
    medians = [float(np.median(side)) for side in sides if side.size]
    return min(medians) if medians and min(medians) > 0 else np.inf


def _edge_width(poly: np.ndarray) -> float:
    """A thin edge: about 1/800 of the polygon's extent (world units), a line of one or two
    screen pixels with the whole scene in view."""
    extent = np.ptp(np.asarray(poly).reshape(-1, 2), axis=0).max()
    return float(max(extent / 800.0, 1e-9))


def _pixel_centres(frame: OutputGrid, step: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rows, cols and CRS (x, y) of the pixel centres on a regular subsample of ``step``."""
    rr, cc = np.meshgrid(np.arange(step // 2, frame.height, step),
                         np.arange(step // 2, frame.width, step), indexing="ij")
    x, y = frame.xy(rr, cc)
    return rr.ravel(), cc.ravel(), x.ravel(), y.ravel()


def parallax_vectors(frame: OutputGrid, shift_east: np.ndarray, shift_north: np.ndarray,
                     height: np.ndarray | None = None, *, step: int,
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


#: vectors across the larger side of the output grid of the automatic spacing
#: (``vector_step_for``)
VECTORS_ACROSS = 60
#: the smallest automatic spacing (px)
MIN_VECTOR_STEP = 8


def vector_step_for(frame: OutputGrid) -> int:
    """The automatic spacing of the parallax vectors (px): about ``VECTORS_ACROSS`` of them
    across the larger side of ``frame``, one every ``MIN_VECTOR_STEP`` px at least. The field
    stays readable in the view that frames the result (fr-alps: one every 49 px, 2.4k vectors,
    where one every 16 px draws 22k arrows, overlapping at ten times their length), and napari
    slices and draws every vector of the layer at each change: showing and first drawing 22k
    take 0.10-0.16 s of a turn each (software GL)."""
    return max(MIN_VECTOR_STEP, max(frame.width, frame.height) // VECTORS_ACROSS)


#: the longest arrow's share of the spacing of the sampled points. An arrow ends on its point
#: (the corrected position) and starts at the uncorrected one, so two neighbours' tails are
#: closer than their points by the difference of their arrows: at most one arrow length when
#: both point to the satellite's side. At less than half the spacing, the tails stay at least
#: one longest arrow apart, and no arrow reaches another
ARROW_ROOM = 0.45


def pixel_metres(frame: OutputGrid) -> float:
    """The smaller ground side of a pixel of ``frame`` (m): a geographic pixel's east-west side
    at the grid's edge farthest from the equator."""
    if not frame.is_geographic:
        return float(min(frame.dx, frame.dy))
    lat = max(abs(frame.y0), abs(frame.y0 - frame.height * frame.dy))
    metre = np.deg2rad(1.0) * MEAN_EARTH_RADIUS
    return float(min(frame.dy * metre, frame.dx * metre * np.cos(np.deg2rad(min(lat, 89.0)))))


#: the fewest vectors across the larger side of the grid that the automatic spacing keeps; a
#: field that would need fewer gets a smaller exaggeration instead (``readable_vectors``)
MIN_VECTORS_ACROSS = 10


def _nice_below(value: float) -> float:
    """``value`` rounded down to two significant digits (3.478 -> 3.4, 0.4712 -> 0.47)."""
    power = 10.0 ** (np.floor(np.log10(value)) - 1)
    return float(np.floor(value / power * (1 + 1e-9)) * power)


def readable_vectors(frame: OutputGrid, shift_east: np.ndarray, shift_north: np.ndarray,
                     exaggeration: float, valid: np.ndarray | None = None
                     ) -> tuple[int, float]:
    """The automatic spacing of the parallax vectors (px) and the exaggeration they are drawn
    with, so that no arrow reaches the next tail (the longest exaggerated shift at most
    ``ARROW_ROOM`` of the spacing) and no two arrows overlap: ``vector_step_for`` widened as
    far as ``MIN_VECTORS_ACROSS`` vectors across; when even that spacing is too short for the
    longest arrow, ``exaggeration`` lowered to a value of two significant digits that fits."""
    length = np.hypot(np.asarray(shift_east, np.float64), np.asarray(shift_north, np.float64))
    keep = np.isfinite(length)
    if valid is not None:
        keep &= np.asarray(valid, bool)
    longest = float(length[keep].max()) if keep.any() else 0.0
    pixel = ARROW_ROOM * pixel_metres(frame)
    base = vector_step_for(frame)
    widest = max(base, max(frame.width, frame.height) // MIN_VECTORS_ACROSS)
    need = int(np.ceil(longest * abs(exaggeration) / pixel))
    if need <= widest:
        return max(base, need), exaggeration
    return widest, min(exaggeration, _nice_below(widest * pixel / longest))


def parallax_name(exaggeration: float) -> str:
    """'parallax ×10': the layer name carries the exaggeration of the vectors."""
    return f"parallax ×{exaggeration:g}"


def parallax_layer_data(frame: OutputGrid, shift_east: np.ndarray, shift_north: np.ndarray,
                        height: np.ndarray | None = None, *, step: int,
                        exaggeration: float = 10.0, valid: np.ndarray | None = None,
                        name: str | None = None) -> tuple[np.ndarray, dict, str]:
    """A Vectors layer tuple of the parallax shifts, one every ``step`` pixels, coloured by
    height (viridis; the legend is in ``metadata["legend"]``, heights in the features)."""
    vectors, h = parallax_vectors(frame, shift_east, shift_north, height, step=step,
                                  exaggeration=exaggeration, valid=valid)
    lo, hi = (float(h.min()), float(h.max())) if len(h) else (0.0, 1.0)
    hi = hi if hi > lo else lo + 1.0
    pixel = max(frame.dx, frame.dy)
    longest = float(np.hypot(vectors[:, 1, 0], vectors[:, 1, 1]).max()) if len(h) else 0.0
    # thin: a twelfth of the spacing, a quarter of the longest arrow at most
    width = max(min(pixel * step / 12.0, longest / 4.0), pixel / 2.0)
    kwargs = {
        "name": name or parallax_name(exaggeration), "edge_width": width,
        "features": {"height": h}, "edge_color": "height", "edge_colormap": "viridis",
        "edge_contrast_limits": (lo, hi), "vector_style": "arrow", "length": 1.0,
        "metadata": {"exaggeration": exaggeration, "step": step, "pixel_size": pixel,
                     "legend": f"colour: height {lo:.0f}–{hi:.0f} m (viridis)"},
        **world_axes(frame.crs),
    }
    return vectors, kwargs, "vectors"


def hidden_layer_data(frame: OutputGrid, hidden: np.ndarray, name: str = "hidden ground"
                      ) -> tuple[np.ndarray, dict, str]:
    """A labels layer tuple of the ground hidden from the sensor by the relief (label 1,
    ``HIDDEN_COLOUR``, semi-transparent over the bands; elsewhere transparent): with hidden
    ``mask`` the holes of the map, with ``keep`` the points mapped from the relief in front."""
    labels = (np.asarray(hidden) != 0).astype(np.uint8)
    n = int(np.count_nonzero(labels))
    kwargs = geo_image_kwargs(
        frame, name=name, opacity=HIDDEN_OPACITY,
        colormap=category_colormap({1: HIDDEN_COLOUR}),
        features={"index": [0, 1], "ground": ["", "hidden by the relief"]},
        metadata={"hidden_points": n,
                  "legend": f"{HIDDEN_COLOUR}: ground hidden from the sensor by the relief "
                            f"({n} points)"})
    return labels, kwargs, "labels"


def geometry_layers(tie_points: Mapping[str, np.ndarray], frame: OutputGrid, suffix: str = "",
                    diagnostics: dict[str, np.ndarray] | None = None, *,
                    valid: np.ndarray | None = None, exaggeration: float = 10.0,
                    step: int = 0) -> list[tuple[Any, dict, str]]:
    """Footprint boundary, tie-point facets and (with diagnostics) parallax shift vectors (one
    every ``step`` px; 0: ``readable_vectors``, which may lower the exaggeration), named
    "footprint", "facets", "parallax ×10" followed by ``suffix``."""
    lat, lon = tie_points["latitude"], tie_points["longitude"]
    layers: list[tuple[Any, dict, str]] = [
        facets_layer_data(lat, lon, frame.crs, name=f"facets{suffix}"),
        footprint_layer_data(lat, lon, frame.crs, name=f"footprint{suffix}")]
    if diagnostics and "shift_east_m" in diagnostics:
        if step <= 0:
            step, exaggeration = readable_vectors(frame, diagnostics["shift_east_m"],
                                                  diagnostics["shift_north_m"], exaggeration,
                                                  valid)
        layers.append(parallax_layer_data(
            frame, diagnostics["shift_east_m"], diagnostics["shift_north_m"],
            diagnostics.get("elevation"), step=step, exaggeration=exaggeration, valid=valid,
            name=f"{parallax_name(exaggeration)}{suffix}"))
    for _, kwargs, _ in layers:  # the world they live in (status bar, the viewer's frame)
        kwargs["metadata"] = {**(kwargs.get("metadata") or {}), WORLD_KEY: geo_metadata(frame)}
    return layers

"""The world frame of the napari front end: where every geocoded layer sits.

World frame (one for every geocoded layer)
------------------------------------------
napari's world axes are (row, column) = (y, x) with y growing downwards. Every geocoded layer
(orthorectified outputs, DEMs, reference images) is placed in the coordinates of the output CRS
with **north up**::

    world y = -northing          world x = easting          (geographic CRS: -lat, lon)

A raster with the rasterio transform ``Affine(dx, 0, x0, 0, -dy, y0)`` (``OutputGrid`` convention,
(x0, y0) = upper-left corner) is shown with ``scale = (dy, dx)`` and
``translate = (-y0 + dy/2, x0 + dx/2)``: napari puts data pixel (i, j) centre at
``translate + scale * (i, j)``, which is the world position of the pixel centre
(x0 + (j + 0.5) dx, y0 - (i + 0.5) dy). Layers of different pixel sizes in the same CRS therefore
overlay exactly. A raster in another CRS is reprojected onto the frame's grid on load.

The georeference of a layer lives in ``layer.metadata["geo"]``: ``{"crs": WKT, "transform":
(a, b, c, d, e, f), "shape": (rows, cols)}``.

Layers placed in the world without a raster grid of their own (products in their acquisition
geometry, placed by an affine fit of their tie points; footprint, facets and parallax vectors)
carry the grid of the world they were placed in as ``layer.metadata["world"]`` (same entries):
the viewer's world is the grid of its bottom-most layer holding either (``viewer_frame``), and a
product opened into an empty viewer founds a world in the UTM zone of its footprint (metres), so
that every layer shares one CRS and one unit (napari keeps its units and the scale bar).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from ..geometry.grid import FOOTPRINT_UTM, OutputGrid, crs_wkt
from ..placement import (
    reproject_onto,
    tie_point_affine,
    transform_world,
)

GEO_KEY = "geo"
#: the world grid a layer without a raster grid of its own was placed in (module doc)
WORLD_KEY = "world"
#: layer metadata: a tie-point grid in world coordinates (n_lines, n_cols, 2), moved with the
#: layer (the facets layer: the status bar names the facet under the cursor)
TIE_GRID_KEY = "tie_grid_world"


# --------------------------------------------------------------------------------------------
# Frames of the layers in a viewer
# --------------------------------------------------------------------------------------------
def layer_frame(layer: Any) -> OutputGrid | None:
    """The grid of a geocoded layer (from ``metadata["geo"]``), else None."""
    geo = getattr(layer, "metadata", {}).get(GEO_KEY)
    if not geo:
        return None
    return OutputGrid.from_transform(geo["crs"], geo["transform"], geo["shape"])


#: layer metadata: the grid a raster came on before it was reprojected into the world
REPROJECTED_KEY = "reprojected_from"


def source_frame(layer: Any) -> OutputGrid | None:
    """The grid a geocoded raster layer came on (its file's or its run's: before any
    reprojection into the viewer's world), else None: a grid other outputs can align with."""
    meta = getattr(layer, "metadata", {}) or {}
    geo = meta.get(REPROJECTED_KEY) or meta.get(GEO_KEY)
    return OutputGrid.from_transform(geo["crs"], geo["transform"], geo["shape"]) if geo else None


def _world_geo(layer: Any) -> dict[str, Any] | None:
    """The grid record of the world a layer lives in: its own (``metadata["geo"]``) or the one
    it was placed in (``metadata["world"]``, product and geometry layers); None if neither."""
    meta = getattr(layer, "metadata", {})
    return meta.get(GEO_KEY) or meta.get(WORLD_KEY) or None


def world_frame(layer: Any) -> OutputGrid | None:
    """The world grid a layer lives in (``_world_geo``); None for a foreign layer."""
    geo = _world_geo(layer)
    return OutputGrid.from_transform(geo["crs"], geo["transform"], geo["shape"]) if geo else None


def world_crs(layer: Any) -> Any:
    """The CRS of the world a layer lives in (``world_frame``'s, without building the grid);
    None for a foreign layer."""
    geo = _world_geo(layer)
    return geo["crs"] if geo else None


def current_viewer() -> Any:
    """napari's current viewer; None without one (no Qt application: plain reading)."""
    try:
        import napari

        return napari.current_viewer()
    except Exception:  # no Qt application
        return None


def viewer_frame(layers: Iterable[Any]) -> OutputGrid | None:
    """The world frame of a viewer: the world grid of its first (bottom-most) layer in one."""
    for layer in layers:
        frame = world_frame(layer)
        if frame is not None:
            return frame
    return None


def product_world(product: Any, frame: OutputGrid | None) -> tuple[np.ndarray, float, OutputGrid]:
    """Where a product-geometry layer goes: the affine fit of its tie points into the world
    ``frame`` (``tie_point_affine``), its RMS error (CRS units) and the world grid; without a
    world yet, the product's default grid (``ortho.product_grid``, section 3.1) in the UTM zone
    of its footprint founds it."""
    if frame is None:
        from ..ortho import product_grid

        frame = product_grid(product, FOOTPRINT_UTM)
    affine, rms = tie_point_affine(product.tie_points, product.lines_per_tie_point,
                                   product.samples_per_tie_point, frame.crs)
    return affine, rms, frame


def layer_scale(frame: OutputGrid) -> tuple[float, float]:
    """napari ``scale`` of a layer on this grid."""
    return (frame.dy, frame.dx)


def layer_translate(frame: OutputGrid) -> tuple[float, float]:
    """napari ``translate``: world position of the centre of pixel (0, 0)."""
    return (-frame.y0 + 0.5 * frame.dy, frame.x0 + 0.5 * frame.dx)


def geo_metadata(frame: OutputGrid) -> dict[str, Any]:
    """The ``layer.metadata["geo"]`` entry of a layer on this grid: CRS WKT, the rasterio
    transform as a 6-tuple and (rows, cols)."""
    return {"crs": frame.crs.to_wkt(), "transform": tuple(frame.transform)[:6],
            "shape": (frame.height, frame.width)}


def world_axes(crs: Any) -> dict[str, Any]:
    """napari ``units`` and ``axis_labels`` of the world frame of ``crs``: metres (the scale bar
    then reads m/km) or degrees; world y is minus the northing (module doc)."""
    from pyproj import CRS

    if CRS.from_user_input(crs_wkt(crs)).is_geographic:
        return {"units": ("degree", "degree"), "axis_labels": ("-latitude", "longitude")}
    return {"units": ("m", "m"), "axis_labels": ("-northing", "easting")}


def geo_image_kwargs(frame: OutputGrid, **extra: Any) -> dict[str, Any]:
    """napari layer kwargs placing an image of ``frame`` in the world frame (see module doc)."""
    metadata = dict(extra.pop("metadata", {}) or {})
    metadata[GEO_KEY] = geo_metadata(frame)
    return {"scale": layer_scale(frame), "translate": layer_translate(frame),
            "metadata": metadata, **world_axes(frame.crs), **extra}


def move_to_frame(layer: tuple[Any, dict, str], source: OutputGrid, target: OutputGrid
                  ) -> tuple[Any, dict, str]:
    """A layer tuple built on ``source`` placed in the world frame ``target``.

    Rasters (images, labels) are reprojected onto the target grid (nearest for labels and
    integer images, bilinear otherwise); shapes and vectors have their vertices projected.
    """
    data, kwargs, kind = layer
    kwargs = dict(kwargs)
    if kind in ("image", "labels"):
        rgb = bool(kwargs.get("rgb"))
        arr = np.moveaxis(np.asarray(data), -1, 0) if rgb else np.asarray(data)
        nearest = kind == "labels" or arr.dtype.kind in "iu" and not rgb
        out = reproject_onto(arr, source, target, nearest=nearest)
        if rgb:
            out = np.moveaxis(out, 0, -1).astype(np.asarray(data).dtype)
        meta = dict(kwargs.pop("metadata", {}) or {})
        meta[REPROJECTED_KEY] = geo_metadata(source)
        kwargs.update(geo_image_kwargs(target, metadata=meta))
        return out, kwargs, kind
    kwargs.update(world_axes(target.crs))
    kwargs["metadata"] = {**(kwargs.get("metadata") or {}), WORLD_KEY: geo_metadata(target)}
    if kind == "shapes":
        moved = [transform_world(p, source.crs, target.crs) for p in data]
        _rescale_width(kwargs, np.concatenate(data), np.concatenate(moved))
        return moved, kwargs, kind
    if kind == "vectors":
        vec = np.asarray(data, np.float64)
        start = transform_world(vec[:, 0], source.crs, target.crs)
        end = transform_world(vec[:, 0] + vec[:, 1], source.crs, target.crs)
        _rescale_width(kwargs, vec[:, 0], start)
        grid = kwargs["metadata"].get(TIE_GRID_KEY)
        if grid is not None:
            grid = np.asarray(grid, np.float64)
            ties = transform_world(grid.reshape(-1, 2), source.crs, target.crs)
            kwargs["metadata"][TIE_GRID_KEY] = ties.reshape(grid.shape)
        return np.stack([start, end - start], axis=1), kwargs, kind
    return layer


def _rescale_width(kwargs: dict[str, Any], before: np.ndarray, after: np.ndarray) -> None:
    """Edge width of moved shapes/vectors in the target world's units (degrees -> metres and
    back): scaled as the extent of their vertices."""
    if "edge_width" not in kwargs or len(before) < 2:
        return
    extent_before = float(np.ptp(np.asarray(before).reshape(-1, 2), axis=0).max())
    extent_after = float(np.ptp(np.asarray(after).reshape(-1, 2), axis=0).max())
    if extent_before > 0 and np.isfinite(extent_after):
        kwargs["edge_width"] = float(kwargs["edge_width"]) * extent_after / extent_before

"""Placement in the world of the napari front end (its conventions: ``_napari.world``): rasters
reprojected by GDAL's warp onto a grid's pixels that cover them, positions of a CRS as world
(row, column) = (-y, x), a product placed by an affine fit of its tie points. No Qt, no napari:
the readers, the sample data and the Flicker widget's disparity use it off the Qt thread."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import OptionsError
from .geometry.grid import OutputGrid, crs_wkt, lonlat_to_crs

#: how much bigger than the frame and the raster a raster reprojected into the world's
#: pixels may get (a world-wide raster opened over a 260 m frame: the frame's extent instead)
COVER_LIMIT = 4


def reproject_onto(data: np.ndarray, source: OutputGrid, target: OutputGrid, *,
                   nearest: bool = False, nodata: float = 0.0) -> np.ndarray:
    """Reproject a (rows, cols) or (bands, rows, cols) raster onto ``target``'s grid (rasterio)."""
    return warp(data, Warp.between(source, target), nearest=nearest, nodata=nodata)


@dataclass(frozen=True)
class Warp:
    """What GDAL's warp needs of two grids, as plain values (affine transforms, WKT, shape):
    ``warp`` then makes no pyproj object, so that it runs in any thread (a pyproj CRS used in a
    pooled Qt thread crashes inside PROJ: ``_napari._qt.waiting.ThreadCall``)."""

    src_transform: Any
    src_wkt: str
    dst_transform: Any
    dst_wkt: str
    shape: tuple[int, int]

    @classmethod
    def between(cls, source: OutputGrid, target: OutputGrid) -> Warp:
        return cls(source.transform, crs_wkt(source.crs), target.transform, crs_wkt(target.crs),
                   (target.height, target.width))


def warp(data: np.ndarray, grids: Warp, *, nearest: bool = False, nodata: float = 0.0
         ) -> np.ndarray:
    """``reproject_onto`` of ``grids`` (``Warp``): bilinear, or nearest for integers and when
    ``nearest``; ``nodata`` left out of the source and filled where it covers nothing."""
    from rasterio.crs import CRS as RioCRS
    from rasterio.warp import Resampling, reproject

    arr = np.asarray(data)
    squeeze = arr.ndim == 2
    src = arr[None] if squeeze else arr
    dtype = src.dtype if src.dtype.kind in "fiu" and src.dtype.itemsize <= 8 else np.float32
    out = np.full((src.shape[0], *grids.shape), nodata, dtype=dtype)
    method = Resampling.nearest if nearest or src.dtype.kind in "iu" else Resampling.bilinear
    for k in range(src.shape[0]):
        reproject(
            np.ascontiguousarray(src[k], dtype=dtype), out[k],
            src_transform=grids.src_transform, src_crs=RioCRS.from_wkt(grids.src_wkt),
            dst_transform=grids.dst_transform, dst_crs=RioCRS.from_wkt(grids.dst_wkt),
            resampling=method, src_nodata=nodata, dst_nodata=nodata,
            num_threads=os.cpu_count() or 1,  # GDAL's warp on every core
        )
    return out[0] if squeeze else out


def place_on_frame(data: np.ndarray, source: OutputGrid, frame: OutputGrid | None,
                   *, nearest: bool = False, nodata: float = 0.0
                   ) -> tuple[np.ndarray, OutputGrid]:
    """Data and grid of a raster placed in the world frame.

    Same CRS and pixel size: kept as is (scale/translate place it). Another CRS or pixel size:
    reprojected onto the frame's pixels that cover it (``OutputGrid.lattice_cover``: the whole
    raster, also beyond the frame's extent; the frame's own extent when that cover would be
    more than ``COVER_LIMIT`` times the frame's and the raster's pixels); ``nodata``: the value
    of its no-data pixels, and of the pixels it does not cover. Both geographic: the raster's
    longitudes are taken on the frame's side (190..193 beside a frame at -170: -170..-167).
    """
    if frame is None or source.same_grid(frame):
        return data, source
    if frame.is_geographic and source.is_geographic:
        apart = sum(frame.bounds[::2]) / 2 - sum(source.bounds[::2]) / 2
        turns = round(apart / 360.0)
        if turns:
            source = OutputGrid(source.crs, source.x0 + 360.0 * turns, source.y0, source.dx,
                                source.dy, source.width, source.height)
    try:
        target = frame.lattice_cover(source)
    except OptionsError:  # no finite extent in the frame's CRS (a polar raster in UTM...)
        target = frame
    limit = COVER_LIMIT * max(frame.width * frame.height, source.width * source.height)
    if target.width * target.height > limit:
        target = frame
    return reproject_onto(data, source, target, nearest=nearest, nodata=nodata), target


# ------------------------------------------------------------------ positions in the world
def to_world(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """CRS (x, y) -> napari world (row, col) = (-y, x), shape (..., 2)."""
    return np.stack([-np.asarray(y, dtype=np.float64), np.asarray(x, dtype=np.float64)], axis=-1)


def from_world(world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """napari world (row, col) -> CRS (x, y)."""
    world = np.asarray(world, dtype=np.float64)
    return world[..., 1], -world[..., 0]


def tie_point_affine(tie_points: Mapping[str, np.ndarray], lines_per_tie_point: int,
                     samples_per_tie_point: int, crs: Any) -> tuple[np.ndarray, float]:
    """The affine map (3 x 3, napari ``affine``) from product (line, column) to the world frame
    of ``crs`` fitted by least squares to the tie points (pixel (i DF, k DJ), section 2.3),
    and its RMS error in CRS units: an approximate placement of a product-geometry layer."""
    lat, lon = tie_points["latitude"], tie_points["longitude"]
    i, k = np.mgrid[0:lat.shape[0], 0:lat.shape[1]].astype(np.float64)
    x, y = lonlat_to_crs(lon, lat, crs)
    world = to_world(x, y).reshape(-1, 2)
    design = np.column_stack([(i * lines_per_tie_point).ravel(),
                              (k * samples_per_tie_point).ravel(), np.ones(i.size)])
    coef, *_ = np.linalg.lstsq(design, world, rcond=None)
    rms = float(np.sqrt(np.mean(np.sum((design @ coef - world) ** 2, axis=1))))
    affine = np.eye(3)
    affine[:2, :] = coef.T
    return affine, rms


# --------------------------------------------------------------------------------------------
# Moving layers into another world frame (another CRS)
# --------------------------------------------------------------------------------------------


def transform_world(points: np.ndarray, source_crs: Any, target_crs: Any) -> np.ndarray:
    """World (row, col) points of ``source_crs`` -> world points of ``target_crs``."""
    from pyproj import Transformer

    x, y = from_world(points)
    tr = Transformer.from_crs(crs_wkt(source_crs), crs_wkt(target_crs), always_xy=True)
    tx, ty = tr.transform(x, y)
    return to_world(np.asarray(tx), np.asarray(ty))

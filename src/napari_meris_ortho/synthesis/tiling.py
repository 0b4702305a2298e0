"""Grid and tile arithmetic of a synthesis (section 3.1): the grid of a new synthesis and its size
check, the footprint window a product may reach (terrain margin), tiles aligned on the store's
chunks."""

from __future__ import annotations

import math
import shutil
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import OptionsError
from .store import CHUNK, Window

if TYPE_CHECKING:
    from ..geometry.grid import OutputGrid
    from ..geometry.tiepoints import ProductGeometry
BLOCK = 256  # tiles are multiples of it
DEFAULT_TILE = 1024
#: terrain parallax a tile must be within to be orthorectified: ``geometry.earth.MAX_TERRAIN_M``
#: seen at 45 deg view zenith or the product's largest one if larger (section 3.1)
SKIP_VIEW_ZENITH_DEG = 45.0
#: full-resolution chunks per layer of a new synthesis grid, at most, unless ``max_pixels`` is
#: given: 65 536 chunks of 512 x 512 pixels are 1.7e10 pixels (the world at 300 m, Europe at
#: 60 m); every reader walks that chunk grid (xarray's and napari's dask arrays, ``export``)
MAX_GRID_CHUNKS = 2**16


# --------------------------------------------------------------------------- grid helpers


def grid_to_dict(grid: OutputGrid) -> dict[str, Any]:
    """The output grid as JSON-able values (CRS as WKT)."""
    from ..geometry.grid import parse_crs

    return {"crs": parse_crs(grid.crs).to_wkt(), "x0": float(grid.x0),
            "y0": float(grid.y0), "dx": float(grid.dx), "dy": float(grid.dy),
            "width": int(grid.width), "height": int(grid.height)}


def grid_from_dict(values: dict[str, Any]) -> OutputGrid:
    """Rebuild an ``geometry.grid.OutputGrid`` from :func:`grid_to_dict` values."""
    from ..geometry.grid import OutputGrid

    return OutputGrid(values["crs"], values["x0"], values["y0"], values["dx"], values["dy"],
                      int(values["width"]), int(values["height"]))


def terrain_margin_px(product: ProductGeometry, grid: OutputGrid) -> int:
    """Output pixels beyond the zero-height segment boundary that a terrain point of the
    product may reach: ``geometry.earth.MAX_TERRAIN_M`` x tan(max(45 deg, largest view
    zenith)), + 2."""
    from ..geometry.grid import terrain_margin_px as margin_px

    tp = product.tie_points
    zenith = max(SKIP_VIEW_ZENITH_DEG, float(np.nanmax(tp["view_zenith"])))
    return margin_px(grid, zenith, float(np.nanmax(np.abs(tp["latitude"]))))


def footprint_window(product: ProductGeometry, grid: OutputGrid, margin: int | None = None
                     ) -> tuple[int, int, int, int] | None:
    """Rows/columns ``(row0, row1, col0, col1)`` of ``grid`` that the product may reach: its
    tie points widened by ``margin`` pixels (default ``terrain_margin_px``); None when
    disjoint."""
    tp = product.tie_points
    lat = np.asarray(tp["latitude"], dtype=np.float64).ravel()
    lon = np.asarray(tp["longitude"], dtype=np.float64).ravel()
    rows, cols = grid.xy_of_lonlat(lon, lat)
    ok = np.isfinite(rows) & np.isfinite(cols)
    if not ok.any():
        return None
    rows, cols = rows[ok], cols[ok]
    margin = terrain_margin_px(product, grid) if margin is None else int(margin)
    row0 = max(0, int(np.floor(rows.min() - margin)))
    row1 = min(grid.height, int(np.ceil(rows.max() + margin)) + 1)
    col0 = max(0, int(np.floor(cols.min() - margin)))
    col1 = min(grid.width, int(np.ceil(cols.max() + margin)) + 1)
    if row0 >= row1 or col0 >= col1:
        return None
    return row0, row1, col0, col1


def tiles(window: tuple[int, int, int, int], tile: int) -> Iterator[tuple[int, int, int, int]]:
    """Tiles of ``tile`` x ``tile`` pixels aligned on multiples of ``tile`` covering ``window``
    (each clipped to ``window``)."""
    row0, row1, col0, col1 = window
    for r in range((row0 // tile) * tile, row1, tile):
        for c in range((col0 // tile) * tile, col1, tile):
            yield max(r, row0), min(r + tile, row1), max(c, col0), min(c + tile, col1)


def products_window(grid: OutputGrid, products: Iterable[ProductGeometry]) -> Window:
    """Rows and columns of ``grid`` that ``products`` may reach: the union of their
    :func:`footprint_window` (terrain margin included); the whole grid when none does."""
    windows = [w for w in (footprint_window(p, grid) for p in products) if w is not None]
    if not windows:
        return (0, grid.height, 0, grid.width)
    return (min(w[0] for w in windows), max(w[1] for w in windows),
            min(w[2] for w in windows), max(w[3] for w in windows))


def tile_of(piece: tuple[int, int, int, int], tile: int, shape: tuple[int, int]
            ) -> tuple[int, int, int, int]:
    """The whole output tile (one chunk of the store) holding ``piece``."""
    r, c = (piece[0] // tile) * tile, (piece[2] // tile) * tile
    return r, min(r + tile, shape[0]), c, min(c + tile, shape[1])


def stored_bytes_per_pixel(n_bands: int, band_bytes: int = 2) -> float:
    """Bytes one grid pixel of a store's layers takes uncompressed, overviews (a third more)
    included: each band (uint16 counts; 4 in stores of version 2, float32), NDVI and count
    (uint16), the product index (int32). An upper bound of what a write costs."""
    return (band_bytes * n_bands + 8) * 4.0 / 3.0


def check_new_grid_size(grid: OutputGrid, n_bands: int, max_pixels: int | None) -> None:
    """A new synthesis grid: at most ``max_pixels``, else :data:`MAX_GRID_CHUNKS` chunks of
    ``store.CHUNK`` pixels square per layer. A store holds the chunks its products wrote, not its
    extent (a Europe-size store is as big as what was merged into it; the free space is
    checked per run, :func:`check_write_size`), but every reader walks the chunk grid."""
    from ..geometry.grid import check_grid_size

    per_pixel = stored_bytes_per_pixel(n_bands)  # the limit, in pixels, is max_pixels if given
    check_grid_size(grid.width, grid.height, (grid.dx, grid.dy), per_pixel, max_pixels,
                    math.ceil(MAX_GRID_CHUNKS * CHUNK * CHUNK * per_pixel),
                    f"{MAX_GRID_CHUNKS} chunks of {CHUNK} x {CHUNK} pixels per layer")


def check_write_size(windows: Iterable[Window], n_bands: int, out_dir: Path,
                     max_pixels: int | None, band_bytes: int = 2,
                     free: int | None = None) -> None:
    """The tiles a run writes (``windows``), uncompressed (:func:`stored_bytes_per_pixel`),
    must fit the free space of the store's file system (``free``: measured when None), so
    that a run too big for the disk stops before it starts rather than when the disk is full.
    Not checked when ``max_pixels`` is given (the user sets the limits)."""
    if max_pixels is not None:
        return
    pixels = sum((r1 - r0) * (c1 - c0) for r0, r1, c0, c1 in windows)
    need = pixels * stored_bytes_per_pixel(n_bands, band_bytes)
    parent = out_dir if out_dir.exists() else out_dir.absolute().parent
    if free is None:
        try:
            free = shutil.disk_usage(parent).free
        except OSError:
            return
    if need <= free:
        return
    from ..geometry.grid import size_text

    raise OptionsError(
        f"the products cover {pixels:.3g} pixels of the synthesis grid (whole tiles): up to "
        f"{size_text(need)} to write, uncompressed, and {size_text(free)} free in {parent}: "
        "free some space (a new synthesis: or use a larger pixel size), or give a pixel limit "
        "(max_pixels; the command line's --max-pixels) to run anyway")

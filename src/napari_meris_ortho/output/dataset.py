"""Results as ``xarray.Dataset``: the form in which xarray, rioxarray, dask and satpy users work.

``grid_dataset(grid, variables, bands=, wavelengths=)`` puts arrays (numpy or dask) of an
``OutputGrid`` into a Dataset: ``x``/``y`` coordinates of the pixel centres (ARCHITECTURE.md
conventions: (x0 + (j + 0.5) dx, y0 - (i + 0.5) dy)), a ``band`` dimension (MERIS band numbers)
with the central ``wavelength`` (nm) as a coordinate, and the CRS as a CF grid mapping (CF 1.8
section 5.6): a scalar ``spatial_ref`` variable with the CF attributes of the CRS, its WKT as
``crs_wkt`` and ``spatial_ref`` and the GDAL ``GeoTransform``, named by every variable's
``grid_mapping``, as rioxarray writes and reads it (``ds.rio.crs``, ``ds.rio.transform()``).

xarray is an optional dependency (extra ``xarray``); ``require_xarray`` imports it or raises
``MissingDependencyError`` with the command that installs it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..errors import MissingDependencyError
from ..geometry.grid import OutputGrid

#: the name of the grid-mapping variable (rioxarray's default)
GRID_MAPPING = "spatial_ref"
#: what installs the optional dependency
INSTALL_HINT = "pip install 'napari-meris-ortho[xarray]' (or: conda install xarray rioxarray)"

#: one variable: (dimensions, values, attributes)
Variable = tuple[tuple[str, ...], Any, Mapping[str, Any]]


def require_xarray() -> Any:
    """The ``xarray`` module, or MissingDependencyError saying how to install it."""
    try:
        import xarray
    except ImportError:
        raise MissingDependencyError(f"results as xarray Datasets need xarray: "
                                     f"{INSTALL_HINT}") from None
    return xarray


def pixel_centres(grid: OutputGrid) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of the pixel centres of ``grid``: x0 + (j + 0.5) dx, y0 - (i + 0.5) dy."""
    x = grid.x0 + (np.arange(grid.width) + 0.5) * grid.dx
    y = grid.y0 - (np.arange(grid.height) + 0.5) * grid.dy
    return x, y


def grid_mapping_attrs(grid: OutputGrid) -> dict[str, Any]:
    """CF grid-mapping attributes of ``grid``'s CRS (pyproj ``to_cf``) with ``crs_wkt``,
    ``spatial_ref`` (WKT, for GDAL) and ``GeoTransform`` (GDAL order: x0 dx 0 y0 0 -dy)."""
    wkt = grid.crs.to_wkt()
    try:
        cf = dict(grid.crs.to_cf())
    except Exception:  # pyproj: a CRS with no CF form keeps its WKT only
        cf = {}
    transform = (grid.x0, grid.dx, 0.0, grid.y0, 0.0, -grid.dy)
    return {**cf, "crs_wkt": wkt, "spatial_ref": wkt,
            "GeoTransform": " ".join(repr(float(v)) for v in transform)}


def _axis_attrs(grid: OutputGrid) -> dict[str, dict[str, Any]]:
    """CF attributes of the x and y coordinates (pyproj ``cs_to_cf``), by axis."""
    out: dict[str, dict[str, Any]] = {"X": {}, "Y": {}}
    try:
        for attrs in grid.crs.cs_to_cf():
            if attrs.get("axis") in out:
                out[attrs["axis"]] = dict(attrs)
    except Exception:  # pyproj: no CF form of the axes
        pass
    return out


def grid_dataset(grid: OutputGrid, variables: Mapping[str, Variable], *,
                 bands: Sequence[int] = (), wavelengths: Sequence[float | None] = (),
                 attrs: Mapping[str, Any] | None = None, band_names: Sequence[str] = (),
                 band_label: str = "MERIS band") -> Any:
    """An ``xarray.Dataset`` of ``variables`` (dimensions among ``band``, ``y``, ``x``) on
    ``grid``, with the coordinates and grid mapping of the module docstring; ``bands`` and
    ``wavelengths`` (nm; None: unknown, NaN) label the ``band`` dimension, ``band_label`` its
    numbers ("OLCI band"), and ``band_names`` (``M07``, ``Oa08``; optional) a
    ``band_name`` coordinate."""
    xr = require_xarray()
    x, y = pixel_centres(grid)
    axes = _axis_attrs(grid)
    coords: dict[str, Any] = {
        "x": ("x", x, axes["X"]), "y": ("y", y, axes["Y"]),
        GRID_MAPPING: ((), np.int64(0), grid_mapping_attrs(grid)),
    }
    if bands:
        coords["band"] = ("band", np.asarray(bands, np.int64), {"long_name": band_label})
        if band_names:
            coords["band_name"] = ("band", np.asarray(list(band_names), str),
                                   {"long_name": "band name"})
        wl = [np.nan if w is None else float(w) for w in wavelengths] or [np.nan] * len(bands)
        coords["wavelength"] = ("band", np.asarray(wl, np.float64),
                                {"long_name": "central wavelength", "units": "nm"})
    data_vars = {name: (dims, values, {**var_attrs, "grid_mapping": GRID_MAPPING})
                 for name, (dims, values, var_attrs) in variables.items()}
    return xr.Dataset(data_vars, coords=coords, attrs=dict(attrs or {}))

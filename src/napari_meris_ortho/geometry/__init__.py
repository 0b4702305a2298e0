"""Shared geometry (numpy and pyproj only): the figures of the Earth, CRS parsing, the output
grid and the tie-point grid. ``io``, ``engine``, ``ortho``, ``synthesis`` and the front ends stand
on it; it imports nothing of the package but ``errors``."""

from __future__ import annotations

from .earth import MEAN_EARTH_RADIUS, WGS84_A, WGS84_B, WGS84_E2, WGS84_F
from .grid import (
    FR_PIXEL_SIZE_M,
    RR_PIXEL_SIZE_M,
    OutputGrid,
    default_grid,
    parse_crs,
    pixel_size_for,
    utm_crs_for,
)
from .tiepoints import TiePointGrid

__all__ = ["FR_PIXEL_SIZE_M", "MEAN_EARTH_RADIUS", "RR_PIXEL_SIZE_M", "WGS84_A", "WGS84_B",
           "WGS84_E2", "WGS84_F", "OutputGrid", "TiePointGrid", "default_grid", "parse_crs",
           "pixel_size_for", "utm_crs_for"]

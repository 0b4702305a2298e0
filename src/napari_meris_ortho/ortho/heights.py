"""Heights of the output points from the DEMs tried in order (handbook section 3.1 "Digital
elevation data", Appendix C ``TimMersynGetAltitudeFromDem``).

The walk over the DEMs is ``dem.stack.DemStack.walk`` (the one walk of the package); this
module gives it the compiled lookup (``engine.terrain``) in the lattice windows the DEMs read
into memory once (``DemStack.prepare``), with the geoid undulation N of EGM96 heights computed
once per block of points.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..engine import terrain
from .stats import SOURCE_TIEPOINTS

if TYPE_CHECKING:
    from ..dem.base import LatticeWindow
    from ..dem.stack import DemStack


def dem_heights(stack: DemStack, lon: np.ndarray, lat: np.ndarray, mask: np.ndarray,
                method: str = "bilinear") -> tuple[np.ndarray, np.ndarray]:
    """DEM heights (float32) at the output points in ``mask`` and the index of the DEM that
    gave each (int8); NaN and ``SOURCE_TIEPOINTS`` elsewhere or without data (the caller falls
    back to the tie points)."""
    h = np.full(lon.shape, np.nan, np.float32)
    src = np.full(lon.shape, SOURCE_TIEPOINTS, np.int8)
    flon = np.ascontiguousarray(lon, dtype=np.float64).reshape(-1)
    flat = np.ascontiguousarray(lat, dtype=np.float64).reshape(-1)
    todo = np.array(mask, dtype=bool, copy=True).reshape(-1)
    lookup = _CompiledLookup(method)
    stack.walk(flon, flat, todo, h.reshape(-1), src.reshape(-1), method,
               window_lookup=lookup)
    return h, src


class _CompiledLookup:
    """``engine.terrain.window_heights`` at the ``todo`` points of a lattice window: DEM x/y by
    the window's transformation (projected DEMs), geoid N for EGM96 heights (``dem.geoid``),
    kept by datum for the DEMs and lattices after this one (the points left only shrink)."""

    def __init__(self, method: str) -> None:
        self.code = terrain.METHOD_CODES[method]
        self.geoid: dict[str, np.ndarray] = {}

    def __call__(self, window: LatticeWindow, index: int, lon: np.ndarray, lat: np.ndarray,
                 todo: np.ndarray, h: np.ndarray, src: np.ndarray, miss: np.ndarray) -> int:
        x, y = lon, lat
        if window.transform is not None:
            sel = np.flatnonzero(todo)
            x, y = np.empty_like(lon), np.empty_like(lat)
            x[sel], y[sel] = window.transform(lon[sel], lat[sel])
        undulation = np.empty(0)
        if window.datum not in (None, "ellipsoid"):
            if window.datum not in self.geoid:
                self.geoid[window.datum] = geoid_at(window.datum, lon, lat, todo)
            undulation = self.geoid[window.datum]
        return int(terrain.window_heights(
            window.data, window.inv, window.lattice, window.wrap_centre, self.code, x, y,
            todo, undulation, index, h, src, miss))


def geoid_at(datum: str, lon: np.ndarray, lat: np.ndarray, todo: np.ndarray) -> np.ndarray:
    """Geoid undulation N of ``datum`` at the ``todo`` points (flat arrays): EGM96 or EGM2008
    by the compiled bilinear between the grid nodes under them (``dem.geoid.nodes_between``,
    ``engine.terrain.geoid_bilinear``: ``dem.geoid.geoid_undulation``'s numbers)."""
    from ..dem.geoid import GEOIDS, grid_step, last_row, node_indices, nodes_between, to_ellipsoid

    out = np.full(lon.shape, np.nan)
    sel = np.flatnonzero(todo)
    if sel.size == 0:
        return out
    if datum not in GEOIDS:  # (no such geoid: one message for an unknown datum)
        out[sel] = to_ellipsoid(np.zeros(sel.size), lon[sel], lat[sel], datum)
        return out
    # the nodes under every point with a position (a few more than under the todo ones: no
    # copies of the points); points without one (NaN, |lat| > 90) get NaN from the kernel
    la0 = np.fmax(np.fmin.reduce(lat), -90.0)  # fmin/fmax: NaN skipped (all NaN: NaN)
    la1 = np.fmin(np.fmax.reduce(lat), 90.0)
    lo0, lo1 = np.fmin.reduce(lon), np.fmax.reduce(lon)
    if not (np.isfinite(lo0) and la0 <= la1):
        return out
    if lo0 < -180.0 or lo1 >= 180.0:
        lon = (lon + 180.0) % 360.0 - 180.0
        lo0, lo1 = np.fmin.reduce(lon), np.fmax.reduce(lon)
    i, j = node_indices(np.array([lo0, lo1]), np.array([la0, la1]), datum)
    nodes = nodes_between(int(i[0]), int(i[1]) + 1, int(j[0]), int(j[1]) + 1, datum)
    terrain.geoid_bilinear(nodes, int(i[0]), int(j[0]), grid_step(datum), lon, lat, todo, out,
                           last_row(datum))
    return out

"""Ground hidden from the sensor by the relief, for the pixel geolocation with DEMs (issue 22,
item 8): such an output point has no antecedent (the pixel whose line of sight passes through
it shows the ridge in front), so it is reported ``OCCLUDED`` and left no data.

An output point T (lon, lat) at the DEM height h is seen when no terrain rises above its line
of sight towards the satellite. The ray leaves T along the view azimuth va of the tie points
at T's antecedent (look vector (tan vz sin va, tan vz cos va), eq. 5a-5b, as the parallax of
eq. 6a uses it); at a ground distance d its height above the ellipsoid is
h + d / tan vz + d^2 / (2 R) (the Earth's surface drops below the tangent plane; R the mean
radius). Two marches sample the terrain from the DEM stack of the run
(``ortho.heights.dem_heights``: the same DEMs tried in order, so the same heights as the
output points got; where no DEM has data the ray goes on): every eighth of a DEM post with
``MARGIN_M`` of slack, which finds the candidates, then every 32nd of a post for them;
each stops once the ray is above the highest post of the DEMs. T is hidden where the terrain
is more than ``TOLERANCE_M`` above the ray: ground just below a crest, whose ray grazes it,
stays seen.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ..engine.pixeldem import look_vectors
from ..geometry.earth import MAX_TERRAIN_M, MEAN_EARTH_RADIUS
from .heights import dem_heights

if TYPE_CHECKING:
    from ..dem.stack import DemStack

#: terrain above the line of sight by more than this (m) hides a point
TOLERANCE_M = 1.0
#: first march's step as a fraction of the finest DEM post (fr-steep, 30" posts: one march
#: every half post finds 73 % of the hidden ground, its ridges rise between the samples)
STEP_OF_POST = 0.125
#: slack (m) of the first march: a point whose ray passes less than this above the sampled
#: terrain is a candidate (the terrain between two samples may rise above them)
MARGIN_M = 50.0
#: the second march (the candidates) steps by the first's step divided by this
FINE = 4
#: first march's step (m) when no DEM gives its post spacing (a lattice read lazily): an
#: eighth of a 30" post
DEFAULT_STEP_M = 115.0


def ceiling_and_step(stack: DemStack, lat: float) -> tuple[float, float]:
    """The highest post of the DEMs' prepared windows (MAX_TERRAIN_M when a DEM has none) and
    the march step (m): ``STEP_OF_POST`` of the finest post spacing at latitude ``lat``."""
    top, post = -math.inf, math.inf
    for dem in stack.sources:
        for part, _ in dem.parts():
            window = part.lattice_window()
            if window is None:
                top = MAX_TERRAIN_M
                continue
            if window.data.size and np.isfinite(window.data).any():
                top = max(top, float(np.nanmax(window.data)))
            a, e = abs(window.inv[0]), abs(window.inv[4])  # posts per unit of x, of y
            if window.transform is None:  # degrees
                metres = math.radians(1.0) * MEAN_EARTH_RADIUS
                post = min(post, metres / e, metres * math.cos(math.radians(lat)) / a)
            else:  # a projected DEM: its units (metres)
                post = min(post, 1.0 / a, 1.0 / e)
    step = STEP_OF_POST * post if math.isfinite(post) else DEFAULT_STEP_M
    return (top if math.isfinite(top) else MAX_TERRAIN_M), step


def hidden(stack: DemStack, lon: np.ndarray, lat: np.ndarray, h: np.ndarray,
           line: np.ndarray, col: np.ndarray, coef: np.ndarray, df: float, dj: float,
           ceiling: float, step: float) -> np.ndarray:
    """True where the point (``lon``, ``lat``, height ``h``; flat) with the antecedent
    (``line``, ``col``) is hidden by the terrain of ``stack`` (module docstring); ``coef``,
    ``df``, ``dj``: the tie-point grid's ``kernel_args``; ``ceiling``, ``step``:
    ``ceiling_and_step``. Two marches: every ``step`` with a slack of ``MARGIN_M`` finds the
    candidates, every ``step / FINE`` decides them."""
    e, n = look_vectors(np.asarray(line, np.float64), np.asarray(col, np.float64), coef,
                        float(df), float(dj))
    ray = (np.asarray(lon, np.float64), np.asarray(lat, np.float64),
           np.asarray(h, np.float64), e, n)
    maybe = np.flatnonzero(_march(stack, ray, ceiling, step, TOLERANCE_M - MARGIN_M))
    out = np.zeros(e.shape, bool)
    out[maybe] = _march(stack, tuple(a[maybe] for a in ray), ceiling, step / FINE,
                        TOLERANCE_M)
    return out


def _march(stack: DemStack, ray: tuple[np.ndarray, ...], ceiling: float, step: float,
           slack: float) -> np.ndarray:
    """True where the terrain rises more than ``slack`` above the line of sight of a point,
    ``ray`` = (lon, lat, h, look vector east, north), sampled every ``step`` metres."""
    lon, lat, h, e, n = ray
    out = np.zeros(lon.shape, bool)
    tz = np.hypot(e, n)  # tan vz
    live = np.flatnonzero((tz > 0.0) & (h + step / np.maximum(tz, 1e-12) < ceiling))
    lon, lat, h, tz = lon[live], lat[live], h[live], tz[live]
    deg = math.degrees(1.0 / MEAN_EARTH_RADIUS)
    dx = deg * e[live] / tz / np.cos(np.radians(lat))  # degrees per metre towards the sensor
    dy = deg * n[live] / tz
    d = step
    while live.size:
        height = h + d / tz + d * d / (2.0 * MEAN_EARTH_RADIUS)
        go = height < ceiling
        if not go.all():
            live, lon, lat, h, tz, dx, dy, height = (a[go] for a in (live, lon, lat, h, tz, dx,
                                                                      dy, height))
            if not live.size:
                break
        terrain, _ = dem_heights(stack, lon + d * dx, lat + d * dy, np.ones(live.size, bool))
        up = terrain > height + slack  # (NaN: no DEM there, the ray goes on)
        if up.any():
            out[live[up]] = True
            keep = ~up
            live, lon, lat, h, tz, dx, dy = (a[keep] for a in (live, lon, lat, h, tz, dx, dy))
        d += step
    return out


def report_hidden(stack: DemStack, kernel_args: tuple, lon: np.ndarray, lat: np.ndarray,
                  h: np.ndarray, res: dict, ceiling: float, step: float) -> None:
    """The antecedents in ``res`` (``pixeldem.solve_pixel_dem`` of a block of output points
    ``lon``, ``lat`` with DEM heights ``h``) of hidden ground dropped: line and column NaN,
    iterations ``OCCLUDED``, counted in its "occluded" search count. Points without a DEM
    height were located on the product's own terrain points, which report their hidden ground
    already."""
    from ..engine.pixelgeo import OCCLUDED

    iters = res["iterations"]
    test = np.flatnonzero(((iters >= 0) & np.isfinite(h)).reshape(-1))
    if test.size == 0:
        return
    _, _, coef, df, dj = kernel_args
    flat = (a.reshape(-1) for a in (lon, lat, h, res["line"], res["col"]))
    flon, flat_, fh, fline, fcol = flat
    gone = test[hidden(stack, flon[test], flat_[test], fh[test].astype(np.float64),
                       fline[test], fcol[test], coef, df, dj, ceiling, step)]
    fline[gone] = np.nan
    fcol[gone] = np.nan
    iters.reshape(-1)[gone] = OCCLUDED
    res["search"]["occluded"] = res["search"].get("occluded", 0) + int(gone.size)

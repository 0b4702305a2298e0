"""Ground hidden from the sensor by the relief, in every mode with DEMs (tie-point geolocation,
both parallax models and searches; pixel geolocation): such an output point has no true
antecedent (the pixel whose line of sight passes through it shows the ridge in front: mapped,
the ridge appears twice), so with hidden ``mask`` it is reported ``OCCLUDED`` and left no
data, with ``keep`` mapped as MERSYN maps it; in both it is in the hidden-ground mask.

An output point T (lon, lat) at the DEM height h is seen when no terrain rises above its line
of sight towards the satellite. The ray leaves T along the view azimuth va of the tie points
at T's antecedent (look vector (tan vz sin va, tan vz cos va), eq. 5a-5b, as the parallax of
eq. 6a uses it); at a ground distance d its height above the ellipsoid is
h + d / tan vz + d^2 / (2 R) (the Earth's surface drops below the tangent plane; R the mean
radius). T is hidden where the terrain rises more than ``TOLERANCE_M`` above the ray: ground
just below a crest, whose ray grazes it, stays seen. The terrain is the DEM stack of the run,
the same heights as the output points got: the stack's first lattice read into memory
(geographic, EGM96 heights made ellipsoidal once; or projected with ellipsoidal heights, along
each point's projected track) is marched by ``engine.sightline`` (cell by cell, the maximum of
terrain minus ray in each cell exact, tiles' maxima to jump); other DEMs, and rays leaving that
window or reaching a cell without data there when DEMs follow, by two marches of
``ortho.heights.dem_heights`` (the DEMs tried in order; where none has data the ray
goes on): every eighth of a DEM post with ``MARGIN_M`` of slack finds the candidates, every
32nd of a post decides them (fr-steep: 97.8 % of the hidden ground found, none seen lost).
Both stop once the ray is above the highest post of the DEMs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from ..engine import sightline
from ..engine.pixeldem import look_vectors
from ..engine.pixelgeo import OCCLUDED
from ..geometry.earth import MAX_TERRAIN_M, MEAN_EARTH_RADIUS, MIN_TERRAIN_M
from .heights import dem_heights, geoid_at

if TYPE_CHECKING:
    from ..dem.base import LatticeWindow
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
#: bound (m) of the geoid undulation |N| (EGM96: -107 .. +86 m): the ceiling of heights above
#: the geoid of a projected DEM (its posts' N not computed)
GEOID_BOUND_M = 110.0
#: chord (m) of the line of sight whose projection gives a projected DEM's track
TRACK_M = 1000.0
#: metres per degree of latitude on the mean sphere
_DEGREE_M = math.radians(1.0) * MEAN_EARTH_RADIUS


@dataclass
class Sightlines:
    """What the marches of a run need, once: the ceiling (the highest post of the DEMs'
    prepared windows; MAX_TERRAIN_M when a DEM has none), the first march's ``step`` (m) and,
    for a stack of one geographic ellipsoidal lattice in memory, its window and its shortest
    post (m) for ``engine.sightline``, which marches there, ending each ray where the window's
    ``bound`` says it is seen or, without a bound, jumping by the tiles' maxima ``tmax``."""

    stack: DemStack
    ceiling: float
    step: float
    window: LatticeWindow | None = None
    tmax: tuple[np.ndarray, ...] = ()
    post: float = 0.0
    gaps: bool = False
    #: ``sightline.horizon_bound`` of the window (None: every point is marched): only the
    #: points ``sightline.reachable`` leaves are
    bound: np.ndarray | None = None
    #: product columns [first, last] whose lines of sight ``bound`` leaves out (near nadir:
    #: they may go either way): always marched
    near_nadir: tuple[float, float] = (math.inf, -math.inf)

    @classmethod
    def of(cls, stack: DemStack, lat: float,
           view: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float] | None = None
           ) -> Sightlines:
        """The ceiling and step of ``stack`` (``STEP_OF_POST`` of its finest post spacing at
        latitude ``lat``), the window ``engine.sightline`` marches: the first lattice of the
        stack when it is geographic, north-up and in memory, its heights made ellipsoidal
        once (posts + geoid N, ``_ellipsoidal``); with DEMs or lattices after it, a cell
        without data there ends its march (the stack marches on). ``view``: the product's
        tie-point latitude, longitude, view zenith and azimuth (deg) and the pixels between
        tie-point columns, for the bound of the terrain its lines of sight can meet
        (``_horizon``)."""
        top, post = -math.inf, math.inf
        windows = []
        for dem in stack.sources:
            for part, datum in dem.parts():
                window = part.lattice_window()
                if window is not None and not window.data.size:
                    continue  # no post within the run's bounds (an SRTM30 tile beside them)
                if window is not None and window.transform is None:
                    window = _ellipsoidal(window, datum)
                elif window is not None and datum in (None, "ellipsoid"):
                    window = replace(window, datum="ellipsoid")
                windows.append(window)
                if window is None:
                    top = MAX_TERRAIN_M
                    continue
                if np.isfinite(window.data).any():
                    high = float(np.nanmax(window.data))
                    if window.datum not in (None, "ellipsoid"):  # (projected: N not known)
                        high += GEOID_BOUND_M
                    top = max(top, high)
                a, e = abs(window.inv[0]), abs(window.inv[4])  # posts per unit of x, of y
                if window.transform is None:  # degrees
                    post = min(post, _DEGREE_M / e, _DEGREE_M * math.cos(math.radians(lat)) / a)
                else:  # a projected DEM: its units (metres)
                    post = min(post, 1.0 / a, 1.0 / e)
        out = cls(stack, top if math.isfinite(top) else MAX_TERRAIN_M,
                  STEP_OF_POST * post if math.isfinite(post) else DEFAULT_STEP_M)
        window = windows[0] if windows else None
        if (window is not None and window.datum == "ellipsoid" and window.inv[1] == 0.0
                and window.inv[3] == 0.0):
            if window.transform is None:
                # the shortest post (m) anywhere in the window: its latitude furthest from 0
                rows = window.lattice[0] + np.array([0.0, window.data.shape[0]])
                lats = (rows - window.inv[5]) / window.inv[4]
                cos = math.cos(math.radians(min(float(np.max(np.abs(lats))), 89.0)))
                shortest = min(_DEGREE_M / abs(window.inv[4]),
                               _DEGREE_M * cos / abs(window.inv[0]))
            else:  # projected: its units (metres; ``hidden`` bounds it by the track's scale)
                shortest = min(1.0 / abs(window.inv[0]), 1.0 / abs(window.inv[4]))
            out.window = window
            out.gaps = len(windows) > 1
            out.post = 0.99 * shortest
            if window.transform is None and view is not None:
                horizon = _horizon(window, out.ceiling, out.gaps, view)
                if horizon is not None:
                    out.bound, out.near_nadir = horizon
            if out.bound is None:  # (else the bound ends the marches: no jumps)
                out.tmax = sightline.tile_maxima(window.data, out.gaps)
        return out

    def candidates(self, lon: np.ndarray, lat: np.ndarray, h: np.ndarray
                   ) -> np.ndarray | None:
        """Of a block of points (``lon``, ``lat`` float64, heights ``h``), those a ray must be
        marched for: terrain within its reach might rise above it (``sightline.reachable``
        on the window's ``bound``); None: every point (no bound)."""
        if self.bound is None or self.window is None:
            return None
        w = self.window
        flat = sightline.reachable(
            np.ascontiguousarray(lon, np.float64).reshape(-1),
            np.ascontiguousarray(lat, np.float64).reshape(-1),
            np.ascontiguousarray(h).reshape(-1), w.inv, w.lattice, w.wrap_centre, self.bound,
            TOLERANCE_M)
        return flat.reshape(np.shape(lon))

    def hidden(self, lon: np.ndarray, lat: np.ndarray, h: np.ndarray, line: np.ndarray,
               col: np.ndarray, coef: np.ndarray, df: float, dj: float,
               cleared: bool = False) -> np.ndarray:
        """True where the point (``lon``, ``lat``, height ``h``; flat) with the antecedent
        (``line``, ``col``) is hidden by the terrain (module docstring); ``coef``, ``df``,
        ``dj``: the tie-point grid's ``kernel_args``. In the window: ``engine.sightline``
        every ``step / FINE``; elsewhere two marches of the stack: every ``step`` with a slack
        of ``MARGIN_M`` finds the candidates, every ``step / FINE`` decides them. With the
        window's ``bound``, only the ``candidates`` are marched (``cleared``: the points given
        are candidates already)."""
        lon, lat, h = (np.ascontiguousarray(a, np.float64) for a in (lon, lat, h))
        out = np.zeros(lon.shape, bool)
        line, col = np.asarray(line, np.float64), np.asarray(col, np.float64)
        if not cleared and (maybe := self.candidates(lon, lat, h)) is not None:
            lo, hi = self.near_nadir
            maybe = np.flatnonzero(maybe | ((col >= lo) & (col <= hi)))
            out[maybe] = self._marched(lon[maybe], lat[maybe], h[maybe], line[maybe],
                                       col[maybe], coef, df, dj)
            return out
        return self._marched(lon, lat, h, line, col, coef, df, dj)

    def _marched(self, lon: np.ndarray, lat: np.ndarray, h: np.ndarray, line: np.ndarray,
                 col: np.ndarray, coef: np.ndarray, df: float, dj: float) -> np.ndarray:
        """``hidden`` of every point given, each ray marched."""
        e, n = look_vectors(line, col, coef, float(df), float(dj))
        ray = (lon, lat, h, e, n)
        out = np.zeros(e.shape, bool)
        todo = np.arange(e.size)
        if self.window is not None:
            w = self.window
            post, track = self.post, None
            if w.transform is not None:
                track = _projected_track(w, *ray)
                fastest = float(np.nanmax(np.abs(track[:, 2:]), initial=0.0))
                if fastest > 0.0:  # a jump of `post` metres: at most one post on the lattice
                    post = min(post, 0.99 / fastest)
            res = sightline.march(*ray, w.data, w.inv, w.lattice, w.wrap_centre, self.tmax,
                                  post, self.ceiling, TOLERANCE_M, self.gaps, track,
                                  self.bound, col, self.near_nadir)
            out = res == sightline.HIDDEN
            todo = np.flatnonzero(res == sightline.UNDECIDED)
        if todo.size:
            maybe = todo[_march(self.stack, tuple(a[todo] for a in ray), self.ceiling,
                                self.step, TOLERANCE_M - MARGIN_M)]
            out[maybe] = _march(self.stack, tuple(a[maybe] for a in ray), self.ceiling,
                                self.step / FINE, TOLERANCE_M)
        return out


#: the look vectors of antecedents beyond the tie-point grid (the search's margin) are
#: extrapolated: their tan vz bounded by the grid's largest times this
TAN_VZ_SLACK = 1.05
#: margin (m) of the box of a tie-point cell's lines of sight beyond their reach: the
#: antecedents the search takes beyond the grid (a few pixels)
VIEW_PAD_M = 3000.0


def _horizon(window: LatticeWindow, ceiling: float, gaps: bool,
             view: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]
             ) -> tuple[np.ndarray, tuple[float, float]] | None:
    """``sightline.horizon_bound`` of a geographic window for a product's lines of sight,
    ``view`` = its tie points' latitude, longitude, view zenith and azimuth (deg) and the
    pixels between tie-point columns: near a tie-point cell they rise at least 1 / tan vz per
    metre (tan vz of its corners, with ``TAN_VZ_SLACK``; ``sightline.view_tiles``), east or
    west as their azimuths go; and the product columns near nadir whose lines of sight reach
    less than a post (either way: they are marched). None when some line of sight that
    reaches further runs closer to north-south than a cell's diagonal (the sweep's rows would
    not hold it: every point is marched)."""
    tie_lat, tie_lon, view_zenith, view_azimuth, dj = view
    rows = window.lattice[0] + np.array([0.0, window.data.shape[0]])
    lats = (rows - window.inv[5]) / window.inv[4]
    cos = math.cos(math.radians(min(float(np.max(np.abs(lats))), 89.0)))
    col_m = _DEGREE_M * cos / abs(window.inv[0])
    row_m = _DEGREE_M / abs(window.inv[4])
    tz = np.tan(np.radians(np.asarray(view_zenith, np.float64)))
    va = np.radians(np.asarray(view_azimuth, np.float64))
    ok = np.isfinite(tz) & np.isfinite(va)
    if not ok.any():
        return None
    low = sightline.lowest_finite(window.data)
    low = low if math.isfinite(low) else 0.0
    # lines of sight that stay within a post of their point (near nadir)
    short = ok & (tz * max(ceiling - low, 1.0) < min(col_m, row_m))
    far = ok & ~short
    east, north = np.sin(va), np.cos(va)
    if np.any(far & (np.abs(north) * col_m > np.abs(east) * row_m)):
        return None
    columns = np.flatnonzero(short.any(axis=0)) if short.ndim == 2 else np.zeros(0, int)
    near = ((float(columns.min() - 1) * dj, float(columns.max() + 1) * dj) if columns.size
            else (math.inf, -math.inf))
    # the tie points' cells of the window; the box of a tie-point cell grown by the reach of
    # its lines of sight twice (the parallax of its points' positions, then their rays), a
    # tile and the antecedents the search takes beyond the grid
    lon = np.asarray(tie_lon, np.float64)
    lon = lon + 360.0 * np.rint((window.wrap_centre - lon) / 360.0)
    a, c, e_, f = window.inv[0], window.inv[2], window.inv[4], window.inv[5]
    cell_col = a * lon + c - 0.5 - window.lattice[1]
    cell_row = e_ * np.asarray(tie_lat, np.float64) + f - 0.5 - window.lattice[0]
    reach = float(tz[ok].max()) * TAN_VZ_SLACK * max(ceiling - low, 0.0)
    pad = 2.0 * reach + VIEW_PAD_M
    tiles = sightline.view_tiles(cell_row, cell_col,
                                 np.where(ok, TAN_VZ_SLACK * tz, np.nan),
                                 np.where(far, east, 0.0),
                                 (window.data.shape[0] - 1, window.data.shape[1] - 1),
                                 (pad / row_m + sightline.VIEW_TILE,
                                  pad / col_m + sightline.VIEW_TILE))
    bound = sightline.horizon_bound(window.data, ceiling, gaps, (col_m, row_m), tiles)
    return bound, near


def _projected_track(window: LatticeWindow, lon: np.ndarray, lat: np.ndarray, h: np.ndarray,
                     e: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(n, 4): fractional post row, column of each point on a projected north-up lattice and
    their rates per metre of ground towards the sensor (the chord of ``TRACK_M`` along the
    look vector, lon/lat linear in the distance as ``_march`` steps)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        tz = np.hypot(e, n)
        deg = TRACK_M * math.degrees(1.0 / MEAN_EARTH_RADIUS)
        x0, y0 = window.transform(lon, lat)  # type: ignore[misc]
        x1, y1 = window.transform(lon + deg * e / tz / np.cos(np.radians(lat)),  # type: ignore[misc]
                                  lat + deg * n / tz)
        rx, ry = (np.asarray(x1) - x0) / TRACK_M, (np.asarray(y1) - y0) / TRACK_M
    a, c, e_, f = window.inv[0], window.inv[2], window.inv[4], window.inv[5]
    return np.column_stack([e_ * np.asarray(y0) + f - 0.5, a * np.asarray(x0) + c - 0.5,
                            e_ * ry, a * rx])


def _ellipsoidal(window: LatticeWindow, datum: str | None) -> LatticeWindow:
    """A geographic window with ellipsoidal heights: its posts + the geoid N of ``datum`` at
    each post (``heights.geoid_at``; the run adds N at the point: between posts the two
    differ by the curvature of N over a post, micrometres), posts without data NaN; itself
    when its heights are ellipsoidal already."""
    if datum in (None, "ellipsoid"):
        return replace(window, datum="ellipsoid")
    rows = window.lattice[0] + np.arange(window.data.shape[0], dtype=np.float64)
    cols = window.lattice[1] + np.arange(window.data.shape[1], dtype=np.float64)
    lat = (rows + 0.5 - window.inv[5]) / window.inv[4]  # (north-up: inv[1] = inv[3] = 0)
    lon = (cols + 0.5 - window.inv[2]) / window.inv[0]
    glon, glat = (np.ascontiguousarray(a).reshape(-1) for a in np.meshgrid(lon, lat))
    n = geoid_at(datum, glon, glat, np.ones(glon.size, bool)).reshape(window.data.shape)
    valid = (window.data >= MIN_TERRAIN_M) & (window.data <= MAX_TERRAIN_M)
    data = np.where(valid, window.data + n, np.nan).astype(np.float32)
    return replace(window, data=data, datum="ellipsoid")


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


def hidden_ground(sight: Sightlines, kernel_args: tuple, lon: np.ndarray, lat: np.ndarray,
                  h: np.ndarray, res: dict, separable: bool = False) -> np.ndarray:
    """Where the output points of a block (``lon``, ``lat`` with DEM heights ``h``) solved in
    ``res`` (``predcorr.solve``, ``pixeldem.solve_pixel_dem``: line, col, iterations) are hidden
    by the terrain (bool, the block's shape): every mode with DEMs the same way, the ray along
    the view angles of the tie points at the point's antecedent. Points without an antecedent
    or a DEM height (no DEM has data there: the tie points' height) are not marched, nor the
    points ``Sightlines.candidates`` clears; a pixel geolocation's own ``OCCLUDED`` points are
    hidden. ``separable``: a block of a geographic grid (``lon`` the same in every row,
    ``lat`` in every column)."""
    iters = res["iterations"]
    out = np.asarray(iters == OCCLUDED).copy()
    w = sight.window
    if sight.bound is not None and w is not None and separable and np.ndim(lon) == 2:
        # one pass over a block of a geographic grid: the points to march
        gh, gcol, giters = (np.ascontiguousarray(a) for a in (h, res["col"], iters))
        index = sightline.to_march_grid(lon[0], lat[:, 0], gh, gcol, giters, w.inv, w.lattice,
                                        w.wrap_centre, sight.bound, TOLERANCE_M,
                                        sight.near_nadir)
    elif sight.bound is not None and w is not None:  # one pass: the points to march
        plon, plat, ph, pcol, piters = (np.ascontiguousarray(a).reshape(-1)
                                         for a in (lon, lat, h, res["col"], iters))
        index = sightline.to_march(plon, plat, ph, pcol, piters, w.inv, w.lattice,
                                   w.wrap_centre, sight.bound, TOLERANCE_M, sight.near_nadir)
    else:
        index = np.flatnonzero(((iters >= 0) & np.isfinite(h)).reshape(-1))
    if index.size == 0:
        return out
    _, _, coef, df, dj = kernel_args
    flon, flat, fh, fline, fcol = (np.asarray(a).reshape(-1) for a in (lon, lat, h, res["line"],
                                                                      res["col"]))
    gone = index[sight.hidden(flon[index], flat[index], fh[index].astype(np.float64),
                              fline[index], fcol[index], coef, df, dj, cleared=True)]
    out.reshape(-1)[gone] = True
    return out


def drop_hidden(res: dict, hidden: np.ndarray) -> None:
    """The antecedents in ``res`` of the ``hidden`` points dropped (hidden ``mask``): line and
    column NaN, iterations ``OCCLUDED``, counted in its "occluded" search count."""
    iters = res["iterations"]
    gone = hidden & (iters >= 0)
    n = int(np.count_nonzero(gone))
    if n == 0:
        return
    res["line"][gone] = np.nan
    res["col"][gone] = np.nan
    iters[gone] = OCCLUDED
    res["search"]["occluded"] = res["search"].get("occluded", 0) + n

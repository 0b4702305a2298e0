"""Segment boundary and its intersections with output lines (handbook section 3.1, figs. 17-20;
Appendix C ``TimMersynComputeBoundary`` and ``TimMersynComputeIntersectionsWithBoundary``).

``segment_boundary(tp_lat, tp_lon)`` builds the closed polygon of the border tie points in
MERSYN's order: first tie column top to bottom, last tie line left to right, last tie column
bottom to top, first tie line right to left, first vertex repeated at the end. Longitudes are
unwrapped so that the polygon is continuous across +-180 deg (first vertex in [-180, 180)).

``row_spans(boundary, grid)`` gives, for every output line, the [start, stop) column intervals
whose pixel centres lie inside the boundary (even-odd scanline rule, half-open crossing test, so
a line touching a single vertex never yields a lone point). The polygons are taken in the output
CRS: a WGS84 geographic grid uses the unwrapped polygon and its copies shifted by +-360 deg (an
x range such as 170..190 works, and so does a grid in [-180, 180) for a segment crossing the
antimeridian); any other CRS uses ``Boundary.split_antimeridian()`` (fig. 20) with densified
vertices projected by pyproj. ``margin`` dilates the spans by whole output pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyproj
from numba import njit

from ..geometry.grid import OutputGrid, parse_crs

_WGS84 = pyproj.CRS.from_epsg(4326)


@dataclass(frozen=True, eq=False)
class Boundary:
    """Closed polygon (first vertex == last) of the segment boundary; lon unwrapped, degrees."""

    lon: np.ndarray
    lat: np.ndarray

    @property
    def crosses_antimeridian(self) -> bool:
        return bool(np.nanmin(self.lon) < -180.0 or np.nanmax(self.lon) > 180.0)

    def densified(self, n: int = 2) -> Boundary:
        """The polygon with ``n - 1`` extra vertices on each edge (linear in lon/lat)."""
        if n <= 1:
            return self
        t = np.arange(n) / n
        lon = (self.lon[:-1, None] + t * np.diff(self.lon)[:, None]).ravel()
        lat = (self.lat[:-1, None] + t * np.diff(self.lat)[:, None]).ravel()
        return Boundary(np.r_[lon, self.lon[-1]], np.r_[lat, self.lat[-1]])

    def split_antimeridian(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Closed polygons in [-180, 180], the boundary cut at +-180 deg (section 3.1, fig. 20)."""
        lo, hi = float(np.nanmin(self.lon)), float(np.nanmax(self.lon))
        k_lo = int(np.floor((lo + 180.0) / 360.0))
        k_hi = int(np.floor((hi + 180.0) / 360.0 - 1e-12))
        pieces = []
        for k in range(k_lo, max(k_hi, k_lo) + 1):
            west, east = -180.0 + 360.0 * k, 180.0 + 360.0 * k
            x, y = _clip_vertical(self.lon[:-1], self.lat[:-1], west, keep_greater=True)
            x, y = _clip_vertical(x, y, east, keep_greater=False)
            if x.size >= 3:
                pieces.append((np.r_[x, x[0]] - 360.0 * k, np.r_[y, y[0]]))
        return pieces

    def polygons(self, crs: Any, densify: int = 2) -> list[tuple[np.ndarray, np.ndarray]]:
        """The boundary in the coordinates of ``crs``: the unwrapped polygon for WGS84 lon/lat,
        else the antimeridian pieces, densified, projected (non-finite vertices dropped)."""
        crs = parse_crs(crs)
        probe = OutputGrid(crs, 0.0, 1.0, 1.0, 1.0, 1, 1)
        if probe.is_lonlat:
            return [(self.lon.copy(), self.lat.copy())]
        tr = pyproj.Transformer.from_crs(_WGS84, crs, always_xy=True)
        out = []
        for lon, lat in self.split_antimeridian():
            b = Boundary(lon, lat).densified(densify)
            x, y = tr.transform(b.lon, b.lat, errcheck=False)
            x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
            ok = np.isfinite(x) & np.isfinite(y)
            if ok.sum() >= 3:
                x, y = x[ok], y[ok]
                if x[0] != x[-1] or y[0] != y[-1]:
                    x, y = np.r_[x, x[0]], np.r_[y, y[0]]
                out.append((x, y))
        return out

    def intersects(self, grid: OutputGrid) -> bool:
        """True when at least one output pixel centre of ``grid`` is inside the boundary."""
        return row_spans(self, grid).count > 0


def segment_boundary(tp_lat: np.ndarray, tp_lon: np.ndarray) -> Boundary:
    """Closed polygon of the border tie points (section 3.1; Appendix C TimMersynComputeBoundary).

    ``tp_lat``/``tp_lon``: (n_tie_lines, n_tie_cols) degrees, stored column order.
    """
    lat = np.asarray(tp_lat, dtype=np.float64)
    lon = np.asarray(tp_lon, dtype=np.float64)
    if lat.ndim != 2 or lat.shape != lon.shape or min(lat.shape) < 2:
        raise ValueError(f"tie-point grids must be 2-D, >= 2 x 2, got {lat.shape}")
    n_lines, n_cols = lat.shape
    il = np.r_[np.arange(n_lines - 1), np.full(n_cols - 1, n_lines - 1),
               np.arange(n_lines - 1, 0, -1), np.zeros(n_cols - 1, int)]
    ic = np.r_[np.zeros(n_lines - 1, int), np.arange(n_cols - 1),
               np.full(n_lines - 1, n_cols - 1), np.arange(n_cols - 1, 0, -1)]
    blon = np.r_[lon[il, ic], lon[0, 0]]
    blat = np.r_[lat[il, ic], lat[0, 0]]
    blon = np.unwrap(blon, period=360.0)
    blon -= 360.0 * np.floor((blon[0] + 180.0) / 360.0)
    return Boundary(blon, blat)


def _clip_vertical(x: np.ndarray, y: np.ndarray, x_cut: float, keep_greater: bool
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Sutherland-Hodgman clip of an open polygon (no repeated vertex) by x >= / <= x_cut."""
    n = x.size
    if n == 0:
        return x, y
    inside = x >= x_cut if keep_greater else x <= x_cut
    ox: list[float] = []
    oy: list[float] = []
    for i in range(n):
        j = (i + 1) % n
        if inside[i]:
            ox.append(x[i])
            oy.append(y[i])
        if inside[i] != inside[j]:
            t = (x_cut - x[i]) / (x[j] - x[i])
            ox.append(x_cut)
            oy.append(y[i] + t * (y[j] - y[i]))
    return np.asarray(ox, dtype=np.float64), np.asarray(oy, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class RowSpans:
    """Column intervals inside the boundary for output rows [row_start, row_start + n_rows).

    Row ``row_start + r`` holds the intervals ``[start[k], stop[k])`` for k in
    ``ptr[r]:ptr[r + 1]``, sorted and disjoint.
    """

    row_start: int
    width: int
    ptr: np.ndarray
    start: np.ndarray
    stop: np.ndarray

    @property
    def n_rows(self) -> int:
        return self.ptr.size - 1

    @property
    def count(self) -> int:
        """Number of output pixels inside."""
        return int(np.sum(self.stop - self.start))

    def spans(self, row: int) -> list[tuple[int, int]]:
        r = row - self.row_start
        return [(int(a), int(b)) for a, b in zip(self.start[self.ptr[r]:self.ptr[r + 1]],
                                                  self.stop[self.ptr[r]:self.ptr[r + 1]],
                                                  strict=True)]

    def mask(self) -> np.ndarray:
        """Boolean (n_rows, width) mask of the pixels inside."""
        out = np.zeros((self.n_rows, self.width), dtype=np.bool_)
        _fill_mask(self.ptr, self.start, self.stop, out)
        return out


def row_spans(boundary: Boundary, grid: OutputGrid, row_start: int = 0,
              row_stop: int | None = None, margin: int = 0) -> RowSpans:
    """Intersections of output lines with the segment boundary (Appendix C
    TimMersynComputeIntersectionsWithBoundary), as column spans (module docstring)."""
    row_stop = grid.height if row_stop is None else int(row_stop)
    margin = max(int(margin), 0)
    polys = boundary.polygons(grid.crs)
    if grid.is_lonlat:
        lo, hi = float(np.nanmin(boundary.lon)), float(np.nanmax(boundary.lon))
        gx0, gx1 = grid.bounds[0], grid.bounds[2]
        k_lo = int(np.floor((gx0 - hi) / 360.0))
        k_hi = int(np.ceil((gx1 - lo) / 360.0))
        shifts = 360.0 * np.arange(k_lo, k_hi + 1, dtype=np.float64)
    else:
        shifts = np.zeros(1)
    xs = [p[0] for p in polys]
    ys = [p[1] for p in polys]
    ptr = np.r_[0, np.cumsum([len(x) for x in xs])].astype(np.int64)
    xv = np.concatenate(xs) if xs else np.empty(0)
    yv = np.concatenate(ys) if ys else np.empty(0)
    r0, r1 = row_start - margin, row_stop + margin
    counts = np.zeros(max(r1 - r0, 0), np.int64)
    buf = np.empty(xv.size * shifts.size + 1)  # the crossings of one line
    none = np.empty(0, np.int64)
    _scan(xv, yv, ptr, shifts, grid.x0, grid.y0, grid.dx, grid.dy, grid.width, r0, margin,
          counts, none, none, np.zeros(1, np.int64), False, buf)
    rptr = np.r_[0, np.cumsum(counts)].astype(np.int64)
    start = np.empty(rptr[-1], np.int64)
    stop = np.empty(rptr[-1], np.int64)
    _scan(xv, yv, ptr, shifts, grid.x0, grid.y0, grid.dx, grid.dy, grid.width, r0, margin,
          counts, start, stop, rptr, True, buf)
    if margin:
        rptr, start, stop = _dilate_rows(rptr, start, stop, margin, row_stop - row_start)
    return RowSpans(row_start, grid.width, rptr, start, stop)


@njit(cache=True)  # serial: a few crossings per line; a parallel loop costs compile time
def _scan(xv, yv, ptr, shifts, x0, y0, dx, dy, width, r0, margin, counts, start, stop, rptr,
          fill, xs):  # pragma: no cover
    """Scanline fill: for each line y = y0 - (i + 0.5) dy, pixel-centre intervals inside.

    The crossings of a line are sorted in place by insertion (a few per line; numba's own sort
    costs seconds of compilation per dtype), in the buffer ``xs`` (edges x shifts values).
    """
    for r in range(counts.size):
        y = y0 - (r0 + r + 0.5) * dy
        n = 0
        for p in range(ptr.size - 1):
            for e in range(ptr[p], ptr[p + 1] - 1):
                ya, yb = yv[e], yv[e + 1]
                if (ya <= y) != (yb <= y):
                    x = xv[e] + (y - ya) * (xv[e + 1] - xv[e]) / (yb - ya)
                    for s in range(shifts.size):
                        v = x + shifts[s]
                        m = n - 1
                        while m >= 0 and xs[m] > v:
                            xs[m + 1] = xs[m]
                            m -= 1
                        xs[m + 1] = v
                        n += 1
        k = 0
        w = rptr[r] if fill else 0
        last_stop = -1
        for m in range(0, n - 1, 2):
            a = math.ceil((xs[m] - x0) / dx - 0.5) - margin
            b = math.ceil((xs[m + 1] - x0) / dx - 0.5) + margin
            a = 0 if a < 0 else (a if a < width else width)
            b = 0 if b < 0 else (b if b < width else width)
            if b <= a:
                continue
            if k > 0 and a <= last_stop:
                if b > last_stop:
                    last_stop = b
                    if fill:
                        stop[w - 1] = b
                continue
            if fill:
                start[w] = a
                stop[w] = b
                w += 1
            k += 1
            last_stop = b
        if not fill:
            counts[r] = k


def _dilate_rows(rptr: np.ndarray, start: np.ndarray, stop: np.ndarray, margin: int,
                 n_rows: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Union over rows i - margin .. i + margin of the (already widened) spans.

    Bounded time whatever the margin: windows of 1, 2, 4, ... rows are built by merging two
    halves (log2(2 margin + 1) passes over the rows), then the window of 2 margin + 1 rows is
    the union of two overlapping power-of-two windows.
    """
    window = 2 * margin + 1
    p = 1
    while 2 * p <= window:
        rptr, start, stop = _merge_shifted(rptr, start, stop, p)  # windows of 2p rows
        p *= 2
    if p < window:
        rptr, start, stop = _merge_shifted(rptr, start, stop, window - p)
    assert rptr.size - 1 == n_rows
    return rptr, start, stop


def _merge_shifted(rptr: np.ndarray, start: np.ndarray, stop: np.ndarray, shift: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows r of the result: union of the spans of rows r and r + shift (n - shift rows)."""
    n_out = rptr.size - 1 - shift
    counts = np.zeros(n_out, np.int64)
    _union_pair(rptr, start, stop, shift, counts, start, stop, counts, False)
    optr = np.r_[0, np.cumsum(counts)].astype(np.int64)
    ostart = np.empty(optr[-1], np.int64)
    ostop = np.empty(optr[-1], np.int64)
    _union_pair(rptr, start, stop, shift, counts, ostart, ostop, optr, True)
    return optr, ostart, ostop


@njit(cache=True)
def _union_pair(rptr, start, stop, shift, counts, ostart, ostop, optr, fill):  # pragma: no cover
    """Merge the sorted disjoint spans of rows r and r + shift (count, then fill)."""
    for r in range(counts.size):
        i, i_end = rptr[r], rptr[r + 1]
        j, j_end = rptr[r + shift], rptr[r + shift + 1]
        k = 0
        w = optr[r] if fill else 0
        last = -1
        while i < i_end or j < j_end:
            if j >= j_end or (i < i_end and start[i] <= start[j]):
                a, b = start[i], stop[i]
                i += 1
            else:
                a, b = start[j], stop[j]
                j += 1
            if k > 0 and a <= last:
                if b > last:
                    last = b
                    if fill:
                        ostop[w - 1] = b
                continue
            if fill:
                ostart[w] = a
                ostop[w] = b
                w += 1
            k += 1
            last = b
        if not fill:
            counts[r] = k


@njit(cache=True)  # serial: memory bound
def _fill_mask(ptr, start, stop, out):  # pragma: no cover
    for r in range(ptr.size - 1):
        for k in range(ptr[r], ptr[r + 1]):
            out[r, start[k]:stop[k]] = True

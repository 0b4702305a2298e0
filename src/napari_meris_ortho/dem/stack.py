"""Elevation sources for orthorectification (handbook section 3.1 "Digital elevation data",
chapter 5 GETASSE30, Appendix C ``TimMersynGetAltitudeFromDem``).

``open_dem(path)`` detects the format:

- a directory (or one file) of GETASSE30 tiles: 15 x 15 deg, 1800 x 1800 posts of 30", named
  from the lower-left corner (``45N015E.GETASSE30``). Handbook variant: float32 (12 960 000
  bytes), rows South to North, byte order detected from the values; BEAM variant: int16
  big-endian (6 480 000 bytes), rows North to South, -32768/32767 no data, also inside
  ``45N015E.zip``. Post (r, c) of a tile with lower-left (lat0, lon0) is at
  lon0 + (c + 0.5)/120 and lat0 + (r + 0.5)/120 (handbook) or lat0 + 15 - (r + 0.5)/120 (BEAM).
  A missing tile is no data.
- SRTM30/GTOPO30 ``.DEM`` + ``.HDR`` tiles (ULXMAP/ULYMAP = centre of the upper-left post,
  BYTEORDER M/I, NODATA -9999), a file or a directory of them.
- any raster GDAL reads (GeoTIFF...) in any CRS: posts at pixel centres, lookups reprojected with
  pyproj, nodata honoured, only the window under the requested points read.

- a directory (searched 3 levels deep) of Copernicus DEM GLO-30 / GLO-90 tiles
  (``Copernicus_DSM_COG_10_N46_00_E010_00_DEM.tif``; ``dem.copernicus``), only the tiles under
  the requested points read; a VRT is any GDAL raster.

Vertical datum: every source has a ``datum``, "ellipsoid" or "egm96"; ``sample``
returns ellipsoidal heights (EGM96 heights + the geoid undulation N, ``dem.geoid``). A DEM entry
``PATH:egm96`` or ``PATH:ellipsoid`` names it; by default SRTM30 and Copernicus are EGM96,
GETASSE30 ellipsoidal, a GDAL raster takes its vertical CRS (compound EGM96/EGM2008 height,
3-D geographic) or its ``VERTICAL_DATUM`` tag, else it is taken as ellipsoidal with a warning.

``DemSource.sample(lon, lat, method="bilinear")`` -> float64 heights, NaN outside or where a post
used by the interpolation is no data (as MERSYN: a background post sends the point to the next
DEM). Methods "nearest", "bilinear" (2x2 posts), "bicubic" (4x4 posts, Keys a = -0.5).
``DemStack(sources).sample(lon, lat)`` -> (heights, source index), trying each DEM in order;
index -1 (and NaN) where none has data (the caller then falls back to the tie points).
``prepare(lon_min, lat_min, lon_max, lat_max)`` (sources and stacks) reads once the window of
a GDAL raster that covers a footprint, decoding its blocks on all cores; later lookups inside it
read nothing more (bilinear: four flat gathers). ``lattice_window()`` then gives that window as
plain data (``LatticeWindow``) for the compiled lookup of ``engine.terrain`` (called by
``ortho``; None for the other sources, which keep ``sample``).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import check_input_file
from ..errors import DemError
from .base import DemSource, LatticeWindow
from .geoid import ELLIPSOID, GEOIDS, geoid_grid_path, resolve_datum, split_datum
from .getasse import _TILE_RE, _ZIP_RE, GetasseSource
from .raster import RasterSource
from .srtm import SrtmTile, srtm30_tiles

log = logging.getLogger(__name__)
#: a compiled lookup in a lattice window (``DemStack.walk``): (window, DEM index, lon, lat,
#: todo, h, index, miss) -> points filled
WindowLookup = Callable[[LatticeWindow, int, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                         np.ndarray, np.ndarray], int]
# ---------------------------------------------------------------------- several sources
class CompositeSource(DemSource):
    """Several sources of one DEM series (tiles): the first with data wins at each point."""

    def __init__(self, name: str, sources: Sequence[DemSource]) -> None:
        self.name = name
        self.sources = list(sources)
        datums = {s.datum for s in self.sources}
        self.datum = datums.pop() if len(datums) == 1 else None

    def set_datum(self, datum: str) -> None:
        self.datum = datum
        for s in self.sources:
            s.set_datum(datum)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        b = np.array([s.bounds for s in self.sources])
        return (b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max())

    def sample(self, lon: Any, lat: Any, method: str = "bilinear") -> np.ndarray:
        return DemStack(self.sources).sample(lon, lat, method)[0]

    def prepare(self, lon_min: float, lat_min: float, lon_max: float, lat_max: float) -> None:
        for s in self.sources:
            s.prepare(lon_min, lat_min, lon_max, lat_max)

    def parts(self) -> list[tuple[DemSource, str | None]]:
        return [part for s in self.sources for part in s.parts()]

    def close(self) -> None:
        for s in self.sources:
            s.close()


class DemStack:
    """DEMs tried in order at each point (section 3.1: outside or background -> next DEM)."""

    def __init__(self, sources: Sequence[DemSource | str | os.PathLike[str]]) -> None:
        self.sources = [s if isinstance(s, DemSource) else open_dem(s) for s in sources]

    def sample(self, lon: Any, lat: Any, method: str = "bilinear"
               ) -> tuple[np.ndarray, np.ndarray]:
        """(heights float64, index int16 of the DEM used; -1 and NaN where none has data)."""
        lon, lat = np.broadcast_arrays(np.asarray(lon, dtype=np.float64),
                                       np.asarray(lat, dtype=np.float64))
        h = np.full(lon.size, np.nan)
        index = np.full(lon.size, -1, dtype=np.int16)
        self.walk(np.ascontiguousarray(lon).reshape(-1), np.ascontiguousarray(lat).reshape(-1),
                  np.ones(lon.size, dtype=bool), h, index, method)
        return h.reshape(lon.shape), index.reshape(lon.shape)

    def walk(self, lon: np.ndarray, lat: np.ndarray, todo: np.ndarray, h: np.ndarray,
             index: np.ndarray, method: str = "bilinear",
             window_lookup: WindowLookup | None = None) -> None:
        """The DEMs tried in order at the ``todo`` points (flat arrays; section 3.1: outside
        or background -> next DEM): where DEM k has data, its height goes to ``h``, k to
        ``index`` and the point leaves ``todo``. The one walk of the package.

        ``window_lookup(window, k, lon, lat, todo, h, index, miss)``: a faster lookup of a
        lattice read into memory (``LatticeWindow``; ``ortho.heights`` passes the compiled
        one); it fills what it can and marks in ``miss`` the points whose posts lie beyond
        the window. Those points, and all points of a lattice without a window, are read by
        the DEM's own ``sample`` (which tries its lattices in the same order)."""
        for k, dem in enumerate(self.sources):
            if not todo.any():
                break
            deferred = np.zeros(todo.size, bool)
            if window_lookup is None:
                deferred |= todo
            else:
                for part, datum in dem.parts():
                    window = part.lattice_window()
                    if window is None:
                        deferred |= todo
                        break
                    miss = np.zeros(todo.size, bool)
                    if window_lookup(replace(window, datum=datum), k, lon, lat, todo, h, index,
                                     miss):
                        deferred |= miss
                        todo &= ~miss
            if deferred.any():
                todo |= deferred
                _sample_into(dem, k, method, np.flatnonzero(deferred), lon, lat, todo, h,
                             index)

    def prepare(self, lon_min: float, lat_min: float, lon_max: float, lat_max: float) -> None:
        """Read once what lookups inside these WGS84 bounds need, from every DEM."""
        for s in self.sources:
            s.prepare(lon_min, lat_min, lon_max, lat_max)

    def close(self) -> None:
        for s in self.sources:
            s.close()


def _sample_into(dem: DemSource, k: int, method: str, sel: np.ndarray, lon: np.ndarray,
                 lat: np.ndarray, todo: np.ndarray, h: np.ndarray, index: np.ndarray) -> None:
    """Heights of DEM ``k`` at the flat points ``sel`` by its ``sample``: where it has data,
    written to ``h``/``index`` and cleared from ``todo``."""
    if sel.size == 0:
        return
    v = dem.sample(lon[sel], lat[sel], method)
    got = np.isfinite(v)
    sel = sel[got]
    h[sel] = v[got]
    index[sel] = k
    todo[sel] = False


_WARNED: set[str] = set()


def open_dem(path: str | os.PathLike[str]) -> DemSource:
    """Open a DEM entry ``PATH[:egm96|:ellipsoid]``, detecting its format and vertical datum
    (module docstring). Raises DemError."""
    text, datum = split_datum(path)
    src = _open_path(Path(text))
    if datum is not None:
        src.set_datum(datum)
    elif _datums(src) & {None}:
        if text not in _WARNED:  # once per path (synthesis opens the DEMs per tile)
            _WARNED.add(text)
            log.warning("%s: the DEM does not say its vertical datum: its heights are taken as "
                        "ellipsoidal (write %s:egm96 for heights above the geoid, %s:ellipsoid "
                        "to silence this)", text, text, text)
        _assume_ellipsoid(src)
    _resolve_geoids(src)
    for datum in sorted(d for d in _datums(src) if d in GEOIDS):
        geoid_grid_path(datum)  # a missing geoid grid fails now, before any work
    return src


def dem_datums(entries: Sequence[str | os.PathLike[str]]) -> list[str | None]:
    """The vertical datum of each DEM entry's heights as read (``open_dem``; None: tiles of
    several datums)."""
    out = []
    for entry in entries:
        src = open_dem(entry)
        try:
            out.append(src.datum)
        finally:
            src.close()
    return out


def _datums(src: DemSource) -> set[str | None]:
    """Vertical datums of a source and of its parts (a CompositeSource of tiles)."""
    parts = getattr(src, "sources", None)
    if parts is None:
        return {src.datum}
    return set().union(*(_datums(p) for p in parts)) if parts else {src.datum}


def _set_datums(src: DemSource, datum_of: Callable[[str | None], str | None]) -> None:
    """Give every single source (every part of a composite, at any depth) the datum
    ``datum_of(its datum)`` when that differs and is not None; a composite then has its parts'
    datum when they share one, else None."""
    parts = getattr(src, "sources", None)
    if parts is None:
        datum = datum_of(src.datum)
        if datum is not None and datum != src.datum:
            src.set_datum(datum)
        return
    for p in parts:
        _set_datums(p, datum_of)
    datums = _datums(src)
    src.datum = datums.pop() if len(datums) == 1 else None


def _resolve_geoids(src: DemSource) -> None:
    """EGM2008 heights with EGM96 when only its grid is there (``geoid.resolve_datum``)."""
    _set_datums(src, resolve_datum)


class SrtmDirectory(CompositeSource):
    """A directory of SRTM30/GTOPO30 tiles (``W020N90.DEM``...)."""

    def missing_tiles(self, bounds: tuple[float, float, float, float]) -> list[str]:
        """The tiles of the SRTM30/GTOPO30 tiling under ``bounds`` the directory lacks (the
        tiling covers the globe, the sea as no data: a missing tile is one not copied)."""
        have = {Path(s.name).stem.upper() for s in self.sources}
        return [f"{n}.DEM" for n in srtm30_tiles(bounds) if n not in have]


def _assume_ellipsoid(src: DemSource) -> None:
    """Ellipsoidal heights where a source (or a part of it) does not say its datum."""
    _set_datums(src, lambda datum: ELLIPSOID if datum is None else datum)


def _open_path(p: Path) -> DemSource:
    if not p.exists():
        raise DemError(f"{p}: DEM not found")
    if p.is_dir():
        return _open_directory(p)
    check_input_file(p, "DEM", DemError)
    if _TILE_RE.match(p.name) or _ZIP_RE.match(p.name):
        return GetasseSource(p.parent, files=[p])
    if p.suffix.upper() in (".DEM", ".HDR"):
        return SrtmTile(p)
    return RasterSource(p)




def _open_directory(p: Path) -> DemSource:
    try:
        files = sorted(f for f in p.iterdir() if f.is_file())
    except OSError as exc:
        raise DemError(f"{p}: cannot list DEM directory ({exc})") from exc
    if any(_TILE_RE.match(f.name) or _ZIP_RE.match(f.name) for f in files):
        return GetasseSource(p, files)
    from .copernicus import CopernicusSource, find_tiles

    tiles = find_tiles(p)
    if tiles:
        return CopernicusSource(p, tiles)
    dems = [f for f in files if f.suffix.upper() == ".DEM"]
    if dems:
        return SrtmDirectory(str(p), [SrtmTile(f) for f in dems])
    rasters = [f for f in files if f.suffix.lower() in (".tif", ".tiff", ".vrt", ".img")]
    if rasters:
        return CompositeSource(str(p), [RasterSource(f) for f in rasters])
    raise DemError(f"{p}: no GETASSE30, SRTM30/GTOPO30 or GeoTIFF DEM found in the directory")


def heights_or_fallback(stack: DemStack | None, lon: np.ndarray, lat: np.ndarray,
                        fallback: np.ndarray, method: str = "bilinear"
                        ) -> tuple[np.ndarray, np.ndarray]:
    """DEM heights with ``fallback`` (e.g. tie-point heights) where no DEM has data
    (section 3.1); index -1 marks the fallback."""
    fallback = np.broadcast_to(np.asarray(fallback, dtype=np.float64), np.shape(lon))
    if stack is None:
        return fallback.copy(), np.full(np.shape(lon), -1, np.int16)
    h, idx = stack.sample(lon, lat, method)
    return np.where(idx >= 0, h, fallback), idx

"""Vertical datums of DEM heights: the EGM96 geoid (issue 11).

The engine needs heights above the WGS84 ellipsoid (the parallax of eq. 6a is computed from the
ellipsoid point). GETASSE30 gives them already (handbook chapter 5); SRTM30 and the Copernicus
DEM give orthometric heights H above the EGM96 / EGM2008 geoid, so h = H + N with the geoid
undulation N (up to +-100 m: 0.3 FR pixel at 40 deg view zenith).

N comes from the EGM96 15' grid ``egm96_15.gtx`` of Debian's ``proj-data`` package (PROJ's
``vgridshift``, bilinear): N = 48.95 m at 10 E, 46 N. The grid is looked up in
``$MERIS_ORTHO_GEOID`` (a file), ``$PROJ_DATA``/``$PROJ_LIB``, pyproj's data directory,
``/usr/share/proj`` and ``/usr/local/share/proj``; a missing grid is a ``DemError`` naming them.
The Copernicus DEM is referred to EGM2008; EGM96 stands in for it (the proj-data package has no
EGM2008 grid), which differs by about a metre in most places.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DemError

EGM96 = "egm96"
ELLIPSOID = "ellipsoid"
#: vertical datums a DEM entry may name (``--dem PATH:egm96``)
DATUMS = (EGM96, ELLIPSOID)
GEOID_GRID = "egm96_15.gtx"
#: node spacing of the EGM96 grid (15')
GRID_STEP_DEG = 0.25
_SEARCH = (Path("/usr/share/proj"), Path("/usr/local/share/proj"))
_local = threading.local()


def _candidates() -> list[Path]:
    dirs: list[Path] = []
    for var in ("PROJ_DATA", "PROJ_LIB"):
        dirs += [Path(p) for p in os.environ.get(var, "").split(os.pathsep) if p]
    try:
        import pyproj.datadir

        dirs += [Path(p) for p in pyproj.datadir.get_data_dir().split(os.pathsep) if p]
    except (ImportError, RuntimeError):  # pragma: no cover
        pass
    return [d / GEOID_GRID for d in [*dirs, *_SEARCH]]


def geoid_grid_path() -> Path:
    """The EGM96 grid file (module docstring), or DemError saying where it was looked for."""
    env = os.environ.get("MERIS_ORTHO_GEOID")
    if env:
        if Path(env).is_file():
            return Path(env)
        raise DemError(f"MERIS_ORTHO_GEOID={env}: geoid grid file not found")
    tried = _candidates()
    for p in tried:
        if p.is_file():
            return p
    raise DemError(
        f"EGM96 geoid grid {GEOID_GRID} not found (looked in "
        f"{', '.join(sorted({str(p.parent) for p in tried}))}): install Debian's proj-data "
        "package (scripts/setup.sh does) or set MERIS_ORTHO_GEOID to the file; needed for "
        "heights above the geoid (SRTM30, Copernicus, ':egm96' DEM entries)")


def _transformer(path: Path) -> Any:
    """A vgridshift transformer of ``path``, one per thread (pyproj objects are not shared)."""
    import pyproj

    cache = getattr(_local, "transformers", None)
    if cache is None:
        cache = _local.transformers = {}
    key = str(path)
    if key not in cache:
        try:
            cache[key] = pyproj.Transformer.from_pipeline(
                f"+proj=vgridshift +grids={path} +multiplier=1")
        except pyproj.exceptions.ProjError as exc:
            raise DemError(f"{path}: cannot read the geoid grid ({exc})") from exc
    return cache[key]


def geoid_undulation(lon: Any, lat: Any) -> np.ndarray:
    """EGM96 geoid undulation N (m) at WGS84 (lon, lat) degrees: ellipsoidal height = H + N.

    NaN where a coordinate is NaN. Raises DemError when the grid is missing.
    """
    lon_a, lat_a = np.broadcast_arrays(np.asarray(lon, dtype=np.float64),
                                       np.asarray(lat, dtype=np.float64))
    out = np.full(lon_a.shape, np.nan)
    ok = np.isfinite(lon_a) & np.isfinite(lat_a) & (np.abs(lat_a) <= 90.0)
    if ok.any():
        out[ok] = _bilinear_on_nodes((lon_a[ok] + 180.0) % 360.0 - 180.0, lat_a[ok])
    return out


def _nodes(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """N at grid nodes, through PROJ (exact there)."""
    tr = _transformer(geoid_grid_path())
    _, _, z = tr.transform(lon, lat, np.zeros(lon.shape), errcheck=False)
    z = np.asarray(z, dtype=np.float64)
    z[~np.isfinite(z) | (np.abs(z) > 1e3)] = np.nan
    return z


def node_indices(lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(row i, column j) of the grid node south-west of each point (lon in [-180, 180)):
    i = floor((lat + 90) / step) within 0..719, j = floor((lon + 180) / step)."""
    i = np.clip(np.floor((lat + 90.0) / GRID_STEP_DEG).astype(np.int64), 0, 719)
    j = np.floor((lon + 180.0) / GRID_STEP_DEG).astype(np.int64)
    return i, j


def nodes_between(i0: int, i1: int, j0: int, j1: int) -> np.ndarray:
    """N (m) at the grid nodes rows i0..i1, columns j0..j1 (inclusive), float64, through PROJ
    (exact there); for a compiled bilinear lookup (``engine.terrain.geoid_bilinear``) that
    gives ``geoid_undulation``'s numbers."""
    rows = np.arange(i0, i1 + 1)
    cols = np.arange(j0, j1 + 1)
    node_lon, node_lat = np.meshgrid(-180.0 + cols * GRID_STEP_DEG, -90.0 + rows * GRID_STEP_DEG)
    return _nodes(node_lon.ravel(), node_lat.ravel()).reshape(node_lon.shape)


def _bilinear_on_nodes(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """PROJ's bilinear interpolation of the 15' grid, done here between the nodes under the
    points (PROJ is asked only for those few nodes; same values to 1e-11 m)."""
    i, j = node_indices(lon, lat)
    i0, j0 = int(i.min()), int(j.min())
    grid = nodes_between(i0, int(i.max()) + 1, j0, int(j.max()) + 1)
    u = (lat + 90.0) / GRID_STEP_DEG - i
    v = (lon + 180.0) / GRID_STEP_DEG - j
    r, c = i - i0, j - j0
    return ((1.0 - u) * ((1.0 - v) * grid[r, c] + v * grid[r, c + 1])
            + u * ((1.0 - v) * grid[r + 1, c] + v * grid[r + 1, c + 1]))


def to_ellipsoid(height: np.ndarray, lon: Any, lat: Any, datum: str) -> np.ndarray:
    """Heights of ``datum`` turned into ellipsoidal heights (``EGM96``: + N; ``ELLIPSOID``: as
    they are)."""
    if datum == ELLIPSOID:
        return height
    if datum == EGM96:
        return height + geoid_undulation(lon, lat)
    raise DemError(f"unknown vertical datum {datum!r}: choose {' or '.join(DATUMS)}")


def split_datum(entry: str | os.PathLike[str]) -> tuple[str, str | None]:
    """``"PATH[:egm96|:ellipsoid]"`` -> (path, datum or None). A string that exists as a path
    is taken whole; an unknown suffix is a DemError."""
    text = os.fspath(entry)
    if os.path.exists(text) or ":" not in text:
        return text, None
    path, _, suffix = text.rpartition(":")
    if "/" in suffix or os.sep in suffix or not path:
        return text, None
    if suffix.lower() not in DATUMS:
        raise DemError(f"{text}: unknown vertical datum {suffix!r} in the DEM entry; "
                       f"use PATH:{' or PATH:'.join(DATUMS)}")
    return path, suffix.lower()


def crs_datum(crs: Any) -> str | None:
    """Vertical datum of a raster's CRS: a compound CRS with EGM96 / EGM2008 height -> egm96,
    a 3-D geographic CRS (EPSG:4979) -> ellipsoid; None when the CRS says nothing."""
    import pyproj

    try:
        c = pyproj.CRS.from_user_input(crs)
    except pyproj.exceptions.CRSError:
        return None
    for sub in c.sub_crs_list:
        if sub.is_vertical:
            name = sub.name.upper()
            if "EGM96" in name or "EGM2008" in name or "EGM08" in name:
                return EGM96
            return None
    if c.is_geographic and len(c.axis_info) == 3:
        return ELLIPSOID
    return None


__all__ = ["DATUMS", "EGM96", "ELLIPSOID", "GEOID_GRID", "crs_datum", "geoid_grid_path",
           "geoid_undulation", "split_datum", "to_ellipsoid"]

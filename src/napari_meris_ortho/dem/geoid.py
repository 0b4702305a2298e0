"""Vertical datums of DEM heights: the EGM96 and EGM2008 geoids.

The engine needs heights above the WGS84 ellipsoid (the parallax of eq. 6a is computed from the
ellipsoid point). GETASSE30 gives them already (handbook chapter 5); SRTM30 gives orthometric
heights H above EGM96, the Copernicus DEM above EGM2008, so h = H + N with the geoid
undulation N (up to +-100 m: 0.3 FR pixel at 40 deg view zenith).

N comes from the grids PROJ ships (PROJ's ``vgridshift``, bilinear between the nodes), under
either of their names: EGM96 15' as ``egm96_15.gtx`` (Debian's proj-data) or
``us_nga_egm96_15.tif`` (PROJ-data, conda-forge's proj-data, ``projsync``); EGM2008 2.5' as
``us_nga_egm08_25.tif``. N = 48.95 m (EGM96) at 10 E, 46 N. A grid is looked up in
``$MERIS_ORTHO_GEOID`` (an EGM96 file), ``$PROJ_DATA``/``$PROJ_LIB``, pyproj's data
directory, pyproj's user-writable directory (where ``projsync`` puts grids),
``/usr/share/proj`` and ``/usr/local/share/proj``. Not found there and PROJ's network enabled
by the user (``PROJ_NETWORK=ON``): PROJ fetches the grid from its CDN (``cdn.proj.org``) and
caches it in the user-writable directory. Else a ``DemError`` saying all the ways to get it.
EGM2008 heights (Copernicus, a raster in EGM2008) use EGM96 with a warning when only EGM96 is
there (about a metre apart in most places).
"""

from __future__ import annotations

import logging
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DemError

log = logging.getLogger(__name__)
EGM96 = "egm96"
EGM2008 = "egm2008"
ELLIPSOID = "ellipsoid"
#: vertical datums a DEM entry may name (``--dem PATH:egm96``)
DATUMS = (EGM96, EGM2008, ELLIPSOID)


@dataclass(frozen=True)
class GeoidModel:
    """A geoid grid as PROJ ships it: its names (first: the one PROJ's CDN serves)."""

    datum: str
    names: tuple[str, ...]
    label: str


GEOIDS = {
    EGM96: GeoidModel(EGM96, ("us_nga_egm96_15.tif", "egm96_15.gtx"), "EGM96 15'"),
    EGM2008: GeoidModel(EGM2008, ("us_nga_egm08_25.tif",), "EGM2008 2.5'"),
}
GEOID_GRID = "egm96_15.gtx"
#: node spacing of the EGM96 grid (15'); each grid's own spacing is read from its file
GRID_STEP_DEG = 0.25
_SEARCH = (Path("/usr/share/proj"), Path("/usr/local/share/proj"))
_local = threading.local()
_WARNED: set[str] = set()
_STEPS: dict[str, float] = {}


def _directories() -> list[Path]:
    """PROJ's search path as pyproj sees it (module docstring), in order, without repeats."""
    dirs: list[Path] = []
    for var in ("PROJ_DATA", "PROJ_LIB"):
        dirs += [Path(p) for p in os.environ.get(var, "").split(os.pathsep) if p]
    try:
        import pyproj.datadir

        dirs += [Path(p) for p in pyproj.datadir.get_data_dir().split(os.pathsep) if p]
        dirs.append(Path(pyproj.datadir.get_user_data_dir()))
    except (ImportError, RuntimeError):  # pragma: no cover
        pass
    # the system directories of PROJ's Debian/conda packages; MERIS_ORTHO_PROJ_SYSTEM_DIRS
    # replaces them (empty: none, as on a machine with pip packages only)
    system = os.environ.get("MERIS_ORTHO_PROJ_SYSTEM_DIRS")
    search = _SEARCH if system is None else [Path(p) for p in system.split(os.pathsep) if p]
    out: list[Path] = []
    for d in [*dirs, *search]:
        if d not in out:
            out.append(d)
    return out


def _candidates(datum: str = EGM96) -> list[Path]:
    return [d / name for d in _directories() for name in GEOIDS[datum].names]


def network_enabled() -> bool:
    """True when the user enabled PROJ's network (``PROJ_NETWORK=ON`` or pyproj's setting)."""
    if os.environ.get("PROJ_NETWORK", "").upper() == "ON":
        return True
    try:
        import pyproj.network

        return bool(pyproj.network.is_network_enabled())
    except (ImportError, AttributeError):  # pragma: no cover
        return False


def find_geoid_grid(datum: str = EGM96) -> Path | str | None:
    """The grid file of ``datum`` (EGM96 or EGM2008), its PROJ name when only PROJ's network
    can give it, or None."""
    if datum == EGM96:
        env = os.environ.get("MERIS_ORTHO_GEOID")
        if env:
            if Path(env).is_file():
                return Path(env)
            raise DemError(f"MERIS_ORTHO_GEOID={env}: geoid grid file not found")
    for p in _candidates(datum):
        if p.is_file():
            return p
    if network_enabled():
        return GEOIDS[datum].names[0]
    return None


def geoid_grid_path(datum: str = EGM96) -> Path | str:
    """The grid of ``datum`` (``find_geoid_grid``), or a DemError saying where it was looked for
    and the three ways to get it."""
    found = find_geoid_grid(datum)
    if found is not None:
        return found
    model = GEOIDS[datum]
    names = " or ".join(model.names)
    raise DemError(
        f"{model.label} geoid grid {names} not found (looked in "
        f"{', '.join(str(d) for d in _directories())}); needed for heights above the geoid "
        "(SRTM30, Copernicus, ':egm96'/':egm2008' DEM entries). Get it one of three ways: "
        f"install PROJ's grids (Debian: apt install proj-data; conda: conda install -c "
        f"conda-forge proj-data), or download it once with `projsync --file "
        f"{model.names[0]}` (into {_user_dir()}), or let PROJ fetch it: PROJ_NETWORK=ON"
        + (" (or set MERIS_ORTHO_GEOID to the file)" if datum == EGM96 else ""))


def _user_dir() -> str:
    try:
        import pyproj.datadir

        return str(pyproj.datadir.get_user_data_dir())
    except (ImportError, RuntimeError):  # pragma: no cover
        return "PROJ's user data directory"


def resolve_datum(datum: str | None) -> str | None:
    """The datum whose grid will be used: EGM2008 when its grid can be had, else EGM96 with a
    warning (once); others as they are."""
    if datum != EGM2008 or find_geoid_grid(EGM2008) is not None:
        return datum
    if EGM2008 not in _WARNED:
        _WARNED.add(EGM2008)
        log.warning("warning: EGM2008 geoid grid us_nga_egm08_25.tif not found: EGM2008 heights "
                    "(Copernicus DEM) are taken as EGM96 heights, about a metre apart in most "
                    "places (get it with `projsync --file us_nga_egm08_25.tif` or "
                    "PROJ_NETWORK=ON)")
    return EGM96


def grid_step(datum: str = EGM96) -> float:
    """Node spacing (degrees) of the grid of ``datum``: from the file (EGM96 15', EGM2008 2.5'
    for PROJ's grids); a grid fetched through PROJ's network: the model's nominal spacing."""
    path = geoid_grid_path(datum)
    key = str(path)
    if key not in _STEPS:
        nominal = 0.25 if datum == EGM96 else 2.5 / 60.0
        step = nominal
        if isinstance(path, Path):
            try:
                import rasterio

                with rasterio.open(path) as ds:
                    step = abs(float(ds.transform.a))
            except Exception:  # an unreadable header: PROJ reads it below or says why
                step = nominal
        _STEPS[key] = step
    return _STEPS[key]


def _transformer(path: Path | str) -> Any:
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


def geoid_undulation(lon: Any, lat: Any, datum: str = EGM96) -> np.ndarray:
    """Geoid undulation N (m) of ``datum`` at WGS84 (lon, lat) degrees: ellipsoidal height =
    H + N. NaN where a coordinate is NaN. Raises DemError when the grid is missing."""
    lon_a, lat_a = np.broadcast_arrays(np.asarray(lon, dtype=np.float64),
                                       np.asarray(lat, dtype=np.float64))
    out = np.full(lon_a.shape, np.nan)
    ok = np.isfinite(lon_a) & np.isfinite(lat_a) & (np.abs(lat_a) <= 90.0)
    if ok.any():
        out[ok] = _bilinear_on_nodes((lon_a[ok] + 180.0) % 360.0 - 180.0, lat_a[ok], datum)
    return out


def _nodes(lon: np.ndarray, lat: np.ndarray, datum: str = EGM96) -> np.ndarray:
    """N at grid nodes, through PROJ (exact there)."""
    tr = _transformer(geoid_grid_path(datum))
    _, _, z = tr.transform(lon, lat, np.zeros(lon.shape), errcheck=False)
    z = np.asarray(z, dtype=np.float64)
    z[~np.isfinite(z) | (np.abs(z) > 1e3)] = np.nan
    return z


def last_row(datum: str = EGM96) -> int:
    """Index of the last node row south of the north pole (rows from -90 deg)."""
    return int(round(180.0 / grid_step(datum))) - 1


def node_indices(lon: np.ndarray, lat: np.ndarray, datum: str = EGM96
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(row i, column j) of the grid node south-west of each point (lon in [-180, 180)):
    i = floor((lat + 90) / step) within 0..last_row, j = floor((lon + 180) / step)."""
    step = grid_step(datum)
    i = np.clip(np.floor((lat + 90.0) / step).astype(np.int64), 0, last_row(datum))
    j = np.floor((lon + 180.0) / step).astype(np.int64)
    return i, j


def nodes_between(i0: int, i1: int, j0: int, j1: int, datum: str = EGM96) -> np.ndarray:
    """N (m) at the grid nodes rows i0..i1, columns j0..j1 (inclusive), float64, through PROJ
    (exact there); for a compiled bilinear lookup (``engine.terrain.geoid_bilinear``) that
    gives ``geoid_undulation``'s numbers."""
    step = grid_step(datum)
    rows = np.arange(i0, i1 + 1)
    cols = np.arange(j0, j1 + 1)
    node_lon, node_lat = np.meshgrid(-180.0 + cols * step, -90.0 + rows * step)
    return _nodes(node_lon.ravel(), node_lat.ravel(), datum).reshape(node_lon.shape)


def _bilinear_on_nodes(lon: np.ndarray, lat: np.ndarray, datum: str = EGM96) -> np.ndarray:
    """PROJ's bilinear interpolation of the grid, done here between the nodes under the
    points (PROJ is asked only for those few nodes; same values to 1e-11 m)."""
    step = grid_step(datum)
    i, j = node_indices(lon, lat, datum)
    i0, j0 = int(i.min()), int(j.min())
    grid = nodes_between(i0, int(i.max()) + 1, j0, int(j.max()) + 1, datum)
    u = (lat + 90.0) / step - i
    v = (lon + 180.0) / step - j
    r, c = i - i0, j - j0
    return ((1.0 - u) * ((1.0 - v) * grid[r, c] + v * grid[r, c + 1])
            + u * ((1.0 - v) * grid[r + 1, c] + v * grid[r + 1, c + 1]))


def to_ellipsoid(height: np.ndarray, lon: Any, lat: Any, datum: str) -> np.ndarray:
    """Heights of ``datum`` turned into ellipsoidal heights (``EGM96``: + N; ``ELLIPSOID``: as
    they are)."""
    if datum == ELLIPSOID:
        return height
    if datum in GEOIDS:
        return height + geoid_undulation(lon, lat, datum)
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


#: vertical CRS names of the global models and the ellipsoid (anything else gravity-related is a
#: national height datum, ``other_height_datum``)
_GLOBAL_HEIGHTS = ("EGM2008", "EGM08", "EGM96", "ELLIPSOID")


def _vertical_crs(crs: Any) -> tuple[Any, Any]:
    """``crs`` parsed and its vertical sub-CRS (None when it has none); (None, None) when
    pyproj cannot parse it."""
    import pyproj

    try:
        c = pyproj.CRS.from_user_input(crs)
    except pyproj.exceptions.CRSError:
        return None, None
    return c, next((sub for sub in c.sub_crs_list if sub.is_vertical), None)


def crs_datum(crs: Any) -> str | None:
    """Vertical datum of a raster's CRS: a compound CRS with EGM96 / EGM2008 height -> egm96 /
    egm2008, another gravity-related height (a national datum: EVRF2007, NAVD88...) -> egm2008
    (with a warning, ``other_height_datum``), a 3-D geographic CRS (EPSG:4979) -> ellipsoid;
    None when the CRS says nothing."""
    c, vertical = _vertical_crs(crs)
    if c is None:
        return None
    if vertical is not None:
        name = vertical.name.upper()
        if "EGM2008" in name or "EGM08" in name:
            return EGM2008
        if "EGM96" in name:
            return EGM96
        return EGM2008 if _national(name) else None
    if c.is_geographic and len(c.axis_info) == 3:
        return ELLIPSOID
    return None


def other_height_datum(crs: Any) -> str | None:
    """The name of a compound CRS's vertical CRS when its heights are gravity-related but not
    EGM96 or EGM2008 ones (a national datum: "EVRF2007 height", "NAVD88 height"); such a datum
    lies within a few metres of EGM2008, the ellipsoid 40-50 m away in Europe. None otherwise."""
    _, vertical = _vertical_crs(crs)
    return str(vertical.name) if vertical is not None and _national(vertical.name.upper()) else None


def _national(name: str) -> bool:
    """A vertical CRS name (upper case) that is none of ``_GLOBAL_HEIGHTS``."""
    return not any(k in name for k in _GLOBAL_HEIGHTS)


__all__ = ["DATUMS", "EGM96", "EGM2008", "ELLIPSOID", "GEOIDS", "GEOID_GRID", "crs_datum",
           "find_geoid_grid", "geoid_grid_path", "geoid_undulation", "other_height_datum",
           "resolve_datum", "split_datum", "to_ellipsoid"]

"""What every DEM source is (handbook section 3.1, Appendix C ``TimMersynGetAltitudeFromDem``):
``DemSource`` (``sample(lon, lat, method)`` -> ellipsoidal heights, NaN outside or on a no-data
post; ``prepare`` reads a footprint's window once) and ``LatticeWindow`` (that window as plain data
for ``engine.terrain``). A DEM path is checked to be a regular file by
``_atomic.check_input_file`` (with ``DemError``), as every input file is."""

from __future__ import annotations

import contextlib
import logging
import threading
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import DemError
from ..geometry.earth import MAX_TERRAIN_M, MIN_TERRAIN_M
from ..geometry.grid import pixel_limit
from ..geometry.interpolation import keys_weights
from ..options import Sampling, choices
from .geoid import ELLIPSOID, to_ellipsoid

log = logging.getLogger(__name__)

METHODS = tuple(choices(Sampling))
_CHUNK = 1 << 18


# ---------------------------------------------------------------------- GDAL's messages
def gdal_reason(exc: BaseException) -> str:
    """The root of GDAL's chain of errors behind ``exc``: rasterio's "Read failed. See
    previous exception for details." says nothing by itself; its causes say what failed
    ("TIFFReadEncodedStrip:Read error at scanline ...; got 2034 bytes, expected 4800")."""
    reasons: list[str] = []
    seen: set[int] = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        seen.add(id(cause))
        text = " ".join(str(cause).split())
        if text and "see previous exception" not in text.lower():
            reasons.append(text)
        cause = cause.__cause__ or cause.__context__
    return reasons[-1] if reasons else type(exc).__name__


class _Collected(logging.Filter):
    """Keeps rasterio's log records of GDAL warnings ("CPLE_AppDefined in ...: IO error during
    reading of GeoPixelScale") from the threads collecting them (``gdal_complaints``)."""

    def __init__(self) -> None:
        super().__init__()
        self.lists: dict[int, list[str]] = {}

    def filter(self, record: logging.LogRecord) -> bool:
        said = self.lists.get(threading.get_ident())
        if said is None:
            return True
        said.append(record.getMessage())
        return False


_COLLECTED = _Collected()
logging.getLogger("rasterio._env").addFilter(_COLLECTED)


@contextlib.contextmanager
def _gdal_complaints() -> Iterator[list[str]]:
    """GDAL's warnings while this thread opens a DEM file, collected instead of printed: a
    file cut short in its header opens with half its tags and no georeferencing (five
    "IO error during reading" lines and rasterio's NotGeoreferencedWarning), and
    ``open_raster`` then says in one message what they mean."""
    said: list[str] = []
    _COLLECTED.lists[threading.get_ident()] = said
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield said
        said.extend(str(w.message) for w in caught)
    finally:
        _COLLECTED.lists.pop(threading.get_ident(), None)


#: words of GDAL's warnings about a file that ends early or cannot be read in part
_READ_FAILURES = ("io error", "read error", "read failed", "truncat")


def _read_failure(said: list[str]) -> str | None:
    """The first of GDAL's collected warnings (``_gdal_complaints``) saying that part of the
    file could not be read, without its "CPLE_AppDefined in NAME:" prefix; None if none."""
    for message in said:
        if any(word in message.lower() for word in _READ_FAILURES):
            return message.split(": ", 1)[-1] if message.startswith("CPLE_") else message
    return None


def cut_short(path: Any, what: str, reason: str) -> DemError:
    """The error of a DEM file (``what``: "DEM", "Copernicus tile") GDAL could read only in
    part: "PATH: cannot read WHAT, the file is damaged or cut short (REASON)"."""
    return DemError(f"{path}: cannot read {what}, the file is damaged or cut short ({reason})")


def open_raster(path: Any, what: str) -> Any:
    """``rasterio.open`` of a DEM file (``what``: "DEM", "Copernicus tile"), in one message
    when it fails: "cannot read WHAT (GDAL's root reason)", or ``cut_short`` when GDAL could
    read only part of its header (its warnings collected, not printed)."""
    import rasterio
    from rasterio.errors import RasterioError

    with _gdal_complaints() as said:
        try:
            ds = rasterio.open(path)
        except (RasterioError, OSError) as exc:
            raise DemError(f"{path}: cannot read {what} ({gdal_reason(exc)})") from exc
    failure = _read_failure(said)
    if failure:  # GDAL read half a header: no georeferencing, tags missing
        ds.close()
        raise cut_short(path, what, failure)
    return ds


# ---------------------------------------------------------------------- interpolation
def _plausible(v: np.ndarray) -> np.ndarray:
    """``v`` with NaN where a height is outside MIN_TERRAIN_M..MAX_TERRAIN_M (no data)."""
    return np.where((v >= MIN_TERRAIN_M) & (v <= MAX_TERRAIN_M), v, np.nan)


def _kernel(frac: np.ndarray, method: str) -> tuple[np.ndarray, np.ndarray]:
    """Integer offsets from floor(x) and weights (n, k) of the 1-D kernel of ``method``."""
    if method == "nearest":
        off = np.where(frac >= 0.5, 1, 0)[:, None]
        return off, np.ones_like(frac)[:, None]
    if method == "bilinear":
        return np.array([[0, 1]]), np.stack([1.0 - frac, frac], axis=1)
    return np.array([[-1, 0, 1, 2]]), np.stack(keys_weights(frac), axis=1)


@dataclass(frozen=True)
class LatticeWindow:
    """Posts of a DEM already in memory, as plain data for a compiled lookup
    (``engine.terrain.window_heights``; same heights as ``DemSource.sample``)."""

    #: float32 (rows, cols) C-contiguous posts; NaN = no data (implausible heights not screened)
    data: np.ndarray
    #: float64 inverse geotransform (a, b, c, d, e, f): col + 0.5 = a x + b y + c,
    #: row + 0.5 = d x + e y + f (posts at integer (row, col))
    inv: np.ndarray
    #: int64 (first row, first column of the window, lattice rows, lattice columns)
    lattice: np.ndarray
    #: geographic DEM: x moved by whole turns of 360 deg next to this longitude; NaN: none
    wrap_centre: float
    #: WGS84 (lon, lat) -> DEM (x, y), float64; None: x, y are lon, lat
    transform: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None
    #: vertical datum of the posts (``dem.geoid``: "egm96" heights get N added)
    datum: str | None


class DemSource:
    """A DEM as a lattice of posts; subclasses give the lattice geometry and the post values."""

    name: str = "DEM"
    n_rows: int = 0
    n_cols: int = 0
    wrap_cols: bool = False
    #: vertical datum of the stored heights ("ellipsoid" or "egm96"); None: unknown (ellipsoid)
    datum: str | None = ELLIPSOID

    def set_datum(self, datum: str) -> None:
        """Declare the vertical datum of the stored heights (a ``PATH:datum`` DEM entry)."""
        self.datum = datum

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(lon_min, lat_min, lon_max, lat_max) covered, degrees."""
        raise NotImplementedError

    def _to_lattice(self, lon: np.ndarray, lat: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Fractional post (row, col) of each point (integers = posts) and an inside mask."""
        raise NotImplementedError

    def _fetch(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """float64 values of posts (rows, cols) (already clamped/wrapped); NaN = no data."""
        raise NotImplementedError

    def sample(self, lon: Any, lat: Any, method: str = "bilinear") -> np.ndarray:
        """Heights (m) at WGS84 (lon, lat) degrees; NaN outside or no data (module docstring)."""
        if method not in METHODS:
            raise DemError(f"{self.name}: unknown DEM interpolation {method!r}")
        lon, lat = np.broadcast_arrays(np.asarray(lon, dtype=np.float64),
                                       np.asarray(lat, dtype=np.float64))
        out = np.full(lon.size, np.nan)
        flon, flat = lon.reshape(-1), lat.reshape(-1)
        for a in range(0, lon.size, _CHUNK):
            b = min(a + _CHUNK, lon.size)
            out[a:b] = self._sample_chunk(flon[a:b], flat[a:b], method)
        if self.datum not in (None, ELLIPSOID):
            ok = np.isfinite(out)
            out[ok] = to_ellipsoid(out[ok], flon[ok], flat[ok], self.datum)
        return out.reshape(lon.shape)

    def _sample_chunk(self, lon: np.ndarray, lat: np.ndarray, method: str) -> np.ndarray:
        out = np.full(lon.size, np.nan)
        ok = np.isfinite(lon) & np.isfinite(lat)
        idx = np.flatnonzero(ok)
        if idx.size == 0:
            return out
        r, c, inside = self._to_lattice(lon[idx], lat[idx])
        idx, r, c = idx[inside], r[inside], c[inside]
        if idx.size == 0:
            return out
        r0, c0 = np.floor(r), np.floor(c)
        roff, rw = _kernel(r - r0, method)
        coff, cw = _kernel(c - c0, method)
        rows = r0.astype(np.int64)[:, None] + roff
        cols = c0.astype(np.int64)[:, None] + coff
        rows = np.clip(rows, 0, self.n_rows - 1)
        cols = cols % self.n_cols if self.wrap_cols else np.clip(cols, 0, self.n_cols - 1)
        kr, kc = rows.shape[1], cols.shape[1]
        rr = np.broadcast_to(rows[:, :, None], (idx.size, kr, kc))
        cc = np.broadcast_to(cols[:, None, :], (idx.size, kr, kc))
        vals = self._fetch(rr.reshape(-1), cc.reshape(-1)).reshape(idx.size, kr, kc)
        vals[~((vals >= MIN_TERRAIN_M) & (vals <= MAX_TERRAIN_M))] = np.nan  # implausible: no data
        out[idx] = np.einsum("nij,ni,nj->n", vals, rw, cw)
        return out

    #: posts read by ``prepare``: (first row, first column, float32 posts, NaN = no data)
    _posts: tuple[int, int, np.ndarray] | None = None

    def _lattice_inv(self) -> tuple[tuple[float, ...], float] | None:
        """For a lattice regular in WGS84 lon/lat: the inverse geotransform (a, b, c, d, e, f),
        col + 0.5 = a lon + b lat + c, row + 0.5 = d lon + e lat + f, and the longitude the
        lookups' longitudes are moved next to (NaN: none); None: ``prepare`` keeps no posts."""
        return None

    def missing_tiles(self, bounds: tuple[float, float, float, float]) -> list[str]:
        """Names of the tiles of this DEM's tiling under ``bounds`` (lon_min, lat_min, lon_max,
        lat_max; lon may pass 180) that it lacks: their points get no height from it. Empty
        for sources that are no tile directory."""
        return []

    def prepare(self, lon_min: float, lat_min: float, lon_max: float, lat_max: float) -> None:
        """Read the posts lookups inside these WGS84 bounds need (plus the bicubic margin),
        once, by ``_fetch`` (tile directories, memmapped tiles): the compiled lookup then
        finds them in memory (``lattice_window``). Nothing for a window over the lattice's
        wrap (the generic lookup wraps) or beyond the memory."""
        if self._lattice_inv() is None or not (
                lon_max > lon_min and lat_max > lat_min and lon_max - lon_min < 360.0):
            return
        t = np.linspace(0.0, 1.0, 21)  # the edges of the bounds
        lons, lats = lon_min + (lon_max - lon_min) * t, lat_min + (lat_max - lat_min) * t
        r, c, _ = self._to_lattice(np.r_[lons, lons, np.full(21, lon_min), np.full(21, lon_max)],
                                   np.r_[np.full(21, lat_min), np.full(21, lat_max), lats, lats])
        r0 = max(int(np.floor(r.min())) - 3, 0)
        r1 = min(int(np.ceil(r.max())) + 4, self.n_rows)
        c0 = max(int(np.floor(c.min())) - 3, 0)
        c1 = min(int(np.ceil(c.max())) + 4, self.n_cols)
        if r1 <= r0 or c1 <= c0:  # the bounds miss this lattice: an empty window
            self._posts = (0, 0, np.zeros((0, 0), np.float32))
            return
        if self.wrap_cols and (c0 == 0 or c1 == self.n_cols):
            return
        if (r1 - r0) * (c1 - c0) > pixel_limit(16):  # beyond the memory: read lazily
            return
        rows, cols = np.meshgrid(np.arange(r0, r1), np.arange(c0, c1), indexing="ij")
        posts = self._fetch(rows.reshape(-1), cols.reshape(-1)).astype(np.float32)
        self._posts = (r0, c0, posts.reshape(r1 - r0, c1 - c0))

    def lattice_window(self) -> LatticeWindow | None:
        """The prepared window as plain data (``LatticeWindow``), None without one."""
        geo = self._lattice_inv()
        if self._posts is None or geo is None:
            return None
        r0, c0, posts = self._posts
        return LatticeWindow(data=posts, inv=np.array(geo[0], dtype=np.float64),
                             lattice=np.array([r0, c0, self.n_rows, self.n_cols], np.int64),
                             wrap_centre=geo[1], transform=None, datum=self.datum)

    def parts(self) -> list[tuple[DemSource, str | None]]:
        """The lattices this DEM tries in order, with the vertical datum of their heights (a
        compiled lookup goes through each one's ``lattice_window``): itself."""
        return [(self, self.datum)]

    def close(self) -> None:
        """Release open files (memmaps, datasets) and prepared posts."""
        self._posts = None

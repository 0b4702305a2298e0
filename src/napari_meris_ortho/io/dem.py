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
  (``Copernicus_DSM_COG_10_N46_00_E010_00_DEM.tif``; ``io.copernicus``), only the tiles under
  the requested points read; a VRT is any GDAL raster.

Vertical datum (issue 11): every source has a ``datum``, "ellipsoid" or "egm96"; ``sample``
returns ellipsoidal heights (EGM96 heights + the geoid undulation N, ``io.geoid``). A DEM entry
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
import re
import stat
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from ..errors import DemError
from ..geometry.earth import MAX_TERRAIN_M, MIN_TERRAIN_M
from ..geometry.grid import pixel_limit
from ..geometry.interpolation import keys_weights
from ..options import Sampling, choices
from .geoid import EGM96, ELLIPSOID, crs_datum, geoid_grid_path, split_datum, to_ellipsoid

log = logging.getLogger(__name__)

METHODS = tuple(choices(Sampling))
_CHUNK = 1 << 18
GETASSE_POSTS = 1800
GETASSE_TILE_DEG = 15
GETASSE_PER_DEG = 120
GETASSE_FLOAT_SIZE = GETASSE_POSTS * GETASSE_POSTS * 4
GETASSE_INT16_SIZE = GETASSE_POSTS * GETASSE_POSTS * 2
_TILE_RE = re.compile(r"^(\d{2})([NS])(\d{3})([EW])\.GETASSE30$", re.IGNORECASE)
_ZIP_RE = re.compile(r"^(\d{2})([NS])(\d{3})([EW])(\.GETASSE30)?\.zip$", re.IGNORECASE)
_WGS84 = pyproj.CRS.from_epsg(4326)


def getasse_tile_name(lat0: int, lon0: int) -> str:
    """Tile name ``nnVeeeH`` from the lower-left corner (handbook chapter 5)."""
    return (f"{abs(lat0):02d}{'N' if lat0 >= 0 else 'S'}"
            f"{abs(lon0):03d}{'E' if lon0 >= 0 else 'W'}.GETASSE30")


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
    #: vertical datum of the posts (``io.geoid``: "egm96" heights get N added)
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


# ---------------------------------------------------------------------- GETASSE30
class _GetasseTile:
    """One GETASSE30 tile: lazily mapped values (rows as stored) and its row order."""

    def __init__(self, path: Path, member: str | None = None) -> None:
        self.path, self.member = path, member
        self._data: np.ndarray | None = None
        self.south_to_north = True
        size = self._size()
        if size == GETASSE_FLOAT_SIZE:
            self.kind = "float32"
        elif size == GETASSE_INT16_SIZE:
            self.kind, self.south_to_north = "int16", False
        else:
            raise DemError(f"{self._label}: {size} bytes is neither a GETASSE30 float32 tile "
                           f"({GETASSE_FLOAT_SIZE}) nor a BEAM int16 tile ({GETASSE_INT16_SIZE})")

    @property
    def _label(self) -> str:
        return f"{self.path}:{self.member}" if self.member else str(self.path)

    def _size(self) -> int:
        try:
            if self.member is None:
                return self.path.stat().st_size
            with zipfile.ZipFile(self.path) as zf:
                return zf.getinfo(self.member).file_size
        except (OSError, zipfile.BadZipFile, KeyError) as exc:
            raise DemError(f"{self._label}: cannot read GETASSE30 tile ({exc})") from exc

    def data(self) -> np.ndarray:
        if self._data is None:
            self._data = self._load()
        return self._data

    def _load(self) -> np.ndarray:
        try:
            raw: np.ndarray
            if self.member is None:
                raw = np.memmap(self.path, dtype=np.uint8, mode="r")
            else:
                with zipfile.ZipFile(self.path) as zf:
                    raw = np.frombuffer(zf.read(self.member), dtype=np.uint8)
        except (OSError, ValueError, zipfile.BadZipFile, KeyError) as exc:
            raise DemError(f"{self._label}: cannot read GETASSE30 tile ({exc})") from exc
        shape = (GETASSE_POSTS, GETASSE_POSTS)
        if self.kind == "int16":
            _check_int16_heights(raw, self._label)
            return raw.view(">i2").reshape(shape)
        return raw.view(_float_order(raw)).reshape(shape)

    def values(self, local_rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        rows = local_rows if self.south_to_north else GETASSE_POSTS - 1 - local_rows
        v = self.data()[rows, cols].astype(np.float64)
        if self.kind == "int16":
            v[(v == -32768) | (v == 32767)] = np.nan
        else:
            v[~np.isfinite(v) | (np.abs(v) > 1e5)] = np.nan
        return v


def _check_int16_heights(raw: np.ndarray, label: str) -> None:
    """A tile of the BEAM int16 size must hold int16 heights: half of a float32 tile read as
    int16 gives the exponent halves of the floats (|v| mostly > 9000 m) and is refused."""
    v = raw[: raw.size // 2 * 2].view(">i2")[::499].astype(np.int64)
    v = v[(v != -32768) & (v != 32767)]
    bad = np.sum((v < MIN_TERRAIN_M) | (v > MAX_TERRAIN_M))
    if v.size and bad > 0.05 * v.size:
        raise DemError(f"{label}: {100 * bad / v.size:.0f}% of the sampled posts are outside "
                       f"{MIN_TERRAIN_M:g}..{MAX_TERRAIN_M:g} m: not a BEAM int16 GETASSE30 tile "
                       "(half of a float32 tile?)")


def _float_order(raw: np.ndarray) -> str:
    """Byte order of a float32 tile: the one whose sampled values are plausible heights
    (0 or 1e-3 < |h| < 12 000 m; a swapped order gives huge, tiny or non-finite values)."""
    starts = np.arange(0, raw.size // 4, 997) * 4
    sample = np.ascontiguousarray(raw[starts[:, None] + np.arange(4)])
    best, score = "<f4", -1
    for order in ("<f4", ">f4"):
        v = sample.view(order)
        with np.errstate(invalid="ignore", over="ignore"):
            a = np.abs(v)
            good = int(np.sum(np.isfinite(v) & (a < 1.2e4) & ((a == 0) | (a > 1e-3))))
        if good > score:
            best, score = order, good
    return best


class GetasseSource(DemSource):
    """GETASSE30 tiles of a directory (both variants, plain or zipped); global 30" lattice with
    rows from South to North (row r at lat -90 + (r + 0.5)/120)."""

    n_rows = 180 * GETASSE_PER_DEG
    n_cols = 360 * GETASSE_PER_DEG
    wrap_cols = True

    def __init__(self, path: str | Path, files: Sequence[Path] | None = None) -> None:
        self.path = Path(path)
        self.name = str(path)
        self.tiles: dict[tuple[int, int], _GetasseTile] = {}
        for f in files if files is not None else sorted(self.path.iterdir()):
            self._add(f)
        if not self.tiles:
            raise DemError(f"{path}: no GETASSE30 tile found")

    def _add(self, f: Path) -> None:
        m = _TILE_RE.match(f.name)
        member = None
        if m is None:
            m = _ZIP_RE.match(f.name)
            if m is None:
                return
            member = _zip_member(f)
        lat0 = int(m.group(1)) * (1 if m.group(2).upper() == "N" else -1)
        lon0 = int(m.group(3)) * (1 if m.group(4).upper() == "E" else -1)
        if lat0 % GETASSE_TILE_DEG or lon0 % GETASSE_TILE_DEG or not (
                -90 <= lat0 < 90 and -180 <= lon0 < 180):
            raise DemError(f"{f}: not a 15-degree GETASSE30 tile name")
        key = ((lat0 + 90) // GETASSE_TILE_DEG, (lon0 + 180) // GETASSE_TILE_DEG)
        self.tiles.setdefault(key, _GetasseTile(f, member))

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        tr = np.array([k[0] for k in self.tiles])
        tc = np.array([k[1] for k in self.tiles])
        return (-180.0 + 15.0 * tc.min(), -90.0 + 15.0 * tr.min(),
                -180.0 + 15.0 * (tc.max() + 1), -90.0 + 15.0 * (tr.max() + 1))

    def _to_lattice(self, lon, lat):
        r = (lat + 90.0) * GETASSE_PER_DEG - 0.5
        c = (((lon + 180.0) % 360.0) * GETASSE_PER_DEG) - 0.5
        return r, c, (lat >= -90.0) & (lat <= 90.0)

    def _lattice_inv(self) -> tuple[tuple[float, ...], float] | None:
        """Posts every 30": col + 0.5 = 120 (lon + 180), row + 0.5 = 120 (lat + 90); lookups
        next to the prepared window's middle (it never spans the wrap)."""
        k = float(GETASSE_PER_DEG)
        mid = 0.0 if self._posts is None else (
            (self._posts[1] + 0.5 * self._posts[2].shape[1] + 0.5) / k - 180.0)
        return (k, 0.0, 180.0 * k, 0.0, k, 90.0 * k), mid

    def _fetch(self, rows, cols):
        out = np.full(rows.size, np.nan)
        n_tc = self.n_cols // GETASSE_POSTS
        key = (rows // GETASSE_POSTS) * n_tc + cols // GETASSE_POSTS
        present = np.flatnonzero(np.bincount(key, minlength=1))
        for k in present:
            tile = self.tiles.get((int(k) // n_tc, int(k) % n_tc))
            if tile is None:
                continue
            if present.size == 1:
                out[:] = tile.values(rows % GETASSE_POSTS, cols % GETASSE_POSTS)
                break
            m = key == k
            out[m] = tile.values(rows[m] % GETASSE_POSTS, cols[m] % GETASSE_POSTS)
        return out


def _zip_member(path: Path) -> str:
    try:
        with zipfile.ZipFile(path) as zf:
            names = [n for n in zf.namelist() if n.upper().endswith(".GETASSE30")]
    except (OSError, zipfile.BadZipFile) as exc:
        raise DemError(f"{path}: cannot read zip file ({exc})") from exc
    if len(names) != 1:
        raise DemError(f"{path}: expected one .GETASSE30 member, found {len(names)}")
    return names[0]


# ---------------------------------------------------------------------- SRTM30 / GTOPO30
def _read_hdr(path: Path) -> dict[str, str]:
    _check_regular(path)
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise DemError(f"{path}: cannot read header ({exc})") from exc
    out = {}
    for line in text.splitlines():
        parts = line.split()
        if len(parts) >= 2:
            out[parts[0].upper()] = parts[1]
    return out


class SrtmTile(DemSource):
    """One SRTM30/GTOPO30 ``.DEM`` tile (int16, ``.HDR`` header; ULXMAP/ULYMAP = post centre);
    heights above the EGM96 geoid."""

    datum = EGM96

    def __init__(self, dem_path: str | Path) -> None:
        p = Path(dem_path)
        dem = next((q for q in (p.with_suffix(".DEM"), p.with_suffix(".dem")) if q.exists()),
                   p.with_suffix(".DEM"))
        hdr = next((q for q in (p.with_suffix(".HDR"), p.with_suffix(".hdr")) if q.exists()),
                   p.with_suffix(".HDR"))
        self.name = str(dem)
        h = _read_hdr(hdr)
        try:
            self.n_rows, self.n_cols = int(h["NROWS"]), int(h["NCOLS"])
            self.ulx, self.uly = float(h["ULXMAP"]), float(h["ULYMAP"])
            self.xdim, self.ydim = float(h["XDIM"]), float(h["YDIM"])
            nbits = int(h.get("NBITS", "16"))
            self.nodata = float(h.get("NODATA", "-9999"))
        except (KeyError, ValueError) as exc:
            raise DemError(f"{hdr}: incomplete SRTM30/GTOPO30 header ({exc})") from exc
        order = ">" if h.get("BYTEORDER", "M").upper().startswith("M") else "<"
        signed = h.get("PIXELTYPE", "SIGNEDINT").upper().startswith("SIGNED")
        if nbits != 16 or self.xdim <= 0 or self.ydim <= 0:
            raise DemError(f"{hdr}: unsupported header (NBITS {nbits}, XDIM/YDIM must be > 0)")
        self.dtype = np.dtype(f"{order}{'i' if signed else 'u'}2")
        _check_regular(dem)
        try:
            size = dem.stat().st_size
        except OSError as exc:
            raise DemError(f"{dem}: cannot read DEM ({exc})") from exc
        if size != self.n_rows * self.n_cols * 2:
            raise DemError(f"{dem}: {size} bytes, expected {self.n_rows * self.n_cols * 2} "
                           f"({self.n_rows} x {self.n_cols} int16)")
        self.dem_path = dem
        self._data: np.ndarray | None = None

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        return (self.ulx - 0.5 * self.xdim, self.uly - (self.n_rows - 0.5) * self.ydim,
                self.ulx + (self.n_cols - 0.5) * self.xdim, self.uly + 0.5 * self.ydim)

    def _to_lattice(self, lon, lat):
        lon_c = 0.5 * (self.bounds[0] + self.bounds[2])
        lon = lon + 360.0 * np.round((lon_c - lon) / 360.0)
        r = (self.uly - lat) / self.ydim
        c = (lon - self.ulx) / self.xdim
        inside = (r >= -0.5) & (r < self.n_rows - 0.5) & (c >= -0.5) & (c < self.n_cols - 0.5)
        return r, c, inside

    def _lattice_inv(self) -> tuple[tuple[float, ...], float] | None:
        """col + 0.5 = (lon - ULXMAP) / XDIM + 0.5, row + 0.5 = (ULYMAP - lat) / YDIM + 0.5;
        lookups next to the tile's middle longitude."""
        return ((1.0 / self.xdim, 0.0, 0.5 - self.ulx / self.xdim, 0.0, -1.0 / self.ydim,
                 0.5 + self.uly / self.ydim), 0.5 * (self.bounds[0] + self.bounds[2]))

    def _fetch(self, rows, cols):
        if self._data is None:
            try:
                self._data = np.memmap(self.dem_path, dtype=self.dtype, mode="r",
                                       shape=(self.n_rows, self.n_cols))
            except (OSError, ValueError) as exc:
                raise DemError(f"{self.dem_path}: cannot read DEM ({exc})") from exc
        v = self._data[rows, cols].astype(np.float64)
        v[v == self.nodata] = np.nan
        return v

    def close(self) -> None:
        self._data = None
        super().close()


# ---------------------------------------------------------------------- GDAL rasters
class RasterSource(DemSource):
    """Any raster GDAL opens (GeoTIFF...), any CRS; posts at pixel centres; nodata honoured."""

    def __init__(self, path: str | Path, band: int = 1) -> None:
        import rasterio
        from rasterio.errors import RasterioError

        self.name = str(path)
        self._band = band
        try:
            self._ds = rasterio.open(path)
        except (RasterioError, OSError) as exc:
            raise DemError(f"{path}: cannot read DEM ({exc})") from exc
        ds = self._ds
        t = ds.transform
        if not (all(np.isfinite(tuple(t)[:6])) and abs(t.determinant) > 0):
            raise DemError(f"{path}: invalid georeferencing: pixel size {t.a:g} x {t.e:g} "
                           f"(transform {tuple(t)[:6]})")
        if ds.crs is None:
            raise DemError(f"{path}: the DEM has no coordinate reference system")
        if not 1 <= band <= ds.count:
            raise DemError(f"{path}: no band {band}")
        if ds.count > 1 and band == 1:
            raise DemError(f"{path}: {ds.count} bands, not a DEM (a DEM has one band of "
                           "heights; radiance GeoTIFFs are not DEMs)")
        self.n_rows, self.n_cols = ds.height, ds.width
        self.crs = pyproj.CRS.from_user_input(ds.crs.to_wkt())
        self.datum = _raster_datum(ds, self.crs)
        self._inv = ~ds.transform
        self._nodata = ds.nodatavals[band - 1]
        self._scale = float((ds.scales or (1.0,))[band - 1] or 1.0)
        self._offset = float((ds.offsets or (0.0,))[band - 1] or 0.0)
        self._tr = pyproj.Transformer.from_crs(_WGS84, self.crs, always_xy=True)
        self._geographic = self.crs.is_geographic
        #: lon/lat are the DEM's x/y (WGS84 geographic DEM): no transformation needed
        self._lonlat = self.crs.equals(_WGS84, ignore_axis_order=True)
        left, bottom, right, top = ds.bounds
        self._x_centre = 0.5 * (left + right)
        self._window: tuple[int, int, np.ndarray] | None = None
        self._prepared = False

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        from rasterio.warp import transform_bounds

        b = self._ds.bounds
        return tuple(transform_bounds(self._ds.crs, "EPSG:4326", *b, densify_pts=21))

    def _to_xy(self, lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """DEM CRS (x, y) of WGS84 (lon, lat), float64."""
        x, y = self._tr.transform(lon, lat, errcheck=False)
        return np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)

    def _to_lattice(self, lon, lat):
        x, y = self._to_xy(lon, lat)
        if self._geographic:
            x = x + 360.0 * np.round((self._x_centre - x) / 360.0)
        a = self._inv
        c = a.a * x + a.b * y + a.c - 0.5
        r = a.d * x + a.e * y + a.f - 0.5
        inside = (r >= -0.5) & (r < self.n_rows - 0.5) & (c >= -0.5) & (c < self.n_cols - 0.5)
        return r, c, inside

    def _read(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """Posts [r0, r1) x [c0, c1) as float heights (float32, float64 for rasters float32
        does not hold exactly; NaN = no data; implausible heights are screened at lookup),
        blocks decoded on all cores (``GDAL_NUM_THREADS``)."""
        import rasterio
        from rasterio.errors import RasterioError
        from rasterio.windows import Window

        raw = np.dtype(self._ds.dtypes[self._band - 1])
        scaled = self._scale != 1.0 or self._offset != 0.0
        direct = not scaled and raw.kind in "iuf" and np.can_cast(raw, np.float32, "safe")
        try:
            with rasterio.Env(GDAL_NUM_THREADS="ALL_CPUS"):  # float32 straight from GDAL
                data = self._ds.read(self._band, window=Window(c0, r0, c1 - c0, r1 - r0),
                                     out_dtype=np.float32 if direct else None)
        except (RasterioError, OSError) as exc:
            raise DemError(f"{self.name}: cannot read DEM ({exc})") from exc
        if direct:  # exact conversion: no data compares the same before and after it
            if self._nodata is not None and not np.isnan(self._nodata):
                np.putmask(data, data == self._nodata, np.float32(np.nan))
            return data
        nodata = np.isnan(data) if data.dtype.kind == "f" else np.zeros(data.shape, bool)
        if self._nodata is not None:
            nodata |= data == self._nodata
        dtype = np.result_type(data.dtype, np.float32)
        if scaled:
            data = data * self._scale + self._offset
        data = data.astype(dtype, copy=False)
        data[nodata] = np.nan
        return data

    def _covers(self, r0: int, r1: int, c0: int, c1: int) -> bool:
        w = self._window
        return w is not None and (w[0] <= r0 and w[1] <= c0 and r1 <= w[0] + w[2].shape[0]
                                  and c1 <= w[1] + w[2].shape[1])

    def _fetch(self, rows, cols):
        r0, r1, c0, c1 = int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1
        if not self._covers(r0, r1, c0, c1):
            data = self._read(r0, r1, c0, c1)
            if self._prepared:  # a point beyond the prepared footprint: keep the footprint
                return data[rows - r0, cols - c0].astype(np.float64)
            self._window = (r0, c0, data)
        w = self._window
        assert w is not None
        return w[2][rows - w[0], cols - w[1]].astype(np.float64)

    def prepare(self, lon_min: float, lat_min: float, lon_max: float, lat_max: float) -> None:
        """Read the posts under the WGS84 bounds (plus the bicubic margin) once."""
        from rasterio.errors import RasterioError
        from rasterio.warp import transform_bounds

        if not (lon_max > lon_min and lat_max > lat_min and lon_max - lon_min < 360.0):
            return
        try:
            x0, y0, x1, y1 = transform_bounds("EPSG:4326", self._ds.crs, lon_min, lat_min,
                                              lon_max, lat_max, densify_pts=21)
        except (RasterioError, ValueError):  # outside the DEM CRS's area: read lazily
            return
        if self._geographic:
            shift = 360.0 * np.round((self._x_centre - 0.5 * (x0 + x1)) / 360.0)
            x0, x1 = x0 + shift, x1 + shift
        a = self._inv
        cs = [a.a * x + a.b * y + a.c for x in (x0, x1) for y in (y0, y1)]
        rs = [a.d * x + a.e * y + a.f for x in (x0, x1) for y in (y0, y1)]
        r0 = max(int(np.floor(min(rs))) - 3, 0)
        r1 = min(int(np.ceil(max(rs))) + 3, self.n_rows)
        c0 = max(int(np.floor(min(cs))) - 3, 0)
        c1 = min(int(np.ceil(max(cs))) + 3, self.n_cols)
        if r1 <= r0 or c1 <= c0 or not all(np.isfinite(cs + rs)):
            return
        if (r1 - r0) * (c1 - c0) > pixel_limit(16):  # beyond the memory: read lazily
            return
        self._window = (r0, c0, self._read(r0, r1, c0, c1))
        self._prepared = True

    def lattice_window(self) -> LatticeWindow | None:
        """The prepared float32 window (``prepare``) as plain data; None before ``prepare``
        or for a float64 raster."""
        w = self._window
        if not self._prepared or w is None or w[2].dtype != np.float32:
            return None
        a = self._inv
        return LatticeWindow(
            data=np.ascontiguousarray(w[2]),
            inv=np.array([a.a, a.b, a.c, a.d, a.e, a.f], dtype=np.float64),
            lattice=np.array([w[0], w[1], self.n_rows, self.n_cols], dtype=np.int64),
            wrap_centre=self._x_centre if self._geographic else float("nan"),
            transform=None if self._lonlat else self._to_xy, datum=self.datum)

    def _sample_chunk(self, lon: np.ndarray, lat: np.ndarray, method: str) -> np.ndarray:
        """Bilinear lookups inside the prepared window: four flat gathers (same numbers as the
        generic 2x2 kernel); anything else: the generic path."""
        if method != "bilinear" or not self._prepared:
            return super()._sample_chunk(lon, lat, method)
        out = np.full(lon.size, np.nan)
        idx = np.flatnonzero(np.isfinite(lon) & np.isfinite(lat))
        r, c, inside = self._to_lattice(lon[idx], lat[idx])
        idx, r, c = idx[inside], r[inside], c[inside]
        if idx.size == 0:
            return out
        rf, cf = np.floor(r), np.floor(c)
        ra = np.clip(rf.astype(np.int64), 0, self.n_rows - 1)
        rb = np.clip(rf.astype(np.int64) + 1, 0, self.n_rows - 1)
        ca = np.clip(cf.astype(np.int64), 0, self.n_cols - 1)
        cb = np.clip(cf.astype(np.int64) + 1, 0, self.n_cols - 1)
        if not self._covers(int(ra.min()), int(rb.max()) + 1, int(ca.min()), int(cb.max()) + 1):
            return super()._sample_chunk(lon, lat, method)
        w0, wc0, data = self._window  # type: ignore[misc]
        flat = data.reshape(-1)
        ra, rb = (ra - w0) * data.shape[1], (rb - w0) * data.shape[1]
        ca, cb = ca - wc0, cb - wc0
        fr, fc = r - rf, c - cf
        top = _plausible(flat[ra + ca]) * (1.0 - fc) + _plausible(flat[ra + cb]) * fc
        bottom = _plausible(flat[rb + ca]) * (1.0 - fc) + _plausible(flat[rb + cb]) * fc
        out[idx] = top * (1.0 - fr) + bottom * fr
        return out

    def close(self) -> None:
        self._ds.close()


def _raster_datum(ds: Any, crs: pyproj.CRS) -> str | None:
    """Vertical datum of a GDAL raster: its ``VERTICAL_DATUM`` tag, its vertical CRS, or a
    Copernicus VRT (EGM96 for EGM2008); None when unknown."""
    tag = str(ds.tags().get("VERTICAL_DATUM", "")).lower()
    if tag in (EGM96, ELLIPSOID):
        return tag
    datum = crs_datum(crs)
    if datum is None and str(ds.name).lower().endswith(".vrt"):
        try:
            if "Copernicus_DSM" in Path(ds.name).read_text(errors="replace"):
                return EGM96
        except OSError:
            pass
    return datum


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
        h = np.full(lon.shape, np.nan)
        index = np.full(lon.shape, -1, dtype=np.int16)
        todo = np.ones(lon.shape, dtype=bool)
        for i, src in enumerate(self.sources):
            if not todo.any():
                break
            v = src.sample(lon[todo], lat[todo], method)
            got = np.isfinite(v)
            sel = np.flatnonzero(todo.ravel())[got]
            h.ravel()[sel] = v[got]
            index.ravel()[sel] = i
            todo.ravel()[sel] = False
        return h, index

    def prepare(self, lon_min: float, lat_min: float, lon_max: float, lat_max: float) -> None:
        """Read once what lookups inside these WGS84 bounds need, from every DEM."""
        for s in self.sources:
            s.prepare(lon_min, lat_min, lon_max, lat_max)

    def close(self) -> None:
        for s in self.sources:
            s.close()


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
    if EGM96 in _datums(src):
        geoid_grid_path()  # a missing geoid grid fails now, before any work
    return src


def _datums(src: DemSource) -> set[str | None]:
    """Vertical datums of a source and of its parts (a CompositeSource of tiles)."""
    parts = getattr(src, "sources", None)
    if parts is None:
        return {src.datum}
    return set().union(*(_datums(p) for p in parts)) if parts else {src.datum}


def _assume_ellipsoid(src: DemSource) -> None:
    """Ellipsoidal heights where a source (or a part of it) does not say its datum."""
    parts = getattr(src, "sources", None)
    if parts is None:
        if src.datum is None:
            src.set_datum(ELLIPSOID)
        return
    for p in parts:
        _assume_ellipsoid(p)
    datums = _datums(src)
    src.datum = datums.pop() if len(datums) == 1 else None


def _open_path(p: Path) -> DemSource:
    if not p.exists():
        raise DemError(f"{p}: DEM not found")
    if p.is_dir():
        return _open_directory(p)
    _check_regular(p)
    if _TILE_RE.match(p.name) or _ZIP_RE.match(p.name):
        return GetasseSource(p.parent, files=[p])
    if p.suffix.upper() in (".DEM", ".HDR"):
        return SrtmTile(p)
    return RasterSource(p)


def _check_regular(p: Path) -> None:
    """A DEM file must be a regular file (a FIFO would block the reader forever)."""
    try:
        mode = p.stat().st_mode
    except OSError as exc:
        raise DemError(f"{p}: cannot read DEM ({exc.strerror or exc})") from None
    if not stat.S_ISREG(mode):
        raise DemError(f"{p}: not a regular file")


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
        return CompositeSource(str(p), [SrtmTile(f) for f in dems])
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


__all__ = ["CompositeSource", "DemSource", "DemStack", "GetasseSource", "LatticeWindow",
           "RasterSource",
           "SrtmTile", "getasse_tile_name", "heights_or_fallback", "open_dem"]

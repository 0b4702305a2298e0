"""GETASSE30 tiles (handbook chapter 5): 15 x 15 deg, 1800 x 1800 posts of 30"; the handbook's
float32 variant (rows South to North, byte order from the values) and BEAM's int16 big-endian
variant (rows North to South, also zipped)."""

from __future__ import annotations

import math
import re
import zipfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..errors import DemError
from ..geometry.earth import MAX_TERRAIN_M, MIN_TERRAIN_M
from .base import DemSource

GETASSE_POSTS = 1800
GETASSE_TILE_DEG = 15
GETASSE_PER_DEG = 120
GETASSE_FLOAT_SIZE = GETASSE_POSTS * GETASSE_POSTS * 4
GETASSE_INT16_SIZE = GETASSE_POSTS * GETASSE_POSTS * 2
_TILE_RE = re.compile(r"^(\d{2})([NS])(\d{3})([EW])\.GETASSE30$", re.IGNORECASE)
_ZIP_RE = re.compile(r"^(\d{2})([NS])(\d{3})([EW])(\.GETASSE30)?\.zip$", re.IGNORECASE)


def getasse_tile_name(lat0: int, lon0: int) -> str:
    """Tile name ``nnVeeeH`` from the lower-left corner (handbook chapter 5)."""
    return (f"{abs(lat0):02d}{'N' if lat0 >= 0 else 'S'}"
            f"{abs(lon0):03d}{'E' if lon0 >= 0 else 'W'}.GETASSE30")


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
    int16 gives the exponent halves of the floats (|v| mostly > 9000 m) and is refused. Zero
    posts (sea) read the same either way and are left out of the count: half of a mostly-sea
    float32 tile (a scene's patch of land in it) passed as int16, with every height 0."""
    v = raw[: raw.size // 2 * 2].view(">i2")[::499].astype(np.int64)
    v = v[(v != -32768) & (v != 32767) & (v != 0)]
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


def _tile_key(lat0: int, lon0: int) -> tuple[int, int]:
    """(row, column) of the 15-degree tile whose south-west corner is ``lat0``, ``lon0``."""
    return (lat0 + 90) // GETASSE_TILE_DEG, (lon0 + 180) // GETASSE_TILE_DEG


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
        self.tiles.setdefault(_tile_key(lat0, lon0), _GetasseTile(f, member))

    def missing_tiles(self, bounds: tuple[float, float, float, float]) -> list[str]:
        """The 15-degree tiles under ``bounds`` the directory lacks (GETASSE30 covers the
        globe: a missing tile is one not copied)."""
        lon_min, lat_min, lon_max, lat_max = bounds
        out = []
        step = GETASSE_TILE_DEG
        lat_lo = max(-90, int(math.floor(lat_min / step)) * step)
        lat_hi = min(90, int(math.ceil(lat_max / step)) * step)
        for lat0 in range(lat_lo, lat_hi, step):
            for k in range(int(math.floor(lon_min / step)), int(math.ceil(lon_max / step))):
                lon0 = (k * step + 180) % 360 - 180
                if _tile_key(lat0, lon0) not in self.tiles:
                    out.append(getasse_tile_name(lat0, lon0))
        return out

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

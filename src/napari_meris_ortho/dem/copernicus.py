"""Copernicus DEM GLO-30 / GLO-90 tile directories as one DEM source.

Tiles are 1 x 1 deg, named from their south-west corner:
``Copernicus_DSM_COG_10_N46_00_E010_00_DEM.tif`` (GLO-30, 1"; ``_30_`` GLO-90, 3"; the DGED
names without ``COG_`` and ``.dt1``/``.dt2`` files are accepted too, in sub-directories up to 3
levels deep). The posts lie on whole multiples of the
spacing: post (k, c) of tile (lat0, lon0) at lat0 + 1 - k dy, lon0 + c dx (GeoTIFF origin half a
post west and north of it); the COG tiles hold 1/dy rows (the DGED ones one more, shared with
the neighbour). The longitude spacing grows with latitude (Copernicus DEM product handbook;
x1 below 50 deg, x1.5 to 60, x2 to 70, x3 to 80, x5 to 85, x10 beyond), so the tiles form one
global lattice per latitude zone, and bilinear interpolation crosses tile seams exactly.
Only the tiles under the requested points are opened, and only the window they need is read.
Heights are above EGM2008; they are turned into ellipsoidal heights with EGM2008 (``dem.geoid``;
EGM96 with a warning when PROJ's EGM2008 grid is not there).
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DemError
from .base import DemSource, cut_short, gdal_reason, open_raster
from .geoid import EGM2008, to_ellipsoid

NAME_RE = re.compile(r"^Copernicus_DSM(?:_COG)?_(10|30)_([NS])(\d{2})_00_([EW])(\d{3})_00_DEM"
                     r"\.(tif|tiff|dt1|dt2)$", re.IGNORECASE)
#: arc seconds of latitude spacing by the name's resolution code
ARCSEC = {"10": 1.0, "30": 3.0}
_ZONES = ((50.0, 1.0), (60.0, 1.5), (70.0, 2.0), (80.0, 3.0), (85.0, 5.0), (90.0, 10.0))
_MAX_DEPTH = 3


def tile_name(lat0: int, lon0: int, code: str = "30") -> str:
    """COG file name of the tile whose south-west corner is (lat0, lon0)."""
    return (f"Copernicus_DSM_COG_{code}_{'N' if lat0 >= 0 else 'S'}{abs(lat0):02d}_00_"
            f"{'E' if lon0 >= 0 else 'W'}{abs(lon0):03d}_00_DEM.tif")


def _short(lat0: int, lon0: int) -> str:
    return f"{'N' if lat0 >= 0 else 'S'}{abs(lat0):02d} {'E' if lon0 >= 0 else 'W'}{abs(lon0):03d}"


def lon_factor(lat0: int) -> float:
    """Longitude spacing / latitude spacing of the tiles with south edge ``lat0``."""
    near = min(abs(lat0), abs(lat0 + 1))
    return next(f for top, f in _ZONES if near < top)


def parse_name(name: str) -> tuple[str, int, int] | None:
    """(resolution code, lat0, lon0) of a tile file name, or None."""
    m = NAME_RE.match(name)
    if m is None:
        return None
    lat0 = int(m.group(3)) * (1 if m.group(2).upper() == "N" else -1)
    lon0 = int(m.group(5)) * (1 if m.group(4).upper() == "E" else -1)
    return m.group(1), lat0, lon0


def find_tiles(root: Path) -> dict[tuple[int, int], Path]:
    """Tiles under ``root`` by (lat0, lon0); {} when there are none. Mixed GLO-30 and GLO-90
    tiles are a DemError (they would form two lattices)."""
    found: dict[tuple[int, int], Path] = {}
    codes = set()
    root_depth = len(root.parts)
    for dirpath, dirnames, filenames in os.walk(root):
        if len(Path(dirpath).parts) - root_depth >= _MAX_DEPTH:
            dirnames[:] = []
        for f in sorted(filenames):
            parsed = parse_name(f)
            if parsed is not None:
                codes.add(parsed[0])
                found.setdefault(parsed[1:], Path(dirpath) / f)
    if len(codes) > 1:
        raise DemError(f"{root}: mixes GLO-30 and GLO-90 Copernicus tiles; give them as two "
                       "DEM entries")
    return found


class _Tile:
    """One tile file, opened on first use; reads windows of posts."""

    def __init__(self, path: Path, lat0: int, lon0: int, dx: float, dy: float) -> None:
        self.path, self.lat0, self.lon0, self.dx, self.dy = path, lat0, lon0, dx, dy
        self._ds: Any = None
        self._window: tuple[int, int, np.ndarray] | None = None

    def _open(self) -> Any:
        ds = open_raster(self.path, "Copernicus tile")
        t = ds.transform
        ok = (abs(t.a - self.dx) < 1e-3 * self.dx and abs(-t.e - self.dy) < 1e-3 * self.dy
              and abs(t.c - (self.lon0 - 0.5 * self.dx)) < 0.01 * self.dx
              and abs(t.f - (self.lat0 + 1 + 0.5 * self.dy)) < 0.01 * self.dy
              and ds.width >= round(1 / self.dx) and ds.height >= round(1 / self.dy))
        if not ok:
            ds.close()
            raise DemError(f"{self.path}: not a Copernicus DEM tile of its name (origin "
                           f"{t.c:.6f}, {t.f:.6f}, post {t.a:.7f} x {-t.e:.7f} deg, "
                           f"{ds.width} x {ds.height})")
        return ds

    def values(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        from rasterio.errors import RasterioError
        from rasterio.windows import Window

        if self._ds is None:
            self._ds = self._open()
        r0, r1, c0, c1 = int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1
        w = self._window
        if w is None or not (w[0] <= r0 and w[1] <= c0 and r1 <= w[0] + w[2].shape[0]
                             and c1 <= w[1] + w[2].shape[1]):
            try:
                data = self._ds.read(1, window=Window(c0, r0, c1 - c0, r1 - r0))
            except (RasterioError, OSError) as exc:
                raise cut_short(self.path, "Copernicus tile", gdal_reason(exc)) from exc
            data = data.astype(np.float64)
            nodata = self._ds.nodata
            if nodata is not None:
                data[data == nodata] = np.nan
            data[~np.isfinite(data) | (data < -1000.0)] = np.nan
            w = self._window = (r0, c0, data)
        return w[2][rows - w[0], cols - w[1]]

    def close(self) -> None:
        if self._ds is not None:
            self._ds.close()
            self._ds = None
        self._window = None


class _Zone(DemSource):
    """The tiles of one longitude-spacing zone as a global lattice of posts (module docstring):
    row r at lat 90 - r dy, column c at lon -180 + c dx."""

    wrap_cols = True

    def __init__(self, name: str, tiles: dict[tuple[int, int], _Tile], dx: float,
                 dy: float) -> None:
        self.name, self.tiles, self.dx, self.dy = name, tiles, dx, dy
        self.rows_per_tile = int(round(1.0 / dy))
        self.cols_per_tile = int(round(1.0 / dx))
        self.n_rows = 180 * self.rows_per_tile + 1
        self.n_cols = 360 * self.cols_per_tile
        lats = [k[0] for k in tiles]
        self.lat_range = (min(lats), max(lats) + 1)
        self.datum = None  # raw heights: the CopernicusSource applies the geoid

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        lons = [k[1] for k in self.tiles]
        return (float(min(lons)), float(self.lat_range[0]), float(max(lons) + 1),
                float(self.lat_range[1]))

    def _to_lattice(self, lon, lat):
        r = (90.0 - lat) / self.dy
        c = ((lon + 180.0) % 360.0) / self.dx
        inside = (lat >= self.lat_range[0]) & (lat <= self.lat_range[1])
        return r, c, inside

    def _lattice_inv(self) -> tuple[tuple[float, ...], float] | None:
        """Posts on whole multiples of dx, dy (pixel-is-point): col + 0.5 = (lon + 180) / dx
        + 0.5, row + 0.5 = (90 - lat) / dy + 0.5; lookups next to the prepared window's
        middle (it never spans the wrap)."""
        mid = 0.0 if self._posts is None else (
            (self._posts[1] + 0.5 * self._posts[2].shape[1]) * self.dx - 180.0)
        return ((1.0 / self.dx, 0.0, 180.0 / self.dx + 0.5, 0.0, -1.0 / self.dy,
                 90.0 / self.dy + 0.5), mid)

    def _fetch(self, rows, cols):
        out = np.full(rows.size, np.nan)
        n, m = self.rows_per_tile, self.cols_per_tile
        lat0 = 89 - rows // n
        lon0 = cols // m - 180
        key = (lat0 + 90) * 360 + (lon0 + 180)
        for k in np.unique(key):
            tile = self.tiles.get((int(k) // 360 - 90, int(k) % 360 - 180))
            if tile is None:
                continue
            sel = np.flatnonzero(key == k)
            out[sel] = tile.values(rows[sel] % n, cols[sel] % m)
        return out

    def close(self) -> None:
        for t in self.tiles.values():
            t.close()
        super().close()


class CopernicusSource(DemSource):
    """A directory of Copernicus DEM tiles as one DEM (module docstring); heights above EGM2008
    (EGM96 with a warning when only its grid is there, ``geoid.resolve_datum``) unless the
    entry says otherwise."""

    datum = EGM2008

    def __init__(self, path: str | Path, tiles: dict[tuple[int, int], Path] | None = None
                 ) -> None:
        self.path = Path(path)
        self.name = str(path)
        tiles = find_tiles(self.path) if tiles is None else tiles
        if not tiles:
            raise DemError(f"{path}: no Copernicus DEM tile found")
        parsed = parse_name(next(iter(tiles.values())).name)
        if parsed is None:
            raise DemError(f"{path}: not a Copernicus DEM tile name")
        code = parsed[0]
        dy = ARCSEC[code] / 3600.0
        self.resolution = "GLO-30" if code == "10" else "GLO-90"
        zones: dict[float, dict[tuple[int, int], _Tile]] = {}
        for (lat0, lon0), p in tiles.items():
            f = lon_factor(lat0)
            zones.setdefault(f, {})[lat0, lon0] = _Tile(p, lat0, lon0, dy * f, dy)
        self.zones = [_Zone(f"{path} (x{f:g})", z, dy * f, dy) for f, z in sorted(zones.items())]

    @property
    def tile_keys(self) -> list[tuple[int, int]]:
        return sorted(k for z in self.zones for k in z.tiles)

    @property
    def tiles_opened(self) -> list[tuple[int, int]]:
        """Tiles read so far (lat0, lon0): only those under the requested points."""
        return sorted(k for z in self.zones for k, t in z.tiles.items() if t._ds is not None)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        b = np.array([z.bounds for z in self.zones])
        return (b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max())

    def sample(self, lon: Any, lat: Any, method: str = "bilinear") -> np.ndarray:
        lon, lat = np.broadcast_arrays(np.asarray(lon, dtype=np.float64),
                                       np.asarray(lat, dtype=np.float64))
        out = np.full(lon.shape, np.nan)
        for z in self.zones:
            todo = ~np.isfinite(out)
            if not todo.any():
                break
            out[todo] = z.sample(lon[todo], lat[todo], method)
        if self.datum not in (None, "ellipsoid"):
            ok = np.isfinite(out)
            out[ok] = to_ellipsoid(out[ok], lon[ok], lat[ok], self.datum)
        return out

    def prepare(self, lon_min: float, lat_min: float, lon_max: float, lat_max: float) -> None:
        for z in self.zones:
            z.prepare(lon_min, lat_min, lon_max, lat_max)

    def parts(self) -> list[tuple[DemSource, str | None]]:
        """The zones in order; their raw heights are above this source's datum."""
        return [(z, self.datum) for z in self.zones]

    def check_covers(self, bounds: tuple[float, float, float, float]) -> None:
        """DemError unless a tile meets ``bounds`` (lon_min, lat_min, lon_max, lat_max; lon may
        be unwrapped past 180)."""
        lon_min, lat_min, lon_max, lat_max = bounds
        for lat0, lon0 in self.tile_keys:
            if lat0 + 1 < lat_min or lat0 > lat_max:
                continue
            rel = (lon0 - lon_min) % 360.0
            if rel <= lon_max - lon_min or rel >= 359.0:
                return
        have = ", ".join(_short(*k) for k in self.tile_keys[:6])
        more = "..." if len(self.tile_keys) > 6 else ""
        raise DemError(
            f"{self.path}: no Copernicus tile covers the product footprint (lon "
            f"{lon_min:.2f}..{lon_max:.2f}, lat {lat_min:.2f}..{lat_max:.2f}); the directory "
            f"holds {len(self.tile_keys)} tile(s): {have}{more}")

    def missing_tiles(self, bounds: tuple[float, float, float, float]) -> list[str]:
        """The 1-degree tiles under ``bounds`` the directory lacks (open sea has none)."""
        have = set(self.tile_keys)
        return [_short(*k) for k in covering_tiles(bounds) if k not in have]

    def close(self) -> None:
        for z in self.zones:
            z.close()


def covering_tiles(bounds: tuple[float, float, float, float]) -> list[tuple[int, int]]:
    """(lat0, lon0) of the 1-degree tiles meeting ``bounds`` (lon unwrapped, wrapped back)."""
    lon_min, lat_min, lon_max, lat_max = bounds
    out = []
    for lat0 in range(math.floor(lat_min), math.ceil(lat_max)):
        for k in range(math.floor(lon_min), math.ceil(lon_max)):
            out.append((lat0, (k + 180) % 360 - 180))
    return out


__all__ = ["CopernicusSource", "covering_tiles", "find_tiles", "lon_factor", "parse_name",
           "tile_name"]

"""SRTM30/GTOPO30 ``.DEM`` + ``.HDR`` tiles (ULXMAP/ULYMAP = centre of the upper-left post,
BYTEORDER M/I, NODATA -9999), EGM96 heights."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._atomic import check_input_file
from ..errors import DemError
from .base import DemSource
from .geoid import EGM96


# ---------------------------------------------------------------------- SRTM30 / GTOPO30
def _read_hdr(path: Path) -> dict[str, str]:
    check_input_file(path, "DEM header", DemError)
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
        check_input_file(dem, "DEM", DemError)
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


def srtm30_tiles(bounds: tuple[float, float, float, float]) -> list[str]:
    """Names of the SRTM30/GTOPO30 tiles meeting ``bounds`` (lon_min, lat_min, lon_max,
    lat_max; lon may pass 180): 40 x 50 deg tiles north of 60 S (``W020N90``: 20 W to 20 E,
    90 N to 40 N), 60 x 30 deg Antarctic tiles (``W000S60``: 0 to 60 E, 60 S to 90 S)."""
    lon_min, lat_min, lon_max, lat_max = bounds
    out = []
    rows = [(90, 40, 40, -180), (40, -10, 40, -180), (-10, -60, 40, -180), (-60, -90, 60, -180)]
    for top, bottom, width, west in rows:
        if lat_max <= bottom or lat_min >= top:
            continue
        for k in range(int((lon_min - west) // width), int(-(-(lon_max - west) // width))):
            lon0 = (west + k * width + 180) % 360 - 180
            name = (f"{'W' if lon0 < 0 or (lon0 == 0 and top == -60) else 'E'}{abs(lon0):03d}"
                    f"{'N' if top > 0 else 'S'}{abs(top):02d}")
            if name not in out:
                out.append(name)
    return out

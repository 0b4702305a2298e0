"""DEM and reference-image exports of a simulated scene, in the formats of the real DEMs.

All exports are resampled from the truth DEM (bilinear between its posts, ellipsoidal heights):

- ``geotiff``: the truth DEM itself (float32, EPSG:4326, posts at pixel centres). The terrain
  used by the simulator is *exactly* bilinear between these posts.
- ``getasse30`` (handbook chapter 5): 15 x 15 deg tiles ``45N015E.GETASSE30`` of 1800 x 1800
  little-endian float32, rows South to North, post (r, c) at (lat0 + (r+0.5)/120,
  lon0 + (c+0.5)/120), plus ``45N015E.GETASSE30_flag`` (uint16: 1 = from the simulator,
  0 = outside the scene, where the height is 0).
- ``getasse30_beam`` (BEAM/SNAP): the same tiles as int16 big-endian, rows North to South
  (lat0 + 15 - (r+0.5)/120); 0 outside the scene.
- ``srtm30`` (SRTM30/GTOPO30): 40 x 50 deg tiles ``W020N90.DEM`` (int16 big-endian, rows North
  to South) + ``.HDR`` (ULXMAP/ULYMAP = centre of the upper-left post); -9999 over the sea and
  outside the scene like real SRTM30; heights above the EGM96 geoid like real SRTM30
  (h - N, ``dem.geoid``).
- ``copernicus`` (Copernicus DEM GLO-90 COG tiles, ``dem.copernicus``): 1 x 1 deg float32
  ``Copernicus_DSM_COG_30_N46_00_E010_00_DEM.tif``, posts every 3" on whole multiples of the
  spacing (origin half a post north-west of the corner), heights above the EGM2008 geoid (EGM96
  where PROJ has no EGM2008 grid), as the Copernicus reader takes them
  (h - N), -32767 outside the scene.
- ``geotiff_utm``: a 250 m UTM GeoTIFF like the handbook's "DEM Italy" (float32, -9999 nodata).
  The GeoTIFF DEMs carry the tag ``VERTICAL_DATUM=ellipsoid``.
- reference image: truth radiances on the DEM posts (float32 GeoTIFF, one band per MERIS band,
  like the handbook's Landsat mosaic, section 4.3).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import rasterio
from rasterio.transform import Affine

from .._atomic import atomic_path
from .terrain import DemGrid

Sampler = Callable[[np.ndarray, np.ndarray], np.ndarray]
GETASSE_POSTS = 1800
PER_DEG = 120


def _write_tif(path: Path, data: np.ndarray, transform: Affine, crs: str,
               nodata: float | None, descriptions: Sequence[str] | None = None,
               tags: dict[str, str] | None = None) -> Path:
    arr = data if data.ndim == 3 else data[None]
    with atomic_path(path, suffix=".tif") as tmp:
        with rasterio.open(tmp, "w", driver="GTiff", width=arr.shape[2], height=arr.shape[1],
                           count=arr.shape[0], dtype=arr.dtype.name, crs=crs,
                           transform=transform, nodata=nodata, tiled=True, blockxsize=256,
                           blockysize=256, BIGTIFF="IF_SAFER") as dst:
            dst.write(arr)
            for i, text in enumerate(descriptions or (), start=1):
                dst.set_band_description(i, text)
            if tags:
                dst.update_tags(**tags)
    return path


def write_geographic_geotiff(path: Path, grid: DemGrid, data: np.ndarray,
                             nodata: float | None = None,
                             descriptions: Sequence[str] | None = None,
                             tags: dict[str, str] | None = None) -> Path:
    """A GeoTIFF on the DEM grid (EPSG:4326; lon0 may exceed 180 across the antimeridian)."""
    transform = Affine(grid.spacing, 0.0, grid.lon0, 0.0, -grid.spacing, grid.lat0)
    return _write_tif(path, data, transform, "EPSG:4326", nodata, descriptions, tags)


#: tag of our DEM GeoTIFFs naming the vertical datum of their heights (``dem``)
ELLIPSOIDAL = {"VERTICAL_DATUM": "ellipsoid"}


def geoid_heights(sample: Sampler, datum: str = "egm96") -> Sampler:
    """A sampler of heights above the geoid of ``datum`` (H = h - N) from an ellipsoidal one;
    "egm2008" is the geoid the readers will use for it (``dem.geoid.resolve_datum``: EGM96
    when PROJ's EGM2008 grid is not there), so that they give h back."""
    from ..dem.geoid import geoid_undulation, resolve_datum

    geoid = resolve_datum(datum) or datum

    def above_geoid(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        return sample(lon, lat) - geoid_undulation(lon, lat, geoid)

    return above_geoid


def _wrap(lon: np.ndarray | float) -> np.ndarray:
    return (np.asarray(lon) + 180.0) % 360.0 - 180.0


def _lon_tiles(lon_min: float, lon_max: float, width: int) -> list[int]:
    """Left edges (in [-180, 180)) of the ``width``-degree tiles meeting [lon_min, lon_max]."""
    out = []
    for left in range(-180, 180, width):
        rel = (left - lon_min) % 360.0
        if rel < lon_max - lon_min or rel > 360.0 - width:
            out.append(left)
    return out


def getasse_tiles(bounds: tuple[float, float, float, float]) -> list[tuple[int, int]]:
    """Lower-left corners (lat0, lon0) of the 15-degree tiles under ``bounds`` (lon unwrapped)."""
    lon_min, lat_min, lon_max, lat_max = bounds
    return [(lat0, lon0) for lat0 in range(-90, 90, 15) if lat0 < lat_max and lat0 + 15 > lat_min
            for lon0 in _lon_tiles(lon_min, lon_max, 15)]


def getasse_tile_name(lat0: int, lon0: int) -> str:
    """``nnVeeeH`` from the lower-left corner (handbook chapter 5)."""
    return (f"{abs(lat0):02d}{'N' if lat0 >= 0 else 'S'}"
            f"{abs(lon0):03d}{'E' if lon0 >= 0 else 'W'}.GETASSE30")


def _tile_heights(sample: Sampler, lat_rows: np.ndarray, lon_cols: np.ndarray,
                  grid: DemGrid) -> tuple[np.ndarray, np.ndarray]:
    """Heights of a tile's posts (rows as given) and a mask of posts inside the scene grid."""
    lon_min, lat_min, lon_max, lat_max = grid.bounds
    rows_in = np.nonzero((lat_rows >= lat_min) & (lat_rows <= lat_max))[0]
    rel = (lon_cols - lon_min) % 360.0
    cols_in = np.nonzero(rel <= lon_max - lon_min)[0]
    heights = np.zeros((lat_rows.size, lon_cols.size), np.float64)
    inside = np.zeros(heights.shape, bool)
    if rows_in.size and cols_in.size:
        lo, la = np.meshgrid(lon_cols[cols_in], lat_rows[rows_in])
        h = sample(lo.ravel(), la.ravel()).reshape(lo.shape)
        ok = np.isfinite(h)
        block = np.where(ok, h, 0.0)
        heights[np.ix_(rows_in, cols_in)] = block
        inside[np.ix_(rows_in, cols_in)] = ok
    return heights, inside


def write_getasse30(out_dir: Path, sample: Sampler, grid: DemGrid,
                    variant: str = "handbook") -> Path:
    """GETASSE30 tiles under the scene, handbook (float32, S->N) or BEAM (int16 BE, N->S)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    post = (np.arange(GETASSE_POSTS) + 0.5) / PER_DEG
    for lat0, lon0 in getasse_tiles(grid.bounds):
        name = getasse_tile_name(lat0, lon0)
        lon_cols = lon0 + post
        if variant == "handbook":
            lat_rows = lat0 + post
            heights, inside = _tile_heights(sample, lat_rows, lon_cols, grid)
            with atomic_path(out_dir / name) as tmp:
                heights.astype("<f4").tofile(tmp)
            with atomic_path(out_dir / f"{name}_flag") as tmp:
                inside.astype("<u2").tofile(tmp)
        else:
            lat_rows = lat0 + 15 - post
            heights, _ = _tile_heights(sample, lat_rows, lon_cols, grid)
            with atomic_path(out_dir / name) as tmp:
                np.clip(np.round(heights), -32767, 32766).astype(">i2").tofile(tmp)
    return out_dir


def srtm30_tiles(bounds: tuple[float, float, float, float]) -> list[tuple[int, int, int, int]]:
    """(left lon, top lat, width, height) in degrees of the GTOPO30/SRTM30 tiles under
    ``bounds``: 40 x 50 deg north of 60 S (W180N90 ... E140S10), 60 x 30 deg below."""
    lon_min, lat_min, lon_max, lat_max = bounds
    out: list[tuple[int, int, int, int]] = []
    for top, height, width in ((90, 50, 40), (40, 50, 40), (-10, 50, 40), (-60, 30, 60)):
        if lat_max <= top - height or lat_min >= top:
            continue
        out.extend((left, top, width, height) for left in _lon_tiles(lon_min, lon_max, width))
    return out


def srtm30_tile_name(left: int, top: int) -> str:
    """``W020N90`` from the upper-left corner."""
    return f"{'W' if left < 0 else 'E'}{abs(left):03d}{'N' if top > 0 else 'S'}{abs(top):02d}"


def write_srtm30(out_dir: Path, sample: Sampler, sea: Sampler, grid: DemGrid) -> list[Path]:
    """SRTM30-style ``.DEM`` + ``.HDR`` tiles under the scene (-9999 over sea and outside);
    ``sample`` gives ellipsoidal heights, the tiles hold heights above the geoid."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for left, top, width, height in srtm30_tiles(grid.bounds):
        nrows, ncols = height * PER_DEG, width * PER_DEG
        lat_rows = top - (np.arange(nrows) + 0.5) / PER_DEG
        lon_cols = left + (np.arange(ncols) + 0.5) / PER_DEG
        heights, inside = _tile_heights(geoid_heights(sample), lat_rows, lon_cols, grid)
        values = np.full(heights.shape, -9999, dtype=">i2")
        keep = inside.copy()
        rr, cc = np.nonzero(inside)
        if rr.size:
            keep[rr, cc] = ~sea(lon_cols[cc], lat_rows[rr])
        values[keep] = np.clip(np.round(heights[keep]), -9998, 32767)
        name = srtm30_tile_name(left, top)
        dem_path = out_dir / f"{name}.DEM"
        with atomic_path(dem_path) as tmp:
            values.tofile(tmp)
        hdr = (f"BYTEORDER      M\nLAYOUT         BIL\nNROWS          {nrows}\n"
               f"NCOLS          {ncols}\nNBANDS         1\nNBITS          16\n"
               f"BANDROWBYTES   {2 * ncols}\nTOTALROWBYTES  {2 * ncols}\n"
               f"BANDGAPBYTES   0\nNODATA         -9999\n"
               f"ULXMAP         {left + 0.5 / PER_DEG:.14f}\n"
               f"ULYMAP         {top - 0.5 / PER_DEG:.14f}\n"
               f"XDIM           {1 / PER_DEG:.14f}\nYDIM           {1 / PER_DEG:.14f}\n")
        with atomic_path(out_dir / f"{name}.HDR") as tmp:
            tmp.write_text(hdr)
        paths.append(dem_path)
    return paths


def utm_epsg(lon: float, lat: float) -> int:
    """EPSG code of the WGS84 UTM zone of a point."""
    zone = int(math.floor((_wrap(lon) + 180.0) / 6.0)) % 60 + 1
    return (32600 if lat >= 0 else 32700) + zone


def write_utm_geotiff(path: Path, sample: Sampler, grid: DemGrid,
                      spacing_m: float = 250.0) -> Path:
    """The truth DEM resampled (bilinear) on a UTM grid, like the handbook's "DEM Italy"."""
    from pyproj import Transformer

    lon_min, lat_min, lon_max, lat_max = grid.bounds
    lon_c = 0.5 * (lon_min + lon_max)
    lat_c = 0.5 * (lat_min + lat_max)
    epsg = utm_epsg(lon_c, lat_c)
    fwd = Transformer.from_crs(4326, epsg, always_xy=True)
    lo = np.linspace(lon_min, lon_max, 41)
    la = np.linspace(lat_min, lat_max, 41)
    lo2, la2 = np.meshgrid(lo, la)
    x, y = fwd.transform(_wrap(lo2), la2)
    x0 = math.floor(np.min(x) / spacing_m) * spacing_m
    x1 = math.ceil(np.max(x) / spacing_m) * spacing_m
    y0 = math.floor(np.min(y) / spacing_m) * spacing_m
    y1 = math.ceil(np.max(y) / spacing_m) * spacing_m
    ncols = int(round((x1 - x0) / spacing_m))
    nrows = int(round((y1 - y0) / spacing_m))
    inv = Transformer.from_crs(epsg, 4326, always_xy=True)
    out = np.empty((nrows, ncols), np.float32)
    xs = x0 + (np.arange(ncols) + 0.5) * spacing_m
    for r0 in range(0, nrows, 256):
        ys = y1 - (np.arange(r0, min(r0 + 256, nrows)) + 0.5) * spacing_m
        xx, yy = np.meshgrid(xs, ys)
        lon, lat = inv.transform(xx, yy)
        h = sample(lon.ravel(), lat.ravel()).reshape(xx.shape)
        out[r0:r0 + ys.size] = np.where(np.isfinite(h), h, -9999.0)
    transform = Affine(spacing_m, 0.0, x0, 0.0, -spacing_m, y1)
    return _write_tif(path, out, transform, f"EPSG:{epsg}", -9999.0, tags=ELLIPSOIDAL)


def write_copernicus(out_dir: Path, sample: Sampler, grid: DemGrid, code: str = "30",
                     nodata: float = -32767.0) -> list[Path]:
    """Copernicus DEM COG tiles under the scene (module docstring); ``sample`` gives the heights
    to store (the caller passes geoid heights)."""
    from ..dem.copernicus import ARCSEC, covering_tiles, lon_factor, tile_name

    out_dir.mkdir(parents=True, exist_ok=True)
    dy = ARCSEC[code] / 3600.0
    paths = []
    for lat0, lon0 in covering_tiles(grid.bounds):
        dx = dy * lon_factor(lat0)
        n, m = int(round(1 / dy)), int(round(1 / dx))
        lat_rows = lat0 + 1 - np.arange(n) * dy
        lon_cols = lon0 + np.arange(m) * dx
        heights, inside = _tile_heights(sample, lat_rows, lon_cols, grid)
        data = np.where(inside, heights, nodata).astype(np.float32)
        transform = Affine(dx, 0.0, lon0 - 0.5 * dx, 0.0, -dy, lat0 + 1 + 0.5 * dy)
        paths.append(_write_tif(out_dir / tile_name(lat0, lon0, code), data, transform,
                                "EPSG:4326", nodata))
    return paths

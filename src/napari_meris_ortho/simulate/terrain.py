"""Synthetic ground truth terrain: the scene's DEM grid and its heights.

The DEM is a geographic grid of posts (rows North to South, posts at pixel centres) of heights
above the WGS84 ellipsoid; the terrain surface is *bilinear between these posts* everywhere in the
simulator. Relief: ridged multifractal mountain ranges (sharp ridges, deep valleys) inside
envelopes given by the scene config, low rolling plains, a sea (height 0) behind a fractal
coastline, and flat lakes; under the sea a seabed (``bathymetry``) for the tie points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft

from .sensor import D_BLOCK, D_DLAT, D_DLON, D_HMAX, D_HMIN, D_LAT0, D_LON0, D_SPMIN

KM_PER_DEG = 111.195


@dataclass
class DemGrid:
    """Geographic grid of posts: post (r, c) at (lon0 + (c + 0.5) d, lat0 - (r + 0.5) d),
    where (lon0, lat0) is the upper-left corner (GeoTIFF pixel-is-area convention)."""

    lon0: float
    lat0: float
    spacing: float
    nrows: int
    ncols: int

    @property
    def post_lons(self) -> np.ndarray:
        return self.lon0 + (np.arange(self.ncols) + 0.5) * self.spacing

    @property
    def post_lats(self) -> np.ndarray:
        return self.lat0 - (np.arange(self.nrows) + 0.5) * self.spacing

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(lon_min, lat_min, lon_max, lat_max) of the outer pixel edges (lon may exceed 180)."""
        return (self.lon0, self.lat0 - self.nrows * self.spacing,
                self.lon0 + self.ncols * self.spacing, self.lat0)

    @classmethod
    def covering(cls, lon_min: float, lat_min: float, lon_max: float, lat_max: float,
                 spacing: float) -> DemGrid:
        """Grid aligned on multiples of ``spacing`` covering the box (lon_max may exceed 180)."""
        c0 = math.floor(lon_min / spacing)
        c1 = math.ceil(lon_max / spacing)
        r0 = math.floor(lat_min / spacing)
        r1 = math.ceil(lat_max / spacing)
        return cls(lon0=c0 * spacing, lat0=r1 * spacing, spacing=spacing,
                   nrows=r1 - r0, ncols=c1 - c0)

    def km_coordinates(self, lon_c: float, lat_c: float) -> tuple[np.ndarray, np.ndarray]:
        """Local east/north kilometres of the posts (1-D x per column, 1-D y per row)."""
        x = (self.post_lons - lon_c) * KM_PER_DEG * math.cos(math.radians(lat_c))
        y = (self.post_lats - lat_c) * KM_PER_DEG
        return x, y

    def geo_vector(self, dem: np.ndarray, block: int) -> np.ndarray:
        """Packed parameters of the numba kernels (sensor.D_*)."""
        geo = np.zeros(8)
        geo[D_LON0] = self.lon0 + 0.5 * self.spacing
        geo[D_LAT0] = self.lat0 - 0.5 * self.spacing
        geo[D_DLON] = self.spacing
        geo[D_DLAT] = self.spacing
        geo[D_BLOCK] = block
        lat_far = max(abs(self.lat0), abs(self.lat0 - self.nrows * self.spacing))
        geo[D_SPMIN] = self.spacing * KM_PER_DEG * 1000.0 * max(math.cos(math.radians(lat_far)),
                                                                0.02)
        geo[D_HMIN] = float(np.min(dem))
        geo[D_HMAX] = float(np.max(dem))
        return geo


def block_max(dem: np.ndarray, block: int) -> np.ndarray:
    """Maximum of the posts of each block of ``block`` x ``block`` posts, dilated by one block
    (so that every point within ``block`` posts of a block is bounded by its value)."""
    nr, nc = dem.shape
    br = -(-nr // block)
    bc = -(-nc // block)
    pad = np.full((br * block, bc * block), -np.inf, dtype=np.float64)
    pad[:nr, :nc] = dem
    bm = pad.reshape(br, block, bc, block).max(axis=(1, 3))
    big = np.pad(bm, 1, mode="edge")
    out = bm.copy()
    for di in (0, 1, 2):
        for dj in (0, 1, 2):
            np.maximum(out, big[di:di + br, dj:dj + bc], out=out)
    return out


def band_noise(rng: np.random.Generator, shape: tuple[int, int], cell_km: tuple[float, float],
               wavelength_km: float, slope: float | None = None) -> np.ndarray:
    """Unit-variance Gaussian noise: band-pass around ``wavelength_km`` or, with ``slope``, a
    fractal (power-law) spectrum from ``wavelength_km`` down to the grid cell."""
    nr, nc = shape
    ky = np.fft.fftfreq(nr, d=cell_km[1])[:, None].astype(np.float32)
    kx = np.fft.rfftfreq(nc, d=cell_km[0])[None, :].astype(np.float32)
    k = np.sqrt(kx * kx + ky * ky)
    k0 = 1.0 / wavelength_km
    if slope is None:
        amp = np.exp(-0.5 * (np.log(np.maximum(k, 1e-9) / k0) / 0.35) ** 2)
    else:
        amp = np.where(k > 0, (np.maximum(k, k0)) ** (-slope / 2.0), 0.0)
    spec = (rng.standard_normal(k.shape, dtype=np.float32)
            + 1j * rng.standard_normal(k.shape, dtype=np.float32)) * amp.astype(np.float32)
    field = scipy.fft.irfft2(spec, s=shape, workers=2).astype(np.float32)
    std = float(field.std())
    return field / std if std > 0 else field


def _segment_distance(x: np.ndarray, y: np.ndarray, a: tuple[float, float],
                      b: tuple[float, float]) -> np.ndarray:
    ax, ay = a
    bx, by = b
    dx, dy = bx - ax, by - ay
    length2 = dx * dx + dy * dy
    t = ((x - ax) * dx + (y - ay) * dy) / max(length2, 1e-9)
    t = np.clip(t, 0.0, 1.0)
    return np.hypot(x - (ax + t * dx), y - (ay + t * dy))


def _to_km(lon: float, lat: float, lon_c: float, lat_c: float) -> tuple[float, float]:
    dlon = (lon - lon_c + 180.0) % 360.0 - 180.0
    return dlon * KM_PER_DEG * math.cos(math.radians(lat_c)), (lat - lat_c) * KM_PER_DEG


@dataclass
class Terrain:
    """Heights (float32, rows North to South) and water masks on a DemGrid."""

    grid: DemGrid
    height: np.ndarray
    sea: np.ndarray
    lake: np.ndarray

    @property
    def water(self) -> np.ndarray:
        return self.sea | self.lake


def make_terrain(grid: DemGrid, cfg: dict, seed: int) -> Terrain:
    """Build the relief described by the ``terrain`` part of a scene config."""
    rng = np.random.default_rng(seed)
    lon_c = grid.lon0 + 0.5 * grid.ncols * grid.spacing
    lat_c = grid.lat0 - 0.5 * grid.nrows * grid.spacing
    xs, ys = grid.km_coordinates(lon_c, lat_c)
    x = xs[None, :].astype(np.float32)
    y = ys[:, None].astype(np.float32)
    shape = (grid.nrows, grid.ncols)
    cell = (abs(xs[1] - xs[0]) if grid.ncols > 1 else 1.0, grid.spacing * KM_PER_DEG)

    envelope = np.zeros(shape, np.float32)
    peak = np.zeros(shape, np.float32)
    for rng_cfg in cfg.get("ranges", []):
        (lon_a, lat_a), (lon_b, lat_b) = rng_cfg["from"], rng_cfg["to"]
        a = _to_km(lon_a, lat_a, lon_c, lat_c)
        b = _to_km(lon_b, lat_b, lon_c, lat_c)
        d = _segment_distance(x, y, a, b)
        env = np.exp(-((d / float(rng_cfg["width_km"])) ** 2)).astype(np.float32)
        np.maximum(peak, np.where(env > envelope, float(rng_cfg["height"]), peak), out=peak)
        np.maximum(envelope, env, out=envelope)
    # ridged multifractal: sharp crests where the band noise crosses zero
    ridged = np.zeros(shape, np.float32)
    weight = 1.0
    total = 0.0
    for wavelength in (60.0, 25.0, 11.0, 5.0, 2.2):
        n = band_noise(rng, shape, cell, wavelength)
        ridged += weight * (1.0 - np.minimum(np.abs(n) / 1.6, 1.0)) ** 2
        total += weight
        weight *= 0.55
    ridged /= total
    mountains = peak * envelope * np.clip(0.15 + 1.1 * ridged, 0.0, 1.0) ** 1.3
    hills = float(cfg.get("plain_height", 120.0)) * (1.2 + 0.6 * band_noise(rng, shape, cell,
                                                                             80.0, slope=3.2))
    height = np.maximum(hills, 5.0) + mountains

    sea_score = np.zeros(shape, np.float32)
    for sea in cfg.get("seas", []):
        cx, cy = _to_km(sea["lon"], sea["lat"], lon_c, lat_c)
        d = np.hypot(x - cx, y - cy)
        np.maximum(sea_score, np.exp(-((d / float(sea["radius_km"])) ** 2)), out=sea_score)
    coast = band_noise(rng, shape, cell, 150.0, slope=3.0)
    landness = (0.5 - sea_score) + 0.12 * coast + 0.4 * envelope
    sea = landness <= 0.0
    height *= np.clip(landness * 6.0, 0.0, 1.0)
    height[sea] = 0.0

    lake = np.zeros(shape, bool)
    lake_noise = band_noise(rng, shape, cell, 6.0, slope=2.5)
    for lk in cfg.get("lakes", []):
        cx, cy = _to_km(lk["lon"], lk["lat"], lon_c, lat_c)
        d = np.hypot(x - cx, y - cy) / float(lk["radius_km"])
        mask = (d + 0.25 * lake_noise < 1.0) & ~sea
        if mask.any():
            level = float(np.percentile(height[mask], 20))
            lake |= mask
            height[mask] = level
    return Terrain(grid=grid, height=height.astype(np.float32), sea=sea, lake=lake)


#: seabed model of ``bathymetry``: depth at the coast (m), shelf slope (m/km) over the first
#: ``SHELF_KM``, continental slope (m/km) beyond, abyssal plain depth (m)
COAST_DEPTH_M, SHELF_SLOPE, SHELF_KM = 20.0, 3.0, 50.0
CONTINENTAL_SLOPE, ABYSSAL_DEPTH_M = 37.0, 5500.0


def bathymetry(terrain: Terrain) -> np.ndarray:
    """Seabed height (float32, m, negative) under the sea posts of ``terrain``, 0 elsewhere: a
    shelf falling 3 m/km from -20 m at the coast for 50 km, then 37 m/km down to an abyssal
    plain at -5500 m (real tie points: -228 m off Portugal, -5103 m in the open Pacific).
    The scene's DEM keeps the sea surface (height 0), as DEMs do; only the tie points' auxiliary
    DEM carries the seabed, as ESA's does."""
    from scipy.ndimage import distance_transform_edt

    if not terrain.sea.any():
        return np.zeros(terrain.sea.shape, np.float32)
    g = terrain.grid
    lat_c = g.lat0 - 0.5 * g.nrows * g.spacing
    cell = (g.spacing * KM_PER_DEG, g.spacing * KM_PER_DEG * math.cos(math.radians(lat_c)))
    d = distance_transform_edt(terrain.sea, sampling=cell)
    depth = (COAST_DEPTH_M + SHELF_SLOPE * np.minimum(d, SHELF_KM)
             + CONTINENTAL_SLOPE * np.maximum(d - SHELF_KM, 0.0))
    return np.where(terrain.sea, -np.minimum(depth, ABYSSAL_DEPTH_M), 0.0).astype(np.float32)


def box_smooth(a: np.ndarray, size: int) -> np.ndarray:
    """Mean over a ``size`` x ``size`` window (edges: the window is clipped)."""
    from scipy.ndimage import uniform_filter

    return uniform_filter(a.astype(np.float64), size=max(int(size), 1), mode="nearest")


def auxiliary_dem(height: np.ndarray, spacing: float,
                  window_deg: float = 5.0 / 60.0) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed DEM and roughness like the MERIS auxiliary DEM (about 5 arc-minutes; handbook
    section 4.4: its peaks are too low). Returns (dem_alt, dem_rough) on the same posts."""
    size = max(int(round(window_deg / spacing)), 1)
    mean = box_smooth(height, size)
    mean2 = box_smooth(height.astype(np.float64) ** 2, size)
    rough = np.sqrt(np.maximum(mean2 - mean * mean, 0.0))
    return mean, rough

"""Ground-truth radiometry: land cover, 15-band spectra, texture, clouds, flags.

The truth radiance of band b at a ground point is *bilinear between the DEM posts* of the post
radiances ``(sum_c cover_c * spectrum[c, b]) * brightness`` mixed with the cloud spectrum by the
cloud cover. Radiances are TOA values in mW m-2 sr-1 nm-1 (the unit of the L1b counts times the
Scaling Factor GADS of Appendix A).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from ..flags import FLAG_BRIGHT, FLAG_COASTLINE, FLAG_GLINT_RISK, FLAG_INVALID, FLAG_LAND_OCEAN
from .sensor import D_DLAT, D_DLON, D_LAT0, D_LON0
from .terrain import KM_PER_DEG, Terrain, band_noise

#: MERIS band centres (nm)
WAVELENGTHS = (412.5, 442.5, 490.0, 510.0, 560.0, 620.0, 665.0, 681.25, 708.75, 753.75,
               760.625, 778.75, 865.0, 885.0, 900.0)
CLASSES = ("water", "vegetation", "rock", "snow")
#: TOA radiance spectra of the classes (mW m-2 sr-1 nm-1, sun zenith about 50 deg)
SPECTRA = np.array([
    [72, 62, 48, 41, 30, 18, 14, 13, 11, 8, 5, 7, 5, 4.5, 4],            # water
    [70, 61, 51, 45, 43, 30, 24, 25, 44, 94, 50, 96, 93, 88, 70],          # vegetation
    [84, 81, 80, 80, 85, 86, 83, 81, 79, 73, 38, 71, 63, 60, 50],          # rock / bare soil
    [175, 185, 182, 178, 172, 160, 150, 148, 140, 125, 60, 120, 100, 95, 75],  # snow
], dtype=np.float64)
CLOUD_SPECTRUM = np.array([205, 212, 206, 200, 195, 186, 180, 178, 172, 162, 82, 158, 140,
                           135, 110], dtype=np.float64)

#: flags kept on the DEM posts (nearest post of T)
POST_LAND, POST_COAST, POST_SNOW = 1, 2, 4


@dataclass
class GroundTruth:
    """Per-post fields: cover (4, rows, cols) uint8 fractions x 255, brightness float32,
    cloud uint8 (x 255), post flags uint8."""

    cover: np.ndarray
    brightness: np.ndarray
    cloud: np.ndarray
    post_flags: np.ndarray


def solar_angles(t: np.ndarray, lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sun zenith and azimuth (deg, azimuth clockwise from north) at MJD2000 seconds ``t``
    (NOAA general solar position: fractional-year series for declination and equation of time)."""
    t = np.asarray(t, dtype=np.float64)
    days = t / 86400.0
    # day of year from 2000-01-01 with a mean year: good to a few hundredths of a degree
    year_frac = 2.0 * np.pi / 365.2422 * ((days + 0.0) % 365.2422)
    g = year_frac
    eqtime = 229.18 * (0.000075 + 0.001868 * np.cos(g) - 0.032077 * np.sin(g)
                       - 0.014615 * np.cos(2 * g) - 0.040849 * np.sin(2 * g))
    decl = (0.006918 - 0.399912 * np.cos(g) + 0.070257 * np.sin(g) - 0.006758 * np.cos(2 * g)
            + 0.000907 * np.sin(2 * g) - 0.002697 * np.cos(3 * g) + 0.00148 * np.sin(3 * g))
    minutes = (days % 1.0) * 1440.0
    tst = minutes + eqtime + 4.0 * np.asarray(lon)
    ha = np.radians(tst / 4.0 - 180.0)
    la = np.radians(lat)
    cos_z = np.sin(la) * np.sin(decl) + np.cos(la) * np.cos(decl) * np.cos(ha)
    zen = np.arccos(np.clip(cos_z, -1.0, 1.0))
    # azimuth clockwise from north
    east = -np.cos(decl) * np.sin(ha)
    north = np.cos(la) * np.sin(decl) - np.sin(la) * np.cos(decl) * np.cos(ha)
    az = np.degrees(np.arctan2(east, north)) % 360.0
    return np.degrees(zen), az


def ecmwf_fields(lon: np.ndarray, lat: np.ndarray) -> dict[str, np.ndarray]:
    """Smooth, plausible meteorological tie-point fields (winds m/s, hPa, DU, %)."""
    lo = np.radians(lon)
    la = np.radians(lat)
    return {
        "zonal_wind": 5.0 + 4.0 * np.sin(2 * la) * np.cos(3 * lo),
        "merid_wind": -2.0 + 3.0 * np.cos(2 * lo) * np.sin(3 * la),
        "atm_pressure": 1013.0 + 8.0 * np.sin(4 * la + 2 * lo),
        "ozone": 300.0 + 30.0 * np.cos(3 * la) * np.sin(lo),
        "rel_humidity": 60.0 + 20.0 * np.sin(5 * lo) * np.cos(4 * la),
    }


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def hillshade(height: np.ndarray, spacing: float, lat_c: float, sun_zenith: float,
              sun_azimuth: float) -> np.ndarray:
    """cos(incidence) / cos(sun zenith) of the sunlit slopes, clipped to [0.15, 1.8]."""
    dy = spacing * KM_PER_DEG * 1000.0
    dx = dy * math.cos(math.radians(lat_c))
    gy, gx = np.gradient(height.astype(np.float32), dy, dx)
    # rows go North to South: north slope component is -gy
    nx, ny, nz = -gx, gy, np.ones_like(gx)
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    sz, sa = math.radians(sun_zenith), math.radians(sun_azimuth)
    sx, sy, szz = math.sin(sz) * math.sin(sa), math.sin(sz) * math.cos(sa), math.cos(sz)
    cos_i = (nx * sx + ny * sy + nz * szz) / norm
    return np.clip(cos_i / max(szz, 0.05), 0.15, 1.8).astype(np.float32)


def land_cover(terrain: Terrain, rng: np.random.Generator, snowline: float = 2900.0) -> np.ndarray:
    """Fractions (4, rows, cols) float32 of water, vegetation, rock, snow from the relief."""
    grid = terrain.grid
    lat_c = grid.lat0 - 0.5 * grid.nrows * grid.spacing
    cell = (grid.spacing * KM_PER_DEG * math.cos(math.radians(lat_c)), grid.spacing * KM_PER_DEG)
    shape = terrain.height.shape
    h = terrain.height
    n1 = band_noise(rng, shape, cell, 20.0, slope=2.5)
    n2 = band_noise(rng, shape, cell, 8.0, slope=2.0)
    snow = _smoothstep((h - (snowline + 250.0 * n1)) / 300.0)
    rock = _smoothstep((h - (snowline - 1000.0 + 250.0 * n2)) / 500.0) * (1.0 - snow)
    density = np.clip(0.72 + 0.22 * band_noise(rng, shape, cell, 12.0, slope=2.2), 0.2, 1.0)
    land = 1.0 - snow - rock
    veg = land * density
    rock = rock + land * (1.0 - density)
    water = terrain.water.astype(np.float32)
    cover = np.stack([water, veg * (1 - water), rock * (1 - water), snow * (1 - water)])
    return cover.astype(np.float32)


def post_flags(terrain: Terrain, cover: np.ndarray) -> np.ndarray:
    """LAND / COAST / SNOW bits on the posts (coast: a land-water boundary at the post)."""
    water = terrain.water
    edge = np.zeros_like(water)
    edge[1:, :] |= water[1:, :] != water[:-1, :]
    edge[:-1, :] |= water[1:, :] != water[:-1, :]
    edge[:, 1:] |= water[:, 1:] != water[:, :-1]
    edge[:, :-1] |= water[:, 1:] != water[:, :-1]
    flags = np.where(water, 0, POST_LAND).astype(np.uint8)
    flags |= np.where(edge, POST_COAST, 0).astype(np.uint8)
    flags |= np.where(cover[3] > 0.5, POST_SNOW, 0).astype(np.uint8)
    return flags


def cloud_field(grid_shape: tuple[int, int], cell: tuple[float, float],
                cfg: dict | None) -> np.ndarray:
    """Cloud cover (0..1) with the requested fraction and scale, seeded by ``cfg['seed']``."""
    if not cfg or float(cfg.get("fraction", 0.0)) <= 0.0:
        return np.zeros(grid_shape, np.float32)
    rng = np.random.default_rng(int(cfg.get("seed", 0)) + 7919)
    n = band_noise(rng, grid_shape, cell, float(cfg.get("scale_km", 40.0)), slope=3.0)
    frac = float(cfg["fraction"])
    thr = np.quantile(n[::4, ::4], 1.0 - frac)
    return np.clip((n - thr) / 0.35 + 0.5, 0.0, 1.0).astype(np.float32)


def make_ground_truth(terrain: Terrain, seed: int, sun_zenith: float, sun_azimuth: float,
                      clouds: dict | None, snowline: float = 2900.0) -> GroundTruth:
    """All per-post fields of the truth."""
    rng = np.random.default_rng(seed + 101)
    grid = terrain.grid
    lat_c = grid.lat0 - 0.5 * grid.nrows * grid.spacing
    cell = (grid.spacing * KM_PER_DEG * math.cos(math.radians(lat_c)), grid.spacing * KM_PER_DEG)
    cover = land_cover(terrain, rng, snowline)
    texture = np.exp(0.16 * band_noise(rng, terrain.height.shape, cell, 30.0, slope=2.0))
    shade = hillshade(terrain.height, grid.spacing, lat_c, sun_zenith, sun_azimuth)
    shade = np.where(terrain.water, 1.0, shade)
    brightness = (texture * shade).astype(np.float32)
    cloud = cloud_field(terrain.height.shape, cell, clouds)
    flags = post_flags(terrain, cover)
    return GroundTruth(cover=np.round(cover * 255.0).astype(np.uint8), brightness=brightness,
                       cloud=np.round(cloud * 255.0).astype(np.uint8), post_flags=flags)


@njit(cache=True)
def _mixture(cover: np.ndarray, brightness: np.ndarray, cloud: np.ndarray, r: int, c: int,
             fx: float, fy: float, acc: np.ndarray) -> float:
    """Bilinear weights folded into the class amounts: acc[k] = sum over the 4 posts of
    w (1 - cloud) brightness cover_k; returns the weighted cloud amount. Then the radiance of
    band b is sum_k acc[k] spectrum[k, b] + cloud * cloud_spectrum[b]."""
    for k in range(acc.size):
        acc[k] = 0.0
    cl_sum = 0.0
    for dr in range(2):
        for dc in range(2):
            w = (fy if dr else 1.0 - fy) * (fx if dc else 1.0 - fx)
            cl = cloud[r + dr, c + dc] / 255.0
            g = w * (1.0 - cl) * brightness[r + dr, c + dc] / 255.0
            for k in range(acc.size):
                acc[k] += g * cover[k, r + dr, c + dc]
            cl_sum += w * cl
    return cl_sum


@njit(cache=True)
def _weights(geo: np.ndarray, nr: int, nc: int, lon: float, lat: float):
    x = ((lon - geo[D_LON0]) % 360.0) / geo[D_DLON]
    y = (geo[D_LAT0] - lat) / geo[D_DLAT]
    if not (x >= 0.0 and y >= 0.0 and x <= nc - 1 and y <= nr - 1):
        return -1, -1, 0.0, 0.0
    c = min(int(x), nc - 2)
    r = min(int(y), nr - 2)
    return r, c, x - c, y - r


@njit(cache=True, parallel=True)
def truth_radiance_kernel(lon: np.ndarray, lat: np.ndarray, bands: np.ndarray,
                          cover: np.ndarray, brightness: np.ndarray, cloud: np.ndarray,
                          spectra: np.ndarray, cloud_spec: np.ndarray, geo: np.ndarray,
                          out: np.ndarray) -> None:
    """out[k, i] = truth radiance of band index bands[k] (0-based) at (lon[i], lat[i]),
    bilinear between the post radiances (NaN outside the DEM grid)."""
    nr, nc = brightness.shape
    for i in prange(lon.size):
        r, c, fx, fy = _weights(geo, nr, nc, lon[i], lat[i])
        if r < 0:
            for k in range(bands.size):
                out[k, i] = np.nan
            continue
        acc = np.empty(spectra.shape[0])
        cl = _mixture(cover, brightness, cloud, r, c, fx, fy, acc)
        for k in range(bands.size):
            b = bands[k]
            v = cl * cloud_spec[b]
            for m in range(acc.size):
                v += acc[m] * spectra[m, b]
            out[k, i] = v


@njit(cache=True)
def nearest_post(geo: np.ndarray, nr: int, nc: int, lon: float, lat: float) -> tuple[int, int]:
    """Row and column of the post nearest to (lon, lat), clipped to the grid."""
    x = ((lon - geo[D_LON0]) % 360.0) / geo[D_DLON]
    y = (geo[D_LAT0] - lat) / geo[D_DLAT]
    c = min(max(int(x + 0.5), 0), nc - 1)
    r = min(max(int(y + 0.5), 0), nr - 1)
    return r, c


@njit(cache=True, parallel=True)
def product_radiometry(t_lon: np.ndarray, t_lat: np.ndarray, glint: np.ndarray,
                       cover: np.ndarray, brightness: np.ndarray, cloud: np.ndarray,
                       post_flags: np.ndarray, spectra: np.ndarray, cloud_spec: np.ndarray,
                       sf_rad: np.ndarray, geo: np.ndarray, counts: np.ndarray,
                       flags: np.ndarray) -> None:
    """Counts (bands, H, W) and flags (H, W) of the product from the truth at the terrain points T;
    the bands are those of ``spectra`` (MERIS 15, OLCI 21).

    ``glint`` (H, W) is True where the sun glint geometry is risky (section 2.2 flags)."""
    nr, nc = brightness.shape
    h, w = t_lon.shape
    for i in prange(h):
        for j in range(w):
            r, c, fx, fy = _weights(geo, nr, nc, t_lon[i, j], t_lat[i, j])
            if r < 0:
                for b in range(counts.shape[0]):
                    counts[b, i, j] = 0
                flags[i, j] = FLAG_INVALID
                continue
            acc = np.empty(spectra.shape[0])
            cl = _mixture(cover, brightness, cloud, r, c, fx, fy, acc)
            for b in range(counts.shape[0]):
                rad = cl * cloud_spec[b]
                for m in range(acc.size):
                    rad += acc[m] * spectra[m, b]
                cnt = math.floor(rad / sf_rad[b] + 0.5)
                counts[b, i, j] = min(max(cnt, 1), 65535)
            pr, pc = nearest_post(geo, nr, nc, t_lon[i, j], t_lat[i, j])
            pf = post_flags[pr, pc]
            f = 0
            if pf & POST_LAND:
                f |= FLAG_LAND_OCEAN
            if pf & POST_COAST:
                f |= FLAG_COASTLINE
            if (pf & POST_SNOW) or cloud[pr, pc] > 127:
                f |= FLAG_BRIGHT
            if (pf & POST_LAND) == 0 and glint[i, j]:
                f |= FLAG_GLINT_RISK
            flags[i, j] = f

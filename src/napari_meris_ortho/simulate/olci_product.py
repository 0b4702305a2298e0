"""The arrays of a simulated OLCI Level 1B product (EFR or ERR), handed to the OLCI writer.

As ESA's products: tie points on every row and every 64 (EFR) or 16 (ERR) columns, located on
the ellipsoid (not orthorectified), with the sun and view angles and meteorological fields;
the per-pixel geolocation (``geo_coordinates``) is the terrain point where each pixel's line of
sight first meets the scene's DEM, its ``altitude`` that point's height: ESA's "DEM corrected"
latitude and longitude. Arrays are in the stored (N1) column order, as the writer takes them.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..progress import ProgressCallback
from . import olci, sensor
from .radiometry import ecmwf_fields, solar_angles

#: radiance fill value of OLCI bands; the largest valid count
FILL_COUNT = 65535
MAX_COUNT = 65534


def camera_fan(geom: Any) -> olci.CameraFan:
    """The cameras' field of view of the scene: the look angles, at the middle row, of the
    full swath's edges (``olci.SWATH_EDGES_M``)."""
    basis = np.empty((4, 3))
    sensor.frame_basis(geom.orb, float(geom.line_time(0.5 * (geom.lines - 1))), basis)
    return olci.CameraFan(sensor.look_angle_of_distance(basis, olci.SWATH_EDGES_M[0]),
                          sensor.look_angle_of_distance(basis, olci.SWATH_EDGES_M[1]))


def column_detectors(geom: Any) -> np.ndarray:
    """Detector of every stored column (int16 (W,)), at the middle row's look angles."""
    basis = np.empty((4, 3))
    sensor.frame_basis(geom.orb, float(geom.line_time(0.5 * (geom.lines - 1))), basis)
    psi = np.array([sensor.look_angle_of_distance(basis, (geom.first_column + j) * geom.spacing)
                    for j in range(geom.columns)])
    return camera_fan(geom).detector(psi)


def tie_point_arrays(geom: Any, e: np.ndarray) -> dict[str, np.ndarray]:
    """Tie points (every row, every ``tie_step`` columns) on the ellipsoid, on the pixel
    centres (i, k x DJ) as the reader gives them back (the writer moves them where ESA's products
    have them): latitude, longitude, view and sun angles (deg) and meteorological fields.
    ``e``: the direct model at the tie points (``scene.locate``, no terrain)."""
    lines = geom.tie_lines
    lon = (e[..., 0] + 180.0) % 360.0 - 180.0
    lat = e[..., 1]
    times = geom.line_time(lines)[:, None] * np.ones_like(lon)
    sz, sa = solar_angles(times, lon, lat)
    tp = {"latitude": lat, "longitude": lon, "view_zenith": e[..., 2],
          "view_azimuth": e[..., 3], "sun_zenith": sz, "sun_azimuth": sa}
    tp.update(ecmwf_fields(lon, lat))
    return tp


def saturate(counts: np.ndarray, cfg: dict) -> np.ndarray:
    """Saturated samples (bool (21, H, W)): a seeded ``saturated_fraction`` of the valid pixels,
    a quarter of them saturated in every band, the others from Oa01 up to a seeded band (bright
    targets saturate the blue bands first); their counts become MAX_COUNT."""
    n_bands, h, w = counts.shape
    sat = np.zeros(counts.shape, bool)
    n = int(round(float(cfg.get("saturated_fraction", 0.0)) * h * w))
    if n == 0:
        return sat
    rng = np.random.default_rng(int(cfg["seed"]) + 57)
    rows = rng.integers(0, h, n)
    cols = rng.integers(0, w, n)
    last = rng.integers(0, n_bands - 1, n)
    for k in range(n):
        if counts[0, rows[k], cols[k]] == FILL_COUNT:
            continue
        upto = n_bands if k < n // 4 else int(last[k]) + 1
        sat[:upto, rows[k], cols[k]] = True
    counts[sat] = MAX_COUNT
    return sat


def olci_arrays(cfg: dict, geom: Any, counts: np.ndarray, meris_flags: np.ndarray,
                points: np.ndarray, ties: np.ndarray) -> dict[str, Any]:
    """The keyword arguments of ``products.olci.write_olci`` from the rendered counts
    (21, H, W) (0 where invalid), the simulator's L1b flags, the terrain points (3, H, W) of
    every pixel and the direct model at the tie points (``ties``). ``counts`` and
    ``meris_flags`` are changed in place."""
    from ..flags import FLAG_DUPLICATED, FLAG_INVALID
    from ..products.olci.layout import FlagBaseline
    from ..products.olci.writer import quality_flags_of

    invalid = (meris_flags & FLAG_INVALID) != 0
    counts[:, invalid] = FILL_COUNT
    sat = saturate(counts, cfg)
    baseline = FlagBaseline(olci.baseline_of(cfg))
    if baseline is FlagBaseline.SINCE_2_24:
        counts[sat] = FILL_COUNT
    detector = np.broadcast_to(column_detectors(geom), meris_flags.shape).copy()
    meris_flags[olci.duplicated(detector)] |= np.uint8(FLAG_DUPLICATED)
    bits = np.zeros(meris_flags.shape, np.uint32)
    for b in range(sat.shape[0]):
        bits[sat[b]] |= np.uint32(1 << b)
    lon, lat, alt = points
    inst = olci.instrument_data(int(cfg["seed"]))
    stamps = np.round((geom.line_time(np.arange(geom.lines)) - geom.t0) * 1e6).astype(np.int64)
    t0_us = int(round(geom.t0 * 1e6))
    return {
        "product_type": geom.product_type, "platform": str(cfg["platform"]),
        "baseline": baseline, "counts": [counts[b] for b in range(counts.shape[0])],
        "scale_factors": list(olci.SCALE_FACTORS),
        "quality_flags": quality_flags_of(meris_flags, bits, baseline),
        "detector_index": detector,
        "tie_points": tie_point_arrays(geom, ties),
        "pixel_geolocation": {"longitude": lon, "latitude": lat,
                              "altitude": np.round(np.nan_to_num(alt))},
        "lambda0": inst["lambda0"], "fwhm": inst["FWHM"], "solar_flux": inst["solar_flux"],
        "start_time": np.datetime64("2000-01-01T00:00:00", "us")
        + np.timedelta64(t0_us, "us"),
        "time_stamps": t0_us + stamps,
    }


def sample_spacing_m(geom: Any) -> float:
    """Along-track distance (m) between rows at the nadir of the middle row."""
    t = float(geom.line_time(0.5 * (geom.lines - 1)))
    pos, _ = geom.orbit.state(np.array([t, t + geom.frame_time]))
    lon0, lat0, _ = sensor.ecef_to_geodetic(*pos[0])
    lon1, lat1, _ = sensor.ecef_to_geodetic(*pos[1])
    r = 6371000.0
    dy = math.radians(lat1 - lat0) * r
    dx = math.radians(lon1 - lon0) * r * math.cos(math.radians(lat0))
    return math.hypot(dx, dy)


def write_olci_scene(target: Path, cfg: dict, geom: Any, counts: np.ndarray,
                     meris_flags: np.ndarray, points: np.ndarray, ties: np.ndarray,
                     progress: ProgressCallback | None = None) -> Path:
    """Write the scene's OLCI ``.SEN3`` directory into ``target`` (an older config's product
    removed); returns its path."""
    import shutil

    from ..products.olci.writer import default_olci_name, write_olci

    args = olci_arrays(cfg, geom, counts, meris_flags, points, ties)
    duration = (geom.lines - 1) * geom.frame_time
    name = default_olci_name(geom.product_type, args["platform"], args["start_time"], duration)
    for old in target.glob("S3?_OL_1_*.SEN3"):
        if old.name != name:
            shutil.rmtree(old, ignore_errors=True)
    return write_olci(target / name, progress=progress, **args)

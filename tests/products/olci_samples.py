"""Small OLCI Level 1B products written by ``products.olci.write_olci`` from synthetic arrays:
a flat earth (altitude 0) on a descending pass, columns west to east in ESA's order, each pixel's
count unique in its neighbourhood, so that a mapping can be checked pixel by pixel."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from napari_meris_ortho.bands import OLCI
from napari_meris_ortho.products.olci import FlagBaseline, quality_flags_of, write_olci
from napari_meris_ortho.products.olci.layout import EFR, ERR

#: metres per degree of latitude (sphere of the handbook's radius)
M_PER_DEG = 6_370_997.0 * np.pi / 180.0
LAT0, LON0 = 45.3, 7.9


def err_geometry(rows: int, kind: str = "ERR") -> dict[str, np.ndarray]:
    """Per-pixel latitude/longitude of an ERR (EFR) product in the N1 column order (column 0
    in the east on a descending pass), 1176 (294) m between rows, 1080 (270) m between
    columns."""
    res, k = (ERR, 1.0) if kind == "ERR" else (EFR, 0.25)
    i = np.arange(rows, dtype=np.float64)[:, None]
    j = np.arange(res.width, dtype=np.float64)[None, :]
    lat = LAT0 - i * k * 1176.0 / M_PER_DEG - j * k * 0.0005
    lon = LON0 - j * k * 1080.0 / (M_PER_DEG * np.cos(np.radians(LAT0))) - i * k * 0.004
    return {"latitude": lat, "longitude": lon}


def counts_pattern(rows: int, band: int, width: int = ERR.width) -> np.ndarray:
    """Counts unique among the pixels within 7 rows and 11 columns of each other."""
    i = np.arange(rows)[:, None]
    j = np.arange(width)[None, :]
    return (100 + band + 7 * (i % 7) + 49 * (j % 11)).astype(np.uint16) * np.uint16(10)


def write_err(path: Path, rows: int = 48, baseline: FlagBaseline = FlagBaseline.PER_BAND,
              platform: str = "S3B", kind: str = "ERR") -> Path:
    """An ``OL_1_ERR___`` (``kind`` "EFR": ``OL_1_EFR___``) product of ``rows`` rows at
    ``path`` (a directory to write it into, or the product's own ``.SEN3``/``.zip`` path);
    altitude 0, view zenith 24.3 deg at the east edge to 56.6 at the west edge."""
    res = ERR if kind == "ERR" else EFR
    geo = err_geometry(rows, kind)
    dj = res.samples_per_tie_point
    tie_cols = np.arange(0, res.width, dj)
    x = tie_cols[None, :] / (res.width - 1.0)  # 0 east .. 1 west (N1 order)
    nadir = 0.3
    oza = np.where(x < nadir, 24.3 * (nadir - x) / nadir, 56.6 * (x - nadir) / (1 - nadir))
    tie = {"latitude": geo["latitude"][:, tie_cols], "longitude": geo["longitude"][:, tie_cols],
           "sun_zenith": np.full((rows, tie_cols.size), 40.0),
           "sun_azimuth": np.full((rows, tie_cols.size), 160.0),
           "view_zenith": np.repeat(oza, rows, axis=0),
           "view_azimuth": np.repeat(np.where(x < nadir, 280.0, 100.0), rows, axis=0)}
    flags = np.zeros((rows, res.width), np.uint8)
    flags[:, :300] = 16  # land in the east
    saturated = np.zeros((rows, res.width), np.uint32)
    saturated[5, 7] = 1 << 16  # Oa17
    spectral = np.tile(np.asarray(OLCI.centres, np.float32)[:, None], (1, 3700))
    detector = np.tile(np.arange(res.width, dtype=np.int16) % 3700, (rows, 1))
    return write_olci(
        path, product_type=kind,
        counts=[counts_pattern(rows, b, res.width) for b in range(1, 22)],
        scale_factors=[0.01 + 0.001 * b for b in range(21)],
        quality_flags=quality_flags_of(flags, saturated, baseline),
        pixel_geolocation={**geo, "altitude": np.zeros((rows, res.width))}, tie_points=tie,
        detector_index=detector, lambda0=spectral,
        fwhm=np.tile(np.asarray(OLCI.widths, np.float32)[:, None], (1, 3700)),
        solar_flux=np.full((21, 3700), 1500.0, np.float32),
        start_time=np.datetime64("2021-08-31T09:10:11"), platform=platform, baseline=baseline)

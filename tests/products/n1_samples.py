"""Synthetic MERIS L1b inputs for the N1 writer/reader tests (deterministic)."""

from __future__ import annotations

import datetime as dt

import numpy as np

from napari_meris_ortho.products.n1 import (
    PRODUCT_TYPES,
    TIE_POINT_NAMES,
    ScalingFactors,
    tie_columns,
    tie_lines,
)
from napari_meris_ortho.products.n1.format import TIE_POINT_FIELDS

#: first line of the Appendix A product (E.4: 117451421.714409 s since 2000)
APPENDIX_A_FIRST_LINE = dt.datetime(2003, 9, 21, 9, 23, 41, 714409)


def sample_inputs(
    product_type: str = "MER_FR__1P",
    height: int = 130,
    width: int | None = None,
    seed: int = 0,
    scaling: ScalingFactors | None = None,
) -> dict:
    """Keyword arguments for ``write_product``: exact-on-the-grid tie points (raw integers times
    the scaling factors, so a round trip is bitwise), random counts, flags without INVALID."""
    res = PRODUCT_TYPES[product_type]
    df, dj = res.lines_per_tie_point, res.samples_per_tie_point
    width = width or res.width
    # the factors as the file stores them (float32), so that raw x factor round-trips bitwise
    scaling = ScalingFactors.from_record((scaling or ScalingFactors.appendix_a()).to_record())
    rng = np.random.default_rng(seed)
    nt, nc = tie_lines(height, df), tie_columns(width, dj)
    i = np.arange(nt, dtype=np.float64)[:, None]
    k = np.arange(nc, dtype=np.float64)[None, :]
    physical = {
        # FR Appendix A scene: first tie point east at nadir, last one west at 40.7 deg
        "latitude": 45.909863 - 0.16 * i + 0.03 * k,
        "longitude": 18.014693 - 0.06 * i - 0.21 * k * dj / 64,
        "dem_alt": rng.integers(-50, 3000, (nt, nc)).astype(np.float64),
        "dem_rough": rng.integers(0, 400, (nt, nc)).astype(np.float64),
        "lat_corr": rng.integers(-2000, 2000, (nt, nc)) * 1e-6,
        "lon_corr": rng.integers(-16000, 16000, (nt, nc)) * 1e-6,
        "sun_zenith": 48.2 - 0.1 * i + 0.1 * k,
        "sun_azimuth": 153.6 - 0.1 * i - 0.2 * k,
        "view_zenith": np.broadcast_to(np.linspace(0.0, 40.7, nc), (nt, nc)),
        "view_azimuth": np.where(k == 0, 182.0, 99.6) + 0 * i,
        "zonal_wind": rng.integers(-300, 300, (nt, nc)) * 0.1,
        "merid_wind": rng.integers(-300, 300, (nt, nc)) * 0.1,
        "atm_pressure": rng.integers(9800, 10300, (nt, nc)) * 0.1,
        "ozone": rng.integers(25000, 35000, (nt, nc)) * 0.01,
        "rel_humidity": rng.integers(0, 1000, (nt, nc)) * 0.1,
    }
    tie_points = {}
    for field in TIE_POINT_FIELDS:
        factor = scaling.factor(field)
        raw = np.round(np.asarray(physical[field.name], dtype=np.float64) / factor)
        tie_points[field.name] = raw * factor
    assert set(tie_points) == set(TIE_POINT_NAMES)
    counts = [rng.integers(0, 65536, (height, width), dtype=np.uint16) for _ in range(15)]
    flags = (rng.integers(0, 128, (height, width))).astype(np.uint8)
    detector_index = rng.integers(0, 3700, (height, width)).astype(np.int16)
    return {
        "product_type": product_type,
        "tie_points": tie_points,
        "counts": counts,
        "flags": flags,
        "detector_index": detector_index,
        "first_line_time": APPENDIX_A_FIRST_LINE,
        "scaling": scaling,
    }

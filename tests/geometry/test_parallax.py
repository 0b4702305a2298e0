"""The tie-point corrections as real N1 products store them (handbook eq. 2, Appendix E)."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho.geometry.parallax import geodetic_offsets, stored_corrections

#: Appendix E dumps of real FR products (2003-2004): dem_alt (m), view zenith and azimuth
#: (deg, one decimal), latitude, and the stored lat_corr, lon_corr (1e-6 deg)
APPENDIX_E = [
    (263, 2.7, 286.3, 50.742379, 31, 169),        # E.1, first tie point of line 1
    (99, 38.9, 100.0, 51.937422, -124, -1146),    # E.1, last tie point of line 1
    (1364, 38.9, 99.9, 46.149686, -1709, -14086),  # E.1, last tie point of line 36
    (300, 38.9, 291.5, 49.074601, 797, 3090),     # E.2, first tie point of line 1
    (271, 2.7, 105.6, 50.743669, -31, -175),      # E.2, last tie point of line 1
    (806, 38.9, 290.5, 46.520884, 2046, 7965),    # E.2, first tie point of line 17
]


@pytest.mark.parametrize("h, vz, va, lat, lat_corr, lon_corr", APPENDIX_E)
def test_stored_corrections_are_the_dumped_ones(h, vz, va, lat, lat_corr, lon_corr) -> None:
    """lat_corr = +h tan(vz) cos(va) / R, lon_corr = -h tan(vz) sin(va) / (R cos lat): the
    dumped values within what their one-decimal angles leave (0.05 deg of view zenith is
    1.9 % at 2.7 deg) and the 1e-6 deg quantization."""
    dlat, dlon = stored_corrections(h, vz, va, lat)
    tan_err = np.radians(0.05) / (np.sin(np.radians(vz)) * np.cos(np.radians(vz)))
    for got, dumped in ((dlat, lat_corr), (dlon, lon_corr)):
        assert float(got) * 1e6 == pytest.approx(dumped, rel=tan_err + 0.01, abs=1.5)
    # the longitude is stored with the sign opposite to the correction added (eq. 2c', 6b')
    add_lon, add_lat = geodetic_offsets(h, vz, va, lat)
    assert np.sign(add_lon) == -np.sign(lon_corr) and np.sign(add_lat) == np.sign(lat_corr)


def test_no_correction_over_the_seabed() -> None:
    dlat, dlon = stored_corrections([-228.0, 0.0], [38.0, 38.0], [100.0, 100.0], [39.0, 39.0])
    assert np.all(dlat == 0.0) and np.all(dlon == 0.0) and not np.signbit(dlon).any()

"""Direct location model and geodetic correction (handbook eq. 3a-6b', Appendix D)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from napari_meris_ortho import geodetic_correction
from napari_meris_ortho.engine.location import direct_location
from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.geometry.tiepoints import TiePointGrid, analytic_swath

FIXTURE = Path(__file__).parents[1] / "fixtures" / "appendix_d.csv"


def _appendix_d() -> dict[str, np.ndarray]:
    with FIXTURE.open() as fh:
        rows = list(csv.DictReader(fh))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def test_geodetic_correction_reproduces_appendix_d():
    d = _appendix_d()
    assert d["nb"].tolist() == list(range(25))  # all 25 points of the appendix
    dlon, dlat = geodetic_correction(d["elevation"], d["view_zenith"], d["view_azimuth"],
                                     d["latitude"])
    assert np.max(np.abs(dlon - d["longitude_correction"])) < 1e-5
    assert np.max(np.abs(dlat - d["latitude_correction"])) < 1e-5
    # point 0 of the lead's notes, by hand
    assert dlon[0] == pytest.approx(0.029666, abs=1e-5)
    assert dlat[0] == pytest.approx(-0.003551, abs=1e-5)


def test_ellipsoid_model_differs_by_the_radii_ratio():
    dlon_s, dlat_s = geodetic_correction(3000.0, 35.0, 100.0, 45.0)
    dlon_e, dlat_e = geodetic_correction(3000.0, 35.0, 100.0, 45.0, model="ellipsoid")
    # at 45 deg: M = 6367381.8 m, N = 6388838.3 m
    assert dlat_e / dlat_s == pytest.approx(6370997.0 / 6367381.8, rel=1e-6)
    assert dlon_e / dlon_s == pytest.approx(6370997.0 / 6388838.3, rel=1e-6)


def test_geodetic_correction_is_vectorised_and_zero_at_nadir():
    dlon, dlat = geodetic_correction(np.full((3, 4), 1000.0), 0.0, 100.0, 45.0)
    assert dlon.shape == (3, 4)
    assert np.all(dlon == 0) and np.all(dlat == 0)
    with pytest.raises(OptionsError, match="parallax"):
        geodetic_correction(1.0, 1.0, 1.0, 1.0, model="flat")


def test_direct_location_interpolates_tie_points_exactly():
    g = analytic_swath()
    lon, lat = direct_location(g, [0.0, 64.0, 128.0], [0.0, 64.0, 2240.0], 0.0)
    assert lat == pytest.approx([g.latitude[0, 0], g.latitude[1, 1], g.latitude[2, 35]], abs=1e-12)
    assert lon == pytest.approx([g.longitude[0, 0], g.longitude[1, 1], g.longitude[2, 35]],
                                abs=1e-12)
    # eq. 4a: midway between two tie points = their mean (bilinear)
    lon_m, lat_m = direct_location(g, 32.0, 32.0, 0.0)
    assert lat_m == pytest.approx(g.latitude[:2, :2].mean(), abs=1e-12)


def test_direct_location_adds_the_parallax_correction():
    g = analytic_swath()
    line, col, h = 100.0, 1500.0, 2500.0
    lon0, lat0 = direct_location(g, line, col, 0.0)
    lon1, lat1 = direct_location(g, line, col, h)
    vz = np.degrees(np.arctan(np.hypot(
        np.interp(col, np.arange(36) * 64.0, g.look_east[1]),
        np.interp(col, np.arange(36) * 64.0, g.look_north[1]))))
    dlon, dlat = geodetic_correction(h, vz, 102.0, lat0)
    assert lon1 - lon0 == pytest.approx(dlon, rel=1e-6)
    assert lat1 - lat0 == pytest.approx(dlat, rel=1e-6)
    # terrain pixel seen from the west edge moves east (towards the satellite)
    assert lon1 > lon0


def test_direct_location_with_tie_point_heights():
    g = analytic_swath()
    lon_t, lat_t = direct_location(g, 64.0, 640.0, None)
    lon_h, lat_h = direct_location(g, 64.0, 640.0, g.dem_alt[1, 10])
    assert float(lon_t) == pytest.approx(float(lon_h), abs=1e-12)
    assert float(lat_t) == pytest.approx(float(lat_h), abs=1e-12)
    assert float(lon_t) != pytest.approx(float(direct_location(g, 64.0, 640.0, 0.0)[0]), abs=1e-6)


def test_parallax_continuous_through_nadir():
    """Azimuth jumps by 180 deg at nadir; the look-vector interpolation keeps the shift small."""
    g = analytic_swath(nadir_col=1120.0)
    cols = np.linspace(1080.0, 1160.0, 161)
    lon0, lat0 = direct_location(g, 200.0, cols, 0.0)
    lon1, lat1 = direct_location(g, 200.0, cols, 3000.0)
    shift_m = np.hypot((lon1 - lon0) * 111e3 * np.cos(np.radians(lat0)), (lat1 - lat0) * 111e3)
    # the true shift is h tan(vz) <= 3000 * tan(1.2 deg) = 63 m around nadir, never a jump
    assert shift_m.max() < 70.0
    assert np.max(np.abs(np.diff(shift_m))) < 2.0
    assert shift_m.min() < 1.0


def test_direct_location_across_the_antimeridian():
    g = analytic_swath(lon0=-176.0)
    lon, lat = direct_location(g, np.full(50, 300.0), np.linspace(0, 2240, 50), 0.0)
    assert np.all((lon >= -180) & (lon < 180))
    assert lon.min() < -170 and lon.max() > 170  # the swath crosses 180 deg
    east = np.unwrap(lon, period=360.0)
    assert np.all(np.diff(east) < 0)  # columns run westwards without a jump


def test_tie_point_grid_rejects_bad_shapes():
    from napari_meris_ortho.errors import GeometryError
    with pytest.raises(GeometryError):
        TiePointGrid(np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)),
                     np.zeros((1, 3)), 64, 64, 1, 129)


def test_ecef_geolocation_agrees_at_tie_points_and_differs_little_inside():
    g = analytic_swath(lat0=70.0)
    line = np.array([0.0, 64.0, 128.0, 32.0, 96.0])
    col = np.array([0.0, 640.0, 2240.0, 1000.0, 1500.0])
    lo_b, la_b = direct_location(g, line, col, 0.0, geolocation="bilinear")
    lo_e, la_e = direct_location(g, line, col, 0.0, geolocation="ecef")
    assert np.max(np.abs(lo_b[:3] - lo_e[:3])) < 1e-9 and np.max(np.abs(la_b[:3] - la_e[:3])) < 1e-9
    # inside facets the two models differ by metres, not by pixels (260 m)
    d_m = np.hypot((lo_b - lo_e) * 111320 * np.cos(np.radians(la_b)), (la_b - la_e) * 111320)
    assert 0.01 < d_m[3:].max() < 50.0
    # the ellipsoid parallax implies the ecef interpolation unless told otherwise
    lo_p, _ = direct_location(g, line, col, 0.0, parallax="ellipsoid")
    assert np.array_equal(lo_p, lo_e)
    with pytest.raises(OptionsError, match="geolocation"):
        direct_location(g, line, col, 0.0, geolocation="spline")

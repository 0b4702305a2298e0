"""Product grid and line-of-sight geometry (handbook section 2.2, App. E)."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import Geod

from napari_meris_ortho.simulate import resolve_config, scene_geometry
from napari_meris_ortho.simulate.scene import locate

GEOD = Geod(ellps="WGS84")


@pytest.fixture(scope="module")
def alps():
    return scene_geometry(resolve_config("fr-alps"))


def test_fr_alps_view_zenith_from_nadir_to_the_swath_edge(alps):
    """Appendix E.4: 0.0 deg on the first stored column, 40.7 deg on the last; nadir east."""
    e = locate(alps, alps.tie_lines, alps.tie_cols)
    vz = e[..., 2]
    assert np.all(vz[:, 0] < 1e-6)
    assert np.all(np.abs(vz[:, -1] - 40.7) < 0.2)
    assert np.all(np.diff(vz, axis=1) > 0)
    # first and last tie points of the first line near the real ones (Appendix E.4)
    assert abs(e[0, 0, 1] - 45.909863) < 1e-7 and abs(e[0, 0, 0] - 18.014693) < 1e-7
    assert abs(e[0, -1, 1] - 47.028196) < 0.05 and abs(e[0, -1, 0] - 10.603496) < 0.05
    # view azimuth at the western edge about 99.6 deg (from the pixel towards the satellite)
    assert np.all(np.abs(e[:, -1, 3] - 99.7) < 0.5)
    # columns stored East to West: longitude decreases along a line
    assert np.all(np.diff(e[..., 0], axis=1) < 0)


def test_column_spacing_is_260_m_and_line_spacing_about_290_m(alps):
    lines = np.array([0.0, 1.0, 1120.0, 1121.0, 2239.0, 2240.0])
    cols = np.arange(0, 2241, dtype=np.float64)
    e = locate(alps, lines, cols)
    lon, lat = e[..., 0], e[..., 1]
    _, _, dcol = GEOD.inv(lon[:, :-1], lat[:, :-1], lon[:, 1:], lat[:, 1:])
    assert np.all(np.abs(dcol - 260.0) < 2.6)  # +- 1 %
    assert np.all(np.abs(dcol - 260.0) < 0.01)  # in fact to the centimetre
    for k in (0, 2, 4):
        _, _, dline = GEOD.inv(lon[k, 0], lat[k, 0], lon[k + 1, 0], lat[k + 1, 0])
        assert 280.0 < dline < 300.0
    # lines perpendicular to the ground track at nadir
    az_line, _, _ = GEOD.inv(lon[0, 0], lat[0, 0], lon[1, 0], lat[1, 0])
    az_cols, _, _ = GEOD.inv(lon[0, 0], lat[0, 0], lon[0, 1], lat[0, 1])
    assert abs(((az_cols - az_line) % 360.0) - 90.0) < 0.05


def test_rr_full_swath_is_centred_on_the_track():
    geom = scene_geometry(resolve_config("rr-segment"))
    e = locate(geom, np.array([0.0, 560.0]), np.arange(0, 1121, 16, dtype=np.float64))
    vz = e[..., 2]
    assert np.all(vz[:, 35] < 1e-6)  # column 560 is the nadir
    assert np.allclose(vz[:, :35], vz[:, 36:][:, ::-1], atol=0.05)
    assert np.all(vz[:, 0] > 40.0)
    lon, lat = e[0, :, 0], e[0, :, 1]
    _, _, width = GEOD.inv(lon[0], lat[0], lon[-1], lat[-1])
    assert abs(width - 1120 * 1040.0) < 1e3  # 1165 km of ground along the curved line


def test_ascending_pass_stores_columns_west_to_east():
    geom = scene_geometry(resolve_config("fr-south-ascending"))
    e = locate(geom, np.array([0.0]), np.array([0.0, 1120.0, 2240.0]))
    assert e[0, 1, 2] < 1e-6  # nadir in the middle column
    lon = e[0, :, 0]
    # left to right of a north(west)-going flight: stored West to East
    assert lon[0] < lon[1] < lon[2]


def test_antimeridian_geometry_is_continuous():
    geom = scene_geometry(resolve_config("rr-antimeridian"))
    e = locate(geom, geom.tie_lines, geom.tie_cols)
    lon = e[..., 0]
    assert lon.min() < -170.0 and lon.max() > 170.0  # the swath crosses +-180
    step = (np.diff(lon, axis=1) + 180.0) % 360.0 - 180.0
    assert np.all(np.abs(step) < 0.5)
    assert np.all(np.abs(np.diff(e[..., 2], axis=1)) < 1.5)

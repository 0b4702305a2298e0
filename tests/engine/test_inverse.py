"""Inverse location model: exact facet offsets and the handbook facet search (section 3.4)."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho.engine.inverse import facet_offsets, inverse_location, search_facet
from napari_meris_ortho.engine.location import direct_location
from napari_meris_ortho.geometry.tiepoints import analytic_swath


@pytest.fixture(scope="module")
def swath():
    return analytic_swath(height=600, width=2241)


def test_inverse_of_direct_is_identity(swath):
    rng = np.random.default_rng(1)
    line = rng.uniform(0, 599, 2000)
    col = rng.uniform(0, 2240, 2000)
    lon, lat = direct_location(swath, line, col, 0.0)
    l2, p2, counts = inverse_location(swath, lon, lat)
    assert np.max(np.abs(l2 - line)) < 1e-6
    assert np.max(np.abs(p2 - col)) < 1e-6
    assert counts["not found"] == 0
    assert sum(counts.values()) == 2000


def test_search_paths_are_counted(swath):
    # points along a product line: mostly the same facet, then the 4-connex neighbour
    col = np.linspace(1.0, 2239.0, 700)
    lon, lat = direct_location(swath, np.full(700, 100.0), col, 0.0)
    _, p2, counts = inverse_location(swath, lon, lat)
    assert np.max(np.abs(p2 - col)) < 1e-6
    assert counts["all"] == 1  # only the first point searches everything
    assert counts["4-connex"] == 34  # one per facet change across 35 facets
    assert counts["same"] == 700 - 35


def test_8_connex_and_not_found(swath):
    lon, lat = direct_location(swath, 64.0 + 96.0, 64.0 + 96.0, 0.0)  # facet (2, 2)
    f, j, u, v, path = search_facet(float(lon), float(lat), 1, 1, swath.latitude,
                                    swath.lon_unwrapped)
    assert (f, j, path) == (2, 2, 2)
    assert (u, v) == pytest.approx((0.5, 0.5), abs=1e-9)
    lon_out, lat_out = direct_location(swath, -300.0, 500.0, 0.0)  # before the first line
    *_, path = search_facet(float(lon_out), float(lat_out), 0, 7, swath.latitude,
                            swath.lon_unwrapped)
    assert path == -1


def test_facet_offsets_outside_and_degenerate():
    lat = np.array([[0.0, 0.0], [1.0, 1.0]])
    lon = np.array([[0.0, 1.0], [0.0, 1.0]])  # a unit square: u = lat, v = lon
    assert facet_offsets(0.25, 0.75, 0, 0, lat, lon) == pytest.approx((0.75, 0.25))
    assert facet_offsets(2.0, -1.0, 0, 0, lat, lon) == pytest.approx((-1.0, 2.0))
    # a facet with parallel opposite edges gives a linear equation (a = 0 branch)
    lon2 = np.array([[0.0, 2.0], [0.5, 2.5]])
    u, v = facet_offsets(1.25, 0.5, 0, 0, lat, lon2)
    assert (u, v) == pytest.approx((0.5, 0.5))
    # a strongly non-parallel (trapezoid) facet
    lon3 = np.array([[0.0, 1.0], [0.4, 0.6]])
    u, v = facet_offsets(0.5 * ((1 - 0.3) * 1.0 + 0.3 * 0.6) + 0.5 * 0.3 * 0.4 - 0.0,
                         0.3, 0, 0, lat, lon3)
    assert (u, v) == pytest.approx((0.3, 0.5))


def test_inverse_across_the_antimeridian():
    g = analytic_swath(height=600, width=2241, lon0=-176.0)
    rng = np.random.default_rng(2)
    line = rng.uniform(0, 599, 500)
    col = rng.uniform(0, 2240, 500)
    lon, lat = direct_location(g, line, col, 0.0)
    assert lon.min() < -170 and lon.max() > 170
    l2, p2, counts = inverse_location(g, lon, lat)
    assert counts["not found"] == 0
    assert np.max(np.abs(l2 - line)) < 1e-6 and np.max(np.abs(p2 - col)) < 1e-6


def test_wrap180_keeps_a_difference_on_the_range_exact():
    """An angle difference already on [-180, 180) is returned bit for bit (no round trip
    through +180); others are brought onto the range."""
    from napari_meris_ortho.engine.inverse import wrap180

    for x in (1e-10, -3.3e-12, 0.0123456789012345, -180.0, 179.99999999999997):
        assert wrap180(x) == x
    assert wrap180(180.0) == -180.0
    assert wrap180(190.25) == -169.75
    assert wrap180(-190.25) == 169.75
    assert wrap180(719.5) == -0.5


@pytest.mark.parametrize("lon0", [11.0, -176.0])
def test_a_point_clear_of_the_grid_is_not_searched_through_every_facet(lon0):
    """Tie points on every row (OLCI: 77 x thousands of facets): a point outside the grid's
    border is known outside at once; the border test agrees with the search through all facets,
    also across the antimeridian and right at the border."""
    from napari_meris_ortho.engine.inverse import BORDER_MARGIN_DEG, clear_of_grid

    g = analytic_swath(height=300, width=1217, df=1, dj=16, lon0=lon0, pixel_m=1080.0)
    lat_tp, lon_tp = g.latitude, g.lon_unwrapped
    rng = np.random.default_rng(3)
    line = rng.uniform(-150, 450, 3000)
    col = rng.uniform(-600, 1800, 3000)
    lon, lat = direct_location(g, line, col, 0.0)
    inside = (line >= 0) & (line <= 299) & (col >= 0) & (col <= 1216)
    for k in range(lon.size):
        clear = clear_of_grid(float(lon[k]), float(lat[k]), lat_tp, lon_tp)
        *_, path = search_facet(float(lon[k]), float(lat[k]), -1, -1, lat_tp, lon_tp)
        assert clear == (not inside[k]), (line[k], col[k])
        assert (path == -1) == (not inside[k])
    # just outside the border: within the margin, searched (and not found); beyond, clear
    edge_lon, edge_lat = direct_location(g, np.array([120.0]), np.array([-1e-5]), 0.0)
    assert not clear_of_grid(float(edge_lon[0]), float(edge_lat[0]), lat_tp, lon_tp)
    far_lon, far_lat = direct_location(g, np.array([120.0]), np.array([-0.01]), 0.0)
    assert clear_of_grid(float(far_lon[0]), float(far_lat[0]), lat_tp, lon_tp)
    assert BORDER_MARGIN_DEG <= 1e-6  # 0.1 m

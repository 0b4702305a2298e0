"""Orbit: Envisat-like sun-synchronous circle on the rotating WGS84 Earth."""

from __future__ import annotations

import math
from datetime import datetime

import numpy as np
import pytest

from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.simulate.orbit import (
    ecef_to_geodetic,
    geodetic_to_ecef,
    solve_pass,
)


def test_pass_over_the_handbook_first_tie_point():
    """Appendix E.4: nadir at (45.909863, 18.014693) on 2003-09-21 near 09:23:41 UTC."""
    orbit, t = solve_pass(datetime(2003, 9, 21), 45.909863, 18.014693, "descending")
    pos, vel = orbit.state(t)
    lon, lat, h = ecef_to_geodetic(*pos)
    assert abs(lat - 45.909863) < 1e-8 and abs(lon - 18.014693) < 1e-8
    assert 780e3 < h < 800e3
    assert abs(t - 117451421.714409) < 60.0  # the real product's first tie line time
    period = 2 * math.pi / orbit.mean_motion
    assert 6020 < period < 6040  # about 100.5 min
    # descending: latitude decreases
    lat_later = ecef_to_geodetic(*orbit.state(t + 10)[0])[1]
    assert lat_later < lat


def test_velocity_is_the_derivative_of_the_position():
    orbit, t = solve_pass(datetime(2004, 7, 15), 64.0, 179.5, "descending")
    _, v = orbit.state(t)
    p1, _ = orbit.state(t + 0.1)
    pm, _ = orbit.state(t - 0.1)
    assert np.max(np.abs((p1 - pm) / 0.2 - v)) < 2e-3
    assert 7.4e3 < np.linalg.norm(v) < 7.6e3  # Earth-fixed speed


def test_descending_node_at_ten_local_time():
    """Sun-synchronous: the equator crossing of the descending pass is at 10:00 local time."""
    orbit, t = solve_pass(datetime(2003, 9, 21), 0.0, 20.0, "descending")
    seconds_of_day = t % 86400.0
    local_h = (seconds_of_day / 3600.0 + 20.0 / 15.0) % 24.0
    assert abs(local_h - 10.0) < 0.25  # mean vs true solar time: equation of time ~ 7 min


def test_ascending_pass_in_the_south():
    orbit, t = solve_pass(datetime(2003, 12, 21), -71.5, -66.0, "ascending")
    lat0 = ecef_to_geodetic(*orbit.state(t)[0])[1]
    lat1 = ecef_to_geodetic(*orbit.state(t + 10)[0])[1]
    assert abs(lat0 + 71.5) < 1e-8 and lat1 > lat0


def test_geodetic_round_trip():
    for lat in np.linspace(-89.5, 89.5, 37):
        for h in (-400.0, 0.0, 4800.0, 8.0e5):
            lon2, lat2, h2 = ecef_to_geodetic(*geodetic_to_ecef(123.4, lat, h))
            assert abs(lat2 - lat) < 1e-10 and abs(h2 - h) < 1e-6 and abs(lon2 - 123.4) < 1e-10


def test_bad_orbit_options():
    with pytest.raises(OptionsError, match="direction"):
        solve_pass(datetime(2003, 9, 21), 45.0, 10.0, "sideways")
    with pytest.raises(OptionsError, match="reach"):
        solve_pass(datetime(2003, 9, 21), 85.0, 10.0)

"""Sun-synchronous circular orbits (Envisat, Sentinel-3) on the rotating WGS84 Earth.

Times are seconds since 2000-01-01T00:00:00 UTC (MJD2000, like the N1 ``dsr_time``; UT1 = UTC,
no leap seconds). An orbit is a circle (Envisat: radius 7159.5 km, inclination 98.55 deg;
Sentinel-3: 7177.9 km, about 814.5 km above the Earth, 98.65 deg; both descending node 10:00),
propagated in an inertial (true-of-date, simplified) frame with its node drifting at the
sun-synchronous rate, then rotated with the Earth by the Greenwich mean sidereal time into ECEF
(WGS84).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime

import numpy as np
from numba import njit

from ..errors import OptionsError
from ..geometry.earth import WGS84_A, WGS84_B, WGS84_E2

#: WGS84 ellipsoid
GM = 3.986004418e14
OMEGA_EARTH = 7.2921158553e-5  # rad/s
#: Envisat orbit: radius (m) of the circle; its inclination and descending-node local time
SEMI_MAJOR_AXIS = 7159500.0
INCLINATION_DEG = 98.55
DESCENDING_NODE_LOCAL_TIME_H = 10.0
#: Sentinel-3 orbit: radius (m) of the circle (814.5 km mean altitude) and its inclination
SENTINEL3_SEMI_MAJOR_AXIS = 7177937.0
SENTINEL3_INCLINATION_DEG = 98.65
NODE_RATE = 2.0 * math.pi / (365.2422 * 86400.0)  # sun-synchronous drift of the node (rad/s)
MJD2000_EPOCH = datetime(2000, 1, 1, tzinfo=UTC)


@dataclass(frozen=True)
class Platform:
    """The circular sun-synchronous orbit of a satellite: radius (m), inclination and local time
    (h) of the descending node."""

    name: str
    radius: float
    inclination_deg: float
    descending_node_h: float = DESCENDING_NODE_LOCAL_TIME_H


ENVISAT = Platform("Envisat", SEMI_MAJOR_AXIS, INCLINATION_DEG)
SENTINEL3 = Platform("Sentinel-3", SENTINEL3_SEMI_MAJOR_AXIS, SENTINEL3_INCLINATION_DEG)


def to_mjd2000_seconds(when: datetime) -> float:
    """Seconds since 2000-01-01T00:00:00 UTC of an aware or naive (taken as UTC) datetime."""
    if when.tzinfo is None:
        when = when.replace(tzinfo=UTC)
    return (when - MJD2000_EPOCH).total_seconds()


@njit(cache=True)
def gmst_rad(t: float) -> float:
    """Greenwich mean sidereal angle (rad) at MJD2000 seconds ``t`` (linear IAU-82 form)."""
    d = t / 86400.0 - 0.5
    return math.radians((280.46061837 + 360.98564736629 * d) % 360.0)


def mean_sun_right_ascension_rad(t: float) -> float:
    """Right ascension of the mean sun (rad), i.e. its mean longitude, at MJD2000 seconds ``t``."""
    d = t / 86400.0 - 0.5
    return math.radians((280.46646 + 0.98564736 * d) % 360.0)


@dataclass(frozen=True)
class Orbit:
    """A circular orbit: ascending node time ``t_node`` (MJD2000 s) and node right ascension."""

    t_node: float
    raan_node: float  # rad, right ascension of the ascending node at t_node
    radius: float = SEMI_MAJOR_AXIS
    inclination: float = math.radians(INCLINATION_DEG)

    @property
    def mean_motion(self) -> float:
        return math.sqrt(GM / self.radius**3)

    def params(self) -> np.ndarray:
        """Packed parameters for the numba kernels."""
        return np.array([self.t_node, self.raan_node, self.radius, self.inclination,
                         self.mean_motion, NODE_RATE])

    def state(self, t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """ECEF position (m) and Earth-fixed velocity (m/s) at times ``t`` (arrays (..., 3))."""
        tt = np.atleast_1d(np.asarray(t, dtype=np.float64)).ravel()
        pos = np.empty((tt.size, 3))
        vel = np.empty((tt.size, 3))
        p = self.params()
        for i in range(tt.size):
            orbit_state(p, tt[i], pos[i], vel[i])
        shape = np.shape(t) + (3,)
        return pos.reshape(shape), vel.reshape(shape)


def sun_synchronous_orbit(t_node: float, platform: Platform = ENVISAT) -> Orbit:
    """The orbit of ``platform`` whose ascending node at ``t_node`` is at 22:00 local time
    (descending 10:00)."""
    ltan = platform.descending_node_h + 12.0
    raan = mean_sun_right_ascension_rad(t_node) + math.radians((ltan - 12.0) * 15.0)
    return Orbit(t_node=t_node, raan_node=raan % (2.0 * math.pi), radius=platform.radius,
                 inclination=math.radians(platform.inclination_deg))


@njit(cache=True)
def orbit_state(p: np.ndarray, t: float, pos: np.ndarray, vel: np.ndarray) -> None:
    """ECEF position and Earth-fixed velocity at MJD2000 seconds ``t`` (writes ``pos``, ``vel``)."""
    t_node, raan0, radius, incl, n, node_rate = p[0], p[1], p[2], p[3], p[4], p[5]
    dt = t - t_node
    u = n * dt
    raan = raan0 + node_rate * dt
    cu, su = math.cos(u), math.sin(u)
    co, so = math.cos(raan), math.sin(raan)
    ci, si = math.cos(incl), math.sin(incl)
    x = radius * (co * cu - so * su * ci)
    y = radius * (so * cu + co * su * ci)
    z = radius * su * si
    # inertial velocity (argument of latitude and node both move)
    vx = radius * (n * (-co * su - so * cu * ci) + node_rate * (-so * cu - co * su * ci))
    vy = radius * (n * (-so * su + co * cu * ci) + node_rate * (co * cu - so * su * ci))
    vz = radius * n * cu * si
    th = gmst_rad(t)
    ct, st = math.cos(th), math.sin(th)
    pos[0] = ct * x + st * y
    pos[1] = -st * x + ct * y
    pos[2] = z
    # v_ecef = R v_eci - omega x r_ecef
    vel[0] = ct * vx + st * vy + OMEGA_EARTH * pos[1]
    vel[1] = -st * vx + ct * vy - OMEGA_EARTH * pos[0]
    vel[2] = vz


@njit(cache=True)
def ecef_to_geodetic(x: float, y: float, z: float) -> tuple[float, float, float]:
    """WGS84 geodetic (lon deg, lat deg, h m) of an ECEF point (Bowring start, 2 iterations)."""
    a = WGS84_A
    e2 = WGS84_E2
    b = WGS84_B
    p = math.hypot(x, y)
    lon = math.atan2(y, x)
    ep2 = (a * a - b * b) / (b * b)
    th = math.atan2(z * a, p * b)
    lat = math.atan2(z + ep2 * b * math.sin(th) ** 3, p - e2 * a * math.cos(th) ** 3)
    h = 0.0
    for _ in range(2):
        sl = math.sin(lat)
        nrad = a / math.sqrt(1.0 - e2 * sl * sl)
        cl = math.cos(lat)
        if abs(cl) > 1e-3:
            h = p / cl - nrad
        else:
            h = z / sl - nrad * (1.0 - e2)
        lat = math.atan2(z, p * (1.0 - e2 * nrad / (nrad + h)))
    sl = math.sin(lat)
    cl = math.cos(lat)
    nrad = a / math.sqrt(1.0 - e2 * sl * sl)
    h = p * cl + z * sl - a * a / nrad
    return math.degrees(lon), math.degrees(lat), h


@njit(cache=True)
def geodetic_to_ecef(lon: float, lat: float, h: float) -> tuple[float, float, float]:
    """ECEF (m) of WGS84 geodetic lon, lat (deg) and ellipsoidal height h (m)."""
    lo = math.radians(lon)
    la = math.radians(lat)
    sl = math.sin(la)
    cl = math.cos(la)
    nrad = WGS84_A / math.sqrt(1.0 - WGS84_E2 * sl * sl)
    return ((nrad + h) * cl * math.cos(lo), (nrad + h) * cl * math.sin(lo),
            (nrad * (1.0 - WGS84_E2) + h) * sl)


def _wrap_deg(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


def _subsatellite(orbit: Orbit, t: float) -> tuple[float, float]:
    pos, _ = orbit.state(t)
    lon, lat, _ = ecef_to_geodetic(pos[0], pos[1], pos[2])
    return lon, lat


def solve_pass(date: datetime, nadir_lat: float, nadir_lon: float,
               direction: str = "descending",
               platform: Platform = ENVISAT) -> tuple[Orbit, float]:
    """Orbit of ``platform`` and time (MJD2000 s) at which the geodetic nadir passes over
    (lat, lon) on ``date``.

    The pass is the one of that UTC day (the day of local time about 10:00 for descending passes);
    ``direction`` chooses the descending or the ascending half of the orbit.
    """
    incl = math.radians(platform.inclination_deg)
    if direction not in ("descending", "ascending"):
        raise OptionsError(
            f"orbit direction must be 'descending' or 'ascending', not {direction!r}")
    max_lat = 180.0 - platform.inclination_deg
    if abs(nadir_lat) >= max_lat - 0.05:
        raise OptionsError(
            f"nadir latitude {nadir_lat} is beyond the orbit's reach (+-{max_lat:.2f})")
    day0 = to_mjd2000_seconds(datetime(date.year, date.month, date.day, tzinfo=UTC))
    s = math.sin(math.radians(nadir_lat)) / math.sin(incl)
    u = math.asin(max(-1.0, min(1.0, s)))
    if direction == "descending":
        u = math.pi - u
    if u < 0.0:
        u += 2.0 * math.pi
    n = math.sqrt(GM / platform.radius**3)
    # first guess of the time over the point: 10:30 local solar time
    t = day0 + (10.5 - nadir_lon / 15.0) * 3600.0
    t = day0 + (t - day0) % 86400.0
    for _ in range(40):
        orbit = sun_synchronous_orbit(t - u / n, platform)
        lon, lat = _subsatellite(orbit, t)
        dlon = _wrap_deg(lon - nadir_lon)
        dlat = lat - nadir_lat
        if abs(dlon) < 1e-10 and abs(dlat) < 1e-10:
            break
        # the ground track moves west at Earth's rate relative to the node; u moves along track
        t += math.radians(dlon) / (OMEGA_EARTH - NODE_RATE)
        dlat_du = math.sin(incl) * math.cos(u) / max(math.cos(math.radians(lat)), 1e-6)
        u -= math.radians(dlat) / dlat_du
    orbit = sun_synchronous_orbit(t - u / n, platform)
    return orbit, t

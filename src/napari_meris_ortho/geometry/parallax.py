"""The parallax (geodetic) correction in numpy (handbook eq. 2, 2c', 6a-6b') and what the
tie points' heights give it: one definition for the engine's ``geodetic_correction``, the
location models' tie-point heights, the simulator's stored corrections and the ``.SEN3``
reader's derived ones.

Over sea, real products store the seabed as a negative ``dem_alt`` (bathymetry: -228 m off
Portugal in MER_FRS_1PNMAP20070709, down to -5103 m in MER_RR__1PRACR20060116 over the open
Pacific) and set ``lat_corr``/``lon_corr`` to exactly 0 there: the line of sight meets the sea
surface, not the seabed. :func:`parallax_height` is that rule. On land, operational N1 products
store eq. 2 of the Detailed Processing Model as it is: ``lat_corr`` with the sign of the
correction added, ``lon_corr`` with the opposite one (Appendix E: every FR and RR dump, e.g.
-1146e-6 deg at view azimuth 100 deg in E.1), which :func:`stored_corrections` writes.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .earth import MEAN_EARTH_RADIUS, WGS84_A, WGS84_E2

#: codes of the radius models (``options.Parallax``): sphere, WGS84 M/N, WGS84 M+h/N+h
SPHERE, ELLIPSOID, ELLIPSOID_PLUS_H = 0, 1, 2


def parallax_height(dem_alt: ArrayLike) -> np.ndarray:
    """Height (m) a tie point's ``dem_alt`` gives the parallax: the terrain, 0 below 0.

    Negative ``dem_alt`` is bathymetry over sea (or a shore below sea level); ESA's zero
    corrections there say that no parallax applies.
    """
    return np.maximum(np.asarray(dem_alt, dtype=np.float64), 0.0)


def geodetic_offsets(height_m: ArrayLike, view_zenith_deg: ArrayLike,
                     view_azimuth_deg: ArrayLike, lat_deg: ArrayLike, model: int = SPHERE
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Parallax correction (dlon, dlat) in degrees ADDED to the ellipsoid position (eq. 2c', 6b')::

        dlon = +h tan(vz) sin(va) / (R cos lat)      dlat = +h tan(vz) cos(va) / R

    ``model``: ``SPHERE`` (R = 6 370 997 m, MERSYN 02.05, BEAM; Appendix D), ``ELLIPSOID``
    (WGS84 prime-vertical N for dlon, meridian M for dlat) or ``ELLIPSOID_PLUS_H`` (N + h,
    M + h). Vectorised over numpy broadcasting.
    """
    h, vz, va, lat = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (
        height_m, view_zenith_deg, view_azimuth_deg, lat_deg)))
    dx = h * np.tan(np.radians(vz))
    east = dx * np.sin(np.radians(va))
    north = dx * np.cos(np.radians(va))
    phi = np.radians(lat)
    if model == SPHERE:
        rm = rn = np.full(phi.shape, MEAN_EARTH_RADIUS)
    else:
        w = 1.0 - WGS84_E2 * np.sin(phi) ** 2
        rn = WGS84_A / np.sqrt(w)
        rm = WGS84_A * (1.0 - WGS84_E2) / w ** 1.5
        if model == ELLIPSOID_PLUS_H:
            rn = rn + h
            rm = rm + h
    return np.degrees(east / (rn * np.cos(phi))), np.degrees(north / rm)


def stored_corrections(dem_alt: ArrayLike, view_zenith_deg: ArrayLike,
                       view_azimuth_deg: ArrayLike, lat_deg: ArrayLike
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Tie-point ``(lat_corr, lon_corr)`` (deg) as operational products store them (eq. 2 on
    the sphere, Appendix E)::

        lat_corr = +h tan(vz) cos(va) / R      lon_corr = -h tan(vz) sin(va) / (R cos lat)

    i.e. ``lat_corr`` is the ``dlat`` of :func:`geodetic_offsets` and ``lon_corr`` minus its
    ``dlon`` (the handbook's remark under eq. 2: the signs are "not compliant"; eq. 2c' is the
    one to add), from the :func:`parallax_height` of ``dem_alt`` (exactly 0 where ``dem_alt``
    <= 0, over sea)."""
    dlon, dlat = geodetic_offsets(parallax_height(dem_alt), view_zenith_deg, view_azimuth_deg,
                                  lat_deg, SPHERE)
    return dlat, -dlon + 0.0  # + 0.0: no -0.0 over sea

"""Figures of the Earth used by the location models (handbook eq. 2, 6a; Appendix C).

One definition of each: the mean Earth sphere of MERSYN and BEAM (``TIM_MERSYN_MEAN_EARTH_RADIUS``)
and the WGS84 ellipsoid (semi-major axis a, flattening f, e2 = f (2 - f)).
"""

from __future__ import annotations

#: mean Earth radius of MERSYN and BEAM, metres (handbook eq. 2, 6a; Appendix C)
MEAN_EARTH_RADIUS = 6_370_997.0
#: WGS84 semi-major axis, metres
WGS84_A = 6_378_137.0
#: WGS84 flattening
WGS84_F = 1.0 / 298.257223563
#: WGS84 first eccentricity squared
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
#: WGS84 semi-minor axis, metres
WGS84_B = WGS84_A * (1.0 - WGS84_F)
#: metres per degree of latitude or of equatorial longitude, as a round figure (margins only)
METRES_PER_DEGREE = 111_320.0
#: highest terrain expected (m): how far beyond the zero-height segment boundary a terrain point
#: may lie (section 3.1)
MAX_TERRAIN_M = 9000.0
#: lowest terrain expected (m): the Dead Sea shore is at -430 m; a DEM value outside
#: MIN_TERRAIN_M..MAX_TERRAIN_M is no data (tie-point heights: MIN_SEABED_M)
MIN_TERRAIN_M = -500.0
#: lowest tie-point ``dem_alt`` (m): real products store the seabed over sea (bathymetry, down
#: to -5103 m in MER_RR__1PRACR20060116 over the Pacific); the deepest seabed, the Challenger
#: Deep, lies about 10 935 m below sea level, plus a margin for the geoid and the auxiliary DEM
MIN_SEABED_M = -11_500.0

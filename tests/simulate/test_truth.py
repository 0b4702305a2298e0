"""Exact ground truth of simulated scenes and their N1 products."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho import geodetic_correction
from napari_meris_ortho.geometry.earth import MEAN_EARTH_RADIUS
from napari_meris_ortho.products.n1 import (
    FLAG_BRIGHT,
    FLAG_COASTLINE,
    FLAG_GLINT_RISK,
    FLAG_INVALID,
    FLAG_LAND_OCEAN,
    read_product,
)


def _random_pixels(scene, n, seed):
    rng = np.random.default_rng(seed)
    g = scene.geometry
    return rng.uniform(0, g.lines - 1, n), rng.uniform(0, g.columns - 1, n)


def _pairs(scene, lines, cols):
    """pixel_geometry for (line, col) pairs."""
    out = {}
    for l, c in zip(lines, cols, strict=True):
        g = scene.pixel_geometry([l], [c])
        for k, v in g.items():
            out.setdefault(k, []).append(float(v[0, 0]))
    return {k: np.array(v) for k, v in out.items()}


@pytest.mark.slow
def test_true_antecedent_of_pixel_terrain_points(fr_small):
    """The terrain point T seen by pixel (l, c) projects back on (l, c) to 0.001 px."""
    lines = np.arange(0, fr_small.geometry.lines, 37, dtype=np.float64)
    cols = np.arange(0, fr_small.geometry.columns, 41, dtype=np.float64)
    g = fr_small.pixel_geometry(lines, cols)
    assert np.nanmax(g["t_h"]) > 1500.0  # mountains are in the sample
    tl, tc = fr_small.true_antecedent(g["t_lon"], g["t_lat"], g["t_h"])
    assert np.max(np.abs(tl - lines[:, None])) < 1e-3
    assert np.max(np.abs(tc - cols[None, :])) < 1e-3
    # the ellipsoid point E projects on the same pixel (h = 0)
    el, ec = fr_small.true_antecedent(g["e_lon"], g["e_lat"], 0.0)
    assert np.max(np.abs(el - lines[:, None])) < 1e-3
    assert np.max(np.abs(ec - cols[None, :])) < 1e-3


def test_terrain_point_lies_on_the_dem_and_is_displaced_towards_the_satellite(fr_small):
    lines = np.arange(0, fr_small.geometry.lines, 29, dtype=np.float64)
    cols = np.arange(0, fr_small.geometry.columns, 31, dtype=np.float64)
    g = fr_small.pixel_geometry(lines, cols)
    h_dem = fr_small.dem_height(g["t_lon"], g["t_lat"])
    assert np.max(np.abs(g["t_h"] - h_dem)) < 1e-3
    # displacement ~ h tan(vz) towards the satellite (eq. 2, within the sphere approximation)
    from pyproj import Geod

    az, _, dist = Geod(ellps="WGS84").inv(g["e_lon"], g["e_lat"], g["t_lon"], g["t_lat"])
    expect = g["t_h"] * np.tan(np.radians(g["view_zenith"]))
    high = g["t_h"] > 500.0
    assert np.allclose(dist[high], expect[high], rtol=0.03)
    assert np.all(np.abs(((az[high] - g["view_azimuth"][high]) + 180) % 360 - 180) < 1.0)


def test_random_ground_points_round_trip_within_a_metre(fr_small):
    """Project random ground points with true_antecedent, intersect the line of sight again:
    the same point within 1 m (unless hidden behind a ridge, then T is nearer the satellite)."""
    s = fr_small
    lines, cols = _random_pixels(s, 60, 3)
    first = _pairs(s, lines, cols)
    lon, lat = first["t_lon"] + 0.003, first["t_lat"] - 0.002  # points near, not on, pixels
    h = s.dem_height(lon, lat)
    tl, tc = s.true_antecedent(lon, lat, h)
    inside = (tl > 0) & (tl < s.geometry.lines - 1) & (tc > 0) & (tc < s.geometry.columns - 1)
    again = _pairs(s, tl[inside], tc[inside])
    from pyproj import Geod

    _, _, d = Geod(ellps="WGS84").inv(lon[inside], lat[inside], again["t_lon"], again["t_lat"])
    dh = np.abs(again["t_h"] - h[inside])
    seen = d < 1.0
    assert seen.mean() > 0.9
    assert np.all(dh[seen] < 1.0)
    # the others are occluded: the line of sight meets the terrain before the point
    assert np.all(again["t_h"][~seen] >= h[inside][~seen] - 1.0)


def test_product_radiance_is_the_truth_at_the_terrain_point(fr_small):
    p = read_product(fr_small.product_path)
    lines = np.arange(3, p.height, 53, dtype=np.float64)
    cols = np.arange(5, p.width, 47, dtype=np.float64)
    g = fr_small.pixel_geometry(lines, cols)
    li, ci = lines.astype(int)[:, None], cols.astype(int)[None, :]
    valid = (p.flags[li, ci] & FLAG_INVALID) == 0
    for band in (2, 7, 13):
        truth = fr_small.truth_radiance(g["t_lon"], g["t_lat"], band)
        got = p.radiance(band)[li, ci]
        sf = p.scaling.radiance[band - 1]
        assert np.all(np.abs(got - truth)[valid] <= 0.5 * sf + 1e-4)
        # the ellipsoid point E sees something else (the parallax matters)
    e_truth = fr_small.truth_radiance(g["e_lon"], g["e_lat"], 13)
    assert np.mean(np.abs(p.radiance(13)[li, ci] - e_truth)[valid]) > 1.0


def test_vegetation_ndvi_and_flags(fr_small):
    p = read_product(fr_small.product_path)
    r7, r13 = p.radiance(7).astype(float), p.radiance(13).astype(float)
    ndvi = (r13 - r7) / np.maximum(r13 + r7, 1e-6)
    land = (p.flags & FLAG_LAND_OCEAN) > 0
    water = ~land & ((p.flags & FLAG_INVALID) == 0)
    assert 0.5 < land.mean() < 0.999 and water.any()
    assert np.percentile(ndvi[land], 75) > 0.4 and np.percentile(ndvi[water], 90) < 0.0
    assert (p.flags & FLAG_COASTLINE).any() and (p.flags & FLAG_BRIGHT).any()
    invalid = (p.flags & FLAG_INVALID) > 0
    assert 0 < invalid.sum() < 50 and np.all(p.counts(7)[invalid] == 0)
    assert not (p.flags[land] & FLAG_GLINT_RISK).any()


def test_stored_corrections_as_operational_products_store_them(fr_small):
    """lat_corr as ``geodetic_correction``'s dlat, lon_corr as minus its dlon (eq. 2 as the
    Appendix E dumps of real products store it): within 0.2 m on land (the 1e-6 deg
    quantization), exactly 0 over the sea, where dem_alt holds the seabed (< 0)."""
    tp = read_product(fr_small.product_path).tie_points
    h, lat = tp["dem_alt"], tp["latitude"]
    dlon, dlat = geodetic_correction(h, tp["view_zenith"], tp["view_azimuth"], lat)
    land, sea = h > 0, h < 0
    assert land.sum() > 40 and sea.sum() >= 3
    m_per_deg = np.pi * MEAN_EARTH_RADIUS / 180.0
    assert np.max(np.abs(tp["lat_corr"] - dlat)[land]) * m_per_deg < 0.2
    east = np.abs(tp["lon_corr"] + dlon) * np.cos(np.radians(lat))
    assert np.max(east[land]) * m_per_deg < 0.2
    assert np.abs(tp["lon_corr"][land]).max() > 0.005  # real corrections, up to ~1 km
    assert np.all(tp["lat_corr"][sea] == 0.0) and np.all(tp["lon_corr"][sea] == 0.0)


def test_open_sea_tie_points_store_the_seabed(fr_small):
    """Over the open sea (the truth sea under the tie point, the smoothed DEM 0) dem_alt is the
    seabed, negative, as in real products; the truth DEM keeps the sea surface at 0."""
    tp = read_product(fr_small.product_path).tie_points
    sea = tp["dem_alt"] < 0
    assert np.all(fr_small.dem_height(tp["longitude"][sea], tp["latitude"][sea]) == 0.0)
    assert -5500.0 <= tp["dem_alt"].min() <= -20.0


def test_tie_point_dem_is_smoothed_so_peaks_are_too_low(fr_small):
    """Handbook section 4.4: the auxiliary DEM (about 5') misses the peaks."""
    tp = read_product(fr_small.product_path).tie_points
    truth = fr_small.dem_height(tp["longitude"], tp["latitude"])
    assert tp["dem_alt"].max() < np.nanmax(fr_small.dem) - 500.0
    assert np.nanmax(truth - tp["dem_alt"]) > 300.0
    assert tp["dem_rough"].max() > 200.0


def test_sun_and_ecmwf_fields_are_plausible(fr_small):
    tp = read_product(fr_small.product_path).tie_points
    assert np.all((tp["sun_zenith"] > 45) & (tp["sun_zenith"] < 55))  # Appendix E.4: 48-52
    assert np.all((tp["sun_azimuth"] > 140) & (tp["sun_azimuth"] < 160))
    assert np.all((tp["atm_pressure"] > 990) & (tp["atm_pressure"] < 1030))
    assert np.all((tp["ozone"] > 200) & (tp["ozone"] < 400))
    assert np.all((tp["rel_humidity"] >= 0) & (tp["rel_humidity"] <= 100))


def test_pyepr_reads_every_generated_product(fr_small, tiny_rr):
    import epr

    for scene in (fr_small, tiny_rr):
        ours = read_product(scene.product_path)
        with epr.open(str(scene.product_path)) as prod:
            assert prod.get_scene_width() == scene.geometry.columns
            assert prod.get_scene_height() == scene.geometry.lines
            rad = prod.get_band("radiance_13").read_as_array()
            # EPR mirrors the lines (west to east on a descending pass)
            assert np.allclose(rad[:, ::-1], ours.radiance(13), rtol=1e-6)
            lat_tp = prod.get_band("latitude").read_as_array()
            assert np.allclose(lat_tp[0, -1], ours.tie_points["latitude"][0, 0], atol=1e-5)


def test_antimeridian_truth_is_continuous(tiny_rr):
    s = tiny_rr
    lat = np.full(5, 63.0)
    lon = np.array([179.98, 179.99, -180.0, -179.99, -179.98])
    h = s.dem_height(lon, lat)
    assert np.all(np.isfinite(h))
    l, c = s.true_antecedent(lon, lat, h)
    assert np.all(np.abs(np.diff(c)) < 1.0) and np.all(np.abs(np.diff(l)) < 1.0)
    assert np.all(np.isfinite(s.truth_radiance(lon, lat, 7)))
    g = s.pixel_geometry(np.array([10.0, 40.0]), np.arange(0, 1121, 80, dtype=np.float64))
    tl, tc = s.true_antecedent(g["t_lon"], g["t_lat"], g["t_h"])
    assert np.max(np.abs(tc - np.arange(0, 1121, 80)[None, :])) < 1e-3

"""Output grid: conventions, validation, default size (Appendix B/C), primary-grid lon/lat."""

from __future__ import annotations

import math

import numpy as np
import pyproj
import pytest
from affine import Affine

from napari_meris_ortho.engine.boundary import segment_boundary
from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.geometry.grid import (
    MEAN_EARTH_RADIUS,
    OutputGrid,
    default_grid,
    footprint_utm,
    is_footprint_utm,
    pixel_pair,
    pixel_size_for,
    product_crs,
    terrain_margin_px,
    utm_crs_for,
)


def fr_footprint(lon0: float = 12.0, lat0: float = 47.5, n_lines: int = 50, azimuth=-167.0):
    """Tie points of an FR-like segment: 36 tie columns over ~1150 km, lines every 64 x 300 m."""
    geod = pyproj.Geod(ellps="WGS84")
    lat = np.empty((n_lines, 36))
    lon = np.empty((n_lines, 36))
    for i in range(n_lines):
        clon, clat, _ = geod.fwd(lon0, lat0, azimuth, i * 64 * 300.0)
        for k in range(36):
            d = (k - 17.5) * 64 * 260.0 * (1 + 0.3 * abs(k - 17.5) / 17.5)
            lon[i, k], lat[i, k], _ = geod.fwd(clon, clat, azimuth + 90.0, d)
    return lat, lon


def max_pixel_error(grid: OutputGrid, row_start: int, row_stop: int) -> float:
    """Largest distance (output px) between the interpolated lon/lat and the exact pixel centre."""
    lon, lat = grid.lonlat(row_start, row_stop)
    r, c = grid.xy_of_lonlat(lon, lat)
    rows = np.arange(row_start, row_stop)[:, None]
    cols = np.arange(grid.width)[None, :]
    return float(np.nanmax(np.hypot(r - rows, c - cols)))


def test_pixel_centre_and_transform_conventions():
    g = OutputGrid("EPSG:32631", 1000.0, 5000.0, 10.0, 20.0, 7, 5)
    x, y = g.xy(np.array([0, 4]), np.array([0, 6]))
    assert x.tolist() == [1005.0, 1065.0]
    assert y.tolist() == [4990.0, 4910.0]
    t = g.transform
    assert (t.a, t.b, t.c, t.d, t.e, t.f) == (10.0, 0.0, 1000.0, 0.0, -20.0, 5000.0)
    assert t @ (0.5, 0.5) == (1005.0, 4990.0)
    assert g.bounds == (1000.0, 4900.0, 1070.0, 5000.0)
    assert not g.is_geographic and g.shape == (5, 7)


def test_from_extent_rounds_outwards_and_validates():
    g = OutputGrid.from_extent("EPSG:4326", (10.0, 46.0), (11.0, 45.0), 0.3)
    assert (g.width, g.height) == (4, 4)
    g = OutputGrid.from_extent("EPSG:32631", (0.0, 2600.0), (2600.0, 0.0), (260.0, 520.0))
    assert (g.width, g.height) == (10, 5)
    with pytest.raises(OptionsError, match="pixel size"):
        OutputGrid.from_extent("EPSG:4326", (10, 46), (11, 45), 0.0)
    with pytest.raises(OptionsError, match="pixel size"):
        OutputGrid.from_extent("EPSG:4326", (10, 46), (11, 45), -1.0)
    with pytest.raises(OptionsError, match="upper-left"):
        OutputGrid.from_extent("EPSG:4326", (11, 46), (10, 45), 0.1)
    with pytest.raises(OptionsError, match="upper-left"):
        OutputGrid.from_extent("EPSG:4326", (10, 45), (11, 46), 0.1)
    with pytest.raises(OptionsError, match="unknown CRS"):
        OutputGrid.from_extent("EPSG:999999", (10, 46), (11, 45), 0.1)
    with pytest.raises(OptionsError, match="unknown CRS"):
        OutputGrid.from_extent("not a crs", (10, 46), (11, 45), 0.1)


def test_default_pixel_sizes_match_mersyn():
    """Appendix C: Geographic pixel = nominal size / mean Earth radius; metric otherwise."""
    fr = pixel_size_for(260.0, "EPSG:4326")
    assert fr == pytest.approx(math.degrees(260.0 / MEAN_EARTH_RADIUS), rel=1e-15)
    assert fr == pytest.approx(0.00233823727, abs=1e-11)
    assert pixel_size_for(1040.0, "EPSG:4326") == pytest.approx(4 * fr, rel=1e-15)
    assert pixel_size_for(260.0, "EPSG:32631") == 260.0
    assert pixel_size_for(260.0, "EPSG:2264") == pytest.approx(260.0 / 0.3048006096, rel=1e-9)


def test_utm_zone_helper():
    assert utm_crs_for(2.5, 45.0).to_epsg() == 32631
    assert utm_crs_for(-3.0, -10.0).to_epsg() == 32730
    assert utm_crs_for(179.9, 0.0).to_epsg() == 32660
    assert utm_crs_for(180.0, 1.0).to_epsg() == 32601
    assert utm_crs_for(-180.0, 1.0).to_epsg() == 32601


def test_footprint_utm_across_the_antimeridian_and_the_word():
    lat = np.array([[40.0, 41.0], [42.0, 43.0]])
    lon = np.array([[178.0, -176.0], [177.0, -177.0]])  # centre 180.5 E: zone 1, not 31
    assert footprint_utm(lat, lon).to_epsg() == 32601
    assert footprint_utm(-lat, lon + 0.0).to_epsg() == 32701
    assert footprint_utm(lat, lon - 170.0).to_epsg() == 32632  # 8-14 E
    assert product_crs(" UTM ", lat, lon).to_epsg() == 32601
    assert product_crs("EPSG:3035", lat, lon).to_epsg() == 3035
    assert is_footprint_utm("utm") and not is_footprint_utm("utm32")
    with pytest.raises(OptionsError, match="unknown CRS"):
        product_crs("utm32", lat, lon)


class _Poly:
    def __init__(self, x, y):
        self.x, self.y = np.asarray(x, float), np.asarray(y, float)

    def polygons(self, crs):
        return [(self.x, self.y)]


def test_default_grid_mersyn_size_reproduces_appendix_b_log():
    """Appendix B: UL (1025533.1875, 5226455.019), LR (2002024.5, 4461188.5) at 260 m gives
    2943 lines and 3755 columns."""
    y_min, y_ul = 4461188.5, 5226455.019
    y_max = (y_ul + y_min / 10000.0) / (1.0 + 1.0 / 10000.0)
    poly = _Poly([1025533.1875, 2002024.5, 2002024.5, 1025533.1875],
                 [y_max, y_max, y_min, y_min])
    g = default_grid(poly, 260.0, "EPSG:32662", mersyn_size=True)
    assert (g.height, g.width) == (2943, 3755)
    assert (g.x0, g.y0) == (1025533.1875, pytest.approx(y_ul, abs=1e-6))
    g = default_grid(poly, 260.0, "EPSG:32662")  # projected: the origin on multiples of 260 m
    y0 = math.ceil(y_max / 260) * 260.0
    assert (g.x0, g.y0) == (3944 * 260.0, y0)  # 1025440 m: 93.19 m west of the boundary
    assert (g.height, g.width) == (math.ceil((y0 - y_min) / 260), 3757)
    assert g.y0 - g.height * g.dy <= y_min and g.x0 + g.width * g.dx >= 2002024.5


def test_default_grid_holds_footprint_geographic_and_utm():
    lat, lon = fr_footprint()
    b = segment_boundary(lat, lon)
    g = default_grid(b, 260.0, "EPSG:4326")
    assert g.dx == pytest.approx(pixel_size_for(260.0, "EPSG:4326"))
    assert g.x0 == pytest.approx(lon.min()) and g.y0 == pytest.approx(lat.max())
    assert g.x0 + g.width * g.dx >= lon.max() > g.x0 + (g.width - 1) * g.dx
    assert g.y0 - g.height * g.dy <= lat.min() < g.y0 - (g.height - 1) * g.dy
    u = default_grid(b, 260.0, utm_crs_for(12.0, 45.0))
    x, y = pyproj.Transformer.from_crs(4326, u.crs, always_xy=True).transform(lon, lat)
    assert u.x0 <= x.min() and u.x0 + u.width * 260.0 >= x.max()
    assert u.y0 >= y.max() and u.y0 - u.height * 260.0 <= y.min()


def test_geographic_lonlat_exact_and_wrapped_past_180():
    g = OutputGrid("EPSG:4326", 170.0, 10.0, 0.5, 0.25, 40, 8)
    lon, lat = g.lonlat(2, 5)
    assert lon.shape == (3, 40)
    assert lat[0, 0] == 10.0 - 2.5 * 0.25 and lat[2, 0] == 10.0 - 4.5 * 0.25
    assert lon[0, 0] == 170.25 and lon[0, 19] == 179.75 and lon[0, 20] == -179.75
    assert np.all((lon >= -180) & (lon < 180))
    r, c = g.xy_of_lonlat(np.array([-179.75, 170.25]), np.array([9.375, 9.375]))
    np.testing.assert_allclose(c, [20.0, 0.0])
    np.testing.assert_allclose(r, [2.0, 2.0])


@pytest.mark.parametrize("epsg", [32631, 32633, 32662])
def test_projected_lonlat_within_a_hundredth_of_pixel(epsg):
    """Primary-grid bilinear lon/lat against pyproj at every pixel of row blocks across an FR
    footprint at 260 m (the terrain-correction paper's 0.01 px)."""
    lat, lon = fr_footprint()
    g = default_grid(segment_boundary(lat, lon), 260.0, f"EPSG:{epsg}")
    assert g.width > 3000 and g.height > 3000
    errors = [max_pixel_error(g, a, a + 40) for a in (0, g.height // 2 - 20, g.height - 40)]
    assert max(errors) <= 0.01
    stats = g.interpolation_stats
    assert 4 <= stats["step"] <= 256
    assert stats["max_error_px"] <= 0.005
    if epsg == 32662:  # Plate Carree is linear in lon/lat: the largest step, no error
        assert stats["step"] == 256 and max(errors) < 1e-6
    else:
        assert stats["trial_max_error_px"] > 0.005 and stats["step"] < 64


def test_projected_lonlat_is_independent_of_row_chunks():
    lat, lon = fr_footprint(n_lines=10)
    g = default_grid(segment_boundary(lat, lon), 1040.0, "EPSG:32633")
    full_lon, full_lat = g.lonlat()
    part_lon, part_lat = g.lonlat(37, 101)
    np.testing.assert_array_equal(part_lon, full_lon[37:101])
    np.testing.assert_array_equal(part_lat, full_lat[37:101])


def test_polar_stereographic_steps_follow_the_bending():
    """An RR grid in EPSG:3995 whose top edge passes 830 km from the North Pole (an Arctic
    descending segment): the longitude bends hardest in the top rows, so the step is chosen band
    by band (64 rows each): small near the pole, larger away from it, still within 0.01 px."""
    g = OutputGrid.from_extent("EPSG:3995", (-1.6e6, -0.83e6), (0.9e6, -3.8e6), 1040.0)
    steps = g.primary_steps()
    assert steps.size == math.ceil(g.height / 64)
    assert steps[0] == steps.min() and steps[-1] >= 2 * steps[0]
    assert np.all(np.diff(steps) >= 0)  # the farther from the pole, the larger the step
    stats = g.interpolation_stats
    assert (stats["step"], stats["max_step"]) == (steps.min(), steps.max())
    errors = [max_pixel_error(g, a, a + 70) for a in (0, g.height // 2 - 35, g.height - 70)]
    assert max(errors) <= 0.01 and stats["max_error_px"] <= 0.005
    full_lon, full_lat = g.lonlat(0, 300)  # rows across band edges: the same values
    part_lon, part_lat = g.lonlat(37, 201)
    np.testing.assert_array_equal(part_lon, full_lon[37:201])
    np.testing.assert_array_equal(part_lat, full_lat[37:201])


@pytest.mark.parametrize("crs", [pytest.param("EPSG:3995", marks=pytest.mark.slow),
                                 "EPSG:4326"])
def test_a_column_window_holds_the_whole_rows_values(crs):
    """lon/lat of columns [c0, c1) are those of the whole rows bit for bit (the same nodes and
    cells), for windows anywhere, one column wide or ending on the last column."""
    if crs == "EPSG:4326":
        g = OutputGrid(crs, 10.0, 50.0, 0.01, 0.01, 500, 300)
    else:
        g = OutputGrid.from_extent(crs, (-1.6e6, -0.83e6), (0.9e6, -3.8e6), 1040.0)
    rng = np.random.default_rng(5)
    windows = [(0, 1), (g.width - 1, g.width), (0, g.width)]
    windows += [tuple(sorted(rng.choice(g.width + 1, 2, replace=False))) for _ in range(12)]
    for k, (c0, c1) in enumerate(windows):
        r0 = int(rng.integers(0, g.height - 100))
        r1 = min(r0 + 1 + 37 * k, g.height)
        lon, lat = g.lonlat(r0, r1)
        wlon, wlat = g.lonlat(r0, r1, col_start=int(c0), col_stop=int(c1))
        assert wlon.shape == (r1 - r0, c1 - c0)
        np.testing.assert_array_equal(wlon, lon[:, c0:c1])
        np.testing.assert_array_equal(wlat, lat[:, c0:c1])
    with pytest.raises(ValueError, match="column range"):
        g.lonlat(0, 2, col_start=3, col_stop=2)


def test_grids_of_one_row_past_a_band():
    """A last band of one row (height 64 k + 1) has no trial cell of its own: it takes the step
    of the band before it and is exact there."""
    g = OutputGrid.from_extent("EPSG:32633", (300000, 5100000), (560000, 5100000 - 129 * 260.0),
                               260.0)
    assert g.height == 129 and g.primary_steps().size == 3
    assert g.primary_steps()[2] == g.primary_steps()[1]
    assert max_pixel_error(g, 0, 129) <= 0.01


def test_cells_off_the_projection_fall_back_to_exact():
    """An orthographic grid larger than the visible disk: corners off the globe are not
    interpolated; every finite pixel equals pyproj's position, pixels off the disk are NaN."""
    crs = "+proj=ortho +lat_0=45 +lon_0=10 +ellps=WGS84"
    g = OutputGrid.from_extent(crs, (-7.0e6, 7.0e6), (7.0e6, -7.0e6), 50_000.0)
    lon, lat = g.lonlat()
    elon, elat = g.lonlat_exact()
    np.testing.assert_array_equal(np.isnan(lon), np.isnan(elon))
    assert np.isnan(elon).sum() > 1000 and np.isfinite(elon).sum() > 1000
    assert g.interpolation_stats["exact_pixels"] > 0
    ok = np.isfinite(elon)
    r, c = g.xy_of_lonlat(lon[ok], lat[ok])
    rows, cols = np.nonzero(ok)
    assert np.max(np.hypot(r - rows, c - cols)) <= 0.01


def test_xy_of_lonlat_round_trip_utm():
    g = OutputGrid.from_extent("EPSG:32631", (300000, 5100000), (700000, 4800000), 260.0)
    lon, lat = g.lonlat_exact(100, 102)
    r, c = g.xy_of_lonlat(lon, lat)
    np.testing.assert_allclose(r, np.broadcast_to(np.arange(100, 102)[:, None], r.shape),
                               atol=1e-6)
    np.testing.assert_allclose(c, np.broadcast_to(np.arange(g.width), c.shape), atol=1e-6)


def test_grid_rejects_bad_size():
    with pytest.raises(OptionsError):
        OutputGrid("EPSG:4326", 0, 0, 0.1, 0.1, 0, 10)
    with pytest.raises(OptionsError):
        OutputGrid("EPSG:4326", 0, 0, 0.1, float("nan"), 10, 10)


def test_window_is_the_same_pixels_of_a_sub_grid():
    grid = OutputGrid("EPSG:32633", 300000.0, 5300000.0, 260.0, 260.0, 800, 600,
                      tolerance=0.005)
    sub = grid.window(50, 120, 30, 90)
    assert (sub.height, sub.width) == (70, 60) and sub.crs == grid.crs
    assert (sub.dx, sub.dy, sub.tolerance) == (260.0, 260.0, 0.005)
    assert (sub.x0, sub.y0) == (300000.0 + 30 * 260.0, 5300000.0 - 50 * 260.0)
    assert sub.transform == grid.transform @ Affine.translation(30, 50)
    # pixel (5, 3) of the window is pixel (55, 33) of the grid, also in lon/lat
    x, y = grid.xy(np.array([55.0]), np.array([33.0]))
    xs, ys = sub.xy(np.array([5.0]), np.array([3.0]))
    assert abs(x[0] - xs[0]) < 1e-9 and abs(y[0] - ys[0]) < 1e-9
    lon, lat = grid.lonlat(50, 120)
    slon, slat = sub.lonlat()
    deg_px = 260.0 / 111320.0
    assert np.max(np.abs(slon - lon[:, 30:90])) < 0.01 * deg_px / math.cos(math.radians(48))
    assert np.max(np.abs(slat - lat[:, 30:90])) < 0.01 * deg_px
    assert grid.window(0, 600, 0, 800) == grid
    for bad in [(10, 10, 0, 5), (0, 601, 0, 5), (-1, 5, 0, 5), (0, 5, 790, 801)]:
        with pytest.raises(OptionsError, match="window"):
            grid.window(*bad)


def test_from_transform_is_the_rasterio_convention_and_refuses_rotation():
    g = OutputGrid.from_transform("EPSG:32632", (250.0, 0.0, 300_000.0, 0.0, -500.0, 5e6),
                                  (3, 40, 60))
    assert (g.x0, g.y0, g.dx, g.dy, g.width, g.height) == (300_000.0, 5e6, 250.0, 500.0, 60, 40)
    assert tuple(g.transform)[:6] == (250.0, 0.0, 300_000.0, 0.0, -500.0, 5e6)
    for bad in [(250.0, 0.1, 0.0, 0.0, -500.0, 0.0), (250.0, 0.0, 0.0, 0.0, 500.0, 0.0)]:
        with pytest.raises(OptionsError, match="north-up"):
            OutputGrid.from_transform("EPSG:32632", bad, (40, 60))


def test_same_grid_compares_crs_and_pixel_size_only():
    a = OutputGrid("EPSG:4326", 10.0, 50.0, 0.01, 0.01, 100, 80)
    assert a.same_grid(OutputGrid("EPSG:4326", -3.0, 40.0, 0.01, 0.01, 7, 9))
    assert not a.same_grid(OutputGrid("EPSG:4326", 10.0, 50.0, 0.01, 0.02, 100, 80))
    assert not a.same_grid(OutputGrid("EPSG:3035", 10.0, 50.0, 0.01, 0.01, 100, 80))


def test_pixel_pair():
    assert pixel_pair(260) == (260.0, 260.0)
    assert pixel_pair((0.5, 0.25)) == (0.5, 0.25)
    assert pixel_pair(np.array([2.0, 3.0])) == (2.0, 3.0)
    assert pixel_pair(np.float32(1.5)) == (1.5, 1.5)


def test_terrain_margin_is_the_parallax_of_the_highest_terrain_in_pixels():
    utm = OutputGrid("EPSG:32632", 0.0, 0.0, 260.0, 300.0, 10, 10)
    # 9000 m at 45 deg: 9000 m over the narrower 260 m side = 34.6 -> 35, + 2
    assert terrain_margin_px(utm, 45.0, 46.0) == 37
    geo = OutputGrid("EPSG:4326", 0.0, 0.0, 0.01, 0.01, 10, 10)
    side = 0.01 * math.cos(math.radians(60.0)) * 111_320.0  # the east-west side at 60 N
    assert terrain_margin_px(geo, 30.0, 60.0, 4000.0) == math.ceil(
        4000.0 * math.tan(math.radians(30.0)) / side) + 2
    assert terrain_margin_px(utm, 0.0, 0.0) == 2


def test_a_geographic_extent_beyond_the_poles_is_refused():
    """--ul 13 95 --lr 14 45.8 is refused, not a grid reaching latitude 95."""
    from napari_meris_ortho.errors import OptionsError

    with pytest.raises(OptionsError, match="beyond \\+-90 degrees"):
        OutputGrid.from_extent("EPSG:4326", (13.0, 95.0), (14.0, 45.8), 0.0025)
    grid = OutputGrid.from_extent("EPSG:4326", (13.0, 90.0), (14.0, 89.0), 0.25)
    assert (grid.width, grid.height) == (4, 4)
    # a projected CRS has no such bound on its y
    OutputGrid.from_extent("EPSG:32632", (300000.0, 9_500_000.0), (301000.0, 9_499_000.0), 100.0)


def test_a_footprint_the_crs_cuts_at_the_antimeridian_is_refused():
    """rr-antimeridian in EPSG:3857 is refused: its grid would be 38534 x 1701, 3.5 % of it
    data (the footprint's two pieces at both ends of Web Mercator's x range). EPSG:4326 and
    Pacific Mercator (EPSG:3832) keep it compact."""
    from napari_meris_ortho.engine.boundary import segment_boundary
    from napari_meris_ortho.errors import OptionsError
    from napari_meris_ortho.geometry.grid import default_grid

    lat, lon = np.meshgrid(np.linspace(62.0, 60.0, 5), np.linspace(178.0, 182.0, 7),
                           indexing="ij")
    boundary = segment_boundary(lat, (lon + 180.0) % 360.0 - 180.0)
    with pytest.raises(OptionsError, match="crosses the antimeridian, where WGS 84 / Pseudo-"):
        default_grid(boundary, crs="EPSG:3857")
    for crs in ("EPSG:4326", "EPSG:3832"):
        grid = default_grid(boundary, crs=crs)
        assert grid.width < 2000, (crs, grid.width)


def test_a_pixel_in_metres_given_to_a_geographic_crs_is_refused():
    """``map --pixel-size 260`` (EPSG:4326 by default) is refused for its unit (degrees), not
    as "the extent misses the product footprint"."""
    from napari_meris_ortho.errors import OptionsError

    with pytest.raises(OptionsError, match=r"pixel size 260 in WGS 84 is in degrees"):
        OutputGrid.from_extent("EPSG:4326", (10.0, 50.0), (20.0, 40.0), 260.0)
    OutputGrid.from_extent("EPSG:4326", (10.0, 50.0), (20.0, 40.0), 1.0)  # a coarse 1-degree
    OutputGrid.from_extent("EPSG:32632", (0.0, 5e6), (1e4, 4.99e6), 260.0)

"""Pixel geolocation model (direct bilinear, inverse by cell search + Newton) on synthetic grids."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho.engine.boundary import row_spans, segment_boundary
from napari_meris_ortho.engine.location import direct_location
from napari_meris_ortho.engine.pixelgeo import direct_pixel_location, solve_pixel
from napari_meris_ortho.engine.predcorr import HEIGHT_NONE, solve
from napari_meris_ortho.geometry.grid import OutputGrid
from napari_meris_ortho.geometry.tiepoints import analytic_swath


def _terrain(lon, lat):
    return 1500.0 + 1200.0 * np.sin(np.radians(lon) * 40.0) * np.cos(np.radians(lat) * 30.0)


def _pixel_grids(tp, heights: bool):
    """Per-pixel terrain points of the analytic swath: the tie-point model at every pixel."""
    line, col = np.meshgrid(np.arange(tp.height, dtype=float), np.arange(tp.width, dtype=float),
                            indexing="ij")
    if not heights:
        return direct_location(tp, line, col, 0.0)
    lon, lat = direct_location(tp, line, col, 0.0)
    for _ in range(3):  # fixed point: the terrain height at the terrain point
        lon, lat = direct_location(tp, line, col, _terrain(lon, lat))
    return lon, lat


def _scene(lon0=11.0, width=513, height=200):
    tp = analytic_swath(height=height, width=width, lon0=lon0)
    b = segment_boundary(tp.latitude, tp.longitude)
    d = np.degrees(260.0 / 6370997.0)
    x0, x1 = b.lon.min(), b.lon.max()
    if x1 - x0 > 180:
        x0, x1 = b.lon[b.lon > 0].min(), b.lon[b.lon < 0].max() + 360
    grid = OutputGrid("EPSG:4326", x0, b.lat.max(), d * 1.4, d, int((x1 - x0) / (d * 1.4)) + 1,
                      int((b.lat.max() - b.lat.min()) / d) + 1)
    lon, lat = grid.lonlat()
    spans = row_spans(b, grid, margin=20)
    return tp, grid, lon, lat, (spans.ptr, spans.start, spans.stop)


def test_direct_model_interpolates_pixel_centres_exactly():
    lon = np.array([[10.0, 10.1], [10.02, 10.12]])
    lat = np.array([[45.0, 44.99], [44.9, 44.89]])
    lo, la = direct_pixel_location(lon, lat, [0, 1, 0.5, 0.25], [1, 0, 0.5, 0.5])
    np.testing.assert_allclose(lo, [10.1, 10.02, 10.06, 10.055], atol=1e-12)
    np.testing.assert_allclose(la, [44.99, 44.9, 44.945, 44.97], atol=1e-12)


def test_direct_model_across_the_antimeridian():
    lon = np.array([[179.99, -179.99], [179.98, -179.995]])
    lat = np.array([[60.0, 60.0], [59.99, 59.99]])
    lo, _ = direct_pixel_location(lon, lat, [0.0, 0.0], [0.5, 0.75])
    np.testing.assert_allclose(lo, [-180.0, -179.995], atol=1e-9)


@pytest.mark.slow
def test_flat_pixel_inverse_matches_the_tie_point_inverse():
    """Without heights the bilinear tie-point model restricted to a pixel cell is bilinear:
    the pixel inverse must find the tie-point antecedents."""
    tp, grid, lon, lat, spans = _scene()
    plon, plat = _pixel_grids(tp, heights=False)
    ref = solve(tp, grid, lon, lat, None, HEIGHT_NONE, spans, tolerance=1e-5)
    res = solve_pixel(plon, plat, grid, lon, lat, spans, tolerance=1e-5)
    ok = (ref["iterations"] >= 0) & (res["iterations"] >= 0)
    assert ok.sum() > 0.97 * (ref["iterations"] >= 0).sum()
    assert np.max(np.abs(res["line"][ok] - ref["line"][ok])) < 2e-3
    assert np.max(np.abs(res["col"][ok] - ref["col"][ok])) < 2e-3
    assert res["search"]["primary not found"] == 0


@pytest.mark.parametrize("lon0", [11.0, 179.5])
def test_terrain_pixel_inverse_is_consistent_with_the_direct_model(lon0):
    tp, grid, lon, lat, spans = _scene(lon0=lon0)
    plon, plat = _pixel_grids(tp, heights=True)
    res = solve_pixel(plon, plat, grid, lon, lat, spans, tolerance=1e-4)
    ok = res["iterations"] >= 0
    assert ok.sum() > 0.5 * np.count_nonzero(spans[2] - spans[1])
    lo, la = direct_pixel_location(plon, plat, res["line"][ok], res["col"][ok])
    dx = ((lo - lon[ok] + 180) % 360 - 180) * 111320 * np.cos(np.radians(lat[ok])) / 260.0
    dy = (la - lat[ok]) * 111320 / 260.0
    assert np.max(np.hypot(dx, dy)) < 1e-3
    assert np.all(res["iterations"][ok] <= 10)


def test_a_jump_cell_hides_the_ground_behind_a_crest():
    """Terrain points of a product line step 1 unit per pixel except across a crest, where the
    line of sight jumps 10 units (pixels 4 -> 5): ground within three neighbour steps of either
    side (seen slopes may be steeper than their neighbours) is seen, at the chord's position;
    the middle of the jump is hidden; ordinary cells are not affected. Found by the bracketing
    search from a prediction 3 lines off."""
    from napari_meris_ortho.engine.pixelgeo import cell_search, seen_antecedent

    x = np.r_[np.arange(5.0), np.arange(14.0, 44.0)] * 0.01  # 35 columns
    lon = np.tile(10.0 + x, (6, 1))
    lat = 45.0 - 0.01 * np.arange(6.0)[:, None] * np.ones_like(lon)

    def where(gx, gy):
        i, j, u, v, _ = cell_search(10.0 + gx * 0.01, 45.0 - gy * 0.01, gy + 3.0, lon, lat)
        assert i >= 0
        return seen_antecedent(10.0 + gx * 0.01, 45.0 - gy * 0.01, i, j, u, v, lon, lat)

    for gx, col in ((2.5, 2.5), (4.5, 4.05), (6.9, 4.29), (11.1, 4.71), (13.5, 4.95),
                    (24.25, 15.25)):
        line, c, seen = where(gx, 2.5)
        assert seen and line == pytest.approx(2.5) and c == pytest.approx(col)
    for gx in (7.1, 9.0, 10.9):
        assert not where(gx, 2.5)[2]
    # outside the product, no cell (the outer half pixel belongs to the edge cells)
    assert cell_search(10.0 + 44.0 * 0.01, 45.0 - 0.025, 2.5, lon, lat)[0] == -1
    assert cell_search(10.0 + 43.4 * 0.01, 45.0 - 0.025, 2.5, lon, lat)[:2] == (2, 33)


@pytest.mark.slow
def test_the_bracket_from_a_hint_is_the_bisection_of_the_whole_line():
    """``_bracket`` closed in from a predicted column (doubling steps, then bisection) finds the
    column the bisection of the whole line finds, from any hint (good, bad, off the line),
    over no-data runs, before the first and past the last pixel; the jump of a crest too."""
    from napari_meris_ortho.engine.pixelgeo import _bracket

    rng = np.random.default_rng(7)
    x = np.cumsum(rng.uniform(0.2, 1.8, 400))  # terrain points in order along the line
    x[150:] += 30.0  # a crest: hidden ground, a jump
    lon = np.tile(10.0 + 0.003 * x, (3, 1))
    lat = np.tile(45.0 - 0.0004 * x, (3, 1)) - 0.003 * np.arange(3.0)[:, None]
    lon[1, 200:260] = lat[1, 200:260] = np.nan  # no data on line 1
    lon[1, 40] = np.nan
    checked = 0
    for i in range(3):
        for t in np.r_[rng.uniform(-5.0, x[-1] + 5.0, 400), x[::37], x[201], x[250]]:
            tlon, tlat = 10.0 + 0.003 * t, 45.0 - 0.0004 * t - 0.003 * i
            whole = _bracket(tlon, tlat, i, lon, lat)
            for hint in (np.searchsorted(x, t), np.searchsorted(x, t) + 9.0, 3.0, 395.7,
                         -50.0, 1e6, rng.uniform(0, 400)):
                assert _bracket(tlon, tlat, i, lon, lat, float(hint)) == whole, (i, t, hint)
            checked += 1
            if x[0] <= t < x[-1] and i != 1:
                assert x[whole] <= t <= x[whole + 1]
    assert checked > 1200


def test_the_pixel_model_searches_only_the_nodes_its_points_read():
    """The primary nodes of ``solve_pixel`` are searched only where a point of the spans reads
    them (``needed_nodes``: the corners of its node cell); those nodes keep the antecedents
    the search of every node gives, and the others (beyond the swath) are not searched."""
    from napari_meris_ortho.engine.pixelgeo import SEED_STEP, primary_grid_pixel
    from napari_meris_ortho.engine.predcorr import PRIMARY_STEP, needed_nodes, primary_nodes

    tp, grid, lon, lat, spans = _scene()
    plon, plat = _pixel_grids(tp, heights=True)
    step = PRIMARY_STEP
    every = primary_nodes(grid, 0, lon.shape, step)
    needed = needed_nodes(spans, step, every[0].shape)
    # the corners of the node cell of every point of the spans, counted point by point
    ptr, start, stop = spans
    want = np.zeros_like(needed)
    for i in range(ptr.size - 1):
        j = np.concatenate([np.arange(a, b) for a, b in zip(start[ptr[i]:ptr[i + 1]],
                                                             stop[ptr[i]:ptr[i + 1]],
                                                             strict=True)] or [[]]).astype(int)
        a = min(i // step, want.shape[0] - 2)
        b = np.minimum(j // step, want.shape[1] - 2)
        for da in (0, 1):
            for db in (0, 1):
                want[a + da, b + db] = True
    np.testing.assert_array_equal(needed, want)
    assert 0.2 < needed.mean() < 0.9
    nodes = primary_nodes(grid, 0, lon.shape, step, spans=spans)
    assert np.isnan(nodes[0][~needed]).all() and not np.isnan(nodes[0][needed]).any()
    cl_all, cp_all, counts_all = primary_grid_pixel(*every, plon, plat, SEED_STEP)
    cl, cp, counts = primary_grid_pixel(*nodes, plon, plat, SEED_STEP)
    np.testing.assert_array_equal(cl[needed], cl_all[needed])
    np.testing.assert_array_equal(cp[needed], cp_all[needed])
    assert np.isnan(cl[~needed]).all()
    assert counts.sum() == needed.sum() < counts_all.sum()

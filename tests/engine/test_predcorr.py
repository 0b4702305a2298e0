"""Prediction/correction loop (handbook section 3.2, Appendix C) on a synthetic swath."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho.engine.boundary import row_spans, segment_boundary
from napari_meris_ortho.engine.location import direct_location
from napari_meris_ortho.engine.predcorr import (
    HEIGHT_GIVEN,
    HEIGHT_NONE,
    HEIGHT_TIEPOINTS,
    full_spans,
    iteration_histogram,
    primary_grid,
    primary_nodes,
    solve,
)
from napari_meris_ortho.geometry.grid import OutputGrid
from napari_meris_ortho.geometry.tiepoints import analytic_swath


def _terrain(lon, lat):
    return 1500.0 + 1200.0 * np.sin(np.radians(lon) * 40.0) * np.cos(np.radians(lat) * 30.0)


def _scene(lon0=11.0, nadir_col=0.0, width=1025):
    tp = analytic_swath(height=300, width=width, lon0=lon0, nadir_col=nadir_col)
    b = segment_boundary(tp.latitude, tp.longitude)
    d = np.degrees(260.0 / 6370997.0)
    x0, x1 = b.lon.min(), b.lon.max()
    grid = OutputGrid("EPSG:4326", x0, b.lat.max(), d * 1.4, d, int((x1 - x0) / (d * 1.4)) + 1,
                      int((b.lat.max() - b.lat.min()) / d) + 1)
    lon, lat = grid.lonlat()
    spans = row_spans(b, grid, margin=30)
    return tp, grid, lon, lat, (spans.ptr, spans.start, spans.stop)


@pytest.fixture(scope="module")
def scene():
    return _scene()


def _check_consistent(tp, lon, lat, res, h, tol_px):
    ok = res["iterations"] >= 0
    line = res["line"][ok].astype(np.float64)
    col = res["col"][ok].astype(np.float64)
    hh = None if h is None else h[ok]
    lon2, lat2 = direct_location(tp, line, col, hh)
    # residual in product pixels of ~260 m
    dx = ((lon2 - lon[ok] + 180) % 360 - 180) * 111320 * np.cos(np.radians(lat[ok])) / 260.0
    dy = (lat2 - lat[ok]) * 111320 / 260.0
    assert np.max(np.hypot(dx, dy)) < tol_px
    return ok


def test_dem_heights_converge_and_match_the_handbook_loop(scene):
    tp, grid, lon, lat, spans = scene
    h = _terrain(lon, lat).astype(np.float32)
    fast = solve(tp, grid, lon, lat, h, HEIGHT_GIVEN, spans, tolerance=1e-4)
    ref = solve(tp, grid, lon, lat, h, HEIGHT_GIVEN, spans, tolerance=1e-4, method="handbook")
    ok = _check_consistent(tp, lon, lat, fast, h.astype(np.float64), 1e-3)
    ok_ref = ref["iterations"] >= 0
    both = ok & ok_ref
    assert both.sum() > 0.97 * max(ok.sum(), ok_ref.sum())
    assert np.max(np.abs(fast["line"][both] - ref["line"][both])) < 1e-3
    assert np.max(np.abs(fast["col"][both] - ref["col"][both])) < 1e-3
    # every product pixel is seen: the antecedents fill the product
    assert fast["line"][ok].min() < 0.5 and fast["line"][ok].max() > 298.5
    assert fast["col"][ok].min() < 0.5 and fast["col"][ok].max() > 1023.5
    s = ref["search"]
    assert s["same"] > 0.8 * (s["same"] + s["4-connex"] + s["8-connex"] + s["all"])


def test_iteration_histogram_and_tolerance(scene):
    tp, grid, lon, lat, spans = scene
    h = _terrain(lon, lat).astype(np.float32)
    res = solve(tp, grid, lon, lat, h, HEIGHT_GIVEN, spans, tolerance=0.01)
    hist = iteration_histogram(res["iterations"])
    assert hist.size == 11 and hist.sum() == np.count_nonzero(res["iterations"] >= 0)
    assert hist[0] == 0 and hist[4:].sum() == 0  # Newton: 1-3 corrections
    _check_consistent(tp, lon, lat, res, h.astype(np.float64), 0.01)
    res01 = solve(tp, grid, lon, lat, h, HEIGHT_GIVEN, spans, tolerance=0.1)
    assert iteration_histogram(res01["iterations"])[1:3].sum() >= hist[1:3].sum()


def test_no_orthorectification_is_the_zero_height_inverse(scene):
    tp, grid, lon, lat, spans = scene
    res = solve(tp, grid, lon, lat, None, HEIGHT_NONE, spans)
    ref = solve(tp, grid, lon, lat, None, HEIGHT_NONE, spans, method="handbook")
    ok = _check_consistent(tp, lon, lat, res, np.zeros(lon.shape), 0.01)
    assert np.all(ref["iterations"][ref["iterations"] >= 0] == 0)  # MERSYN: ITERATION[0] = 100 %
    both = ok & (ref["iterations"] >= 0)
    assert np.max(np.abs(res["line"][both] - ref["line"][both])) < 0.01


def test_tie_point_heights(scene):
    tp, grid, lon, lat, spans = scene
    res = solve(tp, grid, lon, lat, None, HEIGHT_TIEPOINTS, spans, tolerance=1e-4,
                diagnostics=True)
    _check_consistent(tp, lon, lat, res, None, 1e-3)
    ok = res["iterations"] >= 0
    assert np.nanmin(res["elevation"][ok]) >= tp.dem_alt.min() - 1
    assert np.nanmax(res["elevation"][ok]) <= tp.dem_alt.max() + 1
    # seen from the west part of the swath the parallax shift points east (towards nadir)
    far = ok & (res["col"] > 800)
    assert np.all(res["shift_east_m"][far] > 0)
    assert np.nanmax(np.hypot(res["shift_east_m"], res["shift_north_m"])) < 2000 * np.tan(
        np.radians(tp.view_zenith.max())) + 1


def test_points_outside_the_product_are_dropped(scene):
    tp, grid, lon, lat, _ = scene
    spans = full_spans(*lon.shape)
    res = solve(tp, grid, lon, lat, None, HEIGHT_NONE, spans)
    ok = res["iterations"] >= 0
    assert 0.2 < ok.mean() < 0.9  # the swath is oblique in its bounding box
    assert np.all(res["line"][ok] >= -0.5) and np.all(res["line"][ok] < 299.5)
    assert np.all(np.isnan(res["line"][~ok]))


def test_nadir_and_antimeridian_swath():
    tp, grid, lon, lat, spans = _scene(lon0=-179.0, nadir_col=512.0)
    assert np.nanmin(lon) < -179 and np.nanmax(lon) > 179
    h = _terrain(lon, lat).astype(np.float32)
    res = solve(tp, grid, lon, lat, h, HEIGHT_GIVEN, spans, tolerance=1e-4)
    ok = _check_consistent(tp, lon, lat, res, h.astype(np.float64), 1e-3)
    # no hole: every product pixel centre has an output point within 1 px
    hit = np.zeros((300, 1025), bool)
    hit[np.round(res["line"][ok]).astype(int), np.round(res["col"][ok]).astype(int)] = True
    assert hit.mean() > 0.95


def test_ecef_geolocation_converges_on_both_paths(scene):
    tp, grid, lon, lat, spans = scene
    h = _terrain(lon, lat).astype(np.float32)
    fast = solve(tp, grid, lon, lat, h, HEIGHT_GIVEN, spans, tolerance=1e-4, model=1, geo=1)
    ref = solve(tp, grid, lon, lat, h, HEIGHT_GIVEN, spans, tolerance=1e-4, model=1, geo=1,
                method="handbook")
    ok = fast["iterations"] >= 0
    line = fast["line"][ok].astype(np.float64)
    col = fast["col"][ok].astype(np.float64)
    lon2, lat2 = direct_location(tp, line, col, h[ok].astype(np.float64), parallax="ellipsoid")
    dx = ((lon2 - lon[ok] + 180) % 360 - 180) * 111320 * np.cos(np.radians(lat[ok])) / 260.0
    assert np.max(np.hypot(dx, (lat2 - lat[ok]) * 111320 / 260.0)) < 1e-3
    both = ok & (ref["iterations"] >= 0)
    assert np.max(np.abs(fast["col"][both] - ref["col"][both])) < 1e-3
    assert np.max(np.abs(fast["line"][both] - ref["line"][both])) < 1e-3


def test_handbook_loop_without_heights_reads_no_height(scene):
    """With no height and the ecef geolocation the handbook loop runs at h = 0; it never reads
    height[i, j] out of the 1 x 1 placeholder (which would give random antecedents)."""
    tp, grid, lon, lat, spans = scene
    fast = solve(tp, grid, lon, lat, None, HEIGHT_NONE, spans, model=1, geo=1, tolerance=1e-4)
    ref = solve(tp, grid, lon, lat, None, HEIGHT_NONE, spans, model=1, geo=1, tolerance=1e-4,
                method="handbook", diagnostics=True)
    ok = fast["iterations"] >= 0
    ok_ref = ref["iterations"] >= 0
    assert ok_ref.sum() > 0.99 * ok.sum()
    both = ok & ok_ref
    assert np.max(np.abs(fast["line"][both] - ref["line"][both])) < 1e-3
    assert np.max(np.abs(fast["col"][both] - ref["col"][both])) < 1e-3
    assert np.all(ref["elevation"][ok_ref] == 0) and np.all(ref["shift_east_m"][ok_ref] == 0)
    with pytest.raises(ValueError, match="heights"):
        solve(tp, grid, lon, lat, None, HEIGHT_GIVEN, spans)


def test_handbook_loop_returns_the_elevation_diagnostics(scene):
    tp, grid, lon, lat, spans = scene
    h = _terrain(lon, lat).astype(np.float32)
    fast = solve(tp, grid, lon, lat, h, HEIGHT_GIVEN, spans, tolerance=1e-4, diagnostics=True)
    ref = solve(tp, grid, lon, lat, h, HEIGHT_GIVEN, spans, tolerance=1e-4, method="handbook",
                diagnostics=True)
    both = (fast["iterations"] >= 0) & (ref["iterations"] >= 0)
    assert np.array_equal(ref["elevation"][both], h[both])
    for key in ("shift_east_m", "shift_north_m"):
        assert np.max(np.abs(ref[key][both] - fast[key][both])) < 1.0
    assert np.abs(ref["shift_east_m"][both]).max() > 200.0  # nadir swath: up to ~290 m


def test_solved_counts_counts_only_solved_points_in_range():
    from napari_meris_ortho.engine.predcorr import solved_counts

    rng = np.random.default_rng(3)
    iters = rng.integers(-1, 11, (500, 7)).astype(np.int8)
    source = rng.integers(-1, 3, (500, 7)).astype(np.int8)
    ok = iters >= 0
    expected = np.bincount(source[ok].astype(np.int64) + 1, minlength=4)
    assert solved_counts(source, iters, -1, 4).tolist() == expected.tolist()
    assert solved_counts(source, iters, 0, 2).tolist() == expected[1:3].tolist()
    assert iteration_histogram(iters).tolist() == np.bincount(
        iters[ok].astype(np.int64), minlength=11).tolist()
    with pytest.raises(ValueError, match="differ in size"):
        solved_counts(source, iters[:10], -1, 4)


def test_height_rates_put_the_prediction_within_one_newton_step(scene):
    """The prediction moved by h x the nodes' height rates lands within the tolerance of the
    antecedent for most points: one correction, where the zero-height prediction needs two."""
    from napari_meris_ortho.engine.location import direct_point
    from napari_meris_ortho.engine.predcorr import height_rates, primary_grid, primary_nodes

    tp, grid, lon, lat, spans = scene
    h = _terrain(lon, lat).astype(np.float32)
    hist = iteration_histogram(solve(tp, grid, lon, lat, h, HEIGHT_GIVEN, spans)["iterations"])
    assert hist[1] > 0.8 * hist.sum(), hist
    # at every node, the antecedent moved by 1000 m x its rate keeps f(l, p, 1000 m) on the
    # node's lon/lat (residual in product pixels, through the model's Jacobian there)
    lat_tp, lon_tp, coef, df, dj = tp.kernel_args()
    nlon, nlat = primary_nodes(grid, 0, lon.shape, 16)
    cl, cp, _ = primary_grid(nlon, nlat, lat_tp, lon_tp, coef, df, dj, 0)
    rates = height_rates(cl, cp, coef, df, dj, 0, 0)
    nodes = np.argwhere(np.isfinite(rates[0]))
    assert len(nodes) > 100 and np.isfinite(rates[2][tuple(nodes.T)]).all()
    shifts, residuals = [], []
    for a, b in nodes[::7]:
        moved = (cl[a, b] + 1000.0 * rates[0, a, b], cp[a, b] + 1000.0 * rates[1, a, b])
        r = direct_point(*moved, 1000.0, coef, df, dj, 0, 0)
        dlon, dlat = nlon[a, b] - r[0], nlat[a, b] - r[1]
        det = r[5] * r[8] - r[6] * r[7]
        residuals.append(np.hypot((dlon * r[8] - dlat * r[6]) / det,
                                  (r[5] * dlat - r[7] * dlon) / det))
        shifts.append(1000.0 * np.hypot(rates[0, a, b], rates[1, a, b]))
    assert max(shifts) > 1.0  # the parallax of 1000 m is pixels at the swath edge ...
    assert max(residuals) < 0.01  # ... and the rates predict it to a hundredth of a pixel


def test_the_prediction_is_the_bilinear_primary_grid_moved_by_the_height_rates(scene):
    """With no correction (``max_iter=0``) the antecedents are the prediction: the primary
    grid and its height rates interpolated bilinearly at (i / step, j / step), the point moved
    by its height times the rates; in a cell with a missing node, a valid corner, unmoved."""
    from napari_meris_ortho.engine.predcorr import find_antecedents, height_rates

    tp, grid, lon, lat, spans = scene
    h = _terrain(lon, lat).astype(np.float32)
    lat_tp, lon_tp, coef, df, dj = tp.kernel_args()
    cl, cp, _ = primary_grid(*primary_nodes(grid, 0, lon.shape, 16), lat_tp, lon_tp, coef, df,
                             dj, 0)
    rates = height_rates(cl, cp, coef, df, dj, 0, 0)
    gap = (cl.shape[0] // 2, cl.shape[1] // 2)
    cl[gap] = cp[gap] = np.nan
    line, col, iters, *_ = find_antecedents(lon, lat, h, HEIGHT_GIVEN, *spans, cl, cp, rates,
                                            16.0, coef, df, dj, tp.height, tp.width, 0, 0,
                                            0.01, 0, False)
    i, j = np.indices(lon.shape)
    a = np.minimum(i // 16, cl.shape[0] - 2)
    b = np.minimum(j // 16, cl.shape[1] - 2)
    u, v = i / 16 - a, j / 16 - b

    def bilinear(g):
        return ((1 - u) * (1 - v) * g[a, b] + (1 - u) * v * g[a, b + 1]
                + u * (1 - v) * g[a + 1, b] + u * v * g[a + 1, b + 1])

    want_l = bilinear(cl) + h * bilinear(rates[0])
    want_p = bilinear(cp) + h * bilinear(rates[1])
    ok = (iters == 0) & np.isfinite(want_l)
    assert ok.sum() > 0.99 * np.count_nonzero(iters >= 0) > 100_000 and np.ptp(h[ok]) > 1500
    np.testing.assert_allclose(line[ok], want_l[ok], rtol=0, atol=1e-3)
    np.testing.assert_allclose(col[ok], want_p[ok], rtol=0, atol=1e-3)
    near = (iters == 0) & ~np.isfinite(want_l)  # the 4 cells around the missing node
    assert 100 < near.sum() <= 4 * 16 * 16
    corners = {(np.float32(cl[x, y]), np.float32(cp[x, y]))
               for x in (gap[0] - 1, gap[0], gap[0] + 1) for y in (gap[1] - 1, gap[1], gap[1] + 1)}
    assert set(zip(line[near], col[near], strict=True)) <= corners


def test_solve_into_rows_of_a_whole_grid_equals_new_arrays(scene):
    tp, grid, lon, lat, spans = scene
    h = _terrain(lon, lat).astype(np.float32)
    ref = solve(tp, grid, lon, lat, h, HEIGHT_GIVEN, spans)
    whole = (np.zeros((lon.shape[0] + 4, lon.shape[1]), np.float32),
             np.zeros((lon.shape[0] + 4, lon.shape[1]), np.float32),
             np.zeros((lon.shape[0] + 4, lon.shape[1]), np.int8))
    rows = tuple(a[2:-2] for a in whole)
    got = solve(tp, grid, lon, lat, h, HEIGHT_GIVEN, spans, out=rows)
    for key, a in zip(("line", "col", "iterations"), rows, strict=True):
        assert got[key] is a
        np.testing.assert_array_equal(a, ref[key])  # NaN / -1 where dropped, as new arrays
    assert not whole[2][:2].any() and not whole[2][-2:].any()  # the other rows untouched
    with pytest.raises(ValueError, match="C-contiguous"):
        solve(tp, grid, lon, lat, h, HEIGHT_GIVEN, spans,
              out=(rows[0], rows[1], rows[2].astype(np.int16)))


@pytest.mark.parametrize("method", ["primary", "handbook"])
def test_a_column_window_solves_as_the_whole_rows(scene, method):
    """Columns [c0, c1) of the rows (c0 a multiple of the primary step, the spans counted from
    it) give the whole rows' antecedents bit for bit: the same primary-grid nodes."""
    tp, grid, lon, lat, (ptr, start, stop) = scene
    h = _terrain(lon, lat).astype(np.float32)
    ref = solve(tp, grid, lon, lat, h, HEIGHT_GIVEN, (ptr, start, stop), method=method)
    c0 = int(start.min()) // 16 * 16 + 16 * 3  # a window narrower than the spans: cut them
    c1 = int(stop.max()) - 40
    s, e = np.clip(start, c0, c1), np.clip(stop, c0, c1)
    cut = solve(tp, grid, lon[:, c0:c1], lat[:, c0:c1], h[:, c0:c1], HEIGHT_GIVEN,
                (ptr, s - c0, e - c0), method=method, col_start=c0)
    inside = np.zeros(lon.shape, bool)
    for i in range(lon.shape[0]):
        for k in range(ptr[i], ptr[i + 1]):
            inside[i, s[k]:e[k]] = True
    assert inside.sum() > 10_000
    for key in ("line", "col", "iterations"):
        np.testing.assert_array_equal(cut[key][inside[:, c0:c1]], ref[key][inside])
    if method == "primary":
        with pytest.raises(ValueError, match="multiple of the step"):
            solve(tp, grid, lon[:, 5:], lat[:, 5:], h[:, 5:], HEIGHT_GIVEN,
                  (ptr, start - 5, stop - 5), col_start=5)


def test_primary_nodes_depend_on_the_node_alone(scene):
    """A node outside the tie-point grid starts its Newton from the nearest edge tie point, not
    from the node computed before it: a window of the nodes gives their values bit for bit
    (a Newton started from the previous node would differ in the last bits)."""
    tp, grid, lon, _, _ = scene
    lat_tp, lon_tp, coef, df, dj = tp.kernel_args()
    nlon, nlat = primary_nodes(grid, 0, (256, lon.shape[1]), 16)
    line, col, _ = primary_grid(nlon, nlat, lat_tp, lon_tp, coef, df, dj, 0)
    wlon, wlat = primary_nodes(grid, 16, (240, lon.shape[1] - 160), 16, 160)
    wline, wcol, _ = primary_grid(wlon, wlat, lat_tp, lon_tp, coef, df, dj, 0)
    outside = ~((line >= 0) & (line <= (tp.height - 1)) & (col >= 0) & (col <= tp.width - 1))
    assert outside[1:, 10:].sum() > 100
    np.testing.assert_array_equal(wline, line[1:, 10:])
    np.testing.assert_array_equal(wcol, col[1:, 10:])


def test_far_nodes_do_not_lead_the_near_ones_astray():
    """Whole rows of an orthographic world grid: thousands of nodes far outside the segment come
    before those beside it; these still find their antecedents near the product's edge (a
    Newton from the last node found landed at line 37 892 of a 320-line product: the segment
    was lost)."""
    from napari_meris_ortho.engine.boundary import row_spans, segment_boundary

    tp = analytic_swath(height=320, width=513, lon0=10.0, nadir_col=-700.0)
    lat_tp, lon_tp, coef, df, dj = tp.kernel_args()
    g = OutputGrid("+proj=ortho +lat_0=40 +lon_0=10", -7.0e6, 7.0e6, 4000, 4000, 3500, 3500)
    spans = row_spans(segment_boundary(tp.latitude, tp.longitude), g, margin=3)
    rows = np.flatnonzero(np.diff(spans.ptr))
    r0 = int(rows[rows.size // 2]) // 16 * 16
    nlon, nlat = primary_nodes(g, r0, (32, g.width), 16)
    line, col, _ = primary_grid(nlon, nlat, lat_tp, lon_tp, coef, df, dj, 0)
    p0, p1 = spans.ptr[r0 - spans.row_start], spans.ptr[r0 + 1 - spans.row_start]
    near = slice(int(spans.start[p0]) // 16, int(spans.stop[p1 - 1]) // 16 + 2)
    assert np.isfinite(line[0, near]).all()
    assert np.all(np.abs(line[0, near] - 0.5 * (tp.height - 1)) < 2 * tp.height)
    assert np.all((col[0, near] > -0.5 * tp.width) & (col[0, near] < 1.5 * tp.width))

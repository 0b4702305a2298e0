"""DEM heights from a window of posts in memory (section 3.1): the compiled lookup against a
numpy evaluation of the same definition (posts at pixel centres, edge posts clamped, a
background post makes the point no data)."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho.engine.terrain import METHOD_CODES, window_heights
from napari_meris_ortho.geometry.interpolation import keys_weights

# lattice of 60 x 80 posts, 0.01 deg, upper-left corner (10, 47); inverse geotransform
N_ROWS, N_COLS = 60, 80
INV = np.array([100.0, 0.0, -1000.0, 0.0, -100.0, 4700.0])


def reference(posts, x, y, method):
    """numpy heights over the whole lattice ``posts`` (NaN: no data or implausible)."""
    c = INV[0] * x + INV[1] * y + INV[2] - 0.5
    r = INV[3] * x + INV[4] * y + INV[5] - 0.5
    inside = (r >= -0.5) & (r < N_ROWS - 0.5) & (c >= -0.5) & (c < N_COLS - 0.5)
    p = np.where((posts >= -500.0) & (posts <= 9000.0), posts, np.nan).astype(np.float64)
    r0, c0 = np.floor(r), np.floor(c)
    fr, fc = r - r0, c - c0
    if method == "nearest":
        offs, wr, wc = [0], [np.ones_like(fr)], [np.ones_like(fc)]
        r0, c0 = r0 + (fr >= 0.5), c0 + (fc >= 0.5)
    elif method == "bilinear":
        offs, wr, wc = [0, 1], [1.0 - fr, fr], [1.0 - fc, fc]
    else:
        offs, wr, wc = [-1, 0, 1, 2], keys_weights(fr), keys_weights(fc)
    out = np.zeros(x.size)
    for i, di in enumerate(offs):
        rows = np.clip(np.nan_to_num(r0) + di, 0, N_ROWS - 1).astype(int)
        for j, dj in enumerate(offs):
            cols = np.clip(np.nan_to_num(c0) + dj, 0, N_COLS - 1).astype(int)
            out += p[rows, cols] * wr[i] * wc[j]
    return np.where(inside, out, np.nan)


def run(data, lattice, x, y, method, todo=None, undulation=None, wrap=np.nan, index=3):
    n = x.size
    todo = np.ones(n, bool) if todo is None else todo.copy()
    h = np.full(n, -1.0, np.float32)
    src = np.full(n, -1, np.int8)
    miss = np.zeros(n, bool)
    und = np.empty(0) if undulation is None else undulation
    n_miss = window_heights(data, INV, np.asarray(lattice, np.int64), wrap, METHOD_CODES[method],
                            x, y, todo, und, index, h, src, miss)
    return h, src, todo, miss, n_miss


@pytest.fixture(scope="module")
def posts():
    rng = np.random.default_rng(4)
    z = rng.uniform(0.0, 3000.0, (N_ROWS, N_COLS)).astype(np.float32)
    z[20, 30] = np.nan  # no data
    z[40, 10] = 9500.0  # implausible: no data too
    z[5, 70] = -600.0
    return z


@pytest.mark.parametrize("method", ["nearest", "bilinear", "bicubic"])
def test_whole_lattice_window_equals_the_numpy_definition(posts, method):
    rng = np.random.default_rng(5)
    x = np.r_[rng.uniform(9.99, 10.81, 4000), 10.305, 10.105, 10.0, 10.7999, 10.4]
    y = np.r_[rng.uniform(46.39, 47.01, 4000), 46.795, 46.595, 46.5, 46.4001, 47.0]
    h, src, todo, miss, n_miss = run(posts, (0, 0, N_ROWS, N_COLS), x, y, method)
    ref = reference(posts, x, y, method)
    found = np.isfinite(ref)
    assert n_miss == 0 and not miss.any()
    assert 0.8 < found.mean() < 0.99  # some outside the lattice, some next to no data
    np.testing.assert_array_equal(todo, ~found)
    np.testing.assert_array_equal(src, np.where(found, 3, -1))
    np.testing.assert_allclose(h[found], ref[found].astype(np.float32), rtol=0, atol=1e-3)
    assert np.all(h[~found] == -1.0)  # untouched where no height
    if method == "bilinear":  # rounded to float32: the same heights
        np.testing.assert_array_equal(h[found], ref[found].astype(np.float32))
    assert np.all(todo[-5:-3])  # on the no-data post (20, 30), next to the 9500 m post


def test_edge_posts_clamped_and_no_data_posts(posts):
    # half a post beyond the first column and the last row: the edge posts, as on the lattice
    x = np.array([10.002, 10.5, 10.305, 10.305])
    y = np.array([46.7, 46.4049, 46.795, 46.815])
    h, _, todo, _, _ = run(posts, (0, 0, N_ROWS, N_COLS), x, y, "bilinear")
    assert h[0] == pytest.approx(posts[30, 0] * 0.5 + posts[29, 0] * 0.5, abs=1e-3)
    assert h[1] == pytest.approx(0.5 * (posts[59, 49] + posts[59, 50]), abs=1e-3)
    assert todo[2] and np.isnan(posts[20, 30])  # a stencil post is no data: next DEM
    assert not todo[3] and np.isfinite(h[3])  # two posts away


def test_posts_beyond_the_window_are_missed_not_guessed(posts):
    """A window of rows 10..39, columns 20..59 of the lattice: points whose posts lie outside
    are flagged for the caller; the others get the lattice's heights."""
    window = np.ascontiguousarray(posts[10:40, 20:60])
    rng = np.random.default_rng(6)
    x = rng.uniform(10.0, 10.8, 3000)
    y = rng.uniform(46.4, 47.0, 3000)
    h, _, todo, miss, n_miss = run(window, (10, 20, N_ROWS, N_COLS), x, y, "bicubic")
    full_h, *_ = run(posts, (0, 0, N_ROWS, N_COLS), x, y, "bicubic")
    r = 4700.0 - 100.0 * y - 0.5
    c = 100.0 * x - 1000.0 - 0.5
    inside = (np.floor(r) - 1 >= 10) & (np.floor(r) + 2 < 40) & (np.floor(c) - 1 >= 20) & (
        np.floor(c) + 2 < 60)
    np.testing.assert_array_equal(miss, ~inside)
    assert n_miss == int((~inside).sum()) > 1000
    assert np.all(todo[miss])
    ok = inside & ~todo
    assert ok.sum() > 400
    np.testing.assert_array_equal(h[ok], full_h[ok])


def test_only_todo_points_undulation_and_wrap(posts):
    x = np.array([10.2, 10.3, 370.3, -349.7, 10.2])
    y = np.array([46.7, 46.6, 46.6, 46.6, 46.7])
    todo = np.array([False, True, True, True, True])
    und = np.array([0.0, 47.25, 47.25, 47.25, np.nan])
    h, src, left, _, _ = run(posts, (0, 0, N_ROWS, N_COLS), x, y, "bilinear", todo=todo,
                             undulation=und, wrap=10.4, index=1)
    base, *_ = run(posts, (0, 0, N_ROWS, N_COLS), x[1:2], y[1:2], "bilinear")
    assert h[0] == -1.0 and src[0] == -1  # not asked
    assert h[1] == pytest.approx(base[0] + 47.25, abs=1e-3)
    assert h[2:4] == pytest.approx([h[1], h[1]], abs=1e-3)  # a turn away: the same posts
    assert left.tolist() == [False, False, False, False, True]  # N = NaN: no height
    assert src.tolist() == [-1, 1, 1, 1, -1]
    # without the wrap a longitude a turn away is outside the lattice
    _, _, left, _, _ = run(posts, (0, 0, N_ROWS, N_COLS), x, y, "bilinear")
    assert left[2] and left[3] and not left[1]


@pytest.mark.parametrize("method", ["bilinear", "bicubic"])
def test_ranges_on_threads_equal_one_whole_range_call(posts, method):
    from napari_meris_ortho.engine import terrain

    rng = np.random.default_rng(7)
    n = 300_000  # several ranges of at least 1 << 16 points
    x, y = rng.uniform(9.99, 10.81, n), rng.uniform(46.39, 47.01, n)
    window = np.ascontiguousarray(posts[5:55, 5:75])
    lattice = (5, 5, N_ROWS, N_COLS)
    h, src, todo, miss, n_miss = run(window, lattice, x, y, method, index=2)
    todo1, h1 = np.ones(n, bool), np.full(n, -1.0, np.float32)
    src1, miss1 = np.full(n, -1, np.int8), np.zeros(n, bool)
    kernel = terrain._bicubic if method == "bicubic" else terrain._linear
    extra = () if method == "bicubic" else (False,)
    n1 = kernel(0, n, window, INV, np.asarray(lattice, np.int64), np.nan, *extra, x, y, todo1,
                np.empty(0), 2, h1, src1, miss1)
    assert n_miss == n1 == int(miss.sum()) > 1000
    for got, want in ((h, h1), (src, src1), (todo, todo1), (miss, miss1)):
        np.testing.assert_array_equal(got, want)


def test_geoid_bilinear_equals_the_numpy_undulation():
    from napari_meris_ortho.dem.geoid import (
        GRID_STEP_DEG,
        geoid_undulation,
        node_indices,
        nodes_between,
    )
    from napari_meris_ortho.engine.terrain import geoid_bilinear

    rng = np.random.default_rng(9)
    lon = rng.uniform(5.0, 12.0, 20000)
    lat = rng.uniform(42.0, 48.0, 20000)
    i, j = node_indices(np.array([5.0, 12.0]), np.array([42.0, 48.0]))
    nodes = nodes_between(int(i[0]), int(i[1]) + 1, int(j[0]), int(j[1]) + 1)
    todo = rng.random(lon.size) < 0.8
    out = np.full(lon.size, -1.0)
    geoid_bilinear(nodes, int(i[0]), int(j[0]), GRID_STEP_DEG, lon, lat, todo, out)
    np.testing.assert_array_equal(out[todo], geoid_undulation(lon[todo], lat[todo]))
    assert np.all(out[~todo] == -1.0) and np.ptp(out[todo]) > 5.0  # N varies over the Alps
    lat[:3], lon[3:6] = (np.nan, 91.0, -95.0), np.nan  # no position: NaN, as numpy's
    todo[:6] = True
    out[:] = -1.0
    geoid_bilinear(nodes, int(i[0]), int(j[0]), GRID_STEP_DEG, lon, lat, todo, out)
    assert np.all(np.isnan(out[:6])) and np.all(np.isnan(geoid_undulation(lon[:6], lat[:6])))
    beyond = np.full(lon.size, np.nan)  # points past the nodes: NaN, not a wrong node
    geoid_bilinear(nodes, int(i[0]), int(j[0]), GRID_STEP_DEG, lon + 20.0, lat, todo, beyond)
    assert np.all(np.isnan(beyond[todo]))

"""Resampling at fractional antecedents: nearest (MERSYN), bilinear, bicubic (section 3.1)."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho.engine.resample import (
    copy_window,
    overview_level,
    resample,
    resample_bands,
)
from napari_meris_ortho.errors import OptionsError


def test_nearest_rounds_half_up_and_respects_pixel_extent():
    img = np.arange(20, dtype=np.uint16).reshape(4, 5) + 1
    lines = np.array([0.0, 0.49, 0.5, 1.5, -0.5, -0.51, 3.49, 3.5, 0.0, 0.0, np.nan])
    cols = np.array([0.0, 0.0, 0.0, 2.5, 0.0, 0.0, 4.49, 0.0, -0.5, 4.5, 1.0])
    out = resample(img, lines, cols, "nearest")
    assert out.dtype == np.float32
    assert out.tolist() == [1, 1, 6, 14, 1, 0, 20, 0, 1, 0, 0]


def test_bilinear_reproduces_a_plane_and_clamps_edges():
    ll, pp = np.mgrid[0:30, 0:40].astype(float)
    img = (3.0 + 2.0 * ll - 0.5 * pp).astype(np.float64)
    rng = np.random.default_rng(1)
    lines = rng.uniform(0, 29, 500)
    cols = rng.uniform(0, 39, 500)
    out = resample(img, lines, cols, "bilinear")
    np.testing.assert_allclose(out, 3.0 + 2.0 * lines - 0.5 * cols, rtol=1e-6)
    # half a pixel beyond the first line: edge clamped -> value of line 0
    edge = resample(img, np.array([-0.4]), np.array([10.0]), "bilinear")
    assert edge[0] == pytest.approx(3.0 - 5.0)


def test_bicubic_reproduces_quadratics_inside():
    """Keys a = -0.5 is exact for polynomials up to degree 2 (away from the clamped edges)."""
    ll, pp = np.mgrid[0:30, 0:40].astype(float)
    f = lambda a, b: 1.0 + 0.3 * a + 0.7 * b + 0.05 * a * a - 0.02 * b * b + 0.01 * a * b  # noqa: E731
    img = f(ll, pp)
    rng = np.random.default_rng(2)
    lines = rng.uniform(1, 27.99, 500)
    cols = rng.uniform(1, 37.99, 500)
    out = resample(img, lines, cols, "bicubic")
    np.testing.assert_allclose(out, f(lines, cols), rtol=2e-6)
    bil = resample(img, lines, cols, "bilinear")
    assert np.max(np.abs(bil - f(lines, cols))) > 1e-3  # bilinear is not exact there


def test_integer_positions_return_pixels_for_all_methods():
    rng = np.random.default_rng(3)
    img = rng.uniform(0, 100, (12, 9)).astype(np.float32)
    ll, pp = np.mgrid[0:12, 0:9]
    for method in ("nearest", "bilinear", "bicubic"):
        out = resample(img, ll.astype(float), pp.astype(float), method)
        np.testing.assert_allclose(out, img, rtol=1e-6)


def test_many_bands_share_antecedents_and_keep_shape():
    rng = np.random.default_rng(4)
    bands = [rng.uniform(0, 1000, (50, 60)).astype(np.float32) for _ in range(3)]
    lines = rng.uniform(-1, 50, (7, 11))
    cols = rng.uniform(-1, 60, (7, 11))
    lines[0, 0] = np.nan
    for method in ("nearest", "bilinear", "bicubic"):
        many = resample_bands(bands, lines, cols, method)
        assert len(many) == 3 and many[0].shape == (7, 11)
        for b, m in zip(bands, many, strict=True):
            np.testing.assert_array_equal(m, resample(b, lines, cols, method))
        assert many[1][0, 0] == 0.0


def test_big_endian_memmap_and_out_argument(tmp_path):
    data = (np.arange(100, dtype=np.uint16) * 7).reshape(10, 10)
    path = tmp_path / "counts.raw"
    data.astype(">u2").tofile(path)
    mm = np.memmap(path, dtype=">u2", mode="r", shape=(10, 10))
    out = np.full((2, 3), -1.0, np.float32)
    res = resample(mm, np.array([[0, 1, 2], [9, 9.6, 3]], float),
                   np.array([[0, 1, 2], [9, 0, 3]], float), "nearest", out=out)
    assert res is out
    assert out.tolist() == [[0, 77, 154], [693, 0, 231]]


def test_unknown_method_is_an_options_error():
    with pytest.raises(OptionsError, match="sampling method"):
        resample(np.zeros((3, 3)), np.zeros(1), np.zeros(1), "lanczos")


@pytest.mark.slow
def test_overview_level_averages_2x2_ignoring_nodata_and_rounds_half_up():
    a = np.array([[4, 0, 7], [6, 0, 9], [0, 0, 2]], np.uint16)
    np.testing.assert_array_equal(overview_level(a, 0), [[5, 8], [0, 2]])  # (4+6)/2, (7+9)/2
    np.testing.assert_array_equal(overview_level(a, 0, "nearest"), [[4, 7], [0, 2]])
    b = np.array([[1, 2], [2, 2]], np.uint16)  # 7/4 = 1.75 -> 2; [[1, 2]] 1.5 -> 2
    assert overview_level(b, 0)[0, 0] == 2 and overview_level(b[:1], 0)[0, 0] == 2
    f = np.array([[1.0, 2.0, 3.0], [3.0, 4.0, np.nan]], np.float32)
    np.testing.assert_allclose(overview_level(f, None), [[2.5, 3.0]])  # NaN and padding skipped
    assert overview_level(f, None).dtype == np.float32
    with pytest.raises(ValueError, match="resampling"):
        overview_level(a, 0, "cubic")


def test_overview_level_matches_a_numpy_reference_on_random_counts():
    rng = np.random.default_rng(5)
    a = rng.integers(0, 4, (37, 51)).astype(np.uint16) * rng.integers(1, 9000, (37, 51)).astype(
        np.uint16)
    p = np.zeros((38, 52))
    p[:37, :51] = a
    v = np.zeros_like(p)
    v[:37, :51] = a != 0
    s = p[0::2, 0::2] + p[1::2, 0::2] + p[0::2, 1::2] + p[1::2, 1::2]
    n = v[0::2, 0::2] + v[1::2, 0::2] + v[0::2, 1::2] + v[1::2, 1::2]
    ref = np.where(n > 0, np.floor(s / np.maximum(n, 1) + 0.5), 0)
    np.testing.assert_array_equal(overview_level(a, 0), ref)


def test_gather_scaled_equals_counts_times_scale_in_float32():
    from napari_meris_ortho.engine.resample import gather, gather_scaled, nearest_pixel

    rng = np.random.default_rng(2)
    images = rng.integers(0, 65535, (3, 40, 50)).astype(np.uint16)
    lines = rng.uniform(-3, 43, 5000).astype(np.float32)
    cols = rng.uniform(-3, 53, 5000).astype(np.float32)
    index = nearest_pixel(lines, cols, 40, 50)
    counts = np.empty((3, 5000), np.uint16)
    gather(images, index, counts)
    scales = np.array([0.0123456, 0.5, 1e-3])
    out = np.empty((3, 5000), np.float32)
    gather_scaled(images, index, scales, out)
    ref = counts.astype(np.float32) * scales.astype(np.float32)[:, None]
    np.testing.assert_array_equal(out, ref)
    assert np.all(out[:, index < 0] == 0) and (index < 0).any()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_inside_range_equals_the_masked_min_and_max(dtype):
    from napari_meris_ortho.engine.resample import inside_range

    rng = np.random.default_rng(7)
    line = (rng.random((300, 40)) * 70 - 5).astype(dtype)
    col = (rng.random((300, 40)) * 140 - 5).astype(dtype)
    line[rng.random(line.shape) < 0.1] = np.nan
    inside = (line >= -0.5) & (line < 59.5) & (col >= -0.5) & (col < 128.5)
    assert inside_range(line, col, 60, 129) == (
        float(line[inside].min()), float(line[inside].max()), float(col[inside].min()),
        float(col[inside].max()))
    assert inside_range(line, col + 200, 60, 129) is None
    # the edges: -0.5 is inside, H - 0.5 (W - 0.5) is not
    edge = np.array([-0.5, 59.5, 10.0], dtype)
    assert inside_range(edge, np.zeros(3, dtype), 60, 129) == (-0.5, 10.0, 0.0, 0.0)
    cols = np.array([-0.5, 128.5, 7.0], dtype)
    assert inside_range(np.zeros(3, dtype), cols, 60, 129) == (0.0, 0.0, -0.5, 7.0)


def test_nearest_pixel_in_a_window_of_lines_and_columns():
    """The index in a window (line and column offsets) is the whole image's index of the
    same pixel, re-based; points outside the window are -1."""
    from napari_meris_ortho.engine.resample import nearest_pixel

    rng = np.random.default_rng(3)
    lines = rng.random(5000) * 44 - 2
    cols = rng.random(5000) * 54 - 2
    whole = nearest_pixel(lines, cols, 40, 50)
    part = nearest_pixel(lines, cols, 20, 30, line_offset=10, col_offset=15)
    ok = whole >= 0
    wl, wc = whole[ok] // 50, whole[ok] % 50
    inside = (wl >= 10) & (wl < 30) & (wc >= 15) & (wc < 45)
    np.testing.assert_array_equal(part[ok][inside], (wl[inside] - 10) * 30 + wc[inside] - 15)
    assert np.all(part[ok][~inside] == -1) and np.all(part[~ok] == -1)
    assert inside.any() and (~inside).any()


@pytest.mark.parametrize("shape", [(37, 51), (38, 52), (1, 9), (9, 1)])
def test_overview_level_of_floats_matches_a_nan_skipping_mean(shape):
    rng = np.random.default_rng(11)
    a = rng.normal(50.0, 20.0, shape).astype(np.float32)
    a[rng.random(shape) < 0.25] = np.nan
    a[rng.random(shape) < 0.2] = -1.0  # nodata
    h, w = shape
    p = np.full((h + h % 2, w + w % 2), np.nan)
    p[:h, :w] = np.where(a == -1.0, np.nan, a)
    blocks = np.stack([p[0::2, 0::2], p[0::2, 1::2], p[1::2, 0::2], p[1::2, 1::2]])
    n = np.isfinite(blocks).sum(axis=0)
    ref = np.where(n > 0, np.nansum(blocks, axis=0) / np.maximum(n, 1), -1.0)
    np.testing.assert_allclose(overview_level(a, -1.0), ref.astype(np.float32), rtol=1e-6)


@pytest.mark.parametrize("seed", range(4))
def test_finite_extent_is_the_bounding_box_of_the_finite_values(seed):
    """``finite_extent`` (where the antecedents' samplers work) against numpy: random NaN
    fields with finite blobs anywhere, one finite value, none, and infinities (not finite)."""
    from napari_meris_ortho.engine.resample import finite_extent

    rng = np.random.default_rng(seed)
    a = np.full((int(rng.integers(1, 60)), int(rng.integers(1, 70))), np.nan, np.float32)
    assert finite_extent(a) == (0, 0, 0, 0)
    for _ in range(int(rng.integers(1, 4))):
        r, c = int(rng.integers(a.shape[0])), int(rng.integers(a.shape[1]))
        a[r:r + int(rng.integers(1, 9)), c:c + int(rng.integers(1, 9))] = rng.random()
    a[rng.random(a.shape) < 0.05] = np.inf
    rows, cols = np.nonzero(np.isfinite(a))
    assert finite_extent(a) == (rows.min(), rows.max() + 1, cols.min(), cols.max() + 1)
    one = np.full((5, 7), np.nan)
    one[3, 6] = 1.0
    assert finite_extent(one) == (3, 4, 6, 7)
    with pytest.raises(ValueError, match="2-D"):
        finite_extent(np.zeros(3))


def test_gather_places_a_window_of_points_in_the_grid_rows():
    """``gather``/``gather_scaled`` with ``place`` = (width, stride, offset): the points are a
    window of rows of a grid flattened in ``out``; the rest of ``out`` is left as it is."""
    from napari_meris_ortho.engine.resample import gather, gather_scaled

    rng = np.random.default_rng(3)
    images = rng.integers(0, 4000, (3, 20, 30)).astype(np.uint16)
    h, w, nr, nc, r0, c0 = 7, 11, 15, 25, 4, 9
    index = rng.integers(-1, 600, h * w).astype(np.int32)
    out = np.full((3, nr, nc), 9, np.uint16)
    gather(images, index, out.reshape(3, -1), (w, nc, r0 * nc + c0))
    flat = images.reshape(3, -1)
    expected = np.where(index >= 0, flat[:, np.maximum(index, 0)], 0).reshape(3, h, w)
    assert np.array_equal(out[:, r0:r0 + h, c0:c0 + w], expected)
    outside = out.copy()
    outside[:, r0:r0 + h, c0:c0 + w] = 9
    assert (outside == 9).all()
    scaled = np.zeros((3, nr, nc), np.float32)
    scales = np.array([0.5, 0.25, 2.0])
    gather_scaled(images, index, scales, scaled.reshape(3, -1), (w, nc, r0 * nc + c0))
    assert np.array_equal(scaled[:, r0:r0 + h, c0:c0 + w],
                          expected.astype(np.float32) * scales.astype(np.float32)[:, None, None])
    with pytest.raises(ValueError, match="do not fit"):
        gather(images, index, out.reshape(3, -1), (w, nc, (nr - h + 1) * nc))
    with pytest.raises(ValueError, match="do not fit"):
        gather(images, index, out.reshape(3, -1), (w + 1, nc, 0))


def test_copy_window_swaps_big_endian_windows_as_numpy_converts_them():
    """The window of a big-endian uint16 image (the records of an N1 band: a 13-byte header
    then the pixels) is copied with its values, as numpy's conversion gives them; any other
    dtype (native uint16, uint8 flags, float) is numpy's copy."""
    rng = np.random.default_rng(5)
    records = np.zeros((700, 13 + 2 * 301), np.uint8)
    records[:, 13:] = rng.integers(0, 256, (700, 602), dtype=np.uint8)
    image = records[:, 13:].view(">u2")
    assert image.shape == (700, 301) and not image.dtype.isnative
    for rows, cols in [(slice(0, 700), slice(0, 301)), (slice(17, 650), slice(3, 290)),
                       (slice(5, 6), slice(100, 101))]:
        window = image[rows, cols]
        out = np.empty(window.shape, np.uint16)
        copy_window(out, window)
        np.testing.assert_array_equal(out, window.astype(np.uint16))
        assert out.max() > 255 or out.size == 1
    for src in (image.astype(np.uint16), image.astype(np.uint8), image.astype(np.float32)):
        out = np.empty(src.shape, src.dtype)
        copy_window(out, src)
        np.testing.assert_array_equal(out, src)



@pytest.mark.parametrize("place", [None, "rows", "window"])
@pytest.mark.parametrize("dtype", [np.uint16, np.uint8])
@pytest.mark.slow
def test_gather_takes_every_point_of_long_runs(place, dtype):
    """Runs of points longer than a block (``GATHER_BLOCK``, band after band within it) and
    not a multiple of it: every point of every band is the image's value at its index (0 at
    -1), as numpy's indexing gives it, scaled or not, whatever the placement."""
    from napari_meris_ortho.engine.resample import GATHER_BLOCK, gather, gather_scaled

    rng = np.random.default_rng(8)
    n_bands, lines, cols = 15, 90, 80
    images = rng.integers(0, np.iinfo(dtype).max, (n_bands, lines, cols)).astype(dtype)
    flat = images.reshape(n_bands, -1)
    if place is None:  # one run of points
        h, w, nc, r0, c0 = 1, 2 * GATHER_BLOCK + 37, 2 * GATHER_BLOCK + 37, 0, 0
    elif place == "rows":  # rows of the grid one after the other: stride == width
        h, w, nc, r0, c0 = 5, GATHER_BLOCK + 301, GATHER_BLOCK + 301, 2, 0
    else:  # a window of the grid's rows: stride > width
        h, w, nc, r0, c0 = 4, GATHER_BLOCK + 5, GATHER_BLOCK + 40, 1, 17
    nr = r0 + h + 1
    index = rng.integers(-1, lines * cols, h * w).astype(np.int64)
    index[rng.random(index.size) < 0.1] = -1
    expected = np.where(index >= 0, flat[:, np.maximum(index, 0)], 0).reshape(n_bands, h, w)
    spot = None if place is None else (w, nc, r0 * nc + c0)
    out = np.full((n_bands, nr, nc), 7, dtype)
    target = out.reshape(n_bands, -1)
    gather(images, index, target if place else target[:, :h * w], spot)
    assert np.array_equal(out[:, r0:r0 + h, c0:c0 + w], expected)
    rest = out.copy()
    rest[:, r0:r0 + h, c0:c0 + w] = 7
    assert (rest == 7).all()  # nothing written outside the points' places
    scales = rng.uniform(0.001, 0.05, n_bands)
    scaled = np.zeros((n_bands, nr, nc), np.float32)
    flat_scaled = scaled.reshape(n_bands, -1)
    gather_scaled(images, index, scales, flat_scaled if place else flat_scaled[:, :h * w], spot)
    assert np.array_equal(scaled[:, r0:r0 + h, c0:c0 + w],
                          expected.astype(np.float32)
                          * scales.astype(np.float32)[:, None, None])

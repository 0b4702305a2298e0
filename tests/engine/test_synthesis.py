"""Merge rules of the synthesis (section 3.1 use cases 1-2, Appendix C) on small arrays."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho.engine.synthesis import (
    CHUNK_CHANGED,
    CHUNK_NOT_EMPTY,
    FLAG_BRIGHT,
    FLAG_GLINT_RISK,
    FLAG_INVALID,
    TileState,
    WinnerBands,
    chunk_changes,
    combine,
    ndvi_decode,
    ndvi_encode,
    ndvi_value,
    segment_counts_state,
    segment_state,
    validated_pixels,
    winner_state,
)


def test_ndvi_coding_matches_appendix_c() -> None:
    # radioShift = (-65535 - 1) / 65534, radioFactor = 2 / 65534: -1 -> 1, 0 -> 32768, 1 -> 65535
    code = ndvi_encode(np.array([-1.0, 0.0, 1.0, -2.0, 3.0, 0.5]))
    assert code.tolist() == [1, 32768, 65535, 1, 65535, 49152]
    assert code.dtype == np.uint16
    values = ndvi_decode(np.array([0, 1, 32768, 65535], dtype=np.uint16))
    assert np.isnan(values[0])
    np.testing.assert_allclose(values[1:], [-1.0, 0.0, 1.0], atol=1e-7)
    # round trip within half a quantum (1/32767)
    x = np.linspace(-1, 1, 1001)
    assert np.abs(ndvi_decode(ndvi_encode(x)) - x).max() <= 0.5 / 32767 + 1e-7
    assert ndvi_encode(np.array([0.2, 0.3]), background=np.array([True, False]))[0] == 0


def test_ndvi_value_and_zero_sum() -> None:
    assert ndvi_value(10.0, 30.0) == pytest.approx(0.5)
    assert ndvi_value(0.0, 0.0) == 0.0


@pytest.mark.slow
def test_validity_from_flags() -> None:
    flags = np.array([[0, FLAG_GLINT_RISK, FLAG_INVALID, FLAG_BRIGHT, 16 | 1]], dtype=np.uint8)
    inside = np.array([[True, True, True, True, False]])
    assert validated_pixels(inside, flags, False).tolist() == [[True, False, False, True, False]]
    assert validated_pixels(inside, flags, True).tolist() == [[True, False, False, False, False]]


def _merge_all(states: list[TileState], rank: np.ndarray, order: list[int]) -> TileState:
    acc = TileState.empty(states[0].bands.shape[0], states[0].count.shape,
                          states[0].ndvi is not None)
    for k in order:
        combine(acc, states[k], rank)
    return acc


def _same(a: TileState, b: TileState) -> None:
    for x, y in zip(vars(a).values(), vars(b).values(), strict=True):
        assert (x is None and y is None) or x.tobytes() == y.tobytes()


@pytest.mark.slow
def test_minimum_radiance_band_by_band() -> None:
    # two products, bands (7, 13); the stored state holds product 1
    stored = segment_state(np.array([[[50.0, 50.0, 0.0]], [[10.0, 10.0, 0.0]]], np.float32),
                           np.array([[True, True, False]]), 1)
    new = segment_state(np.array([[[40.0, 60.0, 1.0]], [[20.0, 5.0, 1.0]]], np.float32),
                        np.array([[True, True, True]]), 2)
    rank = np.array([0, 1, 2])
    combine(stored, new, rank)
    # pixel 0: band 7 lower, band 13 higher; pixel 1: band 13 lower; pixel 2: background
    assert stored.bands[:, 0].tolist() == [[40.0, 50.0, 1.0], [10.0, 5.0, 1.0]]
    assert stored.count.tolist() == [[2, 2, 1]]
    # the winner is the product of the lowest first-band radiance
    assert stored.winner.tolist() == [[2, 1, 2]]


def test_segment_state_keeps_only_positive_valid_radiances() -> None:
    segment = np.array([[[5.0, -1.0, np.nan, 7.0]]], np.float32)
    state = segment_state(segment, np.array([[True, True, True, False]]), 3)
    assert state.bands.tolist() == [[[5.0, 0.0, 0.0, 0.0]]]
    assert state.winner.tolist() == [[3, 3, 3, 0]] and state.count.tolist() == [[1, 1, 1, 0]]


@pytest.mark.slow
def test_segment_counts_state_is_the_counts_of_segment_state() -> None:
    """A product's contribution as 16-bit counts, made in one pass from the whole planes
    (a window from an origin), equals ``segment_state`` of the cropped window with its bands
    encoded as a compact store encodes them: round(v / scale) on [1, 65535], background
    (v <= 0, NaN, invalid) 0, values past 65535 counts clipped, tiny ones raised to 1."""
    rng = np.random.default_rng(11)
    planes = [rng.uniform(-5.0, 400.0, (40, 50)).astype(np.float32) for _ in range(3)]
    planes[0][3, 7], planes[1][5, 9], planes[2][6, 6] = np.nan, 1e-6, 1e9
    scales = [0.0109, 0.0057, 0.0031]
    divisors = [float(np.float32(s)) for s in scales]
    valid = rng.random((30, 35)) > 0.2
    r0, c0 = 3, 6
    red, nir = planes[1][r0:r0 + 30, c0:c0 + 35], planes[2][r0:r0 + 30, c0:c0 + 35]
    state = segment_counts_state(planes, (r0, c0), divisors, valid, 4, red, nir)
    window = np.stack([p[r0:r0 + 30, c0:c0 + 35] for p in planes])
    expected = segment_state(window, valid, 4, red, nir)
    for k, divisor in enumerate(divisors):
        v = expected.bands[k].astype(np.float64)
        counts = np.clip(np.floor(v / divisor + 0.5), 1, 65535).astype(np.uint16)
        counts[~(v > 0)] = 0
        np.testing.assert_array_equal(state.bands[k], counts)
    assert state.bands.dtype == np.uint16 and state.bands.max() == 65535
    assert state.bands[1][5 - r0, 9 - c0] == (1 if valid[5 - r0, 9 - c0] else 0)
    np.testing.assert_array_equal(state.winner, expected.winner)
    np.testing.assert_array_equal(state.count, expected.count)
    np.testing.assert_array_equal(state.ndvi, expected.ndvi)


@pytest.mark.parametrize("ndvi", [False, True])
@pytest.mark.slow
def test_combine_is_associative_and_commutative(ndvi) -> None:
    """Any order and any grouping of the contributions gives the same bytes, ties included
    (products of equal radiance or equal NDVI code: the lower rank wins)."""
    rng = np.random.default_rng(3)
    n, shape = 6, (30, 40)
    states = []
    for k in range(n):
        segment = rng.choice(np.array([1.0, 2.0, 3.0, 50.0], np.float32), (2, *shape))
        valid = rng.random(shape) > 0.3
        red = nir = None
        if ndvi:  # few distinct values: many equal NDVI codes
            red, nir = segment[0], rng.choice(np.array([2.0, 4.0], np.float32), shape)
        states.append(segment_state(segment, valid, k + 1, red, nir))
    rank = np.array([0, 4, 2, 6, 1, 3, 5])  # sensing time / name order of products 1..6
    reference = _merge_all(states, rank, list(range(n)))
    for order in ([5, 4, 3, 2, 1, 0], [2, 0, 5, 1, 4, 3]):
        _same(reference, _merge_all(states, rank, order))
    # grouping: (0 + 1 + 2) and (3 + 4 + 5) merged separately, then together
    left, right = _merge_all(states, rank, [0, 1, 2]), _merge_all(states, rank, [3, 4, 5])
    combine(right, left, rank)
    _same(reference, right)
    valid = np.stack([s.count for s in states]).astype(bool)
    np.testing.assert_array_equal(reference.count, valid.sum(axis=0))
    if not ndvi:  # band by band the minimum; the winner holds it, lowest rank among equals
        values = np.where(valid[:, None], np.stack([s.bands for s in states]), np.inf)
        expected = values.min(axis=0)
        expected[np.isinf(expected)] = 0
        np.testing.assert_array_equal(reference.bands, expected)
        first = values[:, 0]
        best = (first == first.min(axis=0)) & valid
        ranks = np.where(best, rank[1:, None, None], 99)
        winner = np.where(valid.any(axis=0), ranks.argmin(axis=0) + 1, 0)
        np.testing.assert_array_equal(reference.winner, winner)
    else:  # the greatest code; all bands of that product
        codes = np.where(valid, np.stack([s.ndvi for s in states]).astype(int), -1)
        np.testing.assert_array_equal(reference.ndvi, np.maximum(codes.max(axis=0), 0))
        w = reference.winner
        for k, s in enumerate(states):
            sel = w == k + 1
            np.testing.assert_array_equal(reference.bands[:, sel], s.bands[:, sel])
            ties = (codes[k] == codes.max(axis=0)) & valid[k] & (w > 0)
            assert np.all(rank[w[ties]] <= rank[k + 1])


def test_maximum_ndvi_keeps_greenest_pixel_all_bands() -> None:
    # bands: (7, 13, 3); NDVI of date A = (30-10)/40 = 0.5, of date B = (20-10)/30 = 0.333
    date_a = np.array([[[10.0, 10.0]], [[30.0, 30.0]], [[5.0, 5.0]]], np.float32)
    date_b = np.array([[[10.0, 10.0]], [[20.0, 20.0]], [[7.0, 7.0]]], np.float32)
    valid = np.array([[True, True]])
    a = segment_state(date_a, valid, 1, date_a[0], date_a[1])
    b = segment_state(date_b, valid, 2, date_b[0], date_b[1])
    rank = np.array([0, 1, 2])
    for order in ([0, 1], [1, 0]):
        out = _merge_all([a, b], rank, order)
        assert out.bands[:, 0, 0].tolist() == [10.0, 30.0, 5.0]
        assert out.ndvi.tolist() == [[49152, 49152]] and out.winner.tolist() == [[1, 1]]
        assert out.count.tolist() == [[2, 2]]


@pytest.mark.parametrize("dtype", [np.uint16, np.int32, np.float32])
def test_chunk_changes_are_array_equal_and_any_per_block(dtype) -> None:
    """Per block of a tile (edge blocks cut short, overview views with strides): changed is
    ``not np.array_equal`` (NaN differs from itself), filled is ``block.any()``."""
    rng = np.random.default_rng(11)
    old = rng.integers(0, 3, (300, 260)).astype(dtype)
    new = old.copy()
    new[5, 7] += 1  # block (0, 0): changed
    new[64:128, 64:128] = 0  # block (1, 1): changed, left empty
    old[64:128, 128:192] = 0
    new[64:128, 128:192] = 0  # block (1, 2): the same, empty
    new[299, 259] += 2  # the cut corner block (4, 4)
    if dtype == np.float32:
        new[200, 3] = old[200, 3] = np.nan  # block (3, 0): NaN != NaN
    for view in (slice(None), slice(None, None, 2)):
        a, b = new[view, view], old[view, view]
        marks = chunk_changes(a, b, 64)
        want = np.zeros_like(marks)
        for i in range(marks.shape[0]):
            for j in range(marks.shape[1]):
                x, y = a[64 * i:64 * i + 64, 64 * j:64 * j + 64], b[64 * i:64 * i + 64,
                                                                    64 * j:64 * j + 64]
                want[i, j] = ((0 if np.array_equal(x, y) else CHUNK_CHANGED)
                              | (CHUNK_NOT_EMPTY if x.any() else 0))
        np.testing.assert_array_equal(marks, want)
    marks = chunk_changes(new, old, 64)
    assert marks.shape == (5, 5)
    assert marks[0, 0] == CHUNK_CHANGED | CHUNK_NOT_EMPTY
    assert marks[1, 1] == CHUNK_CHANGED and marks[1, 2] == 0
    assert marks[4, 4] & CHUNK_CHANGED and not marks[2, 2] & CHUNK_CHANGED
    assert bool(marks[3, 0] & CHUNK_CHANGED) == (dtype == np.float32)


@pytest.mark.slow
def test_bands_read_where_a_contribution_wins_are_those_of_the_whole_contribution() -> None:
    """Maximum NDVI on counts: a contribution whose bands are read at its merge, where it wins
    only (``winner_state`` + ``WinnerBands``), leaves the same bytes as the same contribution
    gathered whole (``segment_counts_state`` of the pixels at the nearest index), merged in
    any order with others: fills and saturated bands are background, points without an
    antecedent (index -1) give 0, NDVI ties go to the lower rank."""
    rng = np.random.default_rng(5)
    shape, n_bands, window = (24, 31), 3, (9, 12)
    fills = np.array([65535, -1, 7], np.int64)
    bits = np.array([1 << 0, 1 << 6, 1 << 12], np.uint16)
    rank = np.array([0, 3, 1, 2])
    plain, lazy = [], []
    for k in range(3):
        pixels = rng.choice(np.array([7, 900, 2000, 65535], np.uint16),
                            (n_bands, window[0] * window[1]))
        index = rng.integers(-1, pixels.shape[1], shape).astype(np.int32)
        saturated = rng.choice(np.array([0, 0, 0, 1, 64, 4096], np.uint16), shape)
        valid = (rng.random(shape) > 0.25) & (index >= 0)
        red = rng.choice(np.array([10.0, 20.0], np.float32), shape)  # many equal NDVI codes
        nir = rng.choice(np.array([30.0, 40.0], np.float32), shape)
        gathered = np.where(index >= 0, pixels[:, np.maximum(index, 0)], 0).astype(np.uint16)
        for b in range(n_bands):
            gathered[b][(gathered[b] == fills[b]) | ((saturated & bits[b]) != 0)] = 0
        plain.append(segment_counts_state(list(gathered), (0, 0), None, valid, k + 1, red, nir))
        lazy.append((winner_state(valid, k + 1, red, nir),
                     WinnerBands(pixels, index, fills, saturated, bits)))
    for order in ([0, 1, 2], [2, 0, 1], [1, 2, 0]):
        want = TileState(np.zeros((n_bands, *shape), np.uint16), np.zeros(shape, np.uint16),
                         np.zeros(shape, np.int32), np.zeros(shape, np.uint16))
        got = want.copy()
        for k in order:
            combine(want, plain[k], rank)
            combine(got, lazy[k][0], rank, lazy[k][1])
        _same(got, want)
    assert np.count_nonzero(want.bands) > want.bands.size // 3  # not an empty synthesis
    assert set(np.unique(want.winner)) == {0, 1, 2, 3}
    with pytest.raises(ValueError, match="maximum-NDVI"):
        combine(TileState.empty(n_bands, shape, False), lazy[0][0], rank, lazy[0][1])

"""Merge rules of the synthesis (section 3.1 use cases 1-2, Appendix C) on small arrays."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho.engine.synthesis import (
    FLAG_BRIGHT,
    FLAG_GLINT_RISK,
    FLAG_INVALID,
    merge_maximum_ndvi,
    merge_minimum_radiance,
    ndvi_decode,
    ndvi_encode,
    ndvi_value,
    validated_pixels,
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


def test_validity_from_flags() -> None:
    flags = np.array([[0, FLAG_GLINT_RISK, FLAG_INVALID, FLAG_BRIGHT, 16 | 1]], dtype=np.uint8)
    inside = np.array([[True, True, True, True, False]])
    assert validated_pixels(inside, flags, False).tolist() == [[True, False, False, True, False]]
    assert validated_pixels(inside, flags, True).tolist() == [[True, False, False, False, False]]


def test_minimum_radiance_band_by_band() -> None:
    synthesis = np.array([[[0.0, 50.0, 50.0, 50.0]], [[0.0, 10.0, 10.0, 10.0]]], np.float32)
    count = np.array([[0, 1, 1, 1]], np.uint16)
    segment = np.array([[[40.0, 40.0, 60.0, 1.0]], [[20.0, 20.0, 5.0, 1.0]]], np.float32)
    valid = np.array([[True, True, True, False]])
    added = merge_minimum_radiance(synthesis, count, segment, valid)
    # pixel 0 background -> taken; pixel 1: band 1 lower, band 2 higher; pixel 2: band 2 lower
    assert synthesis[:, 0].tolist() == [[40.0, 40.0, 50.0, 50.0], [20.0, 10.0, 5.0, 10.0]]
    assert count.tolist() == [[1, 2, 2, 1]]
    assert added == 3


def test_minimum_radiance_is_order_independent() -> None:
    rng = np.random.default_rng(3)
    segments = rng.uniform(1, 100, (4, 2, 30, 40)).astype(np.float32)
    masks = rng.random((4, 30, 40)) > 0.3
    results = []
    for order in ([0, 1, 2, 3], [3, 1, 0, 2]):
        synthesis = np.zeros((2, 30, 40), np.float32)
        count = np.zeros((30, 40), np.uint16)
        for k in order:
            merge_minimum_radiance(synthesis, count, segments[k], masks[k])
        results.append((synthesis, count))
    np.testing.assert_array_equal(results[0][0], results[1][0])
    expected = np.where(masks[:, None], segments, np.inf).min(axis=0)
    expected[np.isinf(expected)] = 0
    np.testing.assert_array_equal(results[0][0], expected)
    np.testing.assert_array_equal(results[0][1], masks.sum(axis=0))


def test_maximum_ndvi_keeps_greenest_pixel_all_bands() -> None:
    # bands: (7, 13, 3); NDVI of date A = (30-10)/40 = 0.5, of date B = (20-10)/30 = 0.333
    date_a = np.array([[[10.0, 10.0]], [[30.0, 30.0]], [[5.0, 5.0]]], np.float32)
    date_b = np.array([[[10.0, 10.0]], [[20.0, 20.0]], [[7.0, 7.0]]], np.float32)
    valid = np.array([[True, True]])
    synthesis = np.zeros((3, 1, 2), np.float32)
    ndvi = np.zeros((1, 2), np.uint16)
    count = np.zeros((1, 2), np.uint16)
    assert merge_maximum_ndvi(synthesis, ndvi, count, date_b, date_b[0], date_b[1], valid) == 2
    assert merge_maximum_ndvi(synthesis, ndvi, count, date_a, date_a[0], date_a[1], valid) == 2
    assert synthesis[2].tolist() == [[5.0, 5.0]]
    # a lower NDVI does not replace
    assert merge_maximum_ndvi(synthesis, ndvi, count, date_b, date_b[0], date_b[1], valid) == 0
    assert synthesis[:, 0, 0].tolist() == [10.0, 30.0, 5.0]
    assert ndvi.tolist() == [[49152, 49152]]
    assert count.tolist() == [[3, 3]]

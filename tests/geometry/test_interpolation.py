"""The Keys cubic kernel (geometry/interpolation.py) shared by dem and engine.resample."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho.geometry.interpolation import keys_weights


def test_weights_sum_to_one_and_interpolate_at_the_posts():
    f = np.linspace(0.0, 0.999, 50)
    w = np.stack(keys_weights(f), axis=1)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-14)
    np.testing.assert_array_equal(np.stack(keys_weights(0.0)), [0.0, 1.0, 0.0, 0.0])


@pytest.mark.parametrize("coeffs", [(3.0, -2.0, 0.5), (0.0, 1.0, 0.0), (-1.0, 0.0, 4.0)])
def test_quadratics_are_reproduced_exactly(coeffs):
    """Keys (1981): with a = -0.5 the kernel reproduces polynomials up to degree 2."""
    c0, c1, c2 = coeffs
    f = np.linspace(0.0, 0.99, 34)
    posts = np.array([-1.0, 0.0, 1.0, 2.0])
    values = c0 + c1 * posts + c2 * posts**2
    interpolated = np.stack(keys_weights(f), axis=1) @ values
    np.testing.assert_allclose(interpolated, c0 + c1 * f + c2 * f**2, atol=1e-12)


def test_scalar_and_compiled_kernels_agree():
    from numba import njit

    compiled = njit(keys_weights)
    for f in (0.0, 0.25, 0.5, 0.9):
        assert compiled(f) == pytest.approx(keys_weights(f), abs=1e-15)

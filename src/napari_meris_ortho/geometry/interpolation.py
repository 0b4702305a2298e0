"""Interpolation weights shared by the DEM sampling (``dem``) and the band resampling
(``engine.resample``): one definition of the Keys cubic convolution kernel (a = -0.5), the
bicubic of the handbook's "Retrieve the antecedent" (section 3.1).

Plain arithmetic, so the same function serves numpy arrays (``io``) and, compiled with
``numba.njit``, scalar kernels (``engine``).
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np

#: Keys' free parameter (a = -0.5: third-order accurate, Keys 1981)
KEYS_A = -0.5

X = TypeVar("X", float, np.ndarray)


def keys_weights(f: X) -> tuple[X, X, X, X]:
    """Weights of the 4 neighbours at offsets -1, 0, 1, 2 of ``floor(x)`` for the fraction
    ``f = x - floor(x)`` in [0, 1): the Keys kernel W(t) at t = 1 + f, f, 1 - f, 2 - f."""
    a = KEYS_A
    g = 1.0 - f
    return (a * f * g * g, ((a + 2.0) * f - (a + 3.0)) * f * f + 1.0,
            ((a + 2.0) * g - (a + 3.0)) * g * g + 1.0, a * f * f * g)

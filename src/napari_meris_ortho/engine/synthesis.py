"""Merge rules of the MERSYN synthesis (handbook section 3.1, use cases 1 and 2; Appendix C).

Arrays in, arrays out. A synthesis tile is ``synthesis`` (n_bands, rows, cols) float32 radiances
(0 = background), ``count`` (rows, cols) uint16 (products that contributed a valid pixel) and,
for the maximum-NDVI rule, ``ndvi_code`` (rows, cols) uint16: NDVI in [-1, 1] coded linearly on
[1, 65535], 0 = background (Appendix C, ``radioShift``/``radioFactor``).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

#: MERIS L1b flag bits (MDS(16)) used by the validity test of Appendix C.
FLAG_GLINT_RISK = 4
FLAG_BRIGHT = 32
FLAG_INVALID = 128

#: NDVI 16-bit coding of Appendix C: pixels [1, 65535] <-> values [-1, +1], 0 = background.
NDVI_MIN_PIXEL = 1
NDVI_MAX_PIXEL = 65535
NDVI_FACTOR = 2.0 / (NDVI_MAX_PIXEL - NDVI_MIN_PIXEL)  # radioFactor
NDVI_SHIFT = (-1.0 * NDVI_MAX_PIXEL - 1.0 * NDVI_MIN_PIXEL) / (NDVI_MAX_PIXEL - NDVI_MIN_PIXEL)

#: bands of the NDVI (handbook section 3.1): red = band 7, near infrared = band 13.
NDVI_RED_BAND = 7
NDVI_NIR_BAND = 13


@njit(cache=True)
def ndvi_value(red: float, nir: float) -> float:
    """NDVI = (R13 - R7) / (R13 + R7), 0 when the sum is 0 (section 3.1; Appendix C)."""
    total = nir + red
    if total == 0.0:
        return 0.0
    return (nir - red) / total


@njit(cache=True)
def ndvi_encode_value(ndvi: float) -> np.uint16:
    """Scientific NDVI -> 16-bit pixel: round((v - radioShift) / radioFactor), clipped to
    [1, 65535] (Appendix C, "Transform scientific values into pixel values")."""
    pixel = np.floor((ndvi - NDVI_SHIFT) / NDVI_FACTOR + 0.5)
    if pixel < NDVI_MIN_PIXEL:
        pixel = NDVI_MIN_PIXEL
    if pixel > NDVI_MAX_PIXEL:
        pixel = NDVI_MAX_PIXEL
    return np.uint16(pixel)


@njit(cache=True)
def ndvi_decode_value(pixel: np.uint16) -> float:
    """16-bit pixel (not background) -> NDVI = radioShift + radioFactor * pixel (Appendix C)."""
    return NDVI_SHIFT + NDVI_FACTOR * float(pixel)


def ndvi_encode(ndvi: np.ndarray, background: np.ndarray | None = None) -> np.ndarray:
    """Code an NDVI array on 16 bits (Appendix C); ``background`` pixels (bool mask) become 0."""
    values = np.asarray(ndvi, dtype=np.float64)
    code = np.clip(np.floor((values - NDVI_SHIFT) / NDVI_FACTOR + 0.5), NDVI_MIN_PIXEL,
                   NDVI_MAX_PIXEL).astype(np.uint16)
    if background is not None:
        code[np.asarray(background, dtype=bool)] = 0
    return code


def ndvi_decode(code: np.ndarray) -> np.ndarray:
    """Decode a 16-bit NDVI image (Appendix C) to float32, background (0) -> NaN."""
    pixels = np.asarray(code)
    values = (NDVI_SHIFT + NDVI_FACTOR * pixels.astype(np.float64)).astype(np.float32)
    values[pixels == 0] = np.nan
    return values


@njit(cache=True, parallel=True)
def validated_pixels(inside: np.ndarray, flags: np.ndarray, reject_bright: bool) -> np.ndarray:
    """A pixel enters the synthesis when it has an antecedent and GLINT_RISK and INVALID are not
    set (Appendix C, "Check that pixel is flagged as valid"); BRIGHT optionally (section 3.1)."""
    rejected = FLAG_GLINT_RISK | FLAG_INVALID
    if reject_bright:
        rejected |= FLAG_BRIGHT
    rows, cols = inside.shape
    out = np.zeros((rows, cols), dtype=np.bool_)
    for i in prange(rows):
        for j in range(cols):
            out[i, j] = inside[i, j] and (flags[i, j] & rejected) == 0
    return out


@njit(cache=True, parallel=True)
def merge_minimum_radiance(synthesis: np.ndarray, count: np.ndarray, segment: np.ndarray,
                           valid: np.ndarray) -> int:
    """Use case 1: band by band, S_n = R when R < S_{n-1} or S_{n-1} is background (0).

    A new value of 0 (background) never enters. Appendix C prints the test as
    ``radiance_new == background || radiance_new < radiance_old``; the prose (section 3.1:
    "replace ... only if MERIS pixel is inferior") and the background meaning of 0 read it as
    ``radiance_old == background``. ``synthesis``/``count`` are updated in place; returns the
    number of added points (pixels where at least one band was replaced, MERSYN's
    ``added_point_number``).
    """
    n_bands, rows, cols = synthesis.shape
    added = np.zeros(rows, dtype=np.int64)
    for i in prange(rows):
        for j in range(cols):
            if valid[i, j]:
                count[i, j] += 1
                replaced = False
                for b in range(n_bands):
                    new = segment[b, i, j]
                    old = synthesis[b, i, j]
                    if new > 0.0 and (old == 0.0 or new < old):
                        synthesis[b, i, j] = new
                        replaced = True
                if replaced:
                    added[i] += 1
    return added.sum()


@njit(cache=True, parallel=True)
def merge_maximum_ndvi(synthesis: np.ndarray, ndvi_code: np.ndarray, count: np.ndarray,
                       segment: np.ndarray, red: np.ndarray, nir: np.ndarray,
                       valid: np.ndarray) -> int:
    """Use case 2: all bands of the segment pixel replace the synthesis pixel when its NDVI
    (computed in float32 from R7, R13) is greater than the stored one, or the stored one is
    background; the stored NDVI is the 16-bit code (Appendix C), so the comparison is against
    the decoded code exactly as MERSYN reads its input NDVI image. Returns the added points."""
    n_bands, rows, cols = synthesis.shape
    added = np.zeros(rows, dtype=np.int64)
    for i in prange(rows):
        for j in range(cols):
            if valid[i, j]:
                count[i, j] += 1
                new = np.float32(ndvi_value(np.float32(red[i, j]), np.float32(nir[i, j])))
                old_code = ndvi_code[i, j]
                if old_code == 0 or new > ndvi_decode_value(old_code):
                    for b in range(n_bands):
                        synthesis[b, i, j] = segment[b, i, j]
                    ndvi_code[i, j] = ndvi_encode_value(new)
                    added[i] += 1
    return added.sum()

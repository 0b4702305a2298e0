"""Merge rules of the MERSYN synthesis (handbook section 3.1, use cases 1 and 2; Appendix C).

Arrays in, arrays out. A synthesis tile (:class:`TileState`) is ``bands`` (n_bands, rows, cols)
float32 radiances (0 = background), ``count`` (rows, cols) uint16 (products that contributed a
valid pixel), ``winner`` (rows, cols) int32 (1-based index of the product that won the pixel,
0 = background) and, for the maximum-NDVI rule, ``ndvi`` (rows, cols) uint16: NDVI in [-1, 1]
coded linearly on [1, 65535], 0 = background (Appendix C, ``radioShift``/``radioFactor``).

One product's contribution to a tile is itself a state (:func:`segment_state`; under the
maximum-NDVI rule on counts it may also come without its bands, :func:`winner_state`, which
:func:`combine` reads from a :class:`WinnerBands` where it wins); states are merged by
:func:`combine`, which is associative and commutative: the synthesis does not depend
on the order in which products or tiles are merged, nor on how the work is split. Ties are
broken by the products' ``rank`` (sensing time, then name; lower rank wins).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from ..flags import FLAG_BRIGHT, FLAG_GLINT_RISK, FLAG_INVALID  # validity test, Appendix C

#: NDVI 16-bit coding of Appendix C: pixels [1, 65535] <-> values [-1, +1], 0 = background.
NDVI_MIN_PIXEL = 1
NDVI_MAX_PIXEL = 65535
NDVI_FACTOR = 2.0 / (NDVI_MAX_PIXEL - NDVI_MIN_PIXEL)  # radioFactor
NDVI_SHIFT = (-1.0 * NDVI_MAX_PIXEL - 1.0 * NDVI_MIN_PIXEL) / (NDVI_MAX_PIXEL - NDVI_MIN_PIXEL)

#: largest count of a radiance stored on 16 bits (a compact store's band layers; 0 =
#: background)
MAX_COUNT = 65535


@njit(cache=True)
def ndvi_value(red: float, nir: float) -> float:
    """NDVI = (NIR - R) / (NIR + R), 0 when the sum is 0 (section 3.1, MERIS bands 13 and 7;
    Appendix C): the caller picks the bands (``bands.BandTable.ndvi``: 865 and 665 nm)."""
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
def _segment_fill(bands: np.ndarray, winner: np.ndarray, segment: np.ndarray,
                  valid: np.ndarray, index: int) -> None:
    """A product's pixels: valid ones keep their positive radiances (others, NaN included, are
    background 0) and name the product as winner."""
    n_bands, rows, cols = segment.shape
    for i in prange(rows):
        for j in range(cols):
            if valid[i, j]:
                winner[i, j] = index
        for b in range(n_bands):  # band planes one after the other: contiguous rows
            for j in range(cols):
                if valid[i, j]:
                    v = segment[b, i, j]
                    bands[b, i, j] = v if v > 0.0 else np.float32(0.0)


@njit(cache=True)
def count_of(value: float, divisor: float) -> np.uint16:
    """A radiance as a 16-bit count of ``divisor`` (a band's scale, in float64):
    floor(v / scale + 0.5) on [1, MAX_COUNT] for v > 0; 0 (background) for v <= 0 and NaN."""
    v = np.float64(value)
    if not v > 0.0:
        return np.uint16(0)
    q = np.floor(v / divisor + 0.5)
    if q < 1.0:
        q = 1.0
    if q > MAX_COUNT:
        q = MAX_COUNT
    return np.uint16(q)


@njit(cache=True, parallel=True)
def encode_counts(values: np.ndarray, divisor: float) -> np.ndarray:
    """``count_of`` every value of a 1-D array."""
    out = np.empty(values.shape[0], np.uint16)
    for i in prange(values.shape[0]):
        out[i] = count_of(values[i], divisor)
    return out


@njit(cache=True, parallel=True)
def _count_plane(out: np.ndarray, plane: np.ndarray, valid: np.ndarray, r0: int, c0: int,
                 divisor: float) -> None:
    """``out`` = the counts (``count_of``) of ``plane[r0:, c0:]`` where ``valid``, 0 elsewhere."""
    rows, cols = out.shape
    for i in prange(rows):
        for j in range(cols):
            out[i, j] = count_of(plane[r0 + i, c0 + j], divisor) if valid[i, j] else 0


@njit(cache=True, parallel=True)
def _ndvi_codes(red: np.ndarray, nir: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """16-bit NDVI (float32 from red and near infrared; Appendix C coding) of the valid pixels,
    0 elsewhere."""
    rows, cols = valid.shape
    out = np.zeros((rows, cols), np.uint16)
    for i in prange(rows):
        for j in range(cols):
            if valid[i, j]:
                v = np.float32(ndvi_value(np.float32(red[i, j]), np.float32(nir[i, j])))
                out[i, j] = ndvi_encode_value(v)
    return out


@dataclass
class TileState:
    """A synthesis tile, or one product's contribution to it (module docstring)."""

    bands: np.ndarray
    count: np.ndarray
    winner: np.ndarray
    ndvi: np.ndarray | None = None

    @classmethod
    def empty(cls, n_bands: int, shape: tuple[int, int], with_ndvi: bool) -> TileState:
        return cls(np.zeros((n_bands, *shape), np.float32), np.zeros(shape, np.uint16),
                   np.zeros(shape, np.int32), np.zeros(shape, np.uint16) if with_ndvi else None)

    def window(self, r0: int, r1: int, c0: int, c1: int) -> TileState:
        """View of rows [r0, r1) and columns [c0, c1)."""
        return TileState(self.bands[:, r0:r1, c0:c1], self.count[r0:r1, c0:c1],
                         self.winner[r0:r1, c0:c1],
                         None if self.ndvi is None else self.ndvi[r0:r1, c0:c1])

    def copy(self) -> TileState:
        return TileState(self.bands.copy(), self.count.copy(), self.winner.copy(),
                         None if self.ndvi is None else self.ndvi.copy())


@njit(cache=True, parallel=True)
def _masked_plane(out: np.ndarray, plane: np.ndarray, valid: np.ndarray, r0: int,
                  c0: int) -> None:
    """``out`` = ``plane[r0:, c0:]`` where ``valid``, 0 elsewhere."""
    rows, cols = out.shape
    for i in prange(rows):
        for j in range(cols):
            out[i, j] = plane[r0 + i, c0 + j] if valid[i, j] else 0


def segment_counts_state(planes: list[np.ndarray], origin: tuple[int, int],
                         divisors: list[float] | None, valid: np.ndarray, index: int,
                         red: np.ndarray | None = None, nir: np.ndarray | None = None
                         ) -> TileState:
    """``segment_state`` of the window of ``planes`` (window of the shape of ``valid`` from
    ``origin``) with its bands as 16-bit counts: of radiances, the counts of ``divisors``
    (``count_of``); with ``divisors`` None, ``planes`` already are the store's uint16 counts
    (a product's own at the nearest pixel, of the store's scales), copied where valid: the
    same state, since count x scale / scale gives the count back (an error of at most
    65535 x 2**-24 count). One pass per band, no float32 copy of the window; count 1 and
    winner ``index`` where valid, and the 16-bit NDVI of ``red``/``nir`` if given."""
    valid = np.ascontiguousarray(valid, dtype=np.bool_)
    r0, c0 = origin
    bands = np.empty((len(planes), *valid.shape), np.uint16)
    for k, plane in enumerate(planes):
        if divisors is None:
            _masked_plane(bands[k], plane, valid, int(r0), int(c0))
        else:
            _count_plane(bands[k], plane, valid, int(r0), int(c0), float(divisors[k]))
    winner = np.where(valid, np.int32(index), np.int32(0))
    state = TileState(bands, valid.astype(np.uint16), winner)
    if red is not None and nir is not None:
        state.ndvi = _ndvi_codes(np.ascontiguousarray(red, np.float32),
                                 np.ascontiguousarray(nir, np.float32), valid)
    return state


def segment_state(segment: np.ndarray, valid: np.ndarray, index: int,
                  red: np.ndarray | None = None, nir: np.ndarray | None = None) -> TileState:
    """One product's contribution: ``segment`` (n_bands, rows, cols) radiances, ``valid`` the
    validated pixels, ``index`` the product's 1-based index; with ``red``/``nir`` (665 and 865
    nm: MERIS bands 7 and 13, OLCI Oa08 and Oa17) the 16-bit NDVI of the maximum-NDVI rule."""
    valid = np.ascontiguousarray(valid, dtype=np.bool_)
    state = TileState.empty(segment.shape[0], valid.shape, red is not None)
    _segment_fill(state.bands, state.winner, np.ascontiguousarray(segment, np.float32), valid,
                  int(index))
    state.count[:] = valid
    if red is not None and nir is not None:
        state.ndvi = _ndvi_codes(np.ascontiguousarray(red, np.float32),
                                 np.ascontiguousarray(nir, np.float32), valid)
    return state


@njit(cache=True)
def _beats(value: float, rank: int, old_value: float, old_rank: int) -> bool:
    """Lexicographic order of (value, rank): True when the first pair is smaller."""
    return value < old_value or (value == old_value and rank < old_rank)


@njit(cache=True, parallel=True)
def combine_minimum_radiance(bands: np.ndarray, count: np.ndarray, winner: np.ndarray,
                             new_bands: np.ndarray, new_count: np.ndarray,
                             new_winner: np.ndarray, rank: np.ndarray) -> None:
    """Use case 1, in place: band by band S = min(S, R) over positive radiances (0 =
    background never enters, section 3.1 "replace ... only if MERIS pixel is inferior";
    Appendix C prints ``radiance_new == background`` where the prose means the old one). The
    winner is the product with the lowest first-band radiance, then the lowest rank."""
    n_bands, rows, cols = bands.shape
    for i in prange(rows):
        for j in range(cols):
            count[i, j] += new_count[i, j]
            w = new_winner[i, j]
            if w == 0:
                continue
            old = winner[i, j]
            v_new = new_bands[0, i, j] if new_bands[0, i, j] > 0.0 else np.inf
            v_old = bands[0, i, j] if bands[0, i, j] > 0.0 else np.inf
            if old == 0 or _beats(v_new, rank[w], v_old, rank[old]):
                winner[i, j] = w
        for b in range(n_bands):  # band after band: one stream each (``_gather_points``)
            for j in range(cols):
                new = new_bands[b, i, j]
                prev = bands[b, i, j]
                if new_winner[i, j] != 0 and new > 0.0 and (prev == 0.0 or new < prev):
                    bands[b, i, j] = new


@njit(cache=True, inline="always")
def _ndvi_row_winners(i, ndvi, count, winner, new_ndvi, new_count, new_winner, rank,
                      taken):  # pragma: no cover - numba
    """Row i of the maximum-NDVI rule without the bands: counts added, and where the new
    state's NDVI code is greater (equal: the lower rank) its winner and code taken and
    ``taken[j]`` set; returns how many pixels it took."""
    n_taken = 0
    for j in range(taken.size):
        count[i, j] += new_count[i, j]
        w = new_winner[i, j]
        if w == 0:
            continue
        old = winner[i, j]
        if old == 0 or _beats(-float(new_ndvi[i, j]), rank[w], -float(ndvi[i, j]),
                              rank[old]):
            winner[i, j] = w
            ndvi[i, j] = new_ndvi[i, j]
            taken[j] = True
            n_taken += 1
    return n_taken


@njit(cache=True, parallel=True)
def combine_maximum_ndvi(bands: np.ndarray, ndvi: np.ndarray, count: np.ndarray,
                         winner: np.ndarray, new_bands: np.ndarray, new_ndvi: np.ndarray,
                         new_count: np.ndarray, new_winner: np.ndarray, rank: np.ndarray
                         ) -> None:
    """Use case 2, in place: all bands of the pixel with the greater 16-bit NDVI (Appendix C
    coding; equal codes: the lower rank) replace the synthesis pixel."""
    n_bands, rows, cols = bands.shape
    for i in prange(rows):
        taken = np.zeros(cols, np.bool_)  # the row's pixels the new state wins
        _ndvi_row_winners(i, ndvi, count, winner, new_ndvi, new_count, new_winner, rank, taken)
        for b in range(n_bands):  # band after band: one stream each (``_gather_points``)
            for j in range(cols):
                if taken[j]:
                    bands[b, i, j] = new_bands[b, i, j]


@dataclass
class WinnerBands:
    """The band values of a contribution, not gathered yet: what :func:`combine` takes, under
    the maximum-NDVI rule, for the pixels the contribution wins only (the other pixels' bands
    are never read; the 2nd to 6th of 6 simulated dates merged one by one win 36 % down to
    4 % of their pixels). ``pixels`` (n_bands, n)
    uint16: the product window of each stored band, flattened; ``index`` (rows, cols) the
    flat pixel of each point of the state (its nearest antecedent; -1: none); ``fills``
    (n_bands,) int64: the band's no-data count (-1: none), which is taken as 0 (background);
    ``saturated`` (rows, cols) saturation bits of the point, uint16 (MERIS) or uint32 (OLCI's
    21 bands) (shape (0, 0): none) and ``bits`` (n_bands,) of the same type, each band's bit
    in them: a saturated band is taken as 0."""

    pixels: np.ndarray
    index: np.ndarray
    fills: np.ndarray
    saturated: np.ndarray
    bits: np.ndarray


def winner_state(valid: np.ndarray, index: int, red: np.ndarray, nir: np.ndarray
                 ) -> TileState:
    """The state of a contribution whose bands a :class:`WinnerBands` gives: no band planes,
    count 1 and winner ``index`` where ``valid``, the 16-bit NDVI of ``red``/``nir``
    (Appendix C coding)."""
    valid = np.ascontiguousarray(valid, dtype=np.bool_)
    return TileState(np.empty((0, *valid.shape), np.uint16), valid.astype(np.uint16),
                     np.where(valid, np.int32(index), np.int32(0)),
                     _ndvi_codes(np.ascontiguousarray(red, np.float32),
                                 np.ascontiguousarray(nir, np.float32), valid))


@njit(cache=True, parallel=True, nogil=True)
def combine_maximum_ndvi_gathering(bands: np.ndarray, ndvi: np.ndarray, count: np.ndarray,
                                   winner: np.ndarray, new_ndvi: np.ndarray,
                                   new_count: np.ndarray, new_winner: np.ndarray,
                                   rank: np.ndarray, pixels: np.ndarray, index: np.ndarray,
                                   fills: np.ndarray, saturated: np.ndarray, bits: np.ndarray
                                   ) -> None:
    """``combine_maximum_ndvi`` whose new bands come from a :class:`WinnerBands` (its arrays),
    read at the pixels the new state wins only: the same synthesis, without gathering and
    copying the bands of the pixels it loses."""
    n_bands, rows, cols = bands.shape
    with_saturation = saturated.shape[0] > 0
    for i in prange(rows):
        taken = np.zeros(cols, np.bool_)  # the row's pixels the new state wins
        if _ndvi_row_winners(i, ndvi, count, winner, new_ndvi, new_count, new_winner, rank,
                             taken) == 0:
            continue
        for b in range(n_bands):  # band after band: one stream each (``_gather_points``)
            fill = fills[b]
            bit = bits[b]
            for j in range(cols):
                if taken[j]:
                    p = index[i, j]
                    v = pixels[b, p] if p >= 0 else np.uint16(0)
                    if v == fill or (with_saturation and (saturated[i, j] & bit) != 0):
                        v = np.uint16(0)
                    bands[b, i, j] = v


def combine(acc: TileState, new: TileState, rank: np.ndarray,
            source: WinnerBands | None = None) -> None:
    """Merge state ``new`` into ``acc`` (same shape; in place). Associative and commutative;
    ``rank[k]``: tie-break rank of product ``k`` (distinct ranks). The bands may also be
    uint16 counts of one positive scale per band (both states alike): the rules only compare
    and copy them, and counts order as their radiances do. ``source``: ``new``'s bands are
    read from it where ``new`` wins (``winner_state``; maximum-NDVI rule, uint16 counts)."""
    rank = np.ascontiguousarray(rank, dtype=np.int64)
    if source is not None:
        if acc.ndvi is None or new.ndvi is None or acc.bands.dtype != np.uint16:
            raise ValueError("bands read where a state wins: maximum-NDVI rule on counts only")
        combine_maximum_ndvi_gathering(acc.bands, acc.ndvi, acc.count, acc.winner, new.ndvi,
                                       new.count, new.winner, rank, source.pixels,
                                       source.index, source.fills, source.saturated,
                                       source.bits)
        return
    if acc.ndvi is None or new.ndvi is None:
        combine_minimum_radiance(acc.bands, acc.count, acc.winner, new.bands, new.count,
                                 new.winner, rank)
    else:
        combine_maximum_ndvi(acc.bands, acc.ndvi, acc.count, acc.winner, new.bands, new.ndvi,
                             new.count, new.winner, rank)


@njit(cache=True)
def count_winners(winner: np.ndarray, n: int) -> np.ndarray:
    """Pixels of each product index 0 .. n - 1 in the 2-D ``winner`` layer (indices outside
    are not counted): one pass, no sort, no widened copy (``np.bincount`` casts to int64)."""
    counts = np.zeros(n, np.int64)
    rows, cols = winner.shape
    for i in range(rows):
        for j in range(cols):
            w = winner[i, j]
            if 0 <= w < n:
                counts[w] += 1
    return counts


#: ``chunk_changes`` bits of a block: a value differs from the old one; a value is not 0
CHUNK_CHANGED = 1
CHUNK_NOT_EMPTY = 2


@njit(cache=True, nogil=True)
def chunk_changes(new: np.ndarray, old: np.ndarray, chunk: int) -> np.ndarray:
    """Per ``chunk`` x ``chunk`` block of the 2-D ``new`` against ``old`` (same shape, any
    strides): ``CHUNK_CHANGED`` where a value differs (NaN differs from itself, as in
    ``np.array_equal``), plus ``CHUNK_NOT_EMPTY`` where ``new`` holds a value other than 0 (a
    chunk of fill values only is not stored). One pass, row by row (a row's tests without a
    branch, so they vectorize), each block left at the first row that answers both; without
    the GIL (a store's writes run beside the orthorectification)."""
    rows, cols = new.shape
    out = np.zeros(((rows + chunk - 1) // chunk, (cols + chunk - 1) // chunk), np.uint8)
    for bi in range(out.shape[0]):
        for bj in range(out.shape[1]):
            j0 = bj * chunk
            j1 = min(cols, j0 + chunk)
            changed = 0
            filled = 0
            for i in range(bi * chunk, min(rows, (bi + 1) * chunk)):
                a = new[i, j0:j1]
                b = old[i, j0:j1]
                row_changed = 0
                row_filled = 0
                for j in range(j1 - j0):
                    row_changed |= a[j] != b[j]
                    row_filled |= a[j] != 0
                changed |= row_changed
                filled |= row_filled
                if changed and filled:
                    break
            out[bi, bj] = (CHUNK_CHANGED if changed else 0) | (CHUNK_NOT_EMPTY if filled
                                                                else 0)
    return out

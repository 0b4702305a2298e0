"""Resampling of product bands at fractional antecedents (handbook section 3.1, "Retrieve the
antecedent (l,p)": nearest neighbour in MERSYN; bilinear on 2x2 and bicubic on 4x4 pixels as the
handbook suggests).

``resample(image, lines, cols, method)`` -> float32 array shaped like ``lines``:

- ``lines``/``cols`` are antecedents in product pixel coordinates (integers = pixel centres);
  NaN, or a point outside -0.5 <= l < H - 0.5, -0.5 <= p < W - 0.5, gives the background 0;
- ``"nearest"``: the pixel whose centre is nearest, ties rounded up (floor(x + 0.5));
- ``"bilinear"``: 2x2 pixels; ``"bicubic"``: 4x4 pixels, Keys kernel a = -0.5;
  neighbours beyond the image edge are clamped to the edge pixel.

``resample_bands(images, lines, cols, method)`` resamples several bands at the same antecedents,
computing the indices and weights once per chunk of points.
Images of any numeric dtype (non-native byte order is converted); memmaps are read lazily.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit

from ..geometry.interpolation import keys_weights
from ..options import Sampling, parse
from .threads import split_range

_CHUNK = 1 << 18
#: points gathered band after band (``_gather_points``): long runs keep each band's reads
#: and writes one stream (a whole fr-alps grid gathers in 142 ms by blocks of 2**18 points,
#: 290 ms point after point)
GATHER_BLOCK = 1 << 18


def _check_method(method: str) -> int:
    """Pixels per axis of a sampling method (``options.Sampling``), or OptionsError."""
    return parse(Sampling, method).taps


def _native(image: np.ndarray) -> np.ndarray:
    a = image if isinstance(image, np.ndarray) else np.asarray(image)
    if a.ndim != 2:
        raise ValueError(f"image must be 2-D, got shape {a.shape}")
    if not a.dtype.isnative:
        a = a.astype(a.dtype.newbyteorder("="))
    if a.dtype == np.bool_:
        a = a.view(np.uint8)
    return a


def resample(image: np.ndarray, lines: np.ndarray, cols: np.ndarray, method: str = "nearest",
             out: np.ndarray | None = None) -> np.ndarray:
    """One band resampled at the antecedents (lines, cols); float32, background 0."""
    res = resample_bands([image], lines, cols, method, out=None if out is None else [out])
    return res[0]


def resample_bands(images: Sequence[np.ndarray], lines: np.ndarray, cols: np.ndarray,
                   method: str = "nearest", out: Sequence[np.ndarray] | None = None
                   ) -> list[np.ndarray]:
    """Several bands (all of the same shape) resampled at the same antecedents; weights once."""
    k = _check_method(method)
    images = [_native(im) for im in images]
    if not images:
        return []
    shape = images[0].shape
    if any(im.shape != shape for im in images):
        raise ValueError("all bands must have the same shape")
    lines = np.asarray(lines)
    cols = np.asarray(cols)
    if lines.shape != cols.shape:
        raise ValueError(f"lines {lines.shape} and cols {cols.shape} differ in shape")
    fl, fc = lines.reshape(-1), cols.reshape(-1)
    outs = [np.zeros(lines.shape, np.float32) for _ in images] if out is None else list(out)
    for o in outs:
        if o.shape != lines.shape:
            raise ValueError(f"output shape {o.shape} differs from {lines.shape}")
    if k == 1:
        index = nearest_pixel(fl, fc, shape[0], shape[1])
        for im, o in zip(images, outs, strict=True):
            values = np.empty((1, fl.size), im.dtype)
            gather(im[None], index, values)
            o.flat[:] = values[0]
        return outs
    for a in range(0, fl.size, _CHUNK):
        b = min(a + _CHUNK, fl.size)
        il, wl, ip, wp, valid = _weights(np.asarray(fl[a:b], dtype=np.float64),
                                         np.asarray(fc[a:b], dtype=np.float64),
                                         shape[0], shape[1], k)
        for im, o in zip(images, outs, strict=True):
            chunk = np.empty(b - a, np.float32)
            _apply(im, il, wl, ip, wp, valid, chunk)
            o.flat[a:b] = chunk
    return outs


_keys_weights = njit(cache=True, inline="always")(keys_weights)


def nearest_pixel(lines: np.ndarray, cols: np.ndarray, n_lines: int, n_cols: int,
                  line_offset: int = 0, col_offset: int = 0) -> np.ndarray:
    """Flat index ``round(l - line_offset) * W + round(p - col_offset)`` of the antecedent
    pixel of every point (Appendix C: iline_segment = TimRound(mer_x0), ties rounded up) in a
    window of ``n_lines`` x ``n_cols`` (W) product pixels starting at line ``line_offset``,
    column ``col_offset``; -1 where the point is NaN or outside the window. float32
    antecedents are taken as they are (no float64 copy; the arithmetic is float64 either way).
    Any shape in, 1-D int32 out (int64 past 2**31 window pixels)."""
    dtype = np.float32 if np.asarray(lines).dtype == np.float32 else np.float64
    line = np.ascontiguousarray(lines, dtype=dtype).reshape(-1)
    col = np.ascontiguousarray(cols, dtype=dtype).reshape(-1)
    if line.size != col.size:
        raise ValueError(f"lines ({line.size}) and cols ({col.size}) differ in size")
    # int32 while the window's pixels fit (always, for MERIS): half the memory traffic of the
    # index, which every band's gather reads again
    out = np.empty(line.size, np.int32 if int(n_lines) * int(n_cols) < 2 ** 31 else np.int64)
    args = (line, col, float(line_offset), float(col_offset), np.int64(n_lines),
            np.int64(n_cols), out)
    split_range(lambda lo, hi: _nearest_range(lo, hi, *args), line.size, min_size=1 << 16)
    return out


@njit(cache=True, nogil=True)
def _nearest_range(lo, hi, line, col, offset, col_offset, n_lines, n_cols, out
                   ):  # pragma: no cover
    """Points [lo, hi) of ``nearest_pixel``."""
    for i in range(lo, hi):
        x = np.float64(line[i]) - offset
        y = np.float64(col[i]) - col_offset
        if x >= -0.5 and x < n_lines - 0.5 and y >= -0.5 and y < n_cols - 0.5:
            out[i] = int(math.floor(x + 0.5)) * n_cols + int(math.floor(y + 0.5))
        else:
            out[i] = -1


def finite_extent(values: np.ndarray) -> tuple[int, int, int, int]:
    """Rows ``[r0, r1)`` and columns ``[c0, c1)`` of a 2-D array holding all its finite values
    (antecedent lines: the points a resampling can give a value; the rest of an output grid is
    background), (0, 0, 0, 0) when there is none. One pass that stops, in each row, at the
    first finite value from either end."""
    a = np.asarray(values)
    if a.ndim != 2:
        raise ValueError(f"values must be 2-D, got shape {a.shape}")
    r0, r1, c0, c1 = _finite_extent(a)
    return (int(r0), int(r1), int(c0), int(c1)) if r1 > r0 else (0, 0, 0, 0)


@njit(cache=True, nogil=True)
def _finite_extent(a):  # pragma: no cover
    nr, nc = a.shape
    r0, r1, c0, c1 = nr, 0, nc, 0
    for r in range(nr):
        first = -1
        for c in range(nc):
            if math.isfinite(a[r, c]):
                first = c
                break
        if first < 0:
            continue
        last = first
        for c in range(nc - 1, first, -1):
            if math.isfinite(a[r, c]):
                last = c
                break
        r0 = min(r0, r)
        r1 = r + 1
        c0 = min(c0, first)
        c1 = max(c1, last + 1)
    return r0, r1, c0, c1


def inside_range(lines: np.ndarray, cols: np.ndarray, n_lines: int, n_cols: int
                 ) -> tuple[float, float, float, float] | None:
    """Smallest and largest line, then column, of the antecedents inside the product
    (-0.5 <= l < H - 0.5, -0.5 <= p < W - 0.5; NaN is outside), None when there is none; one
    pass (float32 or float64, any shape)."""
    line = np.asarray(lines).reshape(-1)
    col = np.asarray(cols).reshape(-1)
    if line.size != col.size:
        raise ValueError(f"lines ({line.size}) and cols ({col.size}) differ in size")
    dtype = np.float32 if line.dtype == np.float32 and col.dtype == np.float32 else np.float64
    lo, hi, c_lo, c_hi = _inside_range(np.ascontiguousarray(line, dtype),
                                       np.ascontiguousarray(col, dtype), float(n_lines),
                                       float(n_cols))
    return None if lo > hi else (lo, hi, c_lo, c_hi)


@njit(cache=True, nogil=True)
def _inside_range(line, col, n_lines, n_cols):  # pragma: no cover
    lo, hi, c_lo, c_hi = np.inf, -np.inf, np.inf, -np.inf
    for i in range(line.size):
        x = np.float64(line[i])
        y = np.float64(col[i])
        if x >= -0.5 and x < n_lines - 0.5 and y >= -0.5 and y < n_cols - 0.5:
            lo = min(lo, x)
            hi = max(hi, x)
            c_lo = min(c_lo, y)
            c_hi = max(c_hi, y)
    return lo, hi, c_lo, c_hi


def _pixels(images: np.ndarray) -> np.ndarray:
    """(bands, lines, cols) as (bands, lines x cols): the flat pixel index addresses a pixel
    directly (no division per point); a copy only when the images are not C-contiguous."""
    a = np.ascontiguousarray(images)
    return a.reshape(a.shape[0], -1)


def copy_window(out: np.ndarray, window: np.ndarray) -> None:
    """``out[...] = window`` for 2-D uint16 arrays, the window of an image of the other byte
    order (an N1 band's big-endian memory map) byte-swapped on the engine's threads: a tile's
    15-band stack in 5 ms instead of numpy's 11 ms (fr-alps, 1100 x 690 pixels a band). Any
    other dtype or byte order: numpy's copy."""
    swapped = window.dtype.newbyteorder("=") == np.uint16 and not window.dtype.isnative
    if (not swapped or out.dtype != np.uint16 or window.ndim != 2
            or out.shape != window.shape or window.strides[1] != 2):
        out[...] = window
        return
    native = np.asarray(window).view(np.uint16)  # the stored bytes, read as native
    split_range(lambda lo, hi: _swapped_rows(lo, hi, native, out), out.shape[0],
                min_size=64)


@njit(cache=True, nogil=True)
def _swapped_rows(lo, hi, src, out):  # pragma: no cover - numba
    """Rows [lo, hi) of ``copy_window``: the two bytes of every value swapped."""
    for i in range(lo, hi):
        for j in range(out.shape[1]):
            v = src[i, j]
            out[i, j] = (v >> 8) | ((v & 0xFF) << 8)


def gather(images: np.ndarray, index: np.ndarray, out: np.ndarray,
           place: tuple[int, int, int] | None = None) -> None:
    """Nearest neighbour of all bands in one pass: ``out[b, i] = images[b, pixel index[i]]``,
    0 where the index is -1; ``images`` (bands, lines, cols), ``out`` (bands, points) of the
    same dtype (uint16 counts, uint8 flags: no conversion), ``index`` 1-D; points split over
    threads. ``place`` = (width, stride, offset): the points are a window of ``width`` columns
    of a grid of rows of ``stride`` points flattened in ``out``, starting at ``offset``
    (point i goes to ``offset + (i // width) * stride + i % width``)."""
    _gather(images, index, np.empty(0, np.float32), out, place)


def gather_scaled(images: np.ndarray, index: np.ndarray, scales: np.ndarray,
                  out: np.ndarray, place: tuple[int, int, int] | None = None) -> None:
    """``gather`` of counts straight into float32 physical values:
    ``out[b, i] = float32(images[b, pixel index[i]]) * scales[b]`` (float32 arithmetic, the
    numbers of ``counts.astype(float32) * float32(scale)``), 0 where the index is -1."""
    _gather(images, index, np.ascontiguousarray(scales, dtype=np.float32), out, place)


def _gather(images: np.ndarray, index: np.ndarray, scales: np.ndarray, out: np.ndarray,
            place: tuple[int, int, int] | None) -> None:
    """``gather`` (``scales`` empty) and ``gather_scaled``: the placement checked (every point
    inside ``out``), the rows of points split over threads."""
    pixels = _pixels(images)
    n = int(index.size)
    # no place: rows of one point (the threads split the points)
    width, stride, offset = (1, 1, 0) if place is None else map(int, place)
    if width < 1 or n % width or stride < width or offset < 0 or (
            n and offset + (n // width - 1) * stride + width > out.shape[-1]):
        raise ValueError(f"{n} points as rows of {width} at {offset} every {stride} do not "
                         f"fit in {out.shape[-1]}")
    split_range(lambda lo, hi: _gather_range(lo, hi, pixels, index, scales, out, width, stride,
                                             offset),
                n // width, min_size=max((1 << 16) // width, 1))


@njit(cache=True, nogil=True)
def _gather_range(lo, hi, pixels, index, scales, out, width, stride, offset):  # pragma: no cover
    """Rows [lo, hi) of the points of ``_gather`` (``pixels``: bands x flat pixels; ``scales``
    empty: the values as they are, else float32 times the band's scale)."""
    if stride == width:  # the rows follow each other in ``out``: one run of points
        _gather_points(lo * width, hi * width, offset + lo * width, pixels, index, scales, out)
        return
    for r in range(lo, hi):
        _gather_points(r * width, (r + 1) * width, offset + r * stride, pixels, index, scales,
                       out)


@njit(cache=True, nogil=True)
def _gather_points(i0, i1, j0, pixels, index, scales, out):  # pragma: no cover
    """Points [i0, i1) into ``out[:, j0 + i - i0]``, in blocks of ``GATHER_BLOCK`` points and
    band after band within a block, so that each band is read and written as one stream
    (point after point, 15 bands would make 30 interleaved streams: 1.5 times the time over a
    whole fr-alps grid, 2.6 times over a 1024 x 1024 tile)."""
    n_bands = pixels.shape[0]
    scaled = scales.size > 0
    d = j0 - i0
    for a in range(i0, i1, GATHER_BLOCK):
        z = min(a + GATHER_BLOCK, i1)
        for b in range(n_bands):
            if scaled:
                s = scales[b]
                for i in range(a, z):
                    k = index[i]
                    out[b, d + i] = np.float32(pixels[b, k]) * s if k >= 0 else 0
            else:
                for i in range(a, z):
                    k = index[i]
                    out[b, d + i] = pixels[b, k] if k >= 0 else 0


@njit(cache=True)
def _axis(x: float, n: int, k: int, idx, w, i) -> None:  # pragma: no cover
    """Indices (clamped to [0, n-1]) and weights of the k = 2 or 4 neighbours of coordinate x."""
    base = int(math.floor(x))
    f = x - base
    if k == 2:
        idx[i, 0] = min(max(base, 0), n - 1)
        idx[i, 1] = min(max(base + 1, 0), n - 1)
        w[i, 0] = 1.0 - f
        w[i, 1] = f
        return
    weights = _keys_weights(f)
    for m in range(4):
        idx[i, m] = min(max(base - 1 + m, 0), n - 1)
        w[i, m] = weights[m]


def _weights(lines: np.ndarray, cols: np.ndarray, h: int, wd: int, k: int
             ) -> tuple[np.ndarray, ...]:
    """Neighbour indices and weights along lines and columns, and validity, of every point."""
    n = lines.size
    il = np.zeros((n, k), np.int64)
    ip = np.zeros((n, k), np.int64)
    wl = np.zeros((n, k), np.float64)
    wp = np.zeros((n, k), np.float64)
    valid = np.zeros(n, np.bool_)
    args = (lines, cols, np.int64(h), np.int64(wd), np.int64(k), il, wl, ip, wp, valid)
    split_range(lambda lo, hi: _weights_range(lo, hi, *args), n, min_size=1 << 14)
    return il, wl, ip, wp, valid


@njit(cache=True, nogil=True)
def _weights_range(lo, hi, lines, cols, h, wd, k, il, wl, ip, wp, valid):  # pragma: no cover
    for i in range(lo, hi):
        l_ = lines[i]
        p_ = cols[i]
        if l_ >= -0.5 and l_ < h - 0.5 and p_ >= -0.5 and p_ < wd - 0.5:
            valid[i] = True
            _axis(l_, h, k, il, wl, i)
            _axis(p_, wd, k, ip, wp, i)


def touches(mask: np.ndarray, lines: np.ndarray, cols: np.ndarray, method: str = "bilinear"
            ) -> np.ndarray:
    """True where the resampling of a point reads a pixel of ``mask`` (bool/uint8 image) with a
    non-zero weight: a sample touching a no-data pixel is itself no data, never a value mixed
    with a fill (nearest: the pixel itself). Any shape of points in, bool of that shape out."""
    k = _check_method(method)
    m = np.ascontiguousarray(_native(mask), dtype=np.uint8)
    lines = np.asarray(lines)
    fl = np.ascontiguousarray(lines, dtype=np.float64).reshape(-1)
    fc = np.ascontiguousarray(cols, dtype=np.float64).reshape(-1)
    out = np.zeros(fl.size, np.bool_)
    if k == 1:
        index = nearest_pixel(fl, fc, m.shape[0], m.shape[1])
        flat = m.reshape(-1)
        hit = index >= 0
        out[hit] = flat[index[hit]] != 0
        return out.reshape(lines.shape)
    for a in range(0, fl.size, _CHUNK):
        b = min(a + _CHUNK, fl.size)
        il, wl, ip, wp, valid = _weights(fl[a:b], fc[a:b], m.shape[0], m.shape[1], k)
        _touches(m, il, wl, ip, wp, valid, out[a:b])
    return out.reshape(lines.shape)


def _touches(mask: np.ndarray, il: np.ndarray, wl: np.ndarray, ip: np.ndarray,
             wp: np.ndarray, valid: np.ndarray, out: np.ndarray) -> None:
    split_range(lambda lo, hi: _touches_range(lo, hi, mask, il, wl, ip, wp, valid, out),
                out.size, min_size=1 << 14)


@njit(cache=True, nogil=True)
def _touches_range(lo, hi, mask, il, wl, ip, wp, valid, out):  # pragma: no cover
    k = il.shape[1]
    for i in range(lo, hi):
        if not valid[i]:
            continue
        for a in range(k):
            if wl[i, a] == 0.0:
                continue
            for b in range(k):
                if wp[i, b] != 0.0 and mask[il[i, a], ip[i, b]] != 0:
                    out[i] = True


def _apply(image: np.ndarray, il: np.ndarray, wl: np.ndarray, ip: np.ndarray, wp: np.ndarray,
           valid: np.ndarray, out: np.ndarray) -> None:
    """Separable weighted sum of the neighbours of every point of ``out`` (0 where invalid)."""
    split_range(lambda lo, hi: _apply_range(lo, hi, image, il, wl, ip, wp, valid, out),
                out.size, min_size=1 << 14)


@njit(cache=True, nogil=True)
def _apply_range(lo, hi, image, il, wl, ip, wp, valid, out):  # pragma: no cover
    k = il.shape[1]
    for i in range(lo, hi):
        if not valid[i]:
            out[i] = 0.0
            continue
        acc = 0.0
        for a in range(k):
            row = 0.0
            for b in range(k):
                row += wp[i, b] * image[il[i, a], ip[i, b]]
            acc += wl[i, a] * row
        out[i] = acc


def overview_level(a: np.ndarray, nodata: float | None, resampling: str = "average"
                   ) -> np.ndarray:
    """The next overview level of a 2-D band (GDAL ``AVERAGE``): the mean of each 2 x 2 block
    ignoring ``nodata`` and NaN (integers rounded half up; a block of nodata gives nodata; odd
    sizes: the last row/column averages what there is), or its upper-left pixel ("nearest")."""
    if resampling == "nearest":
        return np.ascontiguousarray(a[0::2, 0::2])
    if resampling != "average":
        raise ValueError(f"unknown overview resampling {resampling!r}")
    src = _native(a)
    out = np.empty(((src.shape[0] + 1) // 2, (src.shape[1] + 1) // 2), src.dtype)
    _halve_average(np.ascontiguousarray(src), out, 0.0 if nodata is None else float(nodata),
                   nodata is not None, src.dtype.kind in "iu")
    return out


@njit(cache=True, inline="always")
def _add(v, fill, skip_fill, s, n):  # pragma: no cover
    if (skip_fill and v == fill) or v != v:
        return s, n
    return s + v, n + 1


@njit(cache=True, nogil=True)  # serial (5 ms for 11 M pixels); nogil: the COG workers go on
def _halve_average(a, out, fill, skip_fill, rounded):  # pragma: no cover
    """``overview_level`` "average" into ``out``: whole 2 x 2 blocks row by row
    (``_whole_blocks``, branch-free: the compiler vectorises it), the last row and column of
    odd sizes pixel by pixel (``_edge_block``)."""
    h, w = a.shape
    for i in range(h // 2):
        _whole_blocks(a, out, i, fill, skip_fill, rounded)
        if w % 2:
            _edge_block(a, out, i, w // 2, fill, skip_fill, rounded)
    if h % 2:
        for j in range(out.shape[1]):
            _edge_block(a, out, h // 2, j, fill, skip_fill, rounded)


@njit(cache=True)
def _whole_blocks(a, out, i, fill, skip_fill, rounded):  # pragma: no cover
    """Output row i from input rows 2i, 2i + 1, every whole 2 x 2 block: the mean of the
    pixels that are not ``fill`` (when ``skip_fill``) nor NaN, in the order and arithmetic of
    ``_edge_block`` (adding 0.0 for a skipped pixel changes no sum), ``fill`` when none is."""
    r0 = 2 * i
    r1 = r0 + 1
    for j in range(a.shape[1] // 2):
        c = 2 * j
        v00 = np.float64(a[r0, c])
        v01 = np.float64(a[r0, c + 1])
        v10 = np.float64(a[r1, c])
        v11 = np.float64(a[r1, c + 1])
        k00 = not ((skip_fill and v00 == fill) or v00 != v00)
        k01 = not ((skip_fill and v01 == fill) or v01 != v01)
        k10 = not ((skip_fill and v10 == fill) or v10 != v10)
        k11 = not ((skip_fill and v11 == fill) or v11 != v11)
        n = np.float64(k00) + np.float64(k01) + np.float64(k10) + np.float64(k11)
        s = (0.0 + (v00 if k00 else 0.0) + (v01 if k01 else 0.0) + (v10 if k10 else 0.0)
             + (v11 if k11 else 0.0))
        m = s / max(n, 1.0)
        if rounded:
            m = math.floor(m + 0.5)
        out[i, j] = m if n > 0.0 else fill


@njit(cache=True)
def _edge_block(a, out, i, j, fill, skip_fill, rounded):  # pragma: no cover
    """Output pixel (i, j) from the up to 2 x 2 input pixels there (past the last row or
    column: the ones there are)."""
    h, w = a.shape
    r0 = 2 * i
    r1 = r0 + 1 if r0 + 1 < h else -1
    c0 = 2 * j
    c1 = c0 + 1
    s, n = _add(a[r0, c0], fill, skip_fill, 0.0, 0)
    if c1 < w:
        s, n = _add(a[r0, c1], fill, skip_fill, s, n)
    if r1 >= 0:
        s, n = _add(a[r1, c0], fill, skip_fill, s, n)
        if c1 < w:
            s, n = _add(a[r1, c1], fill, skip_fill, s, n)
    if n == 0:
        out[i, j] = fill
    elif rounded:
        out[i, j] = math.floor(s / n + 0.5)
    else:
        out[i, j] = s / n

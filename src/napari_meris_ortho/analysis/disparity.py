"""Disparity analysis: ZNCC pattern matching of two images on the same grid (handbook section 4.6).

DISPAR searches, for every pixel of the first image, the homologous point of the second image in an
exploration window (default 9 lines x 19 columns) by the zero-mean normalised cross-correlation
(ZNCC) of a statistical window (default 5 x 5). Pixels whose confidence reaches the threshold
(default 95 %) are the candidate pixels (the tie-points, "pixel sampling of 0.1 pixels").

Algorithm (numba, parallel over blocks of lines)
1. Whole-pixel search: for each displacement, running 5-line column sums of A x B(displaced)
   (two products per pixel and displacement), then ZNCC = (S/n - mean_A mean_B) / (sd_A sd_B).
2. Parabola through the peak and its two neighbours on each axis: a first sub-pixel estimate
   and a forecast of the sub-pixel peak's value.
3. ``subpixel="grid"`` (default): every pixel whose forecast may reach the threshold climbs the
   ZNCC on the 0.1-px grid (8-neighbour moves), B being shifted by bicubic interpolation; this
   removes the parabola's bias towards whole pixels (up to 0.1 px on sharp textures).
   ``subpixel="parabola"``: the parabola's vertex rounded to 0.1 px.

Conventions
- The displacement is that of the **second image relative to the first**: a feature at
  (line, column) in A is found at (line + dY, column + dX) in B; B = A moved by +s gives +s.
- dX is along columns, positive towards increasing columns (east on a north-up grid); dY is along
  lines, positive towards increasing lines (south on a north-up grid). Metres keep the pixel sign
  and are pixels times the pixel size, as DISPAR's "ORIGINAL VALUES".
- The exploration window height bounds dY (|dY| <= 4 for 9 lines), its width bounds dX
  (|dX| <= 9 for 19 columns). A best match on that border is "on limit"; it is never a candidate.
  (DISPAR's own logs print the +-4 range under "X" and the +-9 range under "Y".)
- Confidence index = 100 x ZNCC of the peak (the refined one where refined), clipped at 0 (the
  logs' minimum is 0).
- Background pixels (0, NaN) are not image pixels; a window touching background or the image border
  is not correlated. Image pixels whose statistical window cannot be matched get confidence 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit, prange

from ..display import fixed
from ..errors import OptionsError
from ..progress import ProgressCallback

__all__ = ["DisparityResult", "disparity", "displacement_statistics", "format_report"]

#: lines handed to one numba call between two progress reports
_ROW_CHUNK = 256
#: consecutive lines sharing running column sums in the whole-pixel search
_BLOCK = 32
#: largest exploration window side (lines or columns): displacements up to +-64 px, one FR
#: tie-point interval (about 19 km), seven times the handbook's 9 x 19 (+-4 lines, +-9 columns,
#: section 4.6). Disparities of orthorectified images are geolocation errors of a few pixels;
#: the whole-pixel search costs one ZNCC per pixel and candidate shift, so its time grows with
#: the window's area (400 x 400 px: 0.7 s at 9 x 19, 5.3 s at 121 x 121, 27 s at 241 x 241)
MAX_EXPLORE = 129
#: pixels whose parabola vertex forecasts a confidence above (threshold - this, in %) are refined
_REFINE_MARGIN = 10.0


@dataclass
class DisparityResult:
    """Per-pixel disparity of image B relative to image A (section 4.6) and its statistics.

    Arrays have the images' shape. ``dx``/``dy`` in pixels (NaN where not an analysed image pixel),
    ``confidence`` in % (NaN likewise), ``candidate`` the kept points, ``image`` the image pixels,
    ``on_limit_x``/``on_limit_y`` the best matches on the exploration border.
    """

    dx: np.ndarray
    dy: np.ndarray
    confidence: np.ndarray
    candidate: np.ndarray
    image: np.ndarray
    on_limit_x: np.ndarray
    on_limit_y: np.ndarray
    stat_window: int
    explore: tuple[int, int]
    threshold: float
    pixel_size_m: tuple[float, float] | None
    stats: dict = field(default_factory=dict)

    def vectors(self) -> np.ndarray:
        """Kept points as rows (line, column, dX, dY, confidence), float64 (N, 5)."""
        rows, cols = np.nonzero(self.candidate)
        return np.column_stack(
            [rows, cols, self.dx[rows, cols], self.dy[rows, cols], self.confidence[rows, cols]]
        ).astype(np.float64)

    def napari_vectors(self, scale: float = 1.0) -> np.ndarray:
        """Kept points as napari Vectors data (N, 2, 2): start (row, col), projection (dY, dX)."""
        v = self.vectors()
        data = np.empty((len(v), 2, 2))
        data[:, 0, 0], data[:, 0, 1] = v[:, 0], v[:, 1]
        data[:, 1, 0], data[:, 1, 1] = v[:, 3] * scale, v[:, 2] * scale
        return data

    @property
    def global_displacement(self) -> tuple[float, float]:
        """Algebraic mean (dX, dY) of the candidates, pixels (section 4.6 "Global displacement")."""
        return self.stats["x"]["candidates"]["mean"], self.stats["y"]["candidates"]["mean"]

    def report(self, title: str | None = None) -> str:
        """The statistics printed like DISPAR's ``.sta`` log (section 4.6)."""
        return format_report(self.stats, title=title)


def disparity(
    a: np.ndarray,
    b: np.ndarray,
    *,
    stat_window: int = 5,
    explore: tuple[int, int] = (9, 19),
    threshold: float = 95.0,
    pixel_size_m: tuple[float, float] | None = None,
    step: int = 1,
    mask: np.ndarray | None = None,
    resolution: float = 0.1,
    subpixel: str = "grid",
    progress: ProgressCallback | None = None,
) -> DisparityResult:
    """Disparity of ``b`` relative to ``a`` by ZNCC (section 4.6, DISPAR).

    ``explore`` = (height in lines, width in columns), both odd; ``stat_window`` odd;
    ``threshold`` in %; ``pixel_size_m`` = (x, y) metres for the "ORIGINAL VALUES";
    ``step`` analyses every step-th line and column; ``mask`` (bool) restricts the image pixels;
    ``resolution`` is the sub-pixel sampling (0.1 px). ``subpixel="grid"`` refines every pixel
    that may pass the threshold by maximising the ZNCC against the second image shifted by bicubic
    interpolation on that 0.1-px grid (the confidence is then that of the refined peak);
    ``"parabola"`` keeps the parabola's vertex rounded to ``resolution`` (faster, biased towards
    whole pixels by up to ~0.1 px on sharp textures).
    """
    if subpixel not in ("grid", "parabola"):
        raise OptionsError(f"subpixel must be 'grid' or 'parabola', got {subpixel!r}")
    if subpixel == "grid" and not resolution > 0:
        raise OptionsError("the 'grid' sub-pixel refinement needs a resolution > 0")
    a64, b64, valid = _prepare(a, b, mask)
    _check_options(a64.shape, stat_window, explore, threshold, step)
    half = stat_window // 2
    hy, hx = explore[0] // 2, explore[1] // 2
    mean_a, isd_a = _window_moments(a64, valid, half)
    mean_b, isd_b = _window_moments(b64, valid, half)
    height, width = a64.shape
    analysed = np.zeros((height, width), dtype=np.bool_)
    analysed[::step, ::step] = True
    image = analysed & valid
    invalid_sum = np.zeros((height + 1, width + 1), dtype=np.int32)
    invalid_sum[1:, 1:] = np.cumsum(np.cumsum(~valid, axis=0, dtype=np.int32), axis=1)
    rows = np.arange(0, height, step, dtype=np.int64)
    dx, dy, conf = (np.full((height, width), np.nan, dtype=np.float32) for _ in range(3))
    limit = np.zeros((height, width), dtype=np.uint8)
    vertex = np.zeros((height, width), dtype=np.float32)
    for start in range(0, len(rows), _ROW_CHUNK):
        chunk = rows[start : start + _ROW_CHUNK]
        best_val = np.full((len(chunk), width), -np.inf)
        best_idx = np.zeros((len(chunk), width), dtype=np.int32)
        _integer_search(a64, b64, mean_a, isd_a, mean_b, isd_b, chunk, half, hy, hx,
                        best_val, best_idx)
        _peaks(a64, b64, mean_a, isd_a, mean_b, isd_b, image, chunk, half, hy, hx, step,
               best_val, best_idx, dx, dy, conf, limit, vertex)
        if subpixel == "grid":
            ii, jj = np.nonzero(image[chunk[0] : chunk[-1] + 1])
            ii += chunk[0]
            keep = (vertex[ii, jj] >= threshold - _REFINE_MARGIN) & (limit[ii, jj] == 0)
            _refine_on_grid((a64, b64, mean_a, isd_a, invalid_sum), ii[keep], jj[keep], half,
                            hy, hx, float(resolution), dx, dy, conf)
        if progress is not None:
            progress(min(start + _ROW_CHUNK, len(rows)), len(rows))
    if resolution > 0:
        dx = (np.round(dx / resolution) * resolution).astype(np.float32)
        dy = (np.round(dy / resolution) * resolution).astype(np.float32)
    on_x, on_y = image & (limit & 1 > 0), image & (limit & 2 > 0)
    candidate = image & (conf >= threshold) & ~on_x & ~on_y
    result = DisparityResult(dx, dy, conf, candidate, image, on_x, on_y, stat_window,
                             (int(explore[0]), int(explore[1])), float(threshold), pixel_size_m)
    result.stats = displacement_statistics(result, total_pixels=int(analysed.sum()))
    return result


def _prepare(a, b, mask) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """float64 copies centred on their mean, and the image-pixel mask (non-background in both)."""
    a = np.asarray(a)
    b = np.asarray(b)
    if a.ndim != 2 or b.ndim != 2:
        raise OptionsError(f"disparity needs two 2-D images, got shapes {a.shape} and {b.shape}")
    if a.shape != b.shape:
        raise OptionsError(f"the two images must be on the same grid: {a.shape} vs {b.shape}")
    a64, b64 = a.astype(np.float64), b.astype(np.float64)
    valid = np.isfinite(a64) & np.isfinite(b64) & (a64 != 0) & (b64 != 0)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != a.shape:
            raise OptionsError(f"mask shape {mask.shape} differs from the images {a.shape}")
        valid &= mask
    if not valid.any():
        raise OptionsError("the two images have no common non-background pixel")
    a64 = np.where(valid, a64 - a64[valid].mean(), 0.0)
    b64 = np.where(valid, b64 - b64[valid].mean(), 0.0)
    return a64, b64, valid


def _check_options(shape, stat_window, explore, threshold, step) -> None:
    if stat_window < 1 or stat_window % 2 == 0:
        raise OptionsError(f"--stat-window must be a positive odd number, got {stat_window}")
    if len(explore) != 2 or any(e < 1 or e % 2 == 0 for e in explore):
        raise OptionsError(f"--explore must be two positive odd numbers (lines columns), "
                           f"got {explore}")
    if max(explore) > MAX_EXPLORE:
        raise OptionsError(f"--explore {explore[0]} {explore[1]}: at most {MAX_EXPLORE} lines "
                           f"and columns (displacements up to +-{MAX_EXPLORE // 2} px; the "
                           "handbook's DISPAR explores 9 x 19; the search time grows with the "
                           "window's area)")
    for n, size, what in ((explore[0], shape[0], "lines"), (explore[1], shape[1], "columns")):
        if n > 2 * size - 1:
            raise OptionsError(f"--explore {explore[0]} {explore[1]}: {n} {what} explore "
                               f"shifts beyond the images' {size} {what} (at most "
                               f"{2 * size - 1})")
    if not 0.0 <= threshold <= 100.0:
        raise OptionsError(f"--threshold must be between 0 and 100 %, got {threshold}")
    if step < 1:
        raise OptionsError(f"--step must be >= 1, got {step}")
    if min(shape) < stat_window:
        raise OptionsError(f"images {shape} are smaller than the statistical window {stat_window}")



def _moments(values: np.ndarray) -> dict:
    """RMS, minimum, maximum, mean, standard deviation (population) of ``values``."""
    if values.size == 0:
        return {"n": 0, "rms": math.nan, "minimum": math.nan, "maximum": math.nan,
                "mean": math.nan, "std": math.nan, "variance": math.nan}
    v = values.astype(np.float64)
    return {"n": int(v.size), "rms": float(np.sqrt(np.mean(v * v))), "minimum": float(v.min()),
            "maximum": float(v.max()), "mean": float(v.mean()), "std": float(v.std()),
            "variance": float(v.var())}


def displacement_statistics(result: DisparityResult, total_pixels: int | None = None) -> dict:
    """The statistics of DISPAR's log (section 4.6): counts, confidence, X and Y displacements
    over the image pixels and over the candidates (*), in pixels and metres, global displacement."""
    img, cand = result.image, result.candidate
    n_img, n_cand = int(img.sum()), int(cand.sum())
    stats: dict = {
        "stat_window": result.stat_window, "explore": result.explore,
        "threshold": result.threshold,
        "total_pixels": int(total_pixels if total_pixels is not None else img.size),
        "image_pixels": n_img, "candidate_pixels": n_cand,
        "confidence": {"image": _moments(result.confidence[img]),
                       "candidates": _moments(result.confidence[cand])},
        "pixel_size_m": result.pixel_size_m,
    }
    for axis, d, limit, size_index in (("x", result.dx, result.on_limit_x, 0),
                                       ("y", result.dy, result.on_limit_y, 1)):
        entry = {"on_limit": int(limit.sum()), "image": _moments(d[img]),
                 "candidates": _moments(d[cand])}
        if result.pixel_size_m is not None:
            size = float(result.pixel_size_m[size_index])
            entry["image_m"] = _moments(d[img] * size)
            entry["candidates_m"] = _moments(d[cand] * size)
        stats[axis] = entry
    gx, gy = stats["x"]["candidates"]["mean"], stats["y"]["candidates"]["mean"]
    stats["global_displacement"] = {"dx": gx, "dy": gy}
    if result.pixel_size_m is not None:
        mx, my = gx * result.pixel_size_m[0], gy * result.pixel_size_m[1]
        stats["global_displacement"].update(dx_m=mx, dy_m=my, modulus_m=math.hypot(mx, my))
    return stats


def _vs(label: str, image: float, cand: float, digits: int = 6) -> str:
    return f"{label}\t= {fixed(image, digits)} vs. {fixed(cand, digits)} (*)"


def _moment_lines(image: dict, cand: dict) -> list[str]:
    return [
        _vs("RMS", image["rms"], cand["rms"]),
        _vs("MINIMUM", image["minimum"], cand["minimum"]),
        _vs("MAXIMUM", image["maximum"], cand["maximum"]),
        _vs("MEAN", image["mean"], cand["mean"]),
        _vs("STANDARD DEVIATION", image["std"], cand["std"], 3),
    ]


def format_report(stats: dict, title: str | None = None) -> str:
    """DISPAR's ``.sta`` log layout (section 4.6) from a statistics dict.

    As in the handbook's logs, VARIANCE is that of the confidence taken as a fraction (0..1) and
    printed times 100, i.e. sigma^2 / 100 for sigma in % (33.127544 -> 10.974342).
    """
    n_img, n_cand = stats["image_pixels"], stats["candidate_pixels"]
    share = 100.0 * n_cand / n_img if n_img else 0.0
    ci, cc = stats["confidence"]["image"], stats["confidence"]["candidates"]
    lines = [f"FILE {title}", ""] if title else []
    lines += [
        f"STATISTICAL WINDOW SIZE = {stats['stat_window']}",
        f"EXPLORATION WINDOW HEIGHT = {stats['explore'][0]}",
        f"EXPLORATION WINDOW WIDTH = {stats['explore'][1]}",
        f"CONFIDENCE THRESHOLD = {stats['threshold']:.1f} %", "",
        f"TOTAL NUMBER OF PIXELS = {stats['total_pixels']}",
        f"IMAGE PIXELS = {n_img}",
        f"CANDIDATE PIXELS (*) = {n_cand} ({share:.1f} %)", "",
        f"TIE-POINTS = {n_cand}", "",
        "CONFIDENCE VALUES:", "",
        _vs("MINIMUM", ci["minimum"], cc["minimum"]),
        _vs("MAXIMUM", ci["maximum"], cc["maximum"]),
        _vs("MEAN", ci["mean"], cc["mean"]),
        _vs("VARIANCE", ci["variance"] / 100.0, cc["variance"] / 100.0),
        _vs("STANDARD DEVIATION", ci["std"], cc["std"]), "",
    ]
    for axis in ("x", "y"):
        entry = stats[axis]
        on = 100.0 * entry["on_limit"] / n_img if n_img else 0.0
        lines += [f"{axis.upper()} DISPLACEMENT:", "",
                  f"ON LIMIT\t= {entry['on_limit']} / {n_img} ({on:.2f}%)"]
        lines += _moment_lines(entry["image"], entry["candidates"]) + [""]
        if "image_m" in entry:
            lines += ["ORIGINAL VALUES:", ""]
            lines += _moment_lines(entry["image_m"], entry["candidates_m"]) + [""]
    g = stats["global_displacement"]
    text = f"GLOBAL DISPLACEMENT (dX, dY) = ({fixed(g['dx'], 6)}, {fixed(g['dy'], 6)}) pixels"
    if "modulus_m" in g:
        text += (f" = ({fixed(g['dx_m'], 3)}, {fixed(g['dy_m'], 3)}) m, "
                 f"MODULUS = {fixed(g['modulus_m'], 3)} m")
    lines.append(text)
    return "\n".join(lines) + "\n"




# --- numba kernels -----------------------------------------------------------------------------

@njit(cache=True, nogil=True)  # nogil: the window turns meanwhile
def _window_moments(img, valid, half):
    """Mean and 1/standard deviation of each statistical window; 1/sd is NaN where the window
    leaves the image or touches background, 0 for a flat window (ZNCC = 0)."""
    height, width = img.shape
    n = (2 * half + 1) ** 2
    mean = np.zeros((height, width))
    inv_sd = np.full((height, width), np.nan)
    for i in range(half, height - half):
        for j in range(half, width - half):
            s = 0.0
            s2 = 0.0
            good = True
            for r in range(-half, half + 1):
                for c in range(-half, half + 1):
                    if not valid[i + r, j + c]:
                        good = False
                    v = img[i + r, j + c]
                    s += v
                    s2 += v * v
            if not good:
                continue
            m = s / n
            var = s2 / n - m * m
            mean[i, j] = m
            inv_sd[i, j] = 1.0 / math.sqrt(var) if var > 1e-12 * (s2 / n + 1e-300) else 0.0
    return mean, inv_sd


@njit(cache=True, parallel=True, nogil=True)  # nogil: the window turns meanwhile
def _integer_search(a, b, mean_a, isd_a, mean_b, isd_b, rows, half, hy, hx, best_val, best_idx):
    """Whole-pixel ZNCC peak over the exploration window for the given lines (section 4.6).

    Blocks of lines run in parallel; inside a block the 5-line column sums of A x B(displaced)
    are updated line by line (add the new line, drop the old), so one displacement costs two
    products per pixel. ``best_val``/``best_idx`` (lines of ``rows`` x width) receive the peak.
    """
    height, width = a.shape
    nx = 2 * hx + 1
    inv_n = 1.0 / (2 * half + 1) ** 2
    nblocks = (rows.shape[0] + _BLOCK - 1) // _BLOCK
    for blk in prange(nblocks):
        k0 = blk * _BLOCK
        k1 = min(rows.shape[0], k0 + _BLOCK)
        colsum = np.zeros(width)
        boxsum = np.zeros(width)
        for v in range(-hy, hy + 1):
            for u in range(-hx, hx + 1):
                d = (v + hy) * nx + (u + hx)
                j0, j1 = max(half, half - u), min(width - half, width - half - u)
                c0, c1 = j0 - half, j1 + half
                prev = -10
                for k in range(k0, k1):
                    i = rows[k]
                    ib = i + v
                    if i - half < 0 or i + half >= height or ib - half < 0 or ib + half >= height:
                        prev = -10
                        continue
                    # 1-D views and loops from 0 let LLVM vectorise (no negative-index check)
                    cs = colsum[c0:c1]
                    if prev == i - 1:
                        _slide(cs, a[i + half, c0:c1], b[ib + half, c0 + u : c1 + u],
                               a[i - half - 1, c0:c1], b[ib - half - 1, c0 + u : c1 + u])
                    else:
                        cs[:] = 0.0
                        for r in range(-half, half + 1):
                            _accumulate(cs, a[i + r, c0:c1], b[ib + r, c0 + u : c1 + u])
                    prev = i
                    bs = boxsum[j0:j1]
                    bs[:] = 0.0
                    for c in range(2 * half + 1):
                        _accumulate_sum(bs, colsum[j0 - half + c : j1 - half + c])
                    _keep_best(bs, inv_n, mean_a[i, j0:j1], isd_a[i, j0:j1],
                               mean_b[ib, j0 + u : j1 + u], isd_b[ib, j0 + u : j1 + u],
                               best_val[k, j0:j1], best_idx[k, j0:j1], d)


@njit(cache=True)
def _accumulate(cs, aa, bb):
    """cs += A B (one line of products)."""
    for t in range(cs.shape[0]):
        cs[t] += aa[t] * bb[t]


@njit(cache=True)
def _accumulate_sum(bs, cs):
    """bs += cs."""
    for t in range(bs.shape[0]):
        bs[t] += cs[t]


@njit(cache=True)
def _slide(cs, a_new, b_new, a_old, b_old):
    """Move the column sums one line down: add the new line's products, drop the old ones."""
    for t in range(cs.shape[0]):
        cs[t] += a_new[t] * b_new[t] - a_old[t] * b_old[t]


@njit(cache=True)
def _keep_best(bs, inv_n, ma, ia, mb, ib, best_val, best_idx, d):
    """ZNCC = (sum/n - mean_a mean_b) / (sd_a sd_b) on one line; keep the best displacement."""
    for t in range(bs.shape[0]):
        z = (bs[t] * inv_n - ma[t] * mb[t]) * ia[t] * ib[t]
        better = z > best_val[t]
        best_val[t] = z if better else best_val[t]
        best_idx[t] = d if better else best_idx[t]


@njit(cache=True)
def _zncc_direct(stats, i, j, v, u, half):
    """ZNCC of A's window at (i, j) with B's window at (i + v, j + u); NaN off the image.
    ``stats`` = (A, B, mean and 1/sd of A's windows, mean and 1/sd of B's windows)."""
    a, b, mean_a, isd_a, mean_b, isd_b = stats
    height, width = a.shape
    ib, jb = i + v, j + u
    if ib - half < 0 or ib + half >= height or jb - half < 0 or jb + half >= width:
        return np.nan
    s = 0.0
    for r in range(-half, half + 1):
        for c in range(-half, half + 1):
            s += a[i + r, j + c] * b[ib + r, jb + c]
    n = (2 * half + 1) ** 2
    return (s / n - mean_a[i, j] * mean_b[ib, jb]) * isd_a[i, j] * isd_b[ib, jb]


@njit(cache=True, parallel=True, nogil=True)  # nogil: the window turns meanwhile
def _peaks(a, b, mean_a, isd_a, mean_b, isd_b, image, rows, half, hy, hx, step,
           best_val, best_idx, dx, dy, conf, limit, vertex):
    """Parabola refinement of each whole-pixel peak, confidence (%), on-limit bits (1 X, 2 Y),
    and the parabolas' vertex value (%), a forecast of the sub-pixel peak's confidence."""
    width = a.shape[1]
    nx = 2 * hx + 1
    stats = (a, b, mean_a, isd_a, mean_b, isd_b)
    for k in prange(rows.shape[0]):
        i = rows[k]
        for j in range(0, width, step):
            if not image[i, j]:
                continue
            c0 = best_val[k, j]
            if not c0 > -2.0:  # no matchable window: zero displacement, zero confidence
                dx[i, j], dy[i, j], conf[i, j], limit[i, j], vertex[i, j] = 0.0, 0.0, 0.0, 0, 0.0
                continue
            v, u = best_idx[k, j] // nx - hy, best_idx[k, j] % nx - hx
            bits = 0
            fx = fy = gx = gy = 0.0
            if hx > 0 and (u == -hx or u == hx):
                bits += 1
            elif hx > 0:
                fx, gx = _parabola(_zncc_direct(stats, i, j, v, u - 1, half), c0,
                                   _zncc_direct(stats, i, j, v, u + 1, half))
            if hy > 0 and (v == -hy or v == hy):
                bits += 2
            elif hy > 0:
                fy, gy = _parabola(_zncc_direct(stats, i, j, v - 1, u, half), c0,
                                   _zncc_direct(stats, i, j, v + 1, u, half))
            dx[i, j] = u + fx
            dy[i, j] = v + fy
            conf[i, j] = min(max(c0, 0.0), 1.0) * 100.0
            vertex[i, j] = min(max(c0 + gx + gy, 0.0), 1.0) * 100.0
            limit[i, j] = bits


@njit(cache=True)
def _parabola(cm, c0, cp):
    """Vertex (offset within [-0.5, 0.5], value gain over c0) of the parabola through
    (-1, cm), (0, c0), (1, cp)."""
    if not (cm > -2.0 and cp > -2.0):
        return 0.0, 0.0
    den = cm - 2.0 * c0 + cp
    if den >= 0.0:
        return 0.0, 0.0
    return min(max(0.5 * (cm - cp) / den, -0.5), 0.5), -(cp - cm) ** 2 / (8.0 * den)


@njit(cache=True)
def _cubic(f):
    """Keys bicubic convolution weights (a = -0.5) of taps -1, 0, 1, 2 at fraction f."""
    return (((-0.5 * f + 1.0) * f - 0.5) * f, (1.5 * f - 2.5) * f * f + 1.0,
            ((-1.5 * f + 2.0) * f + 0.5) * f, (0.5 * f - 0.5) * f * f)


@njit(cache=True)
def _zncc_at(a, b, mean_a, isd_a, invalid_sum, i, j, sy, sx, half, tmp):
    """ZNCC of A's window at (i, j) with B's window displaced by (sy, sx) px, B sampled by
    bicubic interpolation; NaN when a tap leaves the image or touches background.
    ``invalid_sum`` is the summed-area table of background pixels; ``tmp`` a scratch array."""
    height, width = a.shape
    size = 2 * half + 1
    by, bx = int(math.floor(sy + 1e-9)), int(math.floor(sx + 1e-9))
    fy, fx = max(sy - by, 0.0), max(sx - bx, 0.0)
    iy, ix = fy > 1e-9, fx > 1e-9  # interpolate along y / x (taps -1..2), else copy
    r0, r1 = i + by - half - (1 if iy else 0), i + by + half + (3 if iy else 1)
    cb = j + bx - half
    c0, c1 = cb - (1 if ix else 0), cb + size + (2 if ix else 0)
    if r0 < 0 or c0 < 0 or r1 > height or c1 > width:
        return np.nan
    if invalid_sum[r1, c1] - invalid_sum[r0, c1] - invalid_sum[r1, c0] + invalid_sum[r0, c0] > 0:
        return np.nan
    w0, w1, w2, w3 = _cubic(fx)
    for r in range(r1 - r0):
        row = b[r0 + r]
        for c in range(size):
            x = cb + c
            if ix:
                tmp[r, c] = w0 * row[x - 1] + w1 * row[x] + w2 * row[x + 1] + w3 * row[x + 2]
            else:
                tmp[r, c] = row[x]
    w0, w1, w2, w3 = _cubic(fy)
    sb = sbb = sab = 0.0
    for r in range(size):
        arow = a[i - half + r]
        for c in range(size):
            if iy:
                vb = w0 * tmp[r, c] + w1 * tmp[r + 1, c] + w2 * tmp[r + 2, c] + w3 * tmp[r + 3, c]
            else:
                vb = tmp[r, c]
            sb += vb
            sbb += vb * vb
            sab += arow[j - half + c] * vb
    n = size * size
    mb = sb / n
    var_b = sbb / n - mb * mb
    if not var_b > 1e-12 * (sbb / n + 1e-300):
        return 0.0
    return (sab / n - mean_a[i, j] * mb) * isd_a[i, j] / math.sqrt(var_b)


@njit(cache=True, parallel=True, nogil=True)  # nogil: the window turns meanwhile
def _refine_on_grid(data, ii, jj, half, hy, hx, res, dx, dy, conf):
    """Climb the ZNCC on the ``res`` grid (8-neighbour moves, within 0.5 px of the parabola's
    estimate and inside the exploration window); write the refined peak and its confidence."""
    span = max(int(round(0.5 / res)), 1)
    n = ii.shape[0]
    nchunks = min(n, 64)
    for q in prange(nchunks):
        tmp = np.empty((2 * half + 4, 2 * half + 1))
        seen = np.empty((2 * span + 1, 2 * span + 1))
        for k in range(q * n // nchunks, (q + 1) * n // nchunks):
            _climb(data, ii[k], jj[k], half, hy, hx, res, span, tmp, seen, dx, dy, conf)


@njit(cache=True)
def _climb(data, i, j, half, hy, hx, res, span, tmp, seen, dx, dy, conf):
    """Hill climbing of one pixel on the sub-pixel grid, memoised in ``seen``;
    ``data`` = (A, B, mean of A's windows, 1/sd of A's windows, background summed-area table)."""
    a, b, mean_a, isd_a, invalid_sum = data
    ty0, tx0 = int(round(dy[i, j] / res)), int(round(dx[i, j] / res))
    best = _zncc_at(a, b, mean_a, isd_a, invalid_sum, i, j, ty0 * res, tx0 * res, half, tmp)
    if not best > -2.0:  # taps off the image: start from the whole-pixel peak
        ty0, tx0 = int(round(round(dy[i, j]) / res)), int(round(round(dx[i, j]) / res))
        best = _zncc_at(a, b, mean_a, isd_a, invalid_sum, i, j, ty0 * res, tx0 * res, half, tmp)
        if not best > -2.0:
            return
    seen[:, :] = -3.0
    seen[span, span] = best
    cy = cx = 0
    for _ in range(4 * span):
        my, mx, mbest = cy, cx, best
        for o in range(9):  # 8-neighbourhood: ZNCC ridges may run diagonally
            ny, nx = cy + o // 3 - 1, cx + o % 3 - 1
            if abs(ny) > span or abs(nx) > span:
                continue
            if abs((ty0 + ny) * res) > hy or abs((tx0 + nx) * res) > hx:
                continue
            c = seen[ny + span, nx + span]
            if c < -2.5:
                c = _zncc_at(a, b, mean_a, isd_a, invalid_sum, i, j, (ty0 + ny) * res,
                             (tx0 + nx) * res, half, tmp)
                seen[ny + span, nx + span] = c
            if c > mbest:
                my, mx, mbest = ny, nx, c
        if my == cy and mx == cx:
            break
        cy, cx, best = my, mx, mbest
    dy[i, j] = (ty0 + cy) * res
    dx[i, j] = (tx0 + cx) * res
    conf[i, j] = min(max(best, 0.0), 1.0) * 100.0

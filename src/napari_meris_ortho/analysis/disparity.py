"""Disparity analysis: ZNCC pattern matching of two images on the same grid (handbook section 4.6).

DISPAR searches, for every pixel of the first image, the homologous point of the second image in an
exploration window (default 9 lines x 19 columns) by the zero-mean normalised cross-correlation
(ZNCC) of a statistical window (default 5 x 5). The integer peak is refined to 0.1 px by a parabola
through the peak and its two neighbours on each axis, then rounded to 0.1 px (the handbook's "pixel
sampling of 0.1 pixels"). Pixels whose confidence reaches the threshold (default 95 %) are the
candidate pixels (the tie-points).

Conventions
- The displacement is that of the **second image relative to the first**: a feature at
  (line, column) in A is found at (line + dY, column + dX) in B; B = A moved by +s gives +s.
- dX is along columns, positive towards increasing columns (east on a north-up grid); dY is along
  lines, positive towards increasing lines (south on a north-up grid). Metres keep the pixel sign
  and are pixels times the pixel size, as DISPAR's "ORIGINAL VALUES".
- The exploration window height bounds dY (|dY| <= 4 for 9 lines), its width bounds dX
  (|dX| <= 9 for 19 columns). A best match on that border is "on limit"; it is never a candidate.
  (DISPAR's own logs print the +-4 range under "X" and the +-9 range under "Y".)
- Confidence index = 100 x ZNCC of the integer peak, clipped at 0 (the logs' minimum is 0).
- Background pixels (0, NaN) are not image pixels; a window touching background or the image border
  is not correlated. Image pixels whose statistical window cannot be matched get confidence 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit, prange

from ..errors import OptionsError
from ..progress import ProgressCallback

__all__ = ["DisparityResult", "disparity", "displacement_statistics", "format_report"]

#: rows handed to one numba call between two progress reports
_ROW_CHUNK = 128
#: pixels whose whole-pixel confidence is within this many % below the threshold are refined
_REFINE_MARGIN = 25.0


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
    mean_a, inv_sd_a, ok_a = _window_moments(a64, valid, half)
    mean_b, inv_sd_b, ok_b = _window_moments(b64, valid, half)
    height, width = a64.shape
    analysed = np.zeros((height, width), dtype=np.bool_)
    analysed[::step, ::step] = True
    image = analysed & valid
    rows = np.arange(0, height, step, dtype=np.int64)
    dx, dy, conf = (np.full((height, width), np.nan, dtype=np.float32) for _ in range(3))
    limit = np.zeros((height, width), dtype=np.uint8)
    for start in range(0, len(rows), _ROW_CHUNK):
        chunk = rows[start : start + _ROW_CHUNK]
        _zncc_rows(a64, b64, mean_a, inv_sd_a, ok_a, mean_b, inv_sd_b, ok_b, image,
                   chunk, half, hy, hx, step, dx, dy, conf, limit)
        if progress is not None:
            progress(min(start + _ROW_CHUNK, len(rows)), len(rows))
        if subpixel == "grid":
            ii, jj = np.nonzero(image[chunk[0] : chunk[-1] + 1])
            ii += chunk[0]
            keep = (conf[ii, jj] >= threshold - _REFINE_MARGIN) & (limit[ii, jj] == 0)
            _refine_on_grid(a64, b64, valid, ii[keep], jj[keep], half, hy, hx,
                            float(resolution), dx, dy, conf)
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
    if not 0.0 <= threshold <= 100.0:
        raise OptionsError(f"--threshold must be between 0 and 100 %, got {threshold}")
    if step < 1:
        raise OptionsError(f"--step must be >= 1, got {step}")
    if min(shape) < stat_window:
        raise OptionsError(f"images {shape} are smaller than the statistical window {stat_window}")


@njit(cache=True)
def _window_moments(img, valid, half):
    """Mean, 1/standard deviation and full-window validity of each statistical window."""
    height, width = img.shape
    n = (2 * half + 1) ** 2
    mean = np.zeros((height, width))
    inv_sd = np.zeros((height, width))
    ok = np.zeros((height, width), dtype=np.bool_)
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
            m = s / n
            var = s2 / n - m * m
            mean[i, j] = m
            ok[i, j] = good
            if good and var > 1e-12 * (s2 / n + 1e-300):
                inv_sd[i, j] = 1.0 / math.sqrt(var)
    return mean, inv_sd, ok


@njit(cache=True, parallel=True)
def _zncc_rows(a, b, mean_a, inv_sd_a, ok_a, mean_b, inv_sd_b, ok_b, image,
               rows, half, hy, hx, step, dx, dy, conf, limit):
    """ZNCC over the exploration window for the given lines: writes the parabola's sub-pixel
    peak (dx, dy), the confidence (%) and the on-limit bits (1: X, 2: Y) of each image pixel."""
    height, width = a.shape
    ny, nx = 2 * hy + 1, 2 * hx + 1
    n = (2 * half + 1) ** 2
    for k in prange(rows.shape[0]):
        i = rows[k]
        corr = np.full((ny, nx, width), -2.0)
        colsum = np.zeros(width)
        for v in range(-hy, hy + 1):
            ib = i + v
            if ib - half < 0 or ib + half >= height or i - half < 0 or i + half >= height:
                continue
            for u in range(-hx, hx + 1):
                j0 = max(0, -u)
                j1 = min(width, width - u)
                for j in range(j0, j1):
                    s = 0.0
                    for r in range(-half, half + 1):
                        s += a[i + r, j] * b[ib + r, j + u]
                    colsum[j] = s
                for j in range(max(j0 + half, half), min(j1 - half, width - half)):
                    if not (ok_a[i, j] and ok_b[ib, j + u]):
                        continue
                    s = 0.0
                    for c in range(-half, half + 1):
                        s += colsum[j + c]
                    cov = s / n - mean_a[i, j] * mean_b[ib, j + u]
                    corr[v + hy, u + hx, j] = cov * inv_sd_a[i, j] * inv_sd_b[ib, j + u]
        for j in range(0, width, step):
            if image[i, j]:
                dx[i, j], dy[i, j], conf[i, j], limit[i, j] = _best_match(corr, j, hy, hx)


@njit(cache=True)
def _best_match(corr, j, hy, hx):
    """Integer peak of the correlation surface at column j, parabola refinement, on-limit flags."""
    ny, nx = 2 * hy + 1, 2 * hx + 1
    bv, bu, bc = hy, hx, -2.0
    for y in range(ny):
        for x in range(nx):
            c = corr[y, x, j]
            if c > bc or (c == bc and abs(y - hy) + abs(x - hx) < abs(bv - hy) + abs(bu - hx)):
                bv, bu, bc = y, x, c
    if bc <= -2.0:  # no matchable window: zero displacement, zero confidence
        return 0.0, 0.0, 0.0, 0
    fx = 0.0
    fy = 0.0
    limit_x = bu == 0 or bu == nx - 1
    limit_y = bv == 0 or bv == ny - 1
    if not limit_x:
        fx = _parabola(corr[bv, bu - 1, j], bc, corr[bv, bu + 1, j])
    if not limit_y:
        fy = _parabola(corr[bv - 1, bu, j], bc, corr[bv + 1, bu, j])
    bits = (1 if limit_x else 0) + (2 if limit_y else 0)
    return bu - hx + fx, bv - hy + fy, min(max(bc, 0.0), 1.0) * 100.0, bits


@njit(cache=True)
def _parabola(cm, c0, cp):
    """Vertex offset of the parabola through (-1, cm), (0, c0), (1, cp), within [-0.5, 0.5]."""
    if cm <= -2.0 or cp <= -2.0:
        return 0.0
    den = cm - 2.0 * c0 + cp
    if den >= 0.0:
        return 0.0
    return min(max(0.5 * (cm - cp) / den, -0.5), 0.5)


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


def _vs(label: str, image: float, cand: float, fmt: str = "{:.6f}") -> str:
    return f"{label}\t= {fmt.format(image)} vs. {fmt.format(cand)} (*)"


def _moment_lines(image: dict, cand: dict) -> list[str]:
    return [
        _vs("RMS", image["rms"], cand["rms"]),
        _vs("MINIMUM", image["minimum"], cand["minimum"]),
        _vs("MAXIMUM", image["maximum"], cand["maximum"]),
        _vs("MEAN", image["mean"], cand["mean"]),
        _vs("STANDARD DEVIATION", image["std"], cand["std"], "{:.3f}"),
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
    text = f"GLOBAL DISPLACEMENT (dX, dY) = ({g['dx']:.6f}, {g['dy']:.6f}) pixels"
    if "modulus_m" in g:
        text += f" = ({g['dx_m']:.3f}, {g['dy_m']:.3f}) m, MODULUS = {g['modulus_m']:.3f} m"
    lines.append(text)
    return "\n".join(lines) + "\n"


@njit(cache=True)
def _cubic_weights(f):
    """Keys bicubic convolution weights (a = -0.5) of taps -1, 0, 1, 2 at fraction f."""
    w = np.empty(4)
    w[0] = ((-0.5 * f + 1.0) * f - 0.5) * f
    w[1] = (1.5 * f - 2.5) * f * f + 1.0
    w[2] = ((-1.5 * f + 2.0) * f + 0.5) * f
    w[3] = (0.5 * f - 0.5) * f * f
    return w


@njit(cache=True)
def _zncc_at(a, b, valid, i, j, sy, sx, half):
    """ZNCC of A's window at (i, j) with B's window displaced by (sy, sx) px, B sampled by
    bicubic interpolation; -2 when a tap leaves the image or touches background."""
    height, width = a.shape
    by, bx = int(math.floor(sy + 1e-9)), int(math.floor(sx + 1e-9))
    fy, fx = max(sy - by, 0.0), max(sx - bx, 0.0)
    wy, wx = _cubic_weights(fy), _cubic_weights(fx)
    r0, c0 = i + by - half - 1, j + bx - half - 1
    size = 2 * half + 1
    # taps with a zero weight (whole-pixel shifts) may lie outside the image
    ly, hy_ = (0, 3) if fy > 1e-9 else (1, 1)
    lx, hx_ = (0, 3) if fx > 1e-9 else (1, 1)
    if r0 + ly < 0 or c0 + lx < 0 or r0 + size - 1 + hy_ >= height \
            or c0 + size - 1 + hx_ >= width:
        return -2.0
    tmp = np.zeros((size + 3, size))
    for r in range(ly, size + hy_):
        for c in range(size):
            s = 0.0
            for m in range(lx, hx_ + 1):
                if not valid[r0 + r, c0 + c + m]:
                    return -2.0
                s += wx[m] * b[r0 + r, c0 + c + m]
            tmp[r, c] = s
    sa = sb = saa = sbb = sab = 0.0
    for r in range(size):
        for c in range(size):
            vb = wy[0] * tmp[r, c] + wy[1] * tmp[r + 1, c] + wy[2] * tmp[r + 2, c] \
                + wy[3] * tmp[r + 3, c]
            va = a[i - half + r, j - half + c]
            sa += va
            sb += vb
            saa += va * va
            sbb += vb * vb
            sab += va * vb
    n = size * size
    var_a, var_b = saa / n - (sa / n) ** 2, sbb / n - (sb / n) ** 2
    if var_a <= 1e-12 * (saa / n + 1e-300) or var_b <= 1e-12 * (sbb / n + 1e-300):
        return 0.0
    return (sab / n - sa * sb / (n * n)) / math.sqrt(var_a * var_b)


@njit(cache=True, parallel=True)
def _refine_on_grid(a, b, valid, ii, jj, half, hy, hx, res, dx, dy, conf):
    """Climb the ZNCC on the ``res`` grid from the parabola's estimate (8-neighbourhood moves,
    within 1 px of the start and inside the exploration window); write the refined peak."""
    span = int(round(1.0 / res))
    for k in prange(ii.shape[0]):
        i, j = ii[k], jj[k]
        ty0, tx0 = int(round(dy[i, j] / res)), int(round(dx[i, j] / res))
        seen = np.full((2 * span + 1, 2 * span + 1), -3.0)
        cy, cx = 0, 0
        best = _zncc_at(a, b, valid, i, j, ty0 * res, tx0 * res, half)
        if best <= -2.0:  # interpolation taps off the image: start from the whole-pixel peak
            ty0, tx0 = int(round(round(dy[i, j]) / res)), int(round(round(dx[i, j]) / res))
            best = _zncc_at(a, b, valid, i, j, ty0 * res, tx0 * res, half)
        seen[span, span] = best
        for _ in range(4 * span):
            my, mx, mbest = cy, cx, best
            for oy in range(-1, 2):
                for ox in range(-1, 2):
                    ny, nx = cy + oy, cx + ox
                    if abs(ny) > span or abs(nx) > span:
                        continue
                    if abs((ty0 + ny) * res) > hy or abs((tx0 + nx) * res) > hx:
                        continue
                    c = seen[ny + span, nx + span]
                    if c < -2.5:
                        c = _zncc_at(a, b, valid, i, j, (ty0 + ny) * res, (tx0 + nx) * res, half)
                        seen[ny + span, nx + span] = c
                    if c > mbest:
                        my, mx, mbest = ny, nx, c
            if my == cy and mx == cx:
                break
            cy, cx, best = my, mx, mbest
        if best > -2.0:
            dy[i, j] = (ty0 + cy) * res
            dx[i, j] = (tx0 + cx) * res
            conf[i, j] = min(max(best, 0.0), 1.0) * 100.0

"""``meris-ortho disparity``: ZNCC disparity of two images on the same grid (DISPAR, section 4.6).

Prints the statistics like the handbook's ``.sta`` logs; optionally writes the kept points
(tie-points above the confidence threshold) as CSV.
"""

from __future__ import annotations

import argparse
import logging
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import OptionsError
from ..geometry.earth import MEAN_EARTH_RADIUS

log = logging.getLogger("napari_meris_ortho")

#: sphere radius of the handbook (eq. 2) to turn degrees into metres for geographic grids


def register(subparsers: Any) -> None:
    """Add the ``disparity`` subcommand."""
    p = subparsers.add_parser(
        "disparity", help="ZNCC disparity analysis of two images (DISPAR)",
        description="Disparity of the second image relative to the first by zero-mean normalised "
        "cross-correlation (handbook section 4.6): dX along columns (east), dY along lines "
        "(south), sub-pixel 0.1 px, statistics as DISPAR's .sta logs.")
    p.add_argument("first", metavar="A.tif", help="reference image (GeoTIFF or any GDAL raster)")
    p.add_argument("second", metavar="B.tif", help="image whose displacement is measured")
    p.add_argument("--band", type=int, nargs="+", default=[1], metavar="N",
                   help="band of A (and of B if a second number is given; default 1)")
    p.add_argument("--stat-window", type=int, default=5, metavar="N",
                   help="statistical window size (odd, default 5)")
    p.add_argument("--explore", type=int, nargs=2, default=(9, 19), metavar=("LINES", "COLUMNS"),
                   help="exploration window height and width (odd, default 9 19, at most "
                   "129 129: displacements up to +-64 px)")
    p.add_argument("--threshold", type=float, default=95.0, metavar="PERCENT",
                   help="confidence threshold in %% (default 95)")
    p.add_argument("--step", type=int, default=1, metavar="N",
                   help="analyse every N-th line and column (default 1)")
    p.add_argument("--subpixel", choices=("grid", "parabola"), default="grid",
                   help="sub-pixel refinement: ZNCC on a 0.1-px grid (default) or parabola")
    p.add_argument("--pixel-size", type=float, nargs=2, default=None, metavar=("X", "Y"),
                   help="pixel size in metres (default: from the georeferencing)")
    p.add_argument("--vectors", default=None, metavar="OUT.csv",
                   help="write the kept points: line, column, x, y, dx, dy (px and m), confidence")
    p.add_argument("--report", default=None, metavar="OUT.sta", help="also write the log to a file")
    p.set_defaults(func=run)


def _read_band(path: str, band: int) -> tuple[np.ndarray, Any, Any]:
    """float64 band with nodata/NaN as background 0, its transform and CRS."""
    import rasterio
    from rasterio.errors import RasterioError

    from .._atomic import check_input_file

    check_input_file(path, "image")
    try:
        with rasterio.open(path) as ds:
            if not 1 <= band <= ds.count:
                raise OptionsError(f"{path}: no band {band} (the image has {ds.count})")
            data = ds.read(band).astype(np.float64)
            nodata, transform, crs = ds.nodata, ds.transform, ds.crs
    except (RasterioError, OSError) as exc:
        raise OptionsError(f"{path}: cannot read image ({exc})") from exc
    if nodata is not None and not math.isnan(nodata):
        data[data == nodata] = 0.0
    data[~np.isfinite(data)] = 0.0
    return data, transform, crs


def same_grid_hint(first: str) -> str:
    """How to bring an image onto the grid of ``first``: the end of the grid error."""
    return (f": the two images must be on the same grid; map the product with --like {first} "
            f"(meris-ortho map PRODUCT --like {first} -o B.tif), or warp B with "
            f"gdalwarp/rio warp --like {first}")


def pixel_size_metres(transform: Any, crs: Any, height: int) -> tuple[float, float] | None:
    """(x, y) pixel size in metres: projected units, or degrees on the handbook sphere at the
    grid's centre latitude; None without a CRS."""
    if crs is None:
        return None
    dx, dy = abs(transform.a), abs(transform.e)
    if crs.is_geographic:
        lat = transform.f + transform.e * height / 2.0
        k = math.pi / 180.0 * MEAN_EARTH_RADIUS
        return dx * k * math.cos(math.radians(lat)), dy * k
    factor = crs.linear_units_factor[1] if crs.linear_units_factor else 1.0
    return dx * factor, dy * factor


def run(args: argparse.Namespace) -> int:
    from .._atomic import atomic_path, check_distinct, check_writable_dir
    from ..analysis.disparity import disparity
    from ..progress import tqdm_progress

    check_distinct({"--vectors": args.vectors, "--report": args.report},
                   {"input image": [args.first, args.second]})

    if len(args.band) > 2:
        raise OptionsError("--band takes one or two band numbers (A [B])")
    for out in (args.vectors, args.report):
        if out:
            check_writable_dir(out)
    band_a, band_b = args.band[0], args.band[-1]
    a, transform, crs = _read_band(args.first, band_a)
    b, transform_b, _ = _read_band(args.second, band_b)
    if a.shape != b.shape:
        raise OptionsError(f"{args.second}: grid {b.shape} differs from {args.first} {a.shape}"
                           f"{same_grid_hint(args.first)}")
    if not transform.almost_equals(transform_b):
        raise OptionsError(f"{args.second}: georeferencing differs from {args.first}"
                           f"{same_grid_hint(args.first)}")
    if args.pixel_size and not all(math.isfinite(v) and v > 0 for v in args.pixel_size):
        raise OptionsError(f"--pixel-size must be two sizes > 0 in metres, got "
                           f"{' '.join(f'{v:g}' for v in args.pixel_size)}")
    size = tuple(args.pixel_size) if args.pixel_size else pixel_size_metres(transform, crs,
                                                                            a.shape[0])
    with tqdm_progress("disparity", enabled=not args.quiet, unit="lines") as progress:
        result = disparity(a, b, stat_window=args.stat_window, explore=tuple(args.explore),
                           threshold=args.threshold, pixel_size_m=size, step=args.step,
                           subpixel=args.subpixel, progress=progress)
    text = result.report(title=f"{Path(args.first).name} / {Path(args.second).name}")
    print(text, end="")
    if args.report:
        with atomic_path(args.report) as tmp:
            tmp.write_text(text)
    if args.vectors:
        _write_vectors(args.vectors, result, transform)
        log.info("%d tie-points written to %s", result.stats["candidate_pixels"], args.vectors)
    return 0


def _write_vectors(path: str, result: Any, transform: Any) -> None:
    from .._atomic import atomic_path
    from ..display import fixed

    v = result.vectors()
    x = transform.c + (v[:, 1] + 0.5) * transform.a + (v[:, 0] + 0.5) * transform.b
    y = transform.f + (v[:, 1] + 0.5) * transform.d + (v[:, 0] + 0.5) * transform.e
    sx, sy = result.pixel_size_m or (math.nan, math.nan)
    with atomic_path(path) as tmp, open(tmp, "w") as f:
        f.write("line,column,x,y,dx_px,dy_px,dx_m,dy_m,confidence\n")
        for (line, col, dx, dy, conf), xi, yi in zip(v, x, y, strict=True):
            f.write(f"{int(line)},{int(col)},{xi:.6f},{yi:.6f},{fixed(dx, 1)},{fixed(dy, 1)},"
                    f"{fixed(dx * sx, 3)},{fixed(dy * sy, 3)},{conf:.6f}\n")

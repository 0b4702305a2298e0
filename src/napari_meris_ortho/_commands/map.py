"""``meris-ortho map``: orthorectified mapping of one product to a GeoTIFF (MERSYN use case 3).

The log follows Appendix B: pixel size, image size and origin, facet-search shares, the
prediction/correction histogram, the processed points and the elapsed time.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
from pathlib import Path
from typing import Any

from ..errors import OptionsError
from ..options import PARALLAX_CHOICES, Geolocation, SearchMethod, choices
from ._options import (
    add_bands_option,
    add_grid_options,
    add_height_options,
    add_sampling_option,
    check_heights,
    grid_from_args,
)

log = logging.getLogger("napari_meris_ortho")
#: dataset tag explaining the band values and the per-band ``sf_rad`` tags
RADIANCE_NOTE = {
    "uint16": "TOA radiance = counts x scale (GDAL scale = sf_rad of the source product, "
              "Scaling Factor GADS); counts 0 = background (nodata)",
    "float32": "TOA radiance (float32, 0 = background) = counts x sf_rad of the source "
               "product (Scaling Factor GADS); no further scaling applies",
}


def register(subparsers: Any) -> None:
    """Add the ``map`` subcommand."""
    p = subparsers.add_parser(
        "map", help="orthorectify one product to a GeoTIFF",
        description="Orthorectify a MERIS L1b product onto a map grid (handbook sections 3.1-3.4, "
        "MERSYN use case 3) and write the radiances as a GeoTIFF.")
    p.add_argument("product", metavar="PRODUCT", help="MERIS L1b product: N1 file or .SEN3 "
                   "directory")
    p.add_argument("-o", "--output", required=True, metavar="OUT.tif", help="output GeoTIFF")
    add_height_options(
        p, dem_help="DEM (repeatable; tried in order at each point, then the tie points)",
        elevation_help="elevation source (default dem; without --dem: the tie points)")
    add_grid_options(p, "EPSG:4326", "output CRS (default EPSG:4326)")
    add_bands_option(p, "bands to map, e.g. 3,5,7 (default all 15)")
    add_sampling_option(p, "resampling (default nearest, as MERSYN)")
    p.add_argument("--tolerance", type=float, default=0.01, metavar="PX",
                   help="prediction/correction tolerance in product pixels (MERSYN: 0.1)")
    p.add_argument("--parallax", choices=choices(PARALLAX_CHOICES), default="handbook",
                   help="parallax model: handbook sphere R=6370997 m or WGS84 radii")
    p.add_argument("--geolocation", choices=choices(Geolocation), default=None,
                   help="tie-point position interpolation: bilinear lon/lat (eq. 4a-4b) or "
                   "ecef unit vectors (default: bilinear with --parallax handbook, ecef with "
                   "ellipsoid); or pixel: the product's own per-pixel terrain-corrected "
                   "geolocation (MER_FRG_1P/MER_FSG_1P, .SEN3; no DEM, no parallax)")
    p.add_argument("--search", choices=choices(SearchMethod), default="primary",
                   help="antecedent search: primary grid + Newton (fast, maps every output "
                   "point seen by the product) or MERSYN's facet search in the loop (as "
                   "MERSYN, it leaves background where the zero-height position or the first "
                   "correction falls outside the tie-point grid: the outer half pixel and, on "
                   "high relief, terrain within one parallax shift of the near-nadir edge)")
    p.add_argument("--dtype", choices=("uint16", "float32"), default="uint16",
                   help="band values: uint16 counts with GDAL scale = sf_rad (default; GDAL, "
                   "QGIS, rasterio read radiances) or float32 radiances")
    p.add_argument("--compress", choices=("zstd", "deflate"), default="zstd",
                   help="Cloud-Optimized GeoTIFF compression, with a predictor (default zstd)")
    p.add_argument("--diagnostics", action="store_true",
                   help="also write OUT_diagnostics.tif: antecedent line/column, elevation, its "
                   "source, iterations, parallax shift east/north (m)")
    p.add_argument("--stats-json", default=None, metavar="FILE", help="write statistics as JSON")
    p.set_defaults(func=run)


def _diagnostics_path(out: Path) -> Path:
    return out.with_name(out.stem + "_diagnostics" + (out.suffix or ".tif"))


def _check(args: argparse.Namespace) -> Any:
    """Every check that needs no product read, before any work (Appendix C parameter checks)."""
    from .._atomic import check_distinct, check_writable_dir
    from ..dem.geoid import split_datum

    outputs = {"-o": args.output, "--stats-json": args.stats_json,
               "the diagnostics output": (_diagnostics_path(Path(args.output))
                                          if args.diagnostics else None)}
    dems = [split_datum(d)[0] for d in args.dem]  # PATH[:egm96|:ellipsoid]
    check_distinct(outputs, {"input product": [args.product], "DEM": dems})
    for out in outputs.values():
        if out is not None:
            check_writable_dir(out)
    check_heights(args)
    if not (math.isfinite(args.tolerance) and args.tolerance > 0):
        raise OptionsError(f"--tolerance must be > 0 product pixels, got {args.tolerance}")
    return grid_from_args(args)


def log_lines(stats: dict[str, Any], default_pixel: bool) -> list[str]:
    """The Appendix B style log of a mapping run."""
    from ..ortho import histogram_lines

    s = stats
    out = []
    if default_pixel:
        out.append("SETTING PIXEL SIZE DEFAULT VALUES")
    out += [f"PIXEL HEIGHT = {s['pixel_height']:.6f}", f"PIXEL WIDTH  = {s['pixel_width']:.6f}",
            "", "COMPUTING IMAGE SIZE AND ORIGIN",
            f"UL: X = {s['ul_x']:.6f}  Y = {s['ul_y']:.6f}",
            f"LR: X = {s['lr_x']:.6f}  Y = {s['lr_y']:.6f}",
            f"IMAGE HEIGHT = {s['ul_y'] - s['lr_y']:.6f} ({s['crs']} units)",
            f"IMAGE WIDTH  = {s['lr_x'] - s['ul_x']:.6f}",
            f"LINE NUMBER  = {s['output_lines']}", f"PIXEL NUMBER = {s['output_columns']}"]
    fs = dict(s["facet_search"])
    primary = fs.pop("primary grid", None)
    fs.pop("not found", None)
    n = sum(fs.values()) or 1
    nb = fs.get("4-connex", 0) + fs.get("8-connex", 0)
    what = "primary-grid nodes" if primary is not None else "points"
    out.append(f"facet search ({what}): -same= {100 * fs.get('same', 0) / n:.1f}% "
               f"-neighbour= {100 * nb / n:.1f}% -all= {100 * fs.get('all', 0) / n:.1f}%")
    if primary is not None:
        out.append(f"points predicted from the primary grid = {primary}")
    sec = s["seconds"]
    out.append(f"Total elapsed time={sec['total']:.3f} seconds "
               f"(prediction/correction {sec['prediction_correction']:.3f} s, "
               f"resampling {sec['resample']:.3f} s, DEM {sec['dem']:.3f} s)")
    out.append("")
    out += histogram_lines(s["iterations_histogram"])
    out.append("")
    total = s["output_points"] or 1
    seg = s["points_in_boundary"] or 1
    out.append(f"ORTHORECTIFICATION PROCESSING = {'YES' if s['orthorectification'] else 'NO'}")
    out.append(f"NUMBER OF PROCESSED POINTS IN SEGMENT = {s['processed_points']} "
               f"({100 * s['processed_points'] / total:.1f}% of image, "
               f"{100 * s['processed_points'] / seg:.1f}% of segment boundary)")
    if s.get("elevation_sources"):
        out.append("ELEVATION SOURCES = " + ", ".join(
            f"{k}: {v}" for k, v in s["elevation_sources"].items()))
    return out


#: bands gathered together (one pass over the antecedent index for several bands)
GATHER_GROUP = 4


def _bands_streamed(args: argparse.Namespace, ante: Any, progress: Any) -> Any:
    """One band at a time (uint16 counts or float32 radiances), gathered ``GATHER_GROUP`` at
    a time, reporting progress."""
    nr, bands = ante.grid.height, ante.bands
    for g in range(0, len(bands), GATHER_GROUP):
        group = bands[g:g + GATHER_GROUP]
        if args.dtype == "uint16":
            values = list(ante.counts(group))
        else:
            radiance = ante.radiance(group)
            values = [radiance[b] for b in group]
        for k, v in enumerate(values):
            yield v
            progress(nr + g + k + 1, nr + len(bands))


def _write(args: argparse.Namespace, ante: Any, progress: Any) -> None:
    """The bands streamed into a Cloud-Optimized GeoTIFF, then the diagnostics."""
    import numpy as np

    from ..engine.resample import overview_level
    from ..ortho import RADIANCE_UNITS, band_metadata
    from ..output.geotiff import meris_band_description, write_cog

    bands, stats = ante.bands, ante.stats
    wl = stats.get("wavelengths", {})
    sf = stats.get("scale_factors", {})
    counts = args.dtype == "uint16"
    write_cog(args.output, _bands_streamed(args, ante, progress), ante.grid, count=len(bands),
              dtype=args.dtype, scales=[sf[b] for b in bands] if counts else None,
              offsets=[0.0] * len(bands) if counts else None,
              units=[RADIANCE_UNITS] * len(bands),
              descriptions=[meris_band_description(b, wl.get(b)) for b in bands],
              band_metadata=band_metadata(stats, bands), compress=args.compress,
              halve=overview_level,
              metadata={"product": stats["product"],
                        "product_name": stats.get("product_name", ""),
                        "radiance": RADIANCE_NOTE[args.dtype], "elevation": args.elevation,
                        "parallax": args.parallax, "geolocation": stats["geolocation"],
                        "tolerance_px": args.tolerance,
                        "sampling": args.sampling, "software": "napari-meris-ortho map"})
    if args.diagnostics:
        names = ("line", "col", "elevation", "elevation_source", "iterations", "shift_east_m",
                 "shift_north_m")
        arrays = (np.nan_to_num(ante.diagnostics[n].astype(np.float32), nan=0.0)
                  for n in names)
        write_cog(_diagnostics_path(Path(args.output)), arrays, ante.grid, count=len(names),
                  nodata=None, descriptions=list(names), dtype="float32",
                  compress=args.compress, overview_resampling="nearest", halve=overview_level,
                  metadata={"elevation_source": "k >= 0: DEM k; -1: tie points; -2: none"})


def _warn_unused_dems(dems: list[str], sources: dict[str, int]) -> None:
    """Warn about each DEM the user listed that gave no height (outside the product, a wrong
    CRS tag, only no data or implausible heights)."""
    for key, count in sources.items():
        index, _, _ = key.partition(":")
        if index.isdigit() and int(index) < len(dems) and count == 0:
            log.warning("warning: DEM %s contributed no height (outside the product, wrong CRS, "
                        "or only no data / heights outside -500..9000 m)", dems[int(index)])


def _map(args: argparse.Namespace, grid: Any) -> Any:
    """Precompute the antecedents and stream the bands into the output (``Antecedents``)."""
    from ..ortho import precompute
    from ..progress import tqdm_progress

    show = log.isEnabledFor(logging.INFO)
    with tqdm_progress("map", enabled=show, unit="step") as progress:
        ante = precompute(args.product, grid=grid, dems=args.dem, elevation=args.elevation,
                          sampling=args.sampling, bands=args.bands, tolerance=args.tolerance,
                          parallax=args.parallax, diagnostics=args.diagnostics,
                          progress=progress, method=args.search, crs=args.crs,
                          pixel_size=args.pixel_size, geolocation=args.geolocation,
                          max_pixels=args.max_pixels)
        _warn_unused_dems(args.dem, ante.stats.get("elevation_sources") or {})
        _write(args, ante, progress)
    return ante


def run(args: argparse.Namespace) -> int:
    """Run ``meris-ortho map``."""
    from .._atomic import atomic_path
    from ..warmup import compile_late_in_background, stop

    grid = _check(args)
    late = compile_late_in_background()  # first run: the other core compiles the late kernels
    try:
        ante = _map(args, grid)
    finally:
        stop(late)
    stats = ante.finish()
    if args.stats_json:
        with atomic_path(args.stats_json) as tmp:
            tmp.write_text(json.dumps(stats, indent=2, default=str))
    for line in log_lines(stats, grid is None and args.pixel_size is None):
        log.info(line)
    log.info("wrote %s (%d x %d, %d bands)", args.output, ante.grid.width, ante.grid.height,
             len(ante.bands))
    return 0

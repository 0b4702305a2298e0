"""``meris-ortho map``: orthorectified mapping of one product to a GeoTIFF (MERSYN use case 3).

The log follows Appendix B: pixel size, image size and origin, facet-search shares, the
prediction/correction histogram, the processed points and the elapsed time.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
from typing import Any

from ..bands import MAX_BANDS
from ..errors import OptionsError
from ..options import PARALLAX_CHOICES, Geolocation, Hidden, OrthoOptions, SearchMethod, choices
from ._options import (
    DEFAULT_GRID,
    add_bands_option,
    add_grid_options,
    add_height_options,
    add_sampling_option,
    grid_from_args,
    ortho_options,
)

log = logging.getLogger("napari_meris_ortho")
#: the ``software`` tag of the files ``map`` writes
SOFTWARE = "napari-meris-ortho map"
#: the output CRS without --crs or --like (MERSYN's geographic grid)
DEFAULT_CRS = "EPSG:4326"


def register(subparsers: Any) -> None:
    """Add the ``map`` subcommand."""
    p = subparsers.add_parser(
        "map", help="orthorectify one product to a GeoTIFF",
        description="Orthorectify a MERIS L1b or OLCI Level 1B product onto a map grid (handbook "
        "sections 3.1-3.4, "
        "MERSYN use case 3) and write the radiances as a GeoTIFF. " + DEFAULT_GRID)
    p.add_argument("product", metavar="PRODUCT", help="MERIS L1b product (N1 file or .SEN3 "
                   "directory) or OLCI Level 1B product (.SEN3 directory or zip)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.tif", help="output GeoTIFF")
    add_height_options(
        p, dem_help="DEM (repeatable; tried in order at each point, then the tie points)",
        elevation_help="elevation source (default: dem with a --dem, else the tie points; "
        "dem given explicitly needs a --dem)")
    add_grid_options(p)
    add_bands_option(p, "bands to map, e.g. 3,5,7 (default all: 15 MERIS, 21 OLCI)",
                     n_bands=MAX_BANDS)
    add_sampling_option(p, "resampling (default nearest, as MERSYN)")
    p.add_argument("--tolerance", type=float, default=OrthoOptions.tolerance, metavar="PX",
                   help="prediction/correction tolerance in product pixels (default "
                   f"{OrthoOptions.tolerance:g}, a tenth of MERSYN's 0.1: the loop ends "
                   "closer to the antecedent)")
    p.add_argument("--parallax", choices=choices(PARALLAX_CHOICES), default="handbook",
                   help="parallax model: handbook sphere R=6370997 m or WGS84 radii")
    p.add_argument("--geolocation", choices=choices(Geolocation), default=None,
                   help="tie-point position interpolation: bilinear lon/lat (eq. 4a-4b) or "
                   "ecef unit vectors (default: bilinear with --parallax handbook, ecef with "
                   "ellipsoid); or pixel: the product's own per-pixel terrain-corrected "
                   "geolocation (MER_FRG_1P/MER_FSG_1P/MER_RRG_1P, .SEN3; with --dem: moved "
                   "back to the ellipsoid, then the DEM's parallax)")
    p.add_argument("--search", choices=choices(SearchMethod), default="primary",
                   help="antecedent search: primary grid + Newton (fast, maps every output "
                   "point seen by the product) or MERSYN's facet search in the loop (as "
                   "MERSYN, it leaves background where the zero-height position or the first "
                   "correction falls outside the tie-point grid: the outer half pixel and, on "
                   "high relief, terrain within one parallax shift of the near-nadir edge)")
    p.add_argument("--hidden", choices=choices(Hidden), default=OrthoOptions.hidden.value,
                   help="ground hidden from the sensor by the relief in front of it (the line of "
                   "sight to the satellite marched over the DEMs; with a --dem): mask leaves it "
                   "no data (default; the pixel that would be taken shows the relief in front "
                   "a second time), keep maps it as MERSYN does; both count it in the log "
                   "(points hidden by the relief), --stats-json and the tags, and flag it in "
                   "the diagnostics' hidden band")
    p.add_argument("--dtype", choices=("uint16", "float32"), default="uint16",
                   help="band values: uint16 counts with GDAL scale = sf_rad (default; GDAL, "
                   "QGIS, rasterio read radiances) or float32 radiances")
    p.add_argument("--compress", choices=("zstd", "deflate"), default="zstd",
                   help="Cloud-Optimized GeoTIFF compression, with a predictor (default zstd)")
    p.add_argument("--diagnostics", action="store_true",
                   help="also write OUT_diagnostics.tif: antecedent line/column, elevation, its "
                   "source, iterations, parallax shift east/north (m), hidden ground (1)")
    p.add_argument("--stats-json", default=None, metavar="FILE", help="write statistics as JSON")
    p.set_defaults(func=run)


def _check(args: argparse.Namespace) -> Any:
    """Every check that needs no product read, before any work (Appendix C parameter checks)."""
    from ..ortho.writing import check_geotiff_name, check_outputs, diagnostics_path

    check_outputs({"-o": args.output, "--stats-json": args.stats_json,
                   "the diagnostics output": (diagnostics_path(args.output)
                                              if args.diagnostics else None)},
                  [args.product], args.dem, references=[args.like] if args.like else [])
    check_geotiff_name("-o", args.output)
    if not (math.isfinite(args.tolerance) and args.tolerance > 0):
        raise OptionsError(f"--tolerance must be > 0 product pixels, got {args.tolerance}")
    args.options = ortho_options(args, n_bands=MAX_BANDS, tolerance=args.tolerance,
                                 parallax=args.parallax, geolocation=args.geolocation,
                                 method=args.search, diagnostics=args.diagnostics,
                                 hidden=args.hidden)
    return grid_from_args(args)


def _map(args: argparse.Namespace, grid: Any) -> Any:
    """Precompute the antecedents and stream the bands into the output (``Antecedents``), a
    bar per stage: reading, locating (output rows), resampling and writing (bands)."""
    from ..ortho import precompute
    from ..ortho.core import band_count
    from ..ortho.writing import write_map
    from ..products.open import read_product
    from ..progress import stages

    with stages(enabled=log.isEnabledFor(logging.INFO)) as bars:
        bars.show("reading the product and DEMs")
        product = read_product(args.product)
        # the bands the engine counts after the rows: all of the product's (15 MERIS, 21 OLCI)
        n = len(args.bands) if args.bands else band_count(product)
        # the engine counts the output rows, then the bands: each stage counts its own
        locate = bars.stage("locating (prediction/correction)", "rows",
                            count=lambda done, total: (min(done, total - n), total - n))
        ante = precompute(product, grid=grid, dems=args.dem, options=args.options,
                          progress=locate, crs=args.crs or DEFAULT_CRS,
                          pixel_size=args.pixel_size,
                          max_pixels=args.max_pixels)
        bars.close()
        for text in ante.stats.gap_warnings():
            log.warning("warning: %s", text)
        for dem in ante.stats.unused_dems():
            log.warning("warning: DEM %s contributed no height (outside the product, wrong "
                        "CRS, or only no data / heights outside -500..9000 m)", dem)
        bands = len(ante.bands) if args.bands is None else n
        write = bars.stage(
            "resampling, writing band", "bands",
            count=lambda done, total: (done - (total - bands), bands),
            describe=lambda done, total: (f"resampling, writing band {done + 1} of {total}"
                                          if done < total else
                                          f"finishing {os.path.basename(args.output)}"))
        write(0, bands)  # drawn before the first band is sampled
        write_map(args.output, ante, dtype=args.dtype, compress=args.compress,
                  diagnostics=args.diagnostics, software=SOFTWARE,
                  progress=write, order=args.bands)
    return ante


def run(args: argparse.Namespace) -> int:
    """Run ``meris-ortho map``."""
    from .._atomic import atomic_path
    from ..ortho.description import stats_document
    from ..ortho.writing import describe_mapped
    from ..warmup import compile_late_in_background, stop

    grid = _check(args)
    late = compile_late_in_background()  # first run: the other core compiles the late kernels
    try:
        ante = _map(args, grid)
    finally:
        stop(late)
    stats = ante.finish()
    if args.stats_json:  # the bands in file order, described as the file describes them
        described = describe_mapped(ante, args.dtype, order=args.bands, software=SOFTWARE)
        with atomic_path(args.stats_json) as tmp:
            tmp.write_text(json.dumps(stats_document(stats, described), indent=2, default=str))
    for line in stats.log_lines(grid is None and args.pixel_size is None):
        log.info(line)
    log.info("wrote %s (%d x %d, %d bands)", args.output, ante.grid.width, ante.grid.height,
             len(ante.bands))
    return 0

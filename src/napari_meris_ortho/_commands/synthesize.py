"""``meris-ortho synthesize``: merge many products into a synthesis (MERSYN use cases 1-2).

Exit code 0 when every product was merged, 1 when some product failed (reported and skipped),
2 on bad options (handbook Appendix C parameter checks).
"""

from __future__ import annotations

import argparse
import logging
from typing import Any

from ..errors import OptionsError
from ..options import MergeRule, choices
from ._options import (
    add_bands_option,
    add_grid_options,
    add_height_options,
    add_sampling_option,
    check_heights,
    grid_from_args,
)

log = logging.getLogger("napari_meris_ortho")


def register(subparsers: Any) -> None:
    """Add the ``synthesize`` subcommand."""
    p = subparsers.add_parser(
        "synthesize", help="orthorectify products and merge them into a synthesis",
        description="Orthorectify MERIS L1b products onto a synthesis grid and merge them by "
        "minimum radiance or maximum NDVI (handbook section 3.1, Appendix C).")
    p.add_argument("products", nargs="+", metavar="PRODUCT.N1", help="MERIS L1b products")
    p.add_argument("--algorithm", choices=choices(MergeRule), default=None,
                   help="selection algorithm (new synthesis: min-radiance; update: the input's)")
    p.add_argument("--out", required=True, metavar="DIR", help="output synthesis directory")
    p.add_argument("--input", metavar="DIR", default=None,
                   help="synthesis to update (may equal --out); grid and bands come from it")
    add_height_options(
        p, dem_help="DEM (repeatable; the first holding a point wins)",
        elevation_help="heights: the DEMs then the tie points (default), tie points only, "
        "or none (no orthorectification)")
    add_sampling_option(p, "resampling of the radiances (MERSYN: nearest)")
    add_bands_option(p, "bands of a new synthesis, e.g. 3,5,7,13 (default all 15)")
    p.add_argument("--reject-bright", action="store_true",
                   help="keep BRIGHT-flagged pixels (clouds) out as well")
    p.add_argument("--tile", type=int, default=1024, metavar="PX",
                   help="tile size in pixels, multiple of 256 (bounds the memory)")
    grid = p.add_argument_group("grid of a new synthesis (refused with --input)")
    add_grid_options(grid, None, "output CRS (default EPSG:4326)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..progress import tqdm_progress
    from ..synthesis import synthesize

    if args.input is not None and (args.ul or args.lr or args.crs or args.pixel_size
                                   or args.bands):
        raise OptionsError("when --input is given, --crs, --pixel-size, --ul, --lr and --bands "
                           "come from the input synthesis and shall not be given")
    check_heights(args)
    grid = grid_from_args(args)
    with tqdm_progress("products", enabled=not args.quiet, unit="product") as progress:
        result = synthesize(
            args.products, args.out, algorithm=args.algorithm, input=args.input, grid=grid,
            crs=None if grid is not None else args.crs,
            pixel_size=None if grid is not None else args.pixel_size, dems=args.dem,
            elevation=args.elevation, sampling=args.sampling, bands=args.bands,
            reject_bright=args.reject_bright, tile=args.tile, progress=progress)
    if result.generation is not None:
        log.info("synthesis %s (%s) written to %s: %d product(s) merged", result.generation,
                 result.algorithm, result.path, len(result.merged))
    if result.failed:
        log.warning("%d of %d product(s) failed and were skipped", len(result.failed),
                    len(result.reports))
        return 1
    return 0

"""``meris-ortho synthesize``: merge many products into a synthesis (MERSYN use cases 1-2).

Exit code 0 when every product was merged, 1 when some product failed (reported and skipped),
2 on bad options (handbook Appendix C parameter checks).
"""

from __future__ import annotations

import argparse
import logging
from typing import Any

from ..errors import OptionsError

log = logging.getLogger("napari_meris_ortho")


def _bands(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.replace(",", " ").split()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"bands {text!r}: expected e.g. 3,5,7") from None
    if not values or any(not 1 <= v <= 15 for v in values):
        raise argparse.ArgumentTypeError(f"bands {text!r}: MERIS bands are 1..15")
    return values


def register(subparsers: Any) -> None:
    """Add the ``synthesize`` subcommand."""
    p = subparsers.add_parser(
        "synthesize", help="orthorectify products and merge them into a synthesis",
        description="Orthorectify MERIS L1b products onto a synthesis grid and merge them by "
        "minimum radiance or maximum NDVI (handbook section 3.1, Appendix C).")
    p.add_argument("products", nargs="+", metavar="PRODUCT.N1", help="MERIS L1b products")
    p.add_argument("--algorithm", choices=("min-radiance", "max-ndvi"), default=None,
                   help="selection algorithm (new synthesis: min-radiance; update: the input's)")
    p.add_argument("--out", required=True, metavar="DIR", help="output synthesis directory")
    p.add_argument("--input", metavar="DIR", default=None,
                   help="synthesis to update (may equal --out); grid and bands come from it")
    p.add_argument("--dem", action="append", default=[], metavar="PATH",
                   help="DEM (repeatable; the first holding a point wins)")
    p.add_argument("--elevation", choices=("none", "tiepoints", "dem"), default="dem",
                   help="heights: the DEMs then the tie points (default), tie points only, "
                   "or none (no orthorectification)")
    p.add_argument("--sampling", choices=("nearest", "bilinear", "bicubic"), default="nearest",
                   help="resampling of the radiances (MERSYN: nearest)")
    p.add_argument("--bands", type=_bands, default=None, metavar="LIST",
                   help="bands of a new synthesis, e.g. 3,5,7,13 (default all 15)")
    p.add_argument("--reject-bright", action="store_true",
                   help="keep BRIGHT-flagged pixels (clouds) out as well")
    p.add_argument("--tile", type=int, default=1024, metavar="PX",
                   help="tile size in pixels, multiple of 256 (bounds the memory)")
    grid = p.add_argument_group("grid of a new synthesis (refused with --input)")
    grid.add_argument("--crs", default=None, help="output CRS (default EPSG:4326)")
    grid.add_argument("--pixel-size", type=float, default=None, metavar="SIZE",
                      help="pixel size in CRS units (default: 260 m FR / 1040 m RR)")
    grid.add_argument("--ul", type=float, nargs=2, default=None, metavar=("X", "Y"),
                      help="upper-left corner")
    grid.add_argument("--lr", type=float, nargs=2, default=None, metavar=("X", "Y"),
                      help="lower-right corner")
    p.set_defaults(func=run)


def _grid(args: argparse.Namespace) -> Any:
    """An explicit grid from --ul/--lr (with --crs and --pixel-size), else None."""
    if args.ul is None and args.lr is None:
        return None
    if args.ul is None or args.lr is None or args.pixel_size is None:
        raise OptionsError("--ul and --lr need each other and --pixel-size")
    from ..engine.grid import OutputGrid

    return OutputGrid.from_extent(args.crs or "EPSG:4326", args.ul, args.lr, args.pixel_size)


def run(args: argparse.Namespace) -> int:
    from ..progress import tqdm_progress
    from ..synthesis import synthesize

    if args.input is not None and (args.ul or args.lr or args.crs or args.pixel_size
                                   or args.bands):
        raise OptionsError("when --input is given, --crs, --pixel-size, --ul, --lr and --bands "
                           "come from the input synthesis and shall not be given")
    grid = _grid(args)
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

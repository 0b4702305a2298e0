"""``meris-ortho synthesize``: merge many products into a synthesis store (MERSYN use cases
1-2) with dask workers.

Exit code 0 when every product was merged (or was already in the synthesis), 1 when some
product failed or missed the synthesis grid (reported and skipped), 2 on bad options
(handbook Appendix C parameter checks), an unreachable scheduler or a store that is not a
synthesis.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from typing import Any

from ..cores import usable_cores
from ..errors import OptionsError
from ..options import Geolocation, MergeRule, StoreCodec, choices
from ._options import (
    DEFAULT_GRID,
    add_bands_option,
    add_grid_options,
    add_height_options,
    add_sampling_option,
    grid_from_args,
    ortho_options,
    positive_int,
)

log = logging.getLogger("napari_meris_ortho")


def register(subparsers: Any) -> None:
    """Add the ``synthesize`` subcommand."""
    p = subparsers.add_parser(
        "synthesize", help="orthorectify products and merge them into a synthesis",
        description="Orthorectify MERIS L1b products onto a synthesis grid and merge them by "
        "minimum radiance or maximum NDVI (handbook section 3.1, Appendix C).")
    p.add_argument("products", nargs="+", metavar="PRODUCT",
                   help="MERIS L1b products (N1 files or .SEN3 directories)")
    p.add_argument("--algorithm", choices=choices(MergeRule), default=None,
                   help="selection algorithm (new synthesis: min-radiance; update: the input's)")
    p.add_argument("--out", required=True, metavar="STORE",
                   help="output synthesis store (an Icechunk repository directory)")
    p.add_argument("--input", metavar="STORE", default=None,
                   help="synthesis to update (may equal --out: one more commit; else it is "
                   "copied to --out first); grid and bands come from it")
    add_height_options(
        p, dem_help="DEM (repeatable; the first holding a point wins)",
        elevation_help="heights: the DEMs then the tie points (default; with no --dem, the "
        "tie points), tie points only, or none (no orthorectification); dem given explicitly "
        "needs a --dem")
    add_sampling_option(p, "resampling of the radiances (MERSYN: nearest)")
    p.add_argument("--geolocation", choices=choices(Geolocation), default=None,
                   help="location model: tie points (bilinear, ecef; default) or pixel, the "
                   "products' per-pixel terrain-corrected geolocation (FRG/FSG N1, .SEN3)")
    add_bands_option(p, "bands of a new synthesis, e.g. 3,5,7,13 (default all 15)")
    p.add_argument("--reject-bright", action="store_true",
                   help="keep BRIGHT-flagged pixels (clouds) out as well")
    p.add_argument("--tile", type=int, default=1024, metavar="PX",
                   help="tile size (store chunk) of a new synthesis in pixels, multiple of 256 "
                   "(bounds the memory of a task)")
    p.add_argument("--codec", choices=choices(StoreCodec), default=None,
                   help="how a new synthesis compresses its bands and NDVI: zstd (default; "
                   "every Zarr v3 reader) or delta-zstd (a delta filter first: about 12 %% "
                   "fewer bytes, read by zarr-python but not by readers of the Zarr v3 core "
                   "codecs only); an update keeps its store's")
    p.add_argument("--keep", type=positive_int("a number of commits >= 1"), default=None,
                   metavar="N", help="after the commit, keep the newest N commits of the store "
                   "and free what only older ones held (as synthesis-prune; default: keep all)")
    engine = p.add_argument_group("workers (dask.distributed)")
    engine.add_argument("--workers", type=int, default=None, metavar="N",
                        help="worker processes of an embedded LocalCluster (default: the "
                        "number of cores; 0: everything in this process)")
    engine.add_argument("--scheduler", default=os.environ.get("DASK_SCHEDULER_ADDRESS"),
                        metavar="tcp://HOST:PORT",
                        help="use this existing dask scheduler (default: "
                        "$DASK_SCHEDULER_ADDRESS); the store and products must be on storage "
                        "all workers see")
    grid = p.add_argument_group("grid of a new synthesis (refused with --input)",
                                DEFAULT_GRID.replace("product's", "first product's"))
    add_grid_options(grid)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..progress import stages
    from ..synthesis.api import synthesize

    if args.input is not None and (args.ul or args.lr or args.crs or args.pixel_size
                                   or args.like or args.bands or args.codec):
        raise OptionsError("when --input is given, --like, --crs, --pixel-size, --ul, --lr, "
                           "--bands and --codec come from the input synthesis and shall not be "
                           "given")
    options = ortho_options(args, geolocation=args.geolocation)
    grid = grid_from_args(args)
    if args.scheduler and args.workers is not None:
        raise OptionsError("--workers and --scheduler exclude each other (the cluster of the "
                           "scheduler has its own workers)")
    workers = usable_cores() if args.workers is None else args.workers
    n = len(args.products)
    with stages(enabled=not args.quiet) as bars:
        bars.show(f"reading {n} product(s)")
        # the bar counts tasks: a product's part of a tile orthorectified, a tile merged; its
        # label the products whose every tile is merged
        state = {"merged": 0, "of": n}

        def merged(done: int, total: int) -> None:
            state["merged"], state["of"] = done, total

        merge = bars.stage(
            "products merged", "tasks (tile parts + tile merges)",
            describe=lambda done, total: (f"products merged {state['merged']}/{state['of']}"
                                          if done < total else "committing the synthesis"))
        result = synthesize(
            args.products, args.out, algorithm=args.algorithm, input=args.input, grid=grid,
            crs=None if grid is not None else args.crs,
            pixel_size=None if grid is not None else args.pixel_size, dems=args.dem,
            options=options, bands=args.bands, reject_bright=args.reject_bright,
            tile=args.tile, progress=merge, workers=0 if args.scheduler else workers,
            scheduler=args.scheduler or None, max_pixels=args.max_pixels, codec=args.codec,
            keep=args.keep, merged=merged)
    if result.snapshot is not None:
        log.info("synthesis %s (%s) committed to %s: %d product(s) merged", result.snapshot,
                 result.algorithm, result.path, len(result.merged))
    if result.pruned is not None:
        log.info("kept %d commit(s), expired %d: %.1f MB freed", result.pruned.kept,
                 result.pruned.expired, result.pruned.bytes_deleted / 1e6)
    if result.skipped:
        log.warning("%d product(s) already in the synthesis, skipped: %s", len(result.skipped),
                    ", ".join(r.product_name for r in result.skipped))
    if result.outside:
        log.warning("%d product(s) outside the synthesis grid, skipped: %s",
                    len(result.outside), ", ".join(r.product for r in result.outside))
    if result.failed:
        log.warning("%d of %d product(s) failed and were skipped", len(result.failed),
                    len(result.reports))
    if result.snapshot is None and (result.failed or result.outside):
        print(f"meris-ortho: error: nothing merged into {args.out}: "
              f"{len(result.failed)} product(s) failed, {len(result.outside)} outside the grid "
              "(their reasons above)", file=sys.stderr)
    return 1 if result.failed or result.outside else 0

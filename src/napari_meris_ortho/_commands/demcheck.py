"""``meris-ortho demcheck``: DEM quality control against GPS points (DEMCHK, section 5.2).

Prints Appendix F's logs (one per interpolation method) and table 4; optionally the histogram of
fig. 64 as a PNG.
"""

from __future__ import annotations

import argparse
import logging
from typing import Any

log = logging.getLogger("napari_meris_ortho")


def register(subparsers: Any) -> None:
    """Add the ``demcheck`` subcommand."""
    p = subparsers.add_parser(
        "demcheck", help="DEM quality control against GPS points (DEMCHK)",
        description="Compare GPS points (lon, lat, ellipsoidal height) with DEM heights "
        "interpolated by nearest neighbour, bilinear or bicubic interpolation (handbook section "
        "5.2, Appendix F): arithmetic and quadratic means, standard deviation, minimum, maximum "
        "of H - h.")
    p.add_argument("points", metavar="POINTS.csv",
                   help="GPS points: CSV with lon, lat, h columns, or a DEMCHK listing")
    p.add_argument("--dem", action="append", required=True, metavar="PATH[:DATUM]",
                   help="DEM (repeatable; tried in order at each point); ':egm96' or "
                   "':ellipsoid' names the vertical datum of its heights (default: SRTM30 and "
                   "Copernicus egm96, GETASSE30 ellipsoid, GeoTIFF from its vertical CRS)")
    p.add_argument("--method", choices=("nearest", "bilinear", "bicubic", "all"), default="all",
                   help="interpolation of the DEM (default all three)")
    p.add_argument("--geoid", nargs="?", const="egm96", default=None, metavar="FILE",
                   help="the DEM heights are above the geoid, h = H_dem + N: without FILE every "
                   "DEM without a ':datum' is taken as EGM96 (proj-data's egm96_15.gtx, as "
                   "--dem PATH:egm96); with FILE a raster of undulations N (m) added to the "
                   "stored heights")
    p.add_argument("--plot", default=None, metavar="FILE.png",
                   help="write the histogram of the differences (fig. 64)")
    p.add_argument("--bin-width", type=float, default=10.0, metavar="M",
                   help="histogram bin width in metres (default 10)")
    p.add_argument("--report", default=None, metavar="FILE", help="also write the log to a file")
    p.add_argument("--no-listing", action="store_true", help="omit the per-GCP listing")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from .._atomic import atomic_path, check_distinct, check_writable_dir
    from ..analysis.demcheck import demcheck, plot_histogram, read_points
    from ..dem.geoid import split_datum

    check_distinct({"--plot": args.plot, "--report": args.report},
                   {"GPS point file": [args.points],
                    "DEM": [split_datum(d)[0] for d in args.dem],
                    "geoid": [args.geoid] if args.geoid else []})

    for out in (args.plot, args.report):
        if out:
            check_writable_dir(out)
    methods = ("nearest", "bilinear", "bicubic") if args.method == "all" else (args.method,)
    points = read_points(args.points)
    result = demcheck(points, args.dem, methods=methods, geoid=args.geoid)
    text = result.report(listing=not args.no_listing)
    if len(methods) > 1:
        text += "\nSTATISTICS OF ELEVATION DIFFERENCES (m)\n" + result.summary_table() + "\n"
    print(text, end="")
    if args.report:
        with atomic_path(args.report) as tmp:
            tmp.write_text(text)
    if args.plot:
        plot_histogram(result, args.plot, bin_width=args.bin_width)
        log.info("histogram written to %s", args.plot)
    return 0

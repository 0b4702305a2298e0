"""``meris-ortho export``: a synthesis store (or one of its snapshots) as a Cloud-Optimized
GeoTIFF."""

from __future__ import annotations

import argparse
import logging
from typing import Any

from ._options import add_bands_option

log = logging.getLogger("napari_meris_ortho")


def register(subparsers: Any) -> None:
    """Add the ``export`` subcommand."""
    p = subparsers.add_parser(
        "export", help="write bands of a synthesis store as a Cloud-Optimized GeoTIFF",
        description="Write chosen bands (or the NDVI, count or winning-product layer) of a "
        "synthesis store as a Cloud-Optimized GeoTIFF.")
    p.add_argument("store", metavar="STORE", help="synthesis store")
    p.add_argument("-o", "--out", required=True, metavar="OUT.tif", help="output COG")
    add_bands_option(p, "bands to write, e.g. 7,13 (default: every band of the synthesis)")
    p.add_argument("--layer", choices=("ndvi", "count", "product"), default=None,
                   help="write this layer instead of bands")
    p.add_argument("--dtype", choices=("uint16", "float32"), default=None,
                   help="band values: uint16 counts with GDAL scale (default, as map writes "
                   "them; GDAL, QGIS, rasterio read radiances) or float32 radiances; NDVI: "
                   "uint16 Appendix C codes with the GDAL scale and offset that give -1..1 "
                   "(default) or float32 NDVI with nodata NaN")
    p.add_argument("--at", metavar="SNAPSHOT", default=None,
                   help="export this snapshot (see synthesis-log) instead of the latest commit")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..progress import stages
    from ..synthesis.export import export_cog
    from ..synthesis.reading import open_synthesis

    store = open_synthesis(args.store, at=args.at)
    with stages(enabled=not args.quiet) as bars:
        if args.layer is not None:  # one plane: written whole, then its overviews
            bars.show(f"writing the {args.layer} layer")
            progress = None
        else:
            # export_cog counts (k, n + 1) as band k goes to the writer, then (1, 1) when
            # the COG is complete: the bar counts bands written
            n = len(dict.fromkeys(args.bands or store.bands))
            progress = bars.stage(
                "writing bands", "bands",
                count=lambda done, total: (n, n) if total == 1 else (done - 1, n),
                describe=lambda done, total: (f"writing band {done + 1} of {total}"
                                              if done < total else f"{total} bands written"))
        out = export_cog(store, args.out, bands=args.bands, layer=args.layer, dtype=args.dtype,
                         progress=progress)
    log.info("%s written (snapshot %s)", out, store.snapshot)
    return 0

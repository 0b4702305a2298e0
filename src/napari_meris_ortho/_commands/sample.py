"""``meris-ortho sample [NAME] --out DIR``: generate a simulated MERIS or OLCI L1b scene with
its DEMs and reference image and print where everything is."""

from __future__ import annotations

import argparse
import json
import logging
from typing import Any

from ..errors import OptionsError

log = logging.getLogger("napari_meris_ortho")


def register(subparsers: Any) -> None:
    """Add the ``sample`` subcommand."""
    p = subparsers.add_parser(
        "sample",
        help="generate a simulated MERIS or OLCI L1b product with exact ground truth",
        description="Generate a named simulated scene (a MERIS N1 product, or an OLCI EFR/ERR "
        ".SEN3 product for the olci-* scenes; DEM exports, reference image). Outputs are "
        "cached and reused when complete.",
    )
    p.add_argument("name", nargs="?", default="fr-alps", metavar="NAME",
                   help="scene name (default fr-alps); --list shows them")
    p.add_argument("--out", metavar="DIR", default=None,
                   help="output directory (default: the cache, $MERIS_ORTHO_CACHE or "
                   "~/.cache/napari-meris-ortho/<scene>-<hash>)")
    p.add_argument("--set", metavar="JSON", default=None, dest="overrides",
                   help='config overrides as JSON, e.g. \'{"clouds": {"seed": 2, '
                   '"fraction": 0.3}}\'')
    p.add_argument("--fsg", action="store_true",
                   help="also write the per-pixel geolocated AMORGOS-like N1: MER_FRG_1P (FR "
                   "scenes) or MER_RRG_1P (RR scenes)")
    p.add_argument("--sen3", action="store_true",
                   help="also write the 4th-reprocessing-like ME_1_FRG___/ME_1_RRG___ .SEN3 "
                   "directory (per-pixel truth geolocation)")
    p.add_argument("--list", action="store_true", help="list the scene names and exit")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..bands import Sensor
    from ..progress import tqdm_progress
    from ..simulate import generate_scene, scene_names
    from ..simulate.scene import check_overrides, resolve_config, sensor_of

    if args.list:
        print("\n".join(scene_names()))
        return 0
    scene: str | dict = args.name
    if args.overrides:
        try:
            over = json.loads(args.overrides)
        except json.JSONDecodeError as exc:
            raise OptionsError(f"--set: not valid JSON ({exc})") from None
        if not isinstance(over, dict):
            raise OptionsError("--set: expected a JSON object")
        check_overrides(args.name, over)
        scene = {"base": args.name, **over}
    if (args.fsg or args.sen3) and sensor_of(resolve_config(scene)) is not Sensor.MERIS:
        raise OptionsError(f"--fsg and --sen3 write MERIS products; scene {args.name!r} is an "
                           "OLCI product, which carries its per-pixel geolocation already")
    quiet = getattr(args, "quiet", False)
    with tqdm_progress(f"sample {args.name}", enabled=not quiet, unit="%") as progress:
        result = generate_scene(scene, out_dir=args.out, progress=progress)
    extra = {}
    if args.fsg or args.sen3:
        from ..simulate.geocorrected import write_geocorrected

        with tqdm_progress("per-pixel geolocated products", enabled=not quiet) as progress:
            extra = write_geocorrected(result, fsg=args.fsg, sen3=args.sen3, progress=progress)
    print(f"scene      {result.name}")
    print(f"directory  {result.out_dir}")
    print(f"product    {result.product_path}")
    for key, path in extra.items():
        print(f"{key:<10} {path}")
    for key, path in result.dem_paths.items():
        print(f"dem        {key:<15} {path}")
    if result.reference_path is not None:
        print(f"reference  {result.reference_path}")
    return 0

"""``meris-ortho synthesis-log``: the commits of a synthesis store and their products."""

from __future__ import annotations

import argparse
from typing import Any


def register(subparsers: Any) -> None:
    """Add the ``synthesis-log`` subcommand."""
    p = subparsers.add_parser(
        "synthesis-log", help="list the commits of a synthesis store and their products",
        description="List the commits of a synthesis store, newest first: snapshot id, time, "
        "message and every product of the run with its status.")
    p.add_argument("store", metavar="STORE", help="synthesis store")
    p.add_argument("--at", metavar="SNAPSHOT", default=None,
                   help="start from this snapshot instead of the latest commit")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..synthesis.reading import open_synthesis

    store = open_synthesis(args.store, at=args.at)
    grid = store.grid
    bands = f"bands {list(store.bands)}"
    if store.sensor.value != "MERIS":  # a store of another band set names its bands
        bands = f"{store.sensor.value} {bands} ({', '.join(store.band_names)})"
    print(f"synthesis {args.store}: {store.algorithm}, {bands}, "
          f"{grid.width} x {grid.height} pixels, {len(store.products)} product(s), "
          f"codec {store.codec}")
    for commit in store.history():
        print(f"\nsnapshot {commit.snapshot}  {commit.written_at:%Y-%m-%d %H:%M:%S %Z}")
        print(f"    {commit.message}")
        for p in commit.products:
            extra = ""
            if p.get("status") == "merged":
                extra = (f" index {p.get('index')}, validated {p.get('validated')}, "
                         f"added {p.get('added')}")
            elif p.get("error"):
                extra = f" ({p['error']})"
            if p.get("sensor"):  # a product of another sensor than MERIS
                extra = f" {p['sensor']}{extra}"
            print(f"    {p.get('status', '?'):>24s}  {p.get('product_name') or p.get('product')}"
                  f"  {p.get('sensing_start', '')}{extra}")
    return 0

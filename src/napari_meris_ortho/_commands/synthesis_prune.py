"""``meris-ortho synthesis-prune``: keep the newest commits of a synthesis store, free the rest."""

from __future__ import annotations

import argparse
from typing import Any

from ._options import positive_int


def register(subparsers: Any) -> None:
    """Add the ``synthesis-prune`` subcommand."""
    p = subparsers.add_parser(
        "synthesis-prune", help="keep the newest commits of a synthesis store, free the rest",
        description="Keep the newest N commits of a synthesis store and delete the chunk "
        "versions and metadata only older commits held (Icechunk's expire_snapshots and "
        "garbage_collect; also the branches of killed runs). The synthesis is unchanged; "
        "synthesis-log and --at reach the commits kept only. Refused while a run uses the "
        "store.")
    p.add_argument("store", metavar="STORE", help="synthesis store")
    p.add_argument("--keep", type=positive_int("a number of commits >= 1"), required=True,
                   metavar="N", help="commits to keep, newest first (1: the current state only)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..synthesis.api import prune_synthesis

    pruned = prune_synthesis(args.store, args.keep)
    print(f"{args.store}: kept {pruned.kept} commit(s), expired {pruned.expired}; deleted "
          f"{pruned.files_deleted} object(s) ({pruned.chunks_deleted} chunks), "
          f"{pruned.bytes_deleted / 1e6:.1f} MB freed"
          + (f"; removed {pruned.run_branches} branch(es) of killed runs"
             if pruned.run_branches else ""))
    return 0

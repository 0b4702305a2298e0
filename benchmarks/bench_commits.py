"""What a season of updates costs the store itself: many small Icechunk commits, measured.

    .venv/bin/python benchmarks/bench_commits.py [--commits 2000] [--chunks 64]

A synthesis update is one Icechunk commit that rewrites the chunks of the tiles its product
touches. This benchmark isolates the store's own cost from the orthorectification: a repository
shaped like a synthesis (``--arrays`` uint16 arrays of ``--chunks`` x ``--chunks`` chunks of
256 x 256, as the layers of a store), then ``--commits`` commits, each writing ``--per-commit``
chunks of every array (a product's tiles) at changing places. Prints, per block of commits, the
median seconds of one commit (session, writes, commit), the seconds to open the repository and
read its history, and the repository's size and file count, so the cost at 2 000 commits is
measured rather than assumed.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np


def size(path: Path) -> tuple[float, int]:
    files = [p for p in path.rglob("*") if p.is_file()]
    return sum(p.stat().st_size for p in files) / 1e6, len(files)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--commits", type=int, default=2000)
    parser.add_argument("--chunks", type=int, default=64, help="chunks per side of each array")
    parser.add_argument("--arrays", type=int, default=18, help="arrays (15 bands, count, ...)")
    parser.add_argument("--per-commit", type=int, default=4, help="chunks written per array")
    parser.add_argument("--every", type=int, default=250, help="report every N commits")
    args = parser.parse_args()

    import icechunk
    import zarr

    icechunk.set_logs_filter("error")
    chunk = 256
    # chunk contents compress to almost nothing: the cost measured is the store's bookkeeping
    # (manifests, snapshots, refs), which grows with commits, not the bytes of the chunks
    tile = np.full((chunk, chunk), 1, np.uint16)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "store"
        repo = icechunk.Repository.create(icechunk.local_filesystem_storage(str(path)))
        session = repo.writable_session("main")
        root = zarr.open_group(session.store, mode="w")
        n = args.chunks * chunk
        for k in range(args.arrays):
            root.create_array(f"a{k:02d}", shape=(n, n), chunks=(chunk, chunk), dtype="uint16",
                              fill_value=0)
        session.commit("layout")
        print(f"{args.arrays} arrays of {n} x {n} ({args.chunks}^2 chunks of {chunk}^2), "
              f"{args.per_commit} chunks per array per commit")
        print(f"{'commits':>8s} {'commit s (median)':>18s} {'open+history s':>15s} "
              f"{'store MB':>9s} {'files':>7s}")
        times: list[float] = []
        for c in range(1, args.commits + 1):
            t0 = time.perf_counter()
            session = repo.writable_session("main")
            group = zarr.open_group(session.store, mode="r+")
            for k in range(args.arrays):
                array = group[f"a{k:02d}"]
                for m in range(args.per_commit):
                    i, j = divmod((c * args.per_commit + m) % (args.chunks ** 2), args.chunks)
                    array[i * chunk:(i + 1) * chunk, j * chunk:(j + 1) * chunk] = tile * (c % 997)
            session.commit(f"update {c}", metadata={"meris_ortho": {"products": [c]}})
            times.append(time.perf_counter() - t0)
            if c % args.every == 0 or c == args.commits:
                t1 = time.perf_counter()
                again = icechunk.Repository.open(icechunk.local_filesystem_storage(str(path)))
                history = list(again.ancestry(branch="main"))
                opened = time.perf_counter() - t1
                mb, files = size(path)
                print(f"{c:8d} {statistics.median(times[-args.every:]):18.3f} {opened:15.3f} "
                      f"{mb:9.1f} {files:7d}  ({len(history)} snapshots)")


if __name__ == "__main__":
    main()

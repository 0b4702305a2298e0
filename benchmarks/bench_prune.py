"""What a season costs the disk, and what ``synthesis-prune`` gives back.

    .venv/bin/python benchmarks/bench_prune.py [--scene fr-alps] [--products 6] [--on europe]

``--products`` cloudy dates of ``--scene`` (as ``bench_synthesis.py`` makes them) merged one
commit each into a maximum-NDVI store (15 bands) on the first product's footprint, or with
``--on europe`` on Europe at 260 m, in this process: the seconds of each commit and the store's
bytes and files on disk after it (Icechunk keeps every chunk version an update replaced, for
the history). Then ``prune_synthesis(keep=1)``: its seconds, what it deleted, the bytes and
files left, and a check that every layer reads the same as before the prune. Wall times depend
on whatever else the machine runs.
"""

from __future__ import annotations

import argparse
import hashlib
import tempfile
import time
from pathlib import Path

from bench_synthesis import EUROPE, PIXEL_260M, products, store_bytes


def digest(path: Path) -> str:
    """One hash over every layer of the synthesis at its latest commit."""
    from napari_meris_ortho.synthesis.reading import open_synthesis

    store = open_synthesis(path)
    h = hashlib.sha256()
    for name in store.layers():
        h.update(name.encode())
        h.update(store.read(name).tobytes())
    return h.hexdigest()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="fr-alps")
    parser.add_argument("--products", type=int, default=6)
    parser.add_argument("--on", choices=("footprint", "europe"), default="footprint")
    args = parser.parse_args()

    from napari_meris_ortho.geometry.grid import OutputGrid
    from napari_meris_ortho.ortho import product_grid
    from napari_meris_ortho.products.n1 import read_product
    from napari_meris_ortho.synthesis.api import prune_synthesis, synthesize

    paths = products(args.products, args.scene)
    grid = (product_grid(read_product(paths[0]), "EPSG:4326") if args.on == "footprint" else
            OutputGrid("EPSG:4326", EUROPE[0], EUROPE[1], PIXEL_260M, PIXEL_260M,
                       round(EUROPE[2] / PIXEL_260M), round(EUROPE[3] / PIXEL_260M)))
    print(f"{len(paths)} {args.scene} products, 15 bands, maximum NDVI, grid {grid.width} x "
          f"{grid.height} ({args.on}), one commit each, in this process")
    print(f"\n{'commit':>8s} {'seconds':>8s} {'store MB':>9s} {'files':>7s}")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "season"
        for k, path in enumerate(paths):
            t0 = time.perf_counter()
            if k == 0:
                synthesize([path], out, grid=grid, algorithm="max-ndvi", elevation="tiepoints")
            else:
                synthesize([path], out, input=out, elevation="tiepoints")
            seconds = time.perf_counter() - t0
            size, files = store_bytes(out)
            print(f"{k + 1:8d} {seconds:8.2f} {size / 1e6:9.1f} {files:7d}")
        before = digest(out)
        t0 = time.perf_counter()
        pruned = prune_synthesis(out, 1)
        seconds = time.perf_counter() - t0
        size, files = store_bytes(out)
        same = digest(out) == before
    print(f"\nsynthesis-prune --keep 1: {seconds:.2f} s, expired {pruned.expired} commit(s), "
          f"deleted {pruned.files_deleted} objects ({pruned.chunks_deleted} chunks, "
          f"{pruned.bytes_deleted / 1e6:.1f} MB); store {size / 1e6:.1f} MB, {files} files; "
          f"layers {'unchanged' if same else 'CHANGED'}")


if __name__ == "__main__":
    main()

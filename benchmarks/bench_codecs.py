"""Compression of a synthesis store's radiance chunks by candidate codecs.

    .venv/bin/python benchmarks/bench_codecs.py [--scene fr-alps] [--bands 2,7,13]

Merges two simulated ``--scene`` products into a maximum-NDVI store on the first one's
footprint (as ``bench_synthesis.py``'s update does), takes every whole 512 x 512 chunk of the
full-resolution ``--bands`` (uint16 counts, background 0) and prints, per codec, the encoded
bytes as a fraction of the raw ones and the encoding speed (raw MB per second, one thread):
zstd at levels 1-5 (the store's default: level 1), Blosc zstd with byte or bit shuffle, a
delta filter (``numcodecs.delta``, the store's ``--codec delta-zstd``: along the rows of the
chunk) or a column delta before zstd, and pcodec when it is installed (not a dependency).
Below them, the floor of a lossless coder that predicts each count from its neighbours: the
0-order entropy (bits per 16-bit count, as a fraction of the raw bytes) of the residual of the
left neighbour and of the MED predictor of JPEG-LS (LOCO-I): what an ideal entropy coder of
those residuals would write. No codec of the store can do much better on these chunks.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bench_synthesis import products


def chunks_of(scene: str, bands: list[int]) -> list[np.ndarray]:
    import zarr

    from napari_meris_ortho.ortho import product_grid
    from napari_meris_ortho.products.n1 import read_product
    from napari_meris_ortho.synthesis.api import synthesize
    from napari_meris_ortho.synthesis.store import BRANCH, CHUNK, open_repository

    paths = products(2, scene)
    grid = product_grid(read_product(paths[0]), "EPSG:4326")
    tmp = Path(tempfile.mkdtemp())
    try:
        out = tmp / "store"
        synthesize(paths, out, grid=grid, bands=sorted(set(bands) | {7, 13}),
                   algorithm="max-ndvi", tile=1024, elevation="tiepoints")
        session = open_repository(out).readonly_session(branch=BRANCH)
        root = zarr.open_group(session.store, mode="r")
        out_chunks = []
        for b in bands:
            a = root[f"band_{b:02d}"][:]
            out_chunks += [np.ascontiguousarray(a[i:i + CHUNK, j:j + CHUNK])
                           for i in range(0, a.shape[0] - CHUNK + 1, CHUNK)
                           for j in range(0, a.shape[1] - CHUNK + 1, CHUNK)]
        return out_chunks
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def codecs() -> dict[str, Callable[[np.ndarray], bytes]]:
    from numcodecs import Blosc, Delta, Zstd

    delta = Delta(dtype="<u2")
    out: dict[str, Callable[[np.ndarray], bytes]] = {}
    for level in (1, 3, 5):
        out[f"zstd {level}"] = Zstd(level=level).encode
    for shuffle, name in ((Blosc.SHUFFLE, "shuffle"), (Blosc.BITSHUFFLE, "bitshuffle")):
        for level in (1, 5):
            out[f"blosc zstd {level} {name}"] = Blosc(cname="zstd", clevel=level,
                                                      shuffle=shuffle).encode
    for level in (1, 3):
        z = Zstd(level=level)
        out[f"delta (rows) + zstd {level}"] = lambda c, z=z: z.encode(delta.encode(c))
    z1 = Zstd(level=1)
    out["delta (columns) + zstd 1"] = lambda c: z1.encode(delta.encode(
        np.ascontiguousarray(c.T)))
    try:
        from pcodec import ChunkConfig, standalone
    except ImportError:
        return out
    for level in (4, 8):
        config = ChunkConfig(compression_level=level)
        out[f"pcodec {level}"] = lambda c, cfg=config: standalone.simple_compress(c.ravel(), cfg)
    return out


def residual_entropy(chunks: list[np.ndarray], predictor: str) -> float:
    """Bits per count of the 0-order entropy of ``predictor``'s residual over all chunks (the
    first row and column of each chunk are left out: they have no full neighbourhood)."""
    histogram: dict[int, int] = {}
    for c in chunks:
        a = c.astype(np.int32)
        here, west, north, northwest = a[1:, 1:], a[1:, :-1], a[:-1, 1:], a[:-1, :-1]
        if predictor == "left":
            guess = west
        else:  # MED: min/max of west and north at an edge, else the planar west + north - nw
            high, low = np.maximum(west, north), np.minimum(west, north)
            guess = np.where(northwest >= high, low,
                             np.where(northwest <= low, high, west + north - northwest))
        values, counts = np.unique(here - guess, return_counts=True)
        for v, n in zip(values.tolist(), counts.tolist(), strict=True):
            histogram[v] = histogram.get(v, 0) + n
    n = np.array(list(histogram.values()), dtype=np.float64)
    p = n / n.sum()
    return float(-(p * np.log2(p)).sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="fr-alps")
    parser.add_argument("--bands", default="2,7,13")
    args = parser.parse_args()
    chunks = chunks_of(args.scene, [int(b) for b in args.bands.split(",")])
    raw = sum(c.nbytes for c in chunks)
    print(f"{len(chunks)} chunks of 512 x 512 uint16 counts ({raw / 1e6:.0f} MB), "
          f"{np.mean([(c == 0).mean() for c in chunks]):.2f} of the pixels background")
    print(f"\n{'codec':>28s} {'of raw':>7s} {'MB/s':>6s}")
    for name, encode in codecs().items():
        t0 = time.perf_counter()
        size = sum(len(encode(c)) for c in chunks)
        seconds = time.perf_counter() - t0
        print(f"{name:>28s} {size / raw:7.3f} {raw / seconds / 1e6:6.0f}")
    for predictor, name in (("left", "left neighbour"), ("med", "MED (JPEG-LS)")):
        bits = residual_entropy(chunks, predictor)
        print(f"{'entropy, ' + name:>28s} {bits / 16:7.3f} {'':>6s}  ({bits:.2f} bits per count)")


if __name__ == "__main__":
    main()

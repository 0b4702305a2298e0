"""Benchmark of the tiled synthesis (handbook section 3.1, use cases 1-2): peak memory and time.

    .venv/bin/python benchmarks/bench_synthesis.py [--bands 15] [--tile 1024] [--products 3]
                                                    [--scene fr-small|fr-alps]

Each case runs in a fresh process (peak RSS = ``VmHWM`` of that process) and merges the
same simulated FR products (``--scene``: fr-small, 320 x 513 pixels, or fr-alps, 2241 x 2241;
a clear date and cloudy dates of it) into a maximum-NDVI synthesis, first as a new synthesis
and then as an update (``--input``):

- ``untiled``: for reference, one ``orthorectify()`` of the first product (no synthesis);
- ``local``: the first product's footprint at 260 m;
- ``continent``: Europe at 260 m (50 x 35 deg, 21384 x 14969 pixels): held whole in memory,
  its layers would need (4 bytes x bands + 2 + 2) x 320 M pixels.

The peak memory of both cases should be about the same: only the tiles the products touch
are ever in memory (and on disk, the GeoTIFFs being sparse).

Measured (2 cores shared with other jobs; fr-alps, 15 bands, per product; times are noisy):
untiled orthorectify 2.1 s, peak 1216 MB; tile 1024: local 5.4 s / 612 MB, continent
6.6 s / 619 MB (its layers whole: 19.5 GB); tile 512: 11 s / 450 MB for both grids.
Most of the tile overhead is ``orthorectify`` reading every band of the whole product at
each call.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

NO_EXPORTS = {"getasse30": False, "getasse30_beam": False, "srtm30": False,
              "geotiff_utm": False, "reference": False}
PIXEL_260M = 0.0023382372764265  # 260 m on the sphere R = 6 370 997 m (engine.grid)
CASES = {"untiled": None, "local": None, "continent": (-10.0, 70.0, 50.0, 35.0)}


def products(n: int, scene: str) -> list[str]:
    from napari_meris_ortho.simulate.scene import generate_scene

    out = []
    for k in range(n):
        clouds = None if k == 0 else {"fraction": 0.4, "scale_km": 20.0, "seed": 10 * k}
        cfg = {"base": scene, "exports": NO_EXPORTS, "clouds": clouds}
        out.append(str(generate_scene(cfg).product_path))
    return out


def peak_rss_mb() -> float:
    """High-water mark of this process's resident memory (``VmHWM``: per address space, so a
    child started with exec does not inherit its parent's peak as ``ru_maxrss`` does)."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError("no VmHWM in /proc/self/status")


def run_untiled(paths: list[str], band_list: list[int]) -> dict:
    """Reference: one untiled orthorectify() of the first product on its footprint grid."""
    from napari_meris_ortho.ortho import orthorectify

    rss0 = peak_rss_mb()
    t0 = time.perf_counter()
    result = orthorectify(paths[0], bands=band_list, elevation="tiepoints")
    t1 = time.perf_counter()
    grid = result.grid
    whole = grid.width * grid.height * (4 * len(band_list) + 2 + 2)
    return {"case": "untiled", "size": f"{grid.width} x {grid.height}",
            "bands": len(band_list), "new_s": t1 - t0, "update_s": float("nan"),
            "baseline_mb": rss0, "peak_mb": peak_rss_mb(),
            "whole_in_memory_mb": whole / 2**20, "disk_mb": 0.0}


def run_case(case: str, paths: list[str], bands: int, tile: int) -> dict:
    """One case in this process: new synthesis of the first product, update with the others."""
    from napari_meris_ortho.geometry.grid import OutputGrid
    from napari_meris_ortho.synthesis import open_synthesis, synthesize

    if CASES[case] is None:  # the first product's footprint
        from napari_meris_ortho.io.n1 import read_product
        from napari_meris_ortho.synthesis import _new_grid

        grid = _new_grid(read_product(paths[0]), "EPSG:4326", None)
    else:
        x0, y0, width_deg, height_deg = CASES[case]
        grid = OutputGrid("EPSG:4326", x0, y0, PIXEL_260M, PIXEL_260M,
                          round(width_deg / PIXEL_260M), round(height_deg / PIXEL_260M))
    band_list = sorted(set(range(1, min(bands, 15) + 1)) | {7, 13})
    if case == "untiled":
        return run_untiled(paths, band_list)
    rss0 = peak_rss_mb()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "syn"
        t0 = time.perf_counter()
        synthesize(paths[:1], out, grid=grid, bands=band_list, algorithm="max-ndvi", tile=tile,
                   elevation="tiepoints")
        t1 = time.perf_counter()
        result = synthesize(paths[1:], out, input=out, tile=tile, elevation="tiepoints")
        t2 = time.perf_counter()
        store = open_synthesis(out)
        disk = sum(p.stat().st_size for p in store.generation_dir.iterdir())
        merged = sum(r.validated for r in result.merged)
    whole = grid.width * grid.height * (4 * len(band_list) + 2 + 2)
    return {"case": case, "size": f"{grid.width} x {grid.height}", "bands": len(band_list),
            "new_s": t1 - t0, "update_s": t2 - t1, "baseline_mb": rss0,
            "peak_mb": peak_rss_mb(),
            "whole_in_memory_mb": whole / 2**20, "disk_mb": disk / 2**20,
            "validated_points_update": merged}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bands", type=int, default=15, help="bands 1..N (plus 7 and 13)")
    parser.add_argument("--tile", type=int, default=1024)
    parser.add_argument("--products", type=int, default=3)
    parser.add_argument("--scene", default="fr-small", help="simulated scene (fr-alps: full FR)")
    parser.add_argument("--case", choices=tuple(CASES), default=None, help=argparse.SUPPRESS)
    parser.add_argument("--paths", nargs="*", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case is not None:  # child process: one case, JSON on stdout
        print(json.dumps(run_case(args.case, args.paths, args.bands, args.tile)))
        return
    paths = products(args.products, args.scene)
    rows = []
    for case in CASES:
        cmd = [sys.executable, __file__, "--case", case, "--bands", str(args.bands),
               "--tile", str(args.tile), "--paths", *paths]
        done = subprocess.run(cmd, check=True, capture_output=True, text=True)
        rows.append(json.loads(done.stdout.strip().splitlines()[-1]))
    print(f"{'case':10s} {'grid':>15s} {'bands':>5s} {'new s':>7s} {'update s':>8s} "
          f"{'base MB':>8s} {'peak MB':>8s} {'whole MB':>9s} {'disk MB':>8s}")
    for r in rows:
        print(f"{r['case']:10s} {r['size']:>15s} {r['bands']:5d} {r['new_s']:7.2f} "
              f"{r['update_s']:8.2f} {r['baseline_mb']:8.0f} {r['peak_mb']:8.0f} "
              f"{r['whole_in_memory_mb']:9.0f} {r['disk_mb']:8.1f}")


if __name__ == "__main__":
    main()

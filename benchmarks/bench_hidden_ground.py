"""Hidden ground of the tie-point geolocation with DEMs: accuracy against the simulator's
truth and the time ``meris-ortho map`` takes with the DEM.

    python benchmarks/bench_hidden_ground.py accuracy [--scene fr-steep --scene fr-alps]
    python benchmarks/bench_hidden_ground.py timing --old OLD/src --new NEW/src [--pairs 5]

``accuracy`` maps each scene with its truth DEM (the package on ``PYTHONPATH``) and compares,
per output point whose ground lies in the product, the hidden-ground mask with
``SimulatedScene.seen_from_sensor`` (a 5 m march over the truth DEM; cached beside the scene):
recall (truly hidden points flagged), false alarms (seen points flagged, share of the seen
points), hidden points still mapped (share of the truly hidden ones) and the RMS distance (px)
of the antecedents of the seen and mapped points to the true ones. A package without the
hidden-ground option gives the RMS alone.

``timing`` runs ``meris-ortho map PRODUCT --dem DEM`` of both scenes with two source trees in
turn (old, new, old, new, ...: paired runs on a shared machine) and prints the median seconds of
each and their ratio.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SCENES = ("fr-steep", "fr-alps")


def _truth(scene, grid):
    """Per output point: DEM height, true antecedent, in the product, seen (cached)."""
    lon, lat = grid.lonlat()
    cache = scene.out_dir / (f"hidden_truth_{grid.width}x{grid.height}_"
                             f"{grid.x0:.6f}_{grid.y0:.6f}_{grid.dx:.8f}.npz")
    if cache.exists():
        z = np.load(cache)
        return z["h"], z["tl"], z["tc"], z["inside"], z["seen"]
    h = scene.dem_height(lon, lat)
    tl, tc = scene.true_antecedent(lon, lat, h)
    g = scene.geometry
    inside = ((tl >= -0.5) & (tl < g.lines - 0.5) & (tc >= -0.5) & (tc < g.columns - 0.5)
              & np.isfinite(h))
    seen = np.zeros(inside.shape, bool)
    seen[inside] = scene.seen_from_sensor(lon[inside], lat[inside], h[inside], tl[inside],
                                          tc[inside], step=5.0)
    np.savez(cache, h=h, tl=tl, tc=tc, inside=inside, seen=seen)
    return h, tl, tc, inside, seen


def accuracy(names: list[str], hidden: str) -> None:
    from napari_meris_ortho import options
    from napari_meris_ortho.ortho import orthorectify
    from napari_meris_ortho.simulate.scene import generate_scene

    has_hidden = hasattr(options, "Hidden")
    print(f"{'scene':9} {'mapped':>9} {'hidden':>7} {'recall':>8} {'false al.':>9} "
          f"{'h. mapped':>9} {'RMS seen px':>12}")
    for name in names:
        scene = generate_scene(name)
        extra = {"hidden": hidden} if has_hidden else {}
        r = orthorectify(scene.product_path, dems=[scene.dem_paths["geotiff"]], bands=[7],
                         diagnostics=True, **extra)
        h, tl, tc, inside, seen = _truth(scene, r.grid)
        truly = inside & ~seen
        ok = seen & r.valid
        e = np.hypot(r.diagnostics["line"] - tl, r.diagnostics["col"] - tc)[ok]
        rms = float(np.sqrt(np.mean(e ** 2)))
        row = f"{name:9} {int(r.valid.sum()):9d} {int(truly.sum()):7d} "
        flagged = getattr(r, "hidden", None)
        if flagged is None:
            row += f"{'-':>8} {'-':>9} {100 * (truly & r.valid).sum() / truly.sum():8.2f}%"
        else:
            recall = 100 * (flagged & truly).sum() / truly.sum()
            false = 100 * (flagged & seen).sum() / seen.sum()
            mapped = 100 * (truly & r.valid).sum() / truly.sum()
            row += f"{recall:7.2f}% {false:8.3f}% {mapped:8.2f}%"
        print(row + f" {rms:12.5f}", flush=True)


def timing(old: str, new: str, pairs: int) -> None:
    from napari_meris_ortho.simulate.scene import generate_scene

    env = dict(os.environ)
    print(f"{'scene':9} {'old s':>8} {'new s':>8} {'new/old':>8}  (medians of {pairs} pairs)")
    with tempfile.TemporaryDirectory() as tmp:
        for name in SCENES:
            scene = generate_scene(name)
            times: dict[str, list[float]] = {"old": [], "new": []}
            for k in range(pairs + 1):  # the first pair warms the caches, not counted
                for which, src in (("old", old), ("new", new)):
                    out = Path(tmp) / f"{which}.tif"
                    cmd = [sys.executable, "-m", "napari_meris_ortho.cli", "map",
                           str(scene.product_path), "--dem", str(scene.dem_paths["geotiff"]),
                           "-o", str(out)]
                    t0 = time.perf_counter()
                    subprocess.run(cmd, env={**env, "PYTHONPATH": src}, check=True,
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                    if k:
                        times[which].append(time.perf_counter() - t0)
                    out.unlink(missing_ok=True)
            a, b = statistics.median(times["old"]), statistics.median(times["new"])
            print(f"{name:9} {a:8.2f} {b:8.2f} {b / a:8.3f}", flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="what", required=True)
    acc = sub.add_parser("accuracy")
    acc.add_argument("--scene", action="append", choices=SCENES, default=None)
    acc.add_argument("--hidden", default="mask", choices=("mask", "keep"))
    tim = sub.add_parser("timing")
    tim.add_argument("--old", required=True, help="src directory of the reference code")
    tim.add_argument("--new", required=True, help="src directory of the code measured")
    tim.add_argument("--pairs", type=int, default=5)
    args = p.parse_args()
    if args.what == "accuracy":
        accuracy(args.scene or list(SCENES), args.hidden)
    else:
        timing(os.path.abspath(args.old), os.path.abspath(args.new), args.pairs)


if __name__ == "__main__":
    main()

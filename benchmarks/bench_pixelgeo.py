"""Accuracy and speed of the pixel geolocation model beside the tie-point model.

For a simulated scene: its FRG N1 and ``.SEN3`` versions (per-pixel truth geolocation) mapped
with ``geolocation="pixel"`` on the grid of the tie-point + DEM run, the error against the
simulator's ``true_antecedent`` (every 5th mapped point) and the run times. A benchmark, not a
test: ``python benchmarks/bench_pixelgeo.py [--scene fr-small] [--scene fr-alps]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def errors(scene, result, stride: int = 5) -> np.ndarray:
    ok = result.valid.copy()
    ok.ravel()[np.arange(ok.size) % stride != 0] = False
    lon, lat = result.grid.lonlat()
    tl, tc = scene.true_antecedent(lon[ok], lat[ok], scene.dem_height(lon[ok], lat[ok]))
    return np.hypot(result.diagnostics["line"][ok] - tl, result.diagnostics["col"][ok] - tc)


def run(name: str) -> list[tuple[str, str, float, float, float, float, int]]:
    from napari_meris_ortho.ortho import orthorectify
    from napari_meris_ortho.simulate.geocorrected import write_geocorrected
    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene(name)
    paths = write_geocorrected(scene, fsg=scene.geometry.product_type == "MER_FR__1P")
    rows = []
    t0 = time.perf_counter()
    ref = orthorectify(scene.product_path, dems=[scene.dem_paths["geotiff"]], bands=[7],
                       parallax="ellipsoid", diagnostics=True)
    runs = [("tie points + DEM (ellipsoid)", ref, time.perf_counter() - t0)]
    for kind, path in paths.items():
        t0 = time.perf_counter()
        r = orthorectify(path, grid=ref.grid, geolocation="pixel", bands=[7], diagnostics=True)
        runs.append((f"{kind} pixel geolocation", r, time.perf_counter() - t0))
    for label, r, seconds in runs:
        e = errors(scene, r)
        rows.append((name, label, float(np.sqrt(np.mean(e ** 2))), float(np.percentile(e, 99)),
                     float(e.max()), seconds, int(r.valid.sum())))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scene", action="append", default=None)
    args = ap.parse_args()
    print(f"{'scene':<12} {'model':<30} {'RMS px':>8} {'p99 px':>8} {'max px':>8} "
          f"{'time s':>7} {'points':>9}")
    for name in args.scene or ["fr-small"]:
        for row in run(name):
            print(f"{row[0]:<12} {row[1]:<30} {row[2]:8.4f} {row[3]:8.4f} {row[4]:8.3f} "
                  f"{row[5]:7.2f} {row[6]:9d}")


if __name__ == "__main__":
    main()

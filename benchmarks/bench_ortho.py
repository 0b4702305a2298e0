"""Speed of ``orthorectify`` on a simulated scene (issue 4), beside pyresample and MERSYN.

Runs the default grid with all 15 bands for the three elevation sources (none / tie points /
DEM), pyresample's ``kd_tree.resample_nearest`` on the same swath and grid (no terrain
correction), and prints MERSYN's published times (handbook section 4, Appendix B) beside them.
Also the accuracy against the simulator's ``true_antecedent`` for each run. A benchmark, not a
test: ``python benchmarks/bench_ortho.py [--scene fr-alps] [--json FILE]``.
"""

from __future__ import annotations

import argparse
import json
import os
import threading
import time
from pathlib import Path

import numpy as np
import psutil

#: MERSYN 02.05 on the handbook's FR scene (Appendix B / the brief): none, tie points, DEM
MERSYN_SECONDS = {"none": 27.7, "tiepoints": 68.8, "dem": 304.0}


class PeakRss:
    """Peak resident memory of this process while the block runs (sampled every 10 ms)."""

    def __enter__(self) -> PeakRss:
        self.proc = psutil.Process(os.getpid())
        self.peak = self.proc.memory_info().rss
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._poll, daemon=True)
        self._thread.start()
        return self

    def _poll(self) -> None:
        while not self._stop.wait(0.01):
            self.peak = max(self.peak, self.proc.memory_info().rss)

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, self.proc.memory_info().rss)


def accuracy(scene, result, stride: int = 5) -> dict[str, float]:
    """RMS / max distance (product px) to the simulator's true antecedent, every ``stride``-th
    mapped output point (the truth is an exact but slow line-of-sight solver)."""
    ok = result.valid.copy()
    ok.ravel()[np.arange(ok.size) % stride != 0] = False
    lon, lat = result.grid.lonlat()
    h = scene.dem_height(lon[ok], lat[ok])
    tl, tc = scene.true_antecedent(lon[ok], lat[ok], h)
    e = np.hypot(result.diagnostics["line"][ok] - tl, result.diagnostics["col"][ok] - tc)
    return {"rms_px": float(np.sqrt(np.mean(e ** 2))), "max_px": float(e.max()),
            "p99_px": float(np.percentile(e, 99)), "points": int(ok.sum())}


def run_engine(scene, label: str, kwargs: dict, with_accuracy: bool) -> dict:
    from napari_meris_ortho import orthorectify

    with PeakRss() as mem:
        t0 = time.perf_counter()
        res = orthorectify(scene.product_path, diagnostics=with_accuracy, **kwargs)
        wall = time.perf_counter() - t0
    sec = res.stats["seconds"]
    row = {"run": label, "wall_s": wall, "engine_s": sec["engine"],
           "prediction_correction_s": sec["prediction_correction"],
           "resample_s": sec["resample"], "lonlat_s": sec["lonlat"], "dem_s": sec["dem"],
           "read_bands_s": sec["read_bands"], "peak_rss_mb": mem.peak / 2 ** 20,
           "grid": [res.grid.height, res.grid.width],
           "processed_points": res.stats["processed_points"],
           "iterations_histogram": res.stats["iterations_histogram"]}
    if with_accuracy:
        row.update(accuracy(scene, res))
    return row


def run_pyresample(scene) -> dict:
    """pyresample nearest neighbour on the product's zero-height geolocation, same grid."""
    from pyresample import geometry, kd_tree

    from napari_meris_ortho.engine.boundary import segment_boundary
    from napari_meris_ortho.engine.location import direct_location
    from napari_meris_ortho.geometry.grid import default_grid
    from napari_meris_ortho.geometry.tiepoints import TiePointGrid
    from napari_meris_ortho.io.n1 import read_product

    prod = read_product(scene.product_path)
    tp = TiePointGrid.from_product(prod)
    grid = default_grid(segment_boundary(tp.latitude, tp.longitude),
                        prod.resolution.column_spacing_m)
    lines, cols = np.mgrid[0:prod.height, 0:prod.width]
    lon, lat = direct_location(tp, lines.astype(float), cols.astype(float), 0.0)
    data = np.dstack([prod.radiance(b) for b in range(1, 16)])
    swath = geometry.SwathDefinition(lons=lon, lats=lat)
    x0, y0, x1, y1 = grid.bounds
    area = geometry.AreaDefinition("out", "out", "out", grid.crs,
                                   grid.width, grid.height, (x0, y0, x1, y1))
    radius = 2.0 * prod.resolution.column_spacing_m
    with PeakRss() as mem:
        t0 = time.perf_counter()
        out = kd_tree.resample_nearest(swath, data, area, radius_of_influence=radius,
                                       fill_value=0, nprocs=2)
        wall = time.perf_counter() - t0
    return {"run": "pyresample resample_nearest", "wall_s": wall, "engine_s": wall,
            "peak_rss_mb": mem.peak / 2 ** 20, "grid": list(out.shape[:2]),
            "processed_points": int(np.count_nonzero(out[..., 6]))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="fr-alps")
    ap.add_argument("--json", default=None, metavar="FILE")
    ap.add_argument("--no-pyresample", action="store_true")
    ap.add_argument("--no-accuracy", action="store_true")
    args = ap.parse_args(argv)

    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene(args.scene)
    dem = scene.dem_paths["geotiff"]
    # warm-up: numba kernels loaded from the cache, files in the page cache
    run_engine(scene, "warm-up", dict(dems=[dem], bands=[7]), False)
    runs = [("none", dict(elevation="none")), ("tiepoints", dict(elevation="tiepoints")),
            ("dem", dict(dems=[dem])), ("dem ellipsoid", dict(dems=[dem], parallax="ellipsoid")),
            ("dem handbook search", dict(dems=[dem], method="handbook", tolerance=0.1))]
    rows = []
    for label, kw in runs:
        # the accuracy run (one band) also warms this configuration up; then best of two
        acc = run_engine(scene, label, {**kw, "bands": [7]}, not args.no_accuracy)
        timed = [run_engine(scene, label, kw, False) for _ in range(2)]
        rows.append(min(timed, key=lambda r: r["engine_s"]))
        rows[-1]["peak_rss_mb"] = max(r["peak_rss_mb"] for r in timed)
        if not args.no_accuracy:
            rows[-1].update({k: acc[k] for k in ("rms_px", "max_px", "p99_px")})
        rows[-1]["mersyn_s"] = MERSYN_SECONDS.get(label.split()[0]) if " " not in label else None
    if not args.no_pyresample:
        rows.append(run_pyresample(scene))
    cores = len(os.sched_getaffinity(0))
    print(f"scene {args.scene}: grid {rows[0]['grid'][0]} x {rows[0]['grid'][1]}, 15 bands, "
          f"{cores} cores")
    head = f"{'run':30s} {'engine s':>9s} {'wall s':>8s} {'MERSYN s':>9s} {'peak MB':>8s} " \
           f"{'RMS px':>8s} {'max px':>8s}"
    print(head)
    print("-" * len(head))
    for r in rows:
        ms = f"{r['mersyn_s']:9.1f}" if r.get("mersyn_s") else f"{'':9s}"
        rms = f"{r['rms_px']:8.4f}" if "rms_px" in r else f"{'':8s}"
        mx = f"{r['max_px']:8.4f}" if "max_px" in r else f"{'':8s}"
        print(f"{r['run']:30s} {r['engine_s']:9.3f} {r['wall_s']:8.3f} {ms} "
              f"{r['peak_rss_mb']:8.0f} {rms} {mx}")
    if not args.no_pyresample:
        dem_row = next(r for r in rows if r["run"] == "dem")
        pr = rows[-1]
        print(f"pyresample nearest / engine DEM mode = {pr['wall_s'] / dem_row['engine_s']:.1f}x")
    if args.json:
        Path(args.json).write_text(json.dumps({"scene": args.scene, "cores": cores,
                                               "runs": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

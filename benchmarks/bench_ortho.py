"""Speed of the whole data path on a simulated scene, beside its peers.

One run prints, for ``fr-alps`` (15 bands, default geographic grid):

1. in-process ``orthorectify`` wall time (DEM sampling, prediction/correction, reading and
   resampling 15 bands: what a Python user waits for) for none / tie points / DEM, the engine
   share, peak memory and the accuracy against the simulator's truth; pyresample's
   ``kd_tree.resample_nearest`` on pyepr's latitude/longitude bands, same grid (no terrain
   correction; swath arrays loaded beforehand, only the resampling is timed);
2. ``meris-ortho map`` end to end (process start to file closed, peak memory, file size) and
   ``gdalwarp -geoloc`` on the same swath and grid (a VRT with a GEOLOCATION domain over
   pyepr's latitude/longitude, the radiances read from the N1 by GDAL's ESAT driver, nearest,
   COG ZSTD output like ours), in ``ROUNDS`` interleaved rounds, the best of each;
3. the first ``map`` in a fresh numba cache directory (every kernel compiled);
4. ``map`` at half the pixel size (4x the output pixels): the cost must grow linearly.

A benchmark, not a test: ``python benchmarks/bench_ortho.py [--scene fr-alps] [--json FILE]``.
Wall times depend on whatever else the machine runs: run it when the machine is quiet (the JSON
file records the system load before and after).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import psutil

#: rounds of ``meris-ortho map`` and ``gdalwarp``, one after the other; the best of each
ROUNDS = 5
#: MERSYN 02.05 on the handbook's FR scene (handbook section 4.5, Appendix B): none, tie points,
#: DEM
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
    sec = res.stats.seconds
    row = {"run": label, "wall_s": wall, "engine_s": sec["engine"],
           "prediction_correction_s": sec["prediction_correction"],
           "resample_s": sec["resample"], "lonlat_s": sec["lonlat"], "dem_s": sec["dem"],
           "read_bands_s": sec["read_bands"], "peak_rss_mb": mem.peak / 2 ** 20,
           "grid": [res.grid.height, res.grid.width],
           "processed_points": res.stats.processed_points,
           "iterations_histogram": res.stats.iterations_histogram}
    if with_accuracy:
        row.update(accuracy(scene, res))
    return row


def pyepr_swath(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """pyepr's latitude/longitude bands and the 15 radiances (pyepr's west-to-east order)."""
    import epr

    with epr.open(str(path)) as product:
        lat = product.get_band("latitude").read_as_array()
        lon = product.get_band("longitude").read_as_array()
        data = np.dstack([product.get_band(f"radiance_{b}").read_as_array()
                          for b in range(1, 16)])
    return lon, lat, data


def default_grid_of(path: Path):
    from napari_meris_ortho.engine.boundary import segment_boundary
    from napari_meris_ortho.geometry.grid import default_grid
    from napari_meris_ortho.geometry.tiepoints import TiePointGrid
    from napari_meris_ortho.products.n1 import read_product

    prod = read_product(path)
    tp = TiePointGrid.from_product(prod)
    return default_grid(segment_boundary(tp.latitude, tp.longitude),
                        prod.resolution.column_spacing_m), prod


def run_pyresample(scene, grid) -> dict:
    """pyresample nearest neighbour on pyepr's geolocation (no terrain correction), same grid."""
    from pyresample import geometry, kd_tree

    lon, lat, data = pyepr_swath(scene.product_path)
    swath = geometry.SwathDefinition(lons=lon, lats=lat)
    x0, y0, x1, y1 = grid.bounds
    area = geometry.AreaDefinition("out", "out", "out", grid.crs,
                                   grid.width, grid.height, (x0, y0, x1, y1))
    with PeakRss() as mem:
        t0 = time.perf_counter()
        out = kd_tree.resample_nearest(swath, data, area, radius_of_influence=520.0,
                                       fill_value=0, nprocs=2)
        wall = time.perf_counter() - t0
    return {"run": "pyresample resample_nearest", "wall_s": wall, "engine_s": wall,
            "peak_rss_mb": mem.peak / 2 ** 20, "grid": list(out.shape[:2]),
            "processed_points": int(np.count_nonzero(out[..., 6]))}


def timed_process(cmd: list[str], env: dict | None = None) -> dict:
    """Wall time (process start to exit), CPU time and peak resident memory (sampled every
    10 ms; ``ru_maxrss`` would count the forked copy of this process) of one command."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    peak = [0]
    done = threading.Event()

    def poll() -> None:
        ps = psutil.Process(proc.pid)
        while not done.wait(0.01):
            try:
                peak[0] = max(peak[0], ps.memory_info().rss)
            except psutil.Error:
                return

    watcher = threading.Thread(target=poll, daemon=True)
    watcher.start()
    out = proc.stdout.read() if proc.stdout else b""
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    done.set()
    watcher.join()
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{out.decode(errors='replace')}")
    return {"wall_s": wall, "peak_rss_mb": peak[0] / 2 ** 20,
            "cpu_s": usage.ru_utime + usage.ru_stime}


def map_cmd(product: Path, out: Path, dem: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "napari_meris_ortho.cli", "-q", "map", str(product),
            "-o", str(out), "--dem", str(dem), *extra]


def run_map(product: Path, out: Path, dem: Path, *extra: str, env: dict | None = None,
            label: str = "meris-ortho map (DEM)") -> dict:
    row = timed_process(map_cmd(product, out, dem, *extra), env)
    row.update(run=label, file_mb=out.stat().st_size / 1e6)
    import rasterio

    with rasterio.open(out) as ds:
        row["grid"] = [ds.height, ds.width]
    return row


def geoloc_vrt(scene, tmp: Path, bands: tuple[int, ...] = tuple(range(1, 16))) -> Path:
    """A VRT over the N1 (ESAT driver: stored column order) with a GEOLOCATION domain pointing
    at pyepr's longitude/latitude, mirrored back to the stored order."""
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    warnings.simplefilter("ignore", NotGeoreferencedWarning)  # plain arrays, on purpose
    lon, lat, _ = pyepr_swath(scene.product_path)
    paths = {}
    for name, arr in (("lon", lon[:, ::-1]), ("lat", lat[:, ::-1])):
        paths[name] = tmp / f"{name}.tif"
        with rasterio.open(paths[name], "w", driver="GTiff", width=arr.shape[1],
                           height=arr.shape[0], count=1, dtype="float32") as ds:
            ds.write(arr.astype(np.float32), 1)
    h, w = lon.shape
    bands = "".join(
        f'<VRTRasterBand dataType="UInt16" band="{b}"><NoDataValue>0</NoDataValue>'
        f"<SimpleSource><SourceFilename>{scene.product_path}</SourceFilename>"
        f"<SourceBand>{b}</SourceBand></SimpleSource></VRTRasterBand>" for b in bands)
    geo = {"SRS": "EPSG:4326", "X_DATASET": paths["lon"], "X_BAND": 1,
           "Y_DATASET": paths["lat"], "Y_BAND": 1, "PIXEL_OFFSET": 0, "LINE_OFFSET": 0,
           "PIXEL_STEP": 1, "LINE_STEP": 1, "GEOREFERENCING_CONVENTION": "PIXEL_CENTER"}
    mdi = "".join(f'<MDI key="{k}">{v}</MDI>' for k, v in geo.items())
    vrt = tmp / "swath.vrt"
    vrt.write_text(f'<VRTDataset rasterXSize="{w}" rasterYSize="{h}">'
                   f'<Metadata domain="GEOLOCATION">{mdi}</Metadata>{bands}</VRTDataset>')
    return vrt


def run_gdalwarp(scene, grid, tmp: Path, bands: tuple[int, ...] = tuple(range(1, 16))) -> dict:
    vrt = geoloc_vrt(scene, tmp, bands)
    out = tmp / "gdalwarp.tif"
    x0, y0, x1, y1 = grid.bounds
    cmd = ["gdalwarp", "-q", "-overwrite", "-geoloc", "-t_srs", grid.crs.to_string(),
           "-te", repr(x0), repr(y0), repr(x1), repr(y1), "-ts", str(grid.width),
           str(grid.height), "-r", "near", "-dstnodata", "0", "-multi",
           "-wo", "NUM_THREADS=ALL_CPUS", "-of", "COG", "-co", "COMPRESS=ZSTD",
           "-co", "LEVEL=1", "-co", "PREDICTOR=YES", "-co", "NUM_THREADS=ALL_CPUS",
           str(vrt), str(out)]
    row = timed_process(cmd)
    row.update(run="gdalwarp -geoloc (no terrain)", file_mb=out.stat().st_size / 1e6,
               grid=[grid.height, grid.width])
    return row


def in_process(scene, dem: Path, with_accuracy: bool) -> list[dict]:
    # warm-up: numba kernels loaded from the cache, files in the page cache
    run_engine(scene, "warm-up", dict(dems=[dem], bands=[7]), False)
    runs = [("none", dict(elevation="none")), ("tiepoints", dict(elevation="tiepoints")),
            ("dem", dict(dems=[dem])), ("dem ellipsoid", dict(dems=[dem], parallax="ellipsoid")),
            ("dem handbook search", dict(dems=[dem], method="handbook", tolerance=0.1))]
    rows = []
    for label, kw in runs:
        acc = run_engine(scene, label, {**kw, "bands": [7]}, with_accuracy)
        timed = [run_engine(scene, label, kw, False) for _ in range(3)]
        rows.append(min(timed, key=lambda r: r["wall_s"]))
        rows[-1]["peak_rss_mb"] = max(r["peak_rss_mb"] for r in timed)
        if with_accuracy:
            rows[-1].update({k: acc[k] for k in ("rms_px", "max_px", "p99_px")})
        rows[-1]["mersyn_s"] = MERSYN_SECONDS.get(label) if " " not in label else None
    return rows


def print_in_process(rows: list[dict]) -> None:
    head = (f"{'run':30s} {'whole s':>8s} {'engine s':>9s} {'MERSYN s':>9s} {'peak MB':>8s} "
            f"{'RMS px':>8s} {'max px':>8s}")
    print(head)
    print("-" * len(head))
    for r in rows:
        ms = f"{r['mersyn_s']:9.1f}" if r.get("mersyn_s") else f"{'':9s}"
        rms = f"{r['rms_px']:8.4f}" if "rms_px" in r else f"{'':8s}"
        mx = f"{r['max_px']:8.4f}" if "max_px" in r else f"{'':8s}"
        print(f"{r['run']:30s} {r['wall_s']:8.2f} {r['engine_s']:9.2f} {ms} "
              f"{r['peak_rss_mb']:8.0f} {rms} {mx}")


def print_processes(rows: list[dict]) -> None:
    head = f"{'command':40s} {'wall s':>7s} {'cpu s':>7s} {'peak MB':>8s} {'file MB':>8s} grid"
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r['run']:40s} {r['wall_s']:7.2f} {r['cpu_s']:7.2f} {r['peak_rss_mb']:8.0f} "
              f"{r['file_mb']:8.1f} {r['grid'][0]} x {r['grid'][1]}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="fr-alps")
    ap.add_argument("--json", default=None, metavar="FILE")
    ap.add_argument("--no-accuracy", action="store_true")
    ap.add_argument("--skip", default="", help="comma list of: inprocess,peers,first,half")
    args = ap.parse_args(argv)
    skip = set(filter(None, args.skip.split(",")))

    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene(args.scene)
    dem = scene.dem_paths["geotiff"]
    grid, _ = default_grid_of(scene.product_path)
    cores = len(os.sched_getaffinity(0))
    load = os.getloadavg()
    report: dict = {"scene": args.scene, "cores": cores, "load_before": load}
    print(f"scene {args.scene}: grid {grid.height} x {grid.width}, 15 bands, {cores} cores")
    tmp = Path(tempfile.mkdtemp(prefix="bench-ortho-"))
    try:
        if "inprocess" not in skip:
            rows = in_process(scene, dem, not args.no_accuracy)
            if "peers" not in skip:
                rows.append(run_pyresample(scene, grid))
            print("\n1. in process (whole orthorectify call, best of three)")
            print_in_process(rows)
            report["in_process"] = rows
            if "peers" not in skip:
                d = next(r for r in rows if r["run"] == "dem")
                print(f"pyresample nearest / orthorectify DEM = "
                      f"{rows[-1]['wall_s'] / d['wall_s']:.1f}x")
        procs = []
        if "peers" not in skip:
            run_map(scene.product_path, tmp / "warm.tif", dem)  # page cache, numba cache
            maps, warps = [], []
            for _ in range(ROUNDS):  # interleaved: both see the same drift of a shared machine
                maps.append(run_map(scene.product_path, tmp / "map.tif", dem))
                warps.append(run_gdalwarp(scene, grid, tmp))
            procs.append(min(maps, key=lambda r: r["wall_s"]))
            procs.append(min(warps, key=lambda r: r["wall_s"]))
        if "half" not in skip:
            half = grid.dx / 2
            procs.append(min((run_map(scene.product_path, tmp / "half.tif", dem, "--pixel-size",
                                      repr(half), label="meris-ortho map, half pixel size")
                              for _ in range(2)), key=lambda r: r["wall_s"]))
        if "first" not in skip:
            env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp / "numba-cache")}
            procs.append(run_map(scene.product_path, tmp / "first.tif", dem, env=env,
                                 label="meris-ortho map, fresh numba cache"))
        if procs:
            print("\n2. end to end (process start to file closed)")
            print_processes(procs)
            report["processes"] = procs
            by = {r["run"]: r for r in procs}
            m = by.get("meris-ortho map (DEM)")
            g = by.get("gdalwarp -geoloc (no terrain)")
            if m and g:
                print(f"gdalwarp -geoloc / meris-ortho map = {g['wall_s'] / m['wall_s']:.1f}x")
            h = by.get("meris-ortho map, half pixel size")
            if m and h:
                px = (h["grid"][0] * h["grid"][1]) / (m["grid"][0] * m["grid"][1])
                print(f"half pixel size: {px:.2f}x the output pixels, "
                      f"{h['wall_s'] / m['wall_s']:.2f}x the time, "
                      f"{h['peak_rss_mb'] / m['peak_rss_mb']:.2f}x the peak memory")
        report["load_after"] = os.getloadavg()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

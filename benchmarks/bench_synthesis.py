"""Benchmark of the synthesis on dask workers (handbook section 3.1, use cases 1-2).

    .venv/bin/python benchmarks/bench_synthesis.py [--scene fr-alps] [--products 8]
                                [--format n1|sen3] [--tile 1024] [--bands 15]
                                [--workers 0,1,2] [--repeat 1] [--codecs zstd,delta-zstd]
                                [--pin]

Prints two tables:

1. Throughput: the same ``--products`` simulated FR products (cloudy dates of ``--scene``, told
   apart by their file counter) merged into a new maximum-NDVI synthesis on their footprint,
   in this process (numba threads) and on a LocalCluster of 1 and 2 worker processes (one
   thread each). Products merged per minute (workers started and warmed up beforehand: the
   time is the run's), speed-up against 1 worker, peak resident memory per worker (``VmHWM``),
   tasks and seconds per (product, tile) task, cores busy per worker (its CPU seconds, all
   threads, over the run's seconds; in process: this process's) and of this process, the
   client (with the scheduler of the LocalCluster). A free worker busy on more
   than one core bounds what N workers can gain against it on this machine: the line under
   the table prints that bound (cores / cores busy of the 1-worker run, the work of the runs
   being the same CPU seconds). Workers as many as the cores are each held to a
   core of its own (all their threads: the task's, Icechunk's, zstd's), as ``--workers N``
   holds them; with ``--pin``, fewer workers are too, so that the rows compare one core with
   two (a worker left free uses more than one core: its writes run beside its task). Rows of
   held workers say "pinned". The client and the scheduler are never held.
2. Update cost: one more product merged into a store holding one product, on the product's
   footprint ("small") and on Europe at 260 m (50 x 35 deg, 21384 x 14969 pixels), for each
   store codec of ``--codecs``: seconds, bytes added to the store, chunks written. Only the
   tiles the product touches are read and written, so neither should grow with the store.

The seconds per (product, tile) task give the estimate of larger runs (10 000 products on 32
workers). Wall times depend on whatever else the machine runs; ``--repeat N`` prints the median
of N runs.
"""

from __future__ import annotations

import argparse
import logging
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

NO_EXPORTS = {"getasse30": False, "getasse30_beam": False, "srtm30": False,
              "geotiff_utm": False, "reference": False}
PIXEL_260M = 0.0023382372764265  # 260 m on the sphere R = 6 370 997 m (geometry.earth)
EUROPE = (-10.0, 70.0, 50.0, 35.0)  # x0, y0, width, height (deg)


def products(n: int, scene: str, fmt: str = "n1") -> list[str]:
    """``n`` cloudy dates of ``scene``: N1 files, or (``fmt`` "sen3") the 4th-reprocessing
    ``.SEN3`` of each, told apart by the cycle field of its name (the simulated dates share a
    sensing time, and a synthesis takes one product per sensing time and name)."""
    from napari_meris_ortho.simulate.geocorrected import write_geocorrected
    from napari_meris_ortho.simulate.scene import generate_scene

    out = []
    for k in range(n):
        cfg = {"base": scene, "exports": NO_EXPORTS, "file_counter": k + 1,
               "clouds": {"fraction": 0.4, "scale_km": 20.0, "seed": 10 * (k + 1)}}
        generated = generate_scene(cfg)
        if fmt == "n1":
            out.append(str(generated.product_path))
            continue
        sen3 = write_geocorrected(generated, fsg=False)["sen3"]
        named = sen3.with_name(sen3.name.replace("_000_000______MOR", f"_{k + 1:03d}_000______MOR"))
        if not named.exists():
            shutil.copytree(sen3, named)
        out.append(str(named))
    return out


def peak_rss_mb() -> float:
    """High-water mark of this process's resident memory (``VmHWM``)."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError("no VmHWM in /proc/self/status")


def store_bytes(path: Path) -> tuple[int, int]:
    """(bytes, files) of a store directory."""
    files = [p for p in path.rglob("*") if p.is_file()]
    return sum(p.stat().st_size for p in files), len(files)


def throughput(paths: list[str], grid, bands: list[int], tile: int, workers: int,
               tmp: Path, pin: bool = False) -> dict:
    """One new synthesis of every product; workers = 0: in this process. The workers are held
    to a core each as ``--workers N`` holds them (``hold_workers_to_cores``: as many workers as
    cores), or, with ``pin``, whatever their number."""
    tmp = Path(tempfile.mkdtemp(dir=tmp))  # a new directory per repetition
    from distributed import Client, LocalCluster

    from napari_meris_ortho.synthesis.api import synthesize
    from napari_meris_ortho.synthesis.run import WORKER_ENV, hold_workers_to_cores

    kwargs = dict(grid=grid, bands=bands, algorithm="max-ndvi", tile=tile,
                  elevation="tiepoints")
    tasks = {"n": 0}

    def count(done: int, total: int) -> None:
        tasks["n"] = total

    if workers == 0:
        synthesize(paths[:1], tmp / "warm0", **kwargs)  # numba kernels loaded
        cpu0 = cpu_seconds()
        t0 = time.perf_counter()
        result = synthesize(paths, tmp / "run0", progress=count, **kwargs)
        seconds = time.perf_counter() - t0
        peaks, held, busy = [peak_rss_mb()], {}, [(cpu_seconds() - cpu0) / seconds]
        mine = busy[0]  # the client is this process
    else:
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                          dashboard_address=None, env=WORKER_ENV,
                          silence_logs=logging.ERROR) as cluster, \
                Client(cluster) as client:
            address = cluster.scheduler_address
            held = hold_workers_to_cores(client, every=pin)
            synthesize(paths[:workers], tmp / f"warm{workers}", scheduler=address, **kwargs)
            client.run(_reset_peak)
            cpu0, mine0 = client.run(cpu_seconds), cpu_seconds()
            t0 = time.perf_counter()
            result = synthesize(paths, tmp / f"run{workers}", scheduler=address,
                                progress=count, **kwargs)
            seconds = time.perf_counter() - t0
            cpu1, mine = client.run(cpu_seconds), (cpu_seconds() - mine0) / seconds
            peaks = sorted(client.run(peak_rss_mb).values())
            busy = sorted((cpu1[w] - cpu0[w]) / seconds for w in cpu1)
    assert len(result.merged) == len(paths), [r.error for r in result.failed]
    return {"workers": workers, "pinned": workers > 0 and bool(held), "seconds": seconds,
            "per_minute": 60.0 * len(paths) / seconds, "peaks": peaks, "tasks": tasks["n"],
            "cores": busy, "client": mine}


def cpu_seconds() -> float:
    """User + system CPU seconds of this process, all its threads."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _reset_peak() -> None:
    """Reset ``VmHWM`` of a worker (Linux: write 5 to clear_refs) so the peak is the run's."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


def update_cost(paths: list[str], grid, bands: list[int], tile: int, tmp: Path,
                name: str, codec: str = "zstd") -> dict:
    """Seconds and bytes of merging one product into a store (of ``codec``) holding
    another."""
    from napari_meris_ortho.synthesis.api import synthesize
    from napari_meris_ortho.synthesis.store import overview_factors

    out = Path(tempfile.mkdtemp(dir=tmp)) / f"update-{name}"
    synthesize(paths[:1], out, grid=grid, bands=bands, algorithm="max-ndvi", tile=tile,
               elevation="tiepoints", codec=codec)
    before, files0 = store_bytes(out)
    t0 = time.perf_counter()
    synthesize(paths[1:2], out, input=out, elevation="tiepoints")
    seconds = time.perf_counter() - t0
    after, files1 = store_bytes(out)
    shutil.rmtree(out, ignore_errors=True)
    levels = len(overview_factors(grid.width, grid.height, tile))
    return {"store": name, "codec": codec, "size": f"{grid.width} x {grid.height}",
            "seconds": seconds,
            "bytes": after - before, "files": files1 - files0, "levels": levels}


def median(runs: list[dict]) -> dict:
    """The run of median seconds (the lower middle one of an even count), with the range of
    the seconds of all runs as ``range``."""
    ordered = sorted(runs, key=lambda r: r["seconds"])
    out = dict(ordered[(len(ordered) - 1) // 2])
    out["range"] = (f"({len(runs)} runs: {ordered[0]['seconds']:.1f}-"
                    f"{ordered[-1]['seconds']:.1f} s)" if len(runs) > 1 else "")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="fr-alps", help="simulated scene (fr-small: quick)")
    parser.add_argument("--products", type=int, default=8)
    parser.add_argument("--format", choices=("n1", "sen3"), default="n1",
                        help="products as N1 files or as 4th-reprocessing .SEN3 directories")
    parser.add_argument("--tile", type=int, default=1024)
    parser.add_argument("--bands", type=int, default=15, help="bands 1..N (plus 7 and 13)")
    parser.add_argument("--workers", default="0,1,2",
                        help="worker counts to run ('' : only the update table)")
    parser.add_argument("--repeat", type=int, default=1,
                        help="runs of every row; the median (by seconds) is printed, with "
                             "the range of the seconds")
    parser.add_argument("--pin", action="store_true",
                        help="hold each worker to a core of its own even when there are fewer "
                             "workers than cores (one core against two)")
    parser.add_argument("--codecs", default="zstd,delta-zstd",
                        help="store codecs of the update table (synthesize's codec=; '': "
                             "no update table)")
    args = parser.parse_args()

    from napari_meris_ortho.geometry.grid import OutputGrid
    from napari_meris_ortho.ortho import product_grid
    from napari_meris_ortho.products.open import read_product

    paths = products(args.products, args.scene, args.format)
    bands = sorted(set(range(1, min(args.bands, 15) + 1)) | {7, 13})
    grid = product_grid(read_product(paths[0]), "EPSG:4326")
    europe = OutputGrid("EPSG:4326", EUROPE[0], EUROPE[1], PIXEL_260M, PIXEL_260M,
                        round(EUROPE[2] / PIXEL_260M), round(EUROPE[3] / PIXEL_260M))
    print(f"{len(paths)} {args.scene} products ({args.format}), {len(bands)} bands, grid "
          f"{grid.width} x {grid.height}, tile {args.tile}; {os.cpu_count()} cores (shared, "
          "loaded)")
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        rows = [median([throughput(paths, grid, bands, args.tile, int(w), tmp, args.pin)
                        for _ in range(args.repeat)])
                for w in args.workers.split(",") if w]
        one = next((r for r in rows if r["workers"] == 1), rows[0] if rows else {})
        print(f"\n{'workers':>10s} {'seconds':>8s} {'prod/min':>9s} {'speed-up':>9s} "
              f"{'tasks':>6s} {'s/task':>7s} {'cores busy':>11s} {'peak MB per worker':>20s}")
        for r in rows:
            label = ("in-process" if r["workers"] == 0 else
                     f"{r['workers']}{' pinned' if r['pinned'] else ''}")
            per_task = r["seconds"] * max(r["workers"], 1) / max(r["tasks"], 1)
            print(f"{label:>10s} {r['seconds']:8.1f} {r['per_minute']:9.2f} "
                  f"{one['seconds'] / r['seconds']:9.2f} {r['tasks']:6d} {per_task:7.2f} "
                  f"{' '.join(f'{c:.2f}' for c in r['cores']):>11s} {r['client']:6.2f} "
                  f"{' '.join(f'{p:.0f}' for p in r['peaks']):>20s}  {r['range']}")
        if one.get("workers") == 1:
            cores = len(os.sched_getaffinity(0))
            print(f"bound of N >= {cores} workers against 1 at the 1-worker run's CPU seconds, "
                  f"every core busy: {cores} / {one['cores'][0]:.2f} cores busy = "
                  f"{cores / one['cores'][0]:.2f}x")
        updates = [median([update_cost(paths, g, bands, args.tile, tmp, name, codec)
                           for _ in range(args.repeat)])
                   for name, g in (("small", grid), ("Europe", europe))
                   for codec in args.codecs.split(",") if codec]
    if not updates:
        return
    print(f"\n{'store':>8s} {'codec':>10s} {'grid':>15s} {'overviews':>9s} {'update s':>9s} "
          f"{'MB added':>9s} {'files added':>12s}")
    for u in updates:
        print(f"{u['store']:>8s} {u['codec']:>10s} {u['size']:>15s} {u['levels']:9d} "
              f"{u['seconds']:9.2f} {u['bytes'] / 1e6:9.1f} {u['files']:12d}  {u['range']}")


if __name__ == "__main__":
    main()

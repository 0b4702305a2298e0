"""napari at engine speed: what a user of the plugin waits for, on fr-alps.

One run prints, in a real napari viewer (run it under Xvfb: ``xvfb-run -a``):

1. open: ``viewer.open`` of the N1 with the plugin's reader, to the first frame drawn
   (``viewer.screenshot`` of the canvas): first in the session (napari's own first-layer costs
   included: importing xarray, building pint's unit registry), then once more (warm);
2. the Orthorectify dock's opening (``add_plugin_dock_widget``, as napari's Plugins menu does it)
   and the 1.5 s after it (the user filling the form): the longest stall;
3. Orthorectify runs (fr-alps with its GeoTIFF DEM, bands 7,5,2, geometry layers, the widget's
   defaults), from Run to the last layer in the viewer: wall time and the longest gap between
   two turns of the Qt event loop (a 10 ms QTimer recording timestamps, until 0.5 s after the
   last layer, so that the first frame drawn with the result counts); the first run loads the
   numba kernels into the process, the later ones are warm;
4. resident memory after the first run, and after ``RUNS`` runs with every layer removed
   (``gc.collect()``, napari's deferred deletions processed), also once glibc's ``malloc_trim``
   has returned the free heap (what is kept for reuse is not held by anything);
5. ``RERUNS`` more runs whose layers replace the previous run's (the user pressing Run again:
   napari removes the old layers and collects garbage), their longest stalls.

With ``--store``: a Europe-size synthesis store (21384 x 14969 pixels at 260 m, 15 bands,
maximum NDVI) holding the scene's product, made once in the cache directory, opened instead
(no runs): what a user opening a season's store waits for.

With ``--synthesis N``: the runs are the widget's synthesis (maximum NDVI, all 15 bands, tie-point
elevations) of N products of the scene (``bench_synthesis.products``: the same season), into a
temporary store read back into layers.

With ``--sen3``: the scene's ``.SEN3`` product instead (``simulate.geocorrected``, written
next to the scene once), opened only (no runs), and the reader's peak allocation
(``tracemalloc`` around ``read_layers``, outside the timed opens).

With ``--first-open-table OLD_SRC``: the first open of a session, each in a fresh process
(``viewer.open`` of the N1 until it returns and one event-loop turn ran), with no dock and with
the Orthorectify dock opened 0.2 s, 1.5 s and 5 s before, ``OPEN_RUNS`` runs each, for this
source tree beside ``OLD_SRC`` (another checkout's ``src``); then, for each tree, the dock's
opening (napari's ``add_plugin_dock_widget``, the user's action), the longest stall of the
window while the dock warms up (from the end of that call to the end of its warm-up) and one
Orthorectify run (time, longest stall, memory). The warm-up is on, as a user has it.

A benchmark, not a test: ``xvfb-run -a python benchmarks/bench_napari.py [--sen3] [--json F]``;
to compare two versions of the package, run the same command with ``PYTHONPATH`` on each
source tree. Wall times depend on whatever else the machine runs.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import time
from typing import Any

import numpy as np
import psutil

#: Orthorectify runs in a row (the memory they leave is printed)
RUNS = 4
#: then runs whose layers replace the previous run's (same names: napari removes them)
RERUNS = 2
#: fresh processes per situation of the first-open table
OPEN_RUNS = 3
#: seconds between the dock's opening and the open, of the table's rows (None: no dock)
DOCK_BEFORE = (None, 0.2, 1.5, 5.0)
#: the issue's targets of the first open (s): no dock or a dock opened 0.2 s before, and a dock
#: opened 1.5 s or more before
TARGET_UNPREPARED_S, TARGET_PREPARED_S = 1.5, 1.0


def _rss_mb() -> float:
    gc.collect()
    return psutil.Process().memory_info().rss / 2**20


def _trimmed_rss_mb() -> float:
    """RSS once glibc has handed its free heap back (``malloc_trim``): what is still in use,
    apart from memory the allocator keeps for reuse."""
    import contextlib
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None).malloc_trim(0)
    return _rss_mb()


class LoopTurns:
    """Timestamps of a 10 ms QTimer: the event loop's turns while the block runs."""

    def __enter__(self) -> LoopTurns:
        from qtpy.QtCore import QTimer

        self.stamps: list[float] = [time.perf_counter()]
        self.timer = QTimer()
        self.timer.timeout.connect(lambda: self.stamps.append(time.perf_counter()))
        self.timer.start(10)
        return self

    def __exit__(self, *exc: object) -> None:
        self.timer.stop()
        self.stamps.append(time.perf_counter())

    @property
    def longest_gap(self) -> float:
        return float(np.diff(self.stamps).max())

    def longest_gap_after(self, t: float) -> float:
        """The longest gap between two turns that both came after ``t``."""
        after = [s for s in self.stamps if s >= t]
        return float(np.diff(after).max()) if len(after) > 1 else 0.0


def _spin(app: Any, until: Any, timeout: float = 600.0) -> None:
    """Run the Qt event loop (as napari.run would) until ``until()`` or the timeout."""
    from qtpy.QtCore import QEventLoop, QTimer

    loop = QEventLoop()
    check = QTimer()
    check.timeout.connect(lambda: loop.quit() if until() else None)
    check.start(5)
    QTimer.singleShot(int(timeout * 1000), loop.quit)
    loop.exec_()
    check.stop()


def _reader_peak_mb(path: str) -> float:
    """Peak traced allocation (MB) of the plugin's reader on ``path`` (the product opened
    once before, so that its headers' allocations are not counted)."""
    import tracemalloc

    from napari_meris_ortho._napari.reader import read_layers
    from napari_meris_ortho.products.open import read_product

    read_product(path)
    tracemalloc.start()
    try:
        read_layers(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak / 2**20


def europe_store(scene_name: str) -> str:
    """A Europe-size maximum-NDVI store holding the scene's product (made once, next to the
    simulated product in the cache)."""
    from pathlib import Path

    from bench_synthesis import EUROPE, PIXEL_260M, products
    from napari_meris_ortho.geometry.grid import OutputGrid
    from napari_meris_ortho.synthesis.api import synthesize
    from napari_meris_ortho.synthesis.reading import is_synthesis

    paths = products(1, scene_name)
    store = Path(paths[0]).parent / "bench-europe-store"
    if not is_synthesis(store):
        grid = OutputGrid("EPSG:4326", EUROPE[0], EUROPE[1], PIXEL_260M, PIXEL_260M,
                          round(EUROPE[2] / PIXEL_260M), round(EUROPE[3] / PIXEL_260M))
        synthesize(paths, store, grid=grid, algorithm="max-ndvi", elevation="tiepoints")
    return str(store)


def bench(scene_name: str, sen3: bool = False, store: bool = False,
          open_only: bool = False, synthesis: int = 0) -> dict[str, Any]:
    import tempfile

    os.environ.setdefault("MERIS_ORTHO_NO_WARMUP", "1")  # no compiler thread competing
    # napari's settings (and the widget's remembered choices) in a fresh place, not the user's
    os.environ["NAPARI_CONFIG"] = os.path.join(tempfile.mkdtemp(prefix="bench-napari-"),
                                               "settings.yaml")
    from qtpy.QtWidgets import QApplication

    import napari
    import napari_meris_ortho
    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene(scene_name)
    product = str(scene.product_path)
    if sen3:
        from napari_meris_ortho.simulate.geocorrected import write_geocorrected

        product = str(write_geocorrected(scene, fsg=False)["sen3"])
    if store:
        product = europe_store(scene_name)
    viewer = napari.Viewer(show=True)
    app = QApplication.instance()
    _spin(app, lambda: False, 1.0)  # the window is up
    out: dict[str, Any] = {"source": os.path.dirname(napari_meris_ortho.__file__),
                           "scene": scene_name, "synthesis": synthesis,
                           "product": os.path.basename(product),
                           "rss_start_mb": _rss_mb()}

    for key in ("", "warm_"):
        with LoopTurns() as turns:
            t0 = time.perf_counter()
            viewer.open(product, plugin="napari-meris-ortho")
            viewer.screenshot(canvas_only=True)  # the first frame drawn
            out[f"{key}open_to_first_pixels_s"] = time.perf_counter() - t0
        out[f"{key}open_longest_stall_s"] = turns.longest_gap
        with LoopTurns() as turns:  # what the opening left to later turns (controls, overlays)
            _spin(app, lambda: False, 1.5)
        out[f"{key}after_open_longest_stall_s"] = turns.longest_gap
        viewer.layers.clear()
        _spin(app, lambda: False, 0.3)
    if sen3:
        out["reader_peak_mb"] = _reader_peak_mb(product)
    if sen3 or store or open_only:
        viewer.close()
        return out

    with LoopTurns() as turns:
        _, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
        _spin(app, lambda: False, 1.5)  # the user filling the form
    out["dock_open_longest_stall_s"] = turns.longest_gap
    if synthesis:
        from bench_synthesis import products

        widget.products.value = products(synthesis, scene_name)
        widget.algorithm.value, widget.bands.value = "max-ndvi", ",".join(map(str, range(1, 16)))
        widget.elevation.value, widget.geometry.value = "tiepoints", False
    else:
        widget.products.value = [scene.product_path]
        widget.add_dem(scene.dem_paths["geotiff"])
        widget.bands.value = "7,5,2"
        widget.elevation.value, widget.pixel_size.value, widget.geometry.value = "dem", 0.0, True
    runs = []
    rss_before = _rss_mb()
    for k in range(RUNS):
        with LoopTurns() as turns:
            t0 = time.perf_counter()
            assert widget.start() is not None, widget.status.value
            _spin(app, lambda: not widget.running)
            seconds = time.perf_counter() - t0
            _spin(app, lambda: False, 0.5)  # the first frames with the result
        assert widget.status.value.startswith("done"), widget.status.value
        runs.append({"run_s": seconds, "longest_stall_s": turns.longest_gap,
                     "layers": len(viewer.layers)})
        if k == 0:
            out["rss_after_first_run_mb"] = _rss_mb()
        viewer.layers.clear()
        _spin(app, lambda: False, 0.3)  # napari's deferred deletions
    out["runs"] = runs
    _spin(app, lambda: False, 1.5)  # the plugin trims the heap 1 s after the last removal
    out["rss_after_runs_removed_mb"] = _rss_mb()
    out["rss_after_malloc_trim_mb"] = _trimmed_rss_mb()
    # reruns: each run's layers replace the previous run's (napari removes them, then collects)
    reruns = []
    for _ in range(RERUNS + 1) if RERUNS else ():
        with LoopTurns() as turns:
            t0 = time.perf_counter()
            assert widget.start() is not None, widget.status.value
            _spin(app, lambda: not widget.running)
            seconds = time.perf_counter() - t0
            _spin(app, lambda: False, 0.5)
        reruns.append({"run_s": seconds, "longest_stall_s": turns.longest_gap,
                       "layers": len(viewer.layers)})
    out["reruns"] = reruns[1:]  # the first one replaces nothing
    out["rss_before_runs_mb"] = rss_before
    viewer.close()
    return out


def _warm_up_done() -> bool:
    """Whether the dock's warm-up has ended (this tree's idle pieces, or an older tree's
    warm-up thread)."""
    import sys

    warm = sys.modules.get("napari_meris_ortho._napari._qt.warm")
    if warm is not None and getattr(warm, "_STARTED", None) is not None:
        return bool(warm._STARTED.done.is_set())
    from napari_meris_ortho import warmup

    thread = getattr(warmup, "_STARTED", None)
    return thread is not None and not thread.is_alive()


def first_open(scene_name: str, dock_before: float | None, warm_up_stall: bool = False
               ) -> dict[str, Any]:
    """One fresh session: the window up, the dock opened ``dock_before`` s before the N1's
    first open (None: no dock), the open timed until it returns and one event turn ran; with
    ``warm_up_stall``, no open: the dock's opening (``add_plugin_dock_widget``) and the
    longest stall from its end to the end of the warm-up."""
    import tempfile

    os.environ["NAPARI_CONFIG"] = os.path.join(tempfile.mkdtemp(prefix="bench-napari-"),
                                               "settings.yaml")
    from qtpy.QtWidgets import QApplication

    import napari
    from napari_meris_ortho.simulate.scene import generate_scene

    product = str(generate_scene(scene_name).product_path)
    viewer = napari.Viewer(show=True)
    app = QApplication.instance()
    _spin(app, lambda: False, 1.0)  # the window is up
    out: dict[str, Any] = {"dock_before_s": dock_before}
    if warm_up_stall:
        with LoopTurns() as turns:
            t0 = time.perf_counter()
            viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
            shown = time.perf_counter()
            _spin(app, _warm_up_done, 600.0)
            out["warm_up_s"] = time.perf_counter() - t0
        out["dock_opening_s"] = shown - t0
        out["warm_up_longest_stall_s"] = turns.longest_gap_after(shown)
        viewer.close()
        return out
    if dock_before is not None:
        viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
        _spin(app, lambda: False, dock_before)
    t0 = time.perf_counter()
    viewer.open(product, plugin="napari-meris-ortho")
    app.processEvents()  # one turn of the event loop
    out["open_s"] = time.perf_counter() - t0
    viewer.close()
    return out


def _child(src: str, args: list[str]) -> dict[str, Any]:
    """This script's figures from a fresh process on the source tree ``src``."""
    import subprocess
    import sys
    import tempfile

    with tempfile.NamedTemporaryFile(suffix=".json") as fh:
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(
            [src, os.path.dirname(os.path.abspath(__file__))]))
        env.pop("MERIS_ORTHO_NO_WARMUP", None)
        subprocess.run([sys.executable, os.path.abspath(__file__), *args, "--json", fh.name],
                       env=env, check=True, timeout=1800)
        with open(fh.name) as result:
            return dict(json.load(result))


def first_open_table(scene_name: str, old_src: str) -> dict[str, Any]:
    """The first-open table, the warm-up's longest stall and one run, this tree and
    ``old_src``, each figure from fresh processes."""
    import napari_meris_ortho

    trees = {"new": os.path.dirname(os.path.dirname(napari_meris_ortho.__file__)),
             "old": os.path.abspath(old_src)}
    table: dict[str, Any] = {"trees": trees, "rows": []}
    for before in DOCK_BEFORE:
        row: dict[str, Any] = {"dock_before_s": before}
        for key, src in trees.items():
            flag = [] if before is None else ["--dock-before", str(before)]
            row[key] = [_child(src, ["--scene", scene_name, "--first-open", *flag])["open_s"]
                        for _ in range(OPEN_RUNS)]
        table["rows"].append(row)
        _print_row(row)
    for key, src in trees.items():
        table[f"{key}_warm_up"] = _child(src, ["--scene", scene_name, "--warm-up-stall"])
        table[f"{key}_run"] = _child(src, ["--scene", scene_name, "--runs", "1"])
    return table


def _print_row(row: dict[str, Any]) -> None:
    before = row["dock_before_s"]
    what = "no dock" if before is None else f"dock opened {before:g} s before"
    target = TARGET_PREPARED_S if before is not None and before >= 1.5 else TARGET_UNPREPARED_S
    cells = [f"{min(row[k]):.2f}-{max(row[k]):.2f} s" for k in ("new", "old")]
    print(f"| {what:<26} | {cells[0]:>13} | {cells[1]:>13} | <= {target:.1f} s |", flush=True)


def _print_table(table: dict[str, Any]) -> None:
    print(f"new: {table['trees']['new']}\nold: {table['trees']['old']}")
    print(f"| {'first open of a session':<26} | {'new':>13} | {'old':>13} | target   |")
    print(f"|{'-' * 28}|{'-' * 15}|{'-' * 15}|----------|")
    for row in table["rows"]:
        _print_row(row)
    for key in ("new", "old"):
        warm, run = table[f"{key}_warm_up"], table[f"{key}_run"]
        first = run["runs"][0]
        print(f"{key}: the dock opened in {warm['dock_opening_s']:.3f} s (napari's "
              f"add_plugin_dock_widget); its warm-up took {warm['warm_up_s']:.1f} s, longest "
              f"stall after the opening {warm['warm_up_longest_stall_s']:.3f} s "
              f"(target <= 0.1 s); a run "
              f"{first['run_s']:.2f} s, longest stall {first['longest_stall_s']:.3f} s, "
              f"{run['rss_after_first_run_mb']:.0f} MB after it "
              f"({run['rss_before_runs_mb']:.0f} MB before)")


def main() -> None:
    global RUNS, RERUNS
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="fr-alps")
    parser.add_argument("--sen3", action="store_true",
                        help="open the scene's .SEN3 product instead of its N1 (no runs)")
    parser.add_argument("--store", action="store_true",
                        help="open a Europe-size synthesis store of the scene (no runs)")
    parser.add_argument("--open-only", action="store_true",
                        help="measure the opening only (no runs)")
    parser.add_argument("--synthesis", type=int, default=0, metavar="N",
                        help="the runs: the widget's synthesis of N products of the scene")
    parser.add_argument("--json", help="write the figures to this file")
    parser.add_argument("--first-open-table", metavar="OLD_SRC",
                        help="the first-open table of this tree beside OLD_SRC's (module doc)")
    parser.add_argument("--first-open", action="store_true",
                        help="one first open of a fresh session (a row's measure)")
    parser.add_argument("--dock-before", type=float, default=None, metavar="S",
                        help="with --first-open: open the dock S seconds before")
    parser.add_argument("--warm-up-stall", action="store_true",
                        help="the longest stall while the dock warms up")
    parser.add_argument("--runs", type=int, default=None, metavar="N",
                        help=f"Orthorectify runs (default {RUNS}), no reruns when given")
    args = parser.parse_args()
    if args.first_open or args.warm_up_stall or args.first_open_table:
        if args.first_open_table:
            out = first_open_table(args.scene, args.first_open_table)
            _print_table(out)
        else:
            out = first_open(args.scene, args.dock_before, args.warm_up_stall)
        if args.json:
            with open(args.json, "w") as fh:
                json.dump(out, fh, indent=1)
        return
    if args.runs is not None:
        RUNS, RERUNS = args.runs, 0
    out = bench(args.scene, args.sen3, args.store, args.open_only, args.synthesis)
    print(f"source: {out['source']}")
    kind = "SEN3" if args.sen3 else "Europe-size synthesis store" if args.store else "N1"
    print(f"open {args.scene} {kind} to first pixels: {out['open_to_first_pixels_s']:.2f} s "
          f"(longest stall {out['open_longest_stall_s']:.2f} s), again "
          f"{out['warm_open_to_first_pixels_s']:.2f} s; longest stall in the 1.5 s after: "
          f"{out['after_open_longest_stall_s']:.2f} s, again "
          f"{out['warm_after_open_longest_stall_s']:.2f} s")
    if args.sen3:
        print(f"reader peak allocation (tracemalloc): {out['reader_peak_mb']:.1f} MB")
    elif not (args.store or args.open_only):
        _print_runs(out)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)


def _print_runs(out: dict[str, Any]) -> None:
    if out.get("synthesis"):
        print(f"runs: the widget's synthesis of {out['synthesis']} products (max-ndvi, 15 bands)")
    print(f"Orthorectify dock opened: longest stall {out['dock_open_longest_stall_s']:.3f} s")
    for k, run in enumerate(out["runs"]):
        print(f"run {k + 1}: {run['run_s']:.2f} s, longest UI stall "
              f"{run['longest_stall_s']:.3f} s, {run['layers']} layers")
    for k, run in enumerate(out.get("reruns", [])):
        print(f"rerun {k + 1} (replacing the last run's layers): {run['run_s']:.2f} s, "
              f"longest UI stall {run['longest_stall_s']:.3f} s, {run['layers']} layers")
    print(f"memory: {out['rss_before_runs_mb']:.0f} MB before the runs, "
          f"{out['rss_after_first_run_mb']:.0f} MB after the first, "
          f"{out['rss_after_runs_removed_mb']:.0f} MB after {RUNS} runs, layers removed "
          f"({out['rss_after_malloc_trim_mb']:.0f} MB after malloc_trim)")


if __name__ == "__main__":
    main()

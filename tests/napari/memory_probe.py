"""Resident memory of a fresh process around Orthorectify runs, for
``test_responsive.test_finished_runs_keep_nothing_but_their_layers``.

    python memory_probe.py PRODUCT.N1 SETTINGS.yaml   (in a session with a DISPLAY: Xvfb)

One warm-up run (numba compiles its kernels, napari makes its first layer of each kind), then
the resident memory (after ``gc.collect`` and glibc's ``malloc_trim``), four runs whose layers
are all removed after each, and the memory again. Prints one JSON line: ``before``, ``after``
(bytes), ``run_mb`` (the bands of one run). A fresh process: what the earlier tests of a pytest
session left in the allocator does not enter the measure.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import json
import os
import sys
import time


def main() -> None:
    product, settings = sys.argv[1], sys.argv[2]
    os.environ.setdefault("MERIS_ORTHO_NO_WARMUP", "1")
    import psutil
    from qtpy.QtCore import QEventLoop, QTimer

    import napari
    from napari import settings as napari_settings
    from napari_meris_ortho._napari.widget_ortho import OrthorectifyWidget

    napari_settings._CFG_PATH = settings  # never the user's napari settings

    def spin(ms: int) -> None:
        """Run the event loop for ``ms`` (deferred deletions of layer controls included)."""
        loop = QEventLoop()
        QTimer.singleShot(ms, loop.quit)
        loop.exec_()

    def run(widget: OrthorectifyWidget) -> None:
        if widget.start() is None:
            raise SystemExit(f"not started: {widget.status.value}")
        t0 = time.perf_counter()
        while widget.running:
            spin(20)
            if time.perf_counter() - t0 > 120:
                raise SystemExit("run did not finish in 120 s")
        if not widget.status.value.startswith("done"):
            raise SystemExit(f"run failed: {widget.status.value}")

    def rss() -> int:
        gc.collect()
        name = ctypes.util.find_library("c")
        if name:
            ctypes.CDLL(name).malloc_trim(0)
        return int(psutil.Process().memory_info().rss)

    viewer = napari.Viewer(show=False)
    widget = OrthorectifyWidget(viewer)
    widget.elevation.value = "tiepoints"
    widget.products.value = [product]
    widget.bands.value = "all"
    widget.pixel_size.value = 130.0  # 0.65 M output pixels: 40 MB of bands a run
    run(widget)
    viewer.layers.clear()
    spin(200)
    before = rss()
    run_mb = 0.0
    for _ in range(4):
        run(widget)
        run_mb = sum(_nbytes(layer) for layer in viewer.layers) / 2**20
        viewer.layers.clear()  # the next run's layers replace nothing: all four would stay
    spin(200)  # napari's layer controls are deleted by the event loop (deleteLater)
    after = rss()
    print(json.dumps({"before": before, "after": after, "run_mb": run_mb}))
    viewer.close()


def _nbytes(layer) -> int:
    """Bytes of a raster layer's arrays (every level of a multiscale one); 0 for shapes."""
    if isinstance(layer.data, list):  # shapes
        return 0
    levels = layer.data if layer.multiscale else [layer.data]
    return sum(level.nbytes for level in levels)


if __name__ == "__main__":
    main()

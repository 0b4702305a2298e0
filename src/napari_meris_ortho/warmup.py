"""Compile the numba kernels of ``orthorectify`` ahead of a user's first run.

numba compiles each kernel on its first call and caches the machine code (``cache=True``:
``__pycache__`` next to the sources, or ``NUMBA_CACHE_DIR``). ``warm_up()`` orthorectifies a
tiny synthetic product (``geometry.tiepoints.analytic_swath``, written as a real N1 file) with
every elevation source, sampling method and search method, on a geographic and a UTM grid, so
that the kernels and specialisations a ``meris-ortho map`` uses are compiled once (and the
COG overview kernel of its output dtypes).
``scripts/setup.sh`` runs ``python -m napari_meris_ortho.warmup`` in the background after
installing.

The napari Orthorectify widget never compiles in its own process: numba's compiler holds the
GIL for the length of a compilation, and a user opening a product meanwhile would wait for it.
``kernels_out_of_process`` runs ``warm_up`` in a child process of low priority (it fills
numba's on-disk cache, or only reads it when it is warm) and returns the specialisations it
used (``kernel_signatures``); the widget then loads them from the cache one kernel at a time
(``load_kernel``), each piece a few milliseconds, only in turns when the window is idle.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from ._process import numba_cache_index, start_numba_without_blas, tune_process

_STARTED: threading.Thread | None = None
#: (elevation, sampling, method, crs) combinations compiled by ``warm_up``
RUNS = (("none", "nearest", "primary", "EPSG:4326"),
        ("tiepoints", "bilinear", "primary", "EPSG:4326"),
        ("dem", "bicubic", "primary", "EPSG:4326"),
        ("dem", "nearest", "primary", "utm"),
        ("dem", "nearest", "handbook", "EPSG:4326"))


def _tiny_product(directory: Path) -> tuple[Path, Path]:
    """A 70 x 129 FR product on the analytic swath and a GeoTIFF DEM under it."""
    import rasterio
    from rasterio.transform import from_origin

    from .geometry.tiepoints import analytic_swath
    from .products.n1 import write_product

    height, width = 70, 129
    g = analytic_swath(height=height, width=width)
    tp = dict(latitude=g.latitude, longitude=(g.longitude + 180.0) % 360.0 - 180.0,
              view_zenith=g.view_zenith, view_azimuth=g.view_azimuth,
              dem_alt=np.round(g.dem_alt))
    counts = [np.full((height, width), 100 + b, np.uint16) for b in range(15)]
    product = write_product(directory / "warmup.N1", product_type="MER_FR__1P", tie_points=tp,
                            counts=counts, flags=np.zeros((height, width), np.uint8),
                            detector_index=np.zeros((height, width), np.int16),
                            first_line_time=dt.datetime(2003, 9, 21, 9, 23))
    lon0, lat0 = float(tp["longitude"].min()) - 0.5, float(tp["latitude"].min()) - 0.5
    lon1, lat1 = float(tp["longitude"].max()) + 0.5, float(tp["latitude"].max()) + 0.5
    res = 0.01
    w, h = int((lon1 - lon0) / res), int((lat1 - lat0) / res)
    dem = directory / "warmup_dem.tif"
    with rasterio.open(dem, "w", driver="GTiff", width=w, height=h, count=1, dtype="float32",
                       crs="EPSG:4326", transform=from_origin(lon0, lat1, res, res)) as ds:
        ds.write(np.full((h, w), 1000.0, np.float32), 1)
        ds.update_tags(VERTICAL_DATUM="ellipsoid")  # says its datum: no warning at every start
    return product, dem


#: band dtypes of ``meris-ortho map`` outputs (``--dtype``): their COG overview kernel
OVERVIEW_DTYPES = (np.uint16, np.float32)


def warm_up() -> float:
    """Run ``orthorectify`` on a tiny product in every configuration of ``RUNS``, the
    overview kernel of the map outputs (``engine.resample.overview_level``) and the ZNCC
    disparity (``analysis.disparity``: the Flicker widget's "Measure disparity" would compile
    it, 8 s, at its first use); seconds."""
    from .analysis.disparity import disparity
    from .engine.resample import overview_level
    from .geometry.grid import utm_crs_for
    from .ortho import orthorectify
    from .products.n1 import read_product

    t0 = time.perf_counter()
    for dtype in OVERVIEW_DTYPES:
        overview_level(np.ones((3, 3), dtype), 0.0)
    texture = np.random.default_rng(0).random((40, 40)).astype(np.float32) + 1.0
    disparity(texture, texture, pixel_size_m=(260.0, 260.0))  # the widget's arguments
    with tempfile.TemporaryDirectory(prefix="meris-ortho-warmup-") as tmp:
        product, dem = _tiny_product(Path(tmp))
        tp = read_product(product).tie_points
        utm = utm_crs_for(float(tp["longitude"].mean()), float(tp["latitude"].mean()))
        for elevation, sampling, method, crs in RUNS:
            orthorectify(product, dems=[dem] if elevation == "dem" else (), elevation=elevation,
                         sampling=sampling, method=method, bands=[1, 2],
                         crs=utm if crs == "utm" else crs, diagnostics=method == "handbook")
    return time.perf_counter() - t0


def compile_late() -> float:
    """Compile, on tiny inputs of the types ``meris-ortho map`` gives them, the kernels a map
    calls after its first ones, in the order it needs them (while the map compiles the
    primary-grid search, this compiles what comes next): the height rates and
    prediction/correction rows, the counts of solved points, the antecedent window, the
    extent of the antecedents, the byte-swapped copy of the bands' window, the nearest-pixel
    index and gather of counts, the COG overview kernel, and the DEM lookup and geoid
    interpolation (the numba cache keeps them); seconds."""
    from .engine import terrain
    from .engine.predcorr import find_antecedents, height_rates, solved_counts
    from .engine.resample import (
        copy_window,
        finite_extent,
        gather,
        inside_range,
        nearest_pixel,
        overview_level,
    )
    from .geometry.tiepoints import analytic_swath

    t0 = time.perf_counter()
    tp = analytic_swath(height=70, width=129)
    _, _, coef, df, dj = tp.kernel_args()
    z = np.zeros((2, 2))
    spans = (np.array([0, 1, 2], np.int64), np.zeros(2, np.int64), np.full(2, 2, np.int64))
    rates = height_rates(z, z, coef, df, dj, 0, 0)
    find_antecedents(z, z, np.zeros((2, 2), np.float32), 2, *spans, z, z, rates, 16.0, coef,
                     df, dj, tp.height, tp.width, 0, 0, 0.01, 10, False)
    solved_counts(np.zeros(2, np.int8), np.zeros(2, np.int8), -1, 2)
    inside_range(np.zeros(2, np.float32), np.zeros(2, np.float32), 2, 2)
    finite_extent(np.zeros((2, 2), np.float32))
    copy_window(np.zeros((2, 2), np.uint16), np.zeros((2, 2), ">u2"))
    index = nearest_pixel(np.zeros(4, np.float32), np.zeros(4, np.float32), 2, 2,
                          line_offset=1, col_offset=1)
    gather(np.zeros((1, 2, 2), np.uint16), index, np.zeros((1, 4), np.uint16))
    overview_level(np.ones((3, 3), np.uint16), 0.0)
    one = np.zeros(1)  # last: a map needs it early, before this child is up (it compiles it)
    terrain.window_heights(np.zeros((2, 2), np.float32), np.zeros(6), np.zeros(4, np.int64),
                           0.0, terrain.METHOD_CODES["bilinear"], one, one,
                           np.zeros(1, bool), np.empty(0), 0, np.zeros(1, np.float32),
                           np.zeros(1, np.int8), np.zeros(1, bool))
    terrain.geoid_bilinear(np.zeros((2, 2)), 0, 0, 0.25, one, one, np.ones(1, bool), one)
    return time.perf_counter() - t0


def cache_is_cold() -> bool:
    """True when numba's cache holds no machine code of the prediction/correction kernel for
    this installation (a first run): its index file is missing."""
    from .engine import predcorr

    index = numba_cache_index(predcorr._antecedent_rows)
    return index is not None and not os.path.exists(index)


def compile_late_in_background() -> subprocess.Popen[bytes] | None:
    """On a cold cache (``cache_is_cold``), ``compile_late`` in a child process, on the other
    core, while this process compiles and runs the first kernels of a map; the map then loads
    the late ones from the cache. None when the cache is warm or ``MERIS_ORTHO_NO_WARMUP`` is
    set. The caller ends the child with ``stop``."""
    if os.environ.get("MERIS_ORTHO_NO_WARMUP") or not cache_is_cold():
        return None
    try:
        return subprocess.Popen([sys.executable, "-m", "napari_meris_ortho.warmup", "--late"],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
    except OSError:  # best effort: a cold cache only costs time
        return None


def stop(child: subprocess.Popen[bytes] | None) -> None:
    """End a background compilation that is still running (numba writes its cache files
    atomically: an interrupted compilation leaves nothing half written)."""
    if child is not None and child.poll() is None:
        child.terminate()
        with contextlib.suppress(subprocess.TimeoutExpired):
            child.wait(timeout=5)


Signature = tuple[str, str, Any]  # module, kernel name, argument types


def kernel_signatures() -> list[Signature]:
    """Every specialisation of the package's ``cache=True`` kernels compiled (or loaded) in
    this process so far: (module, name, argument types), in the order of the modules."""
    from numba.core.dispatcher import Dispatcher

    out: list[Signature] = []
    for module_name, module in list(sys.modules.items()):
        if not module_name.startswith("napari_meris_ortho.") or module is None:
            continue
        for name, obj in list(vars(module).items()):
            if (isinstance(obj, Dispatcher) and obj.__module__ == module_name
                    and numba_cache_index(obj) is not None):
                out += [(module_name, name, sig) for sig in obj.signatures]
    return out


#: seconds the child of ``kernels_out_of_process`` may take (a cold cache compiles every kernel)
CHILD_TIMEOUT_S = 900.0


def kernels_out_of_process(timeout: float = CHILD_TIMEOUT_S) -> list[Signature]:
    """``warm_up`` in a child process at the lowest priority (numba's on-disk cache filled, or
    read when warm), and the specialisations it used (``kernel_signatures``); [] when the child
    fails. Waiting holds no GIL."""
    import pickle

    try:
        proc = subprocess.run([sys.executable, "-m", "napari_meris_ortho.warmup", "--child"],
                              stdin=subprocess.DEVNULL, capture_output=True, timeout=timeout,
                              check=True)
        return list(pickle.loads(proc.stdout))
    except (OSError, subprocess.SubprocessError, pickle.UnpicklingError, EOFError,
            ValueError, TypeError, AttributeError, ImportError):
        return []  # best effort: the first run loads or compiles what it needs


def load_kernel(signature: Signature) -> bool:
    """Load one specialisation from numba's on-disk cache into this process (a few ms); False,
    doing nothing, when the cache has no file of that kernel (it would compile here, holding
    the GIL for seconds)."""
    import importlib

    module_name, name, sig = signature
    kernel: Any = getattr(importlib.import_module(module_name), name, None)
    index = None if kernel is None else numba_cache_index(kernel)
    if kernel is None or index is None or not os.path.exists(index):
        return False
    if tuple(sig) not in kernel.overloads:
        kernel.compile(tuple(sig))
    return True


def warm_up_in_background() -> threading.Thread | None:
    """``warm_up`` once per process in a daemon thread (errors are ignored: a cold cache
    only costs time); nothing when ``MERIS_ORTHO_NO_WARMUP`` is set (tests)."""
    global _STARTED
    if os.environ.get("MERIS_ORTHO_NO_WARMUP"):
        return None
    if _STARTED is None:
        def run() -> None:
            try:
                warm_up()
            except Exception:  # best effort: never disturbs the caller
                pass

        _STARTED = threading.Thread(target=run, name="meris-ortho-warmup", daemon=True)
        _STARTED.start()
    return _STARTED


def _child() -> None:
    """``kernels_out_of_process``'s child: ``warm_up`` at the lowest priority, then the
    pickled ``kernel_signatures`` on stdout (nothing else is written there)."""
    import pickle

    with contextlib.suppress(OSError):
        os.nice(19)
    tune_process()
    start_numba_without_blas()
    out = sys.stdout.buffer
    sys.stdout = sys.stderr  # anything printed meanwhile stays off the pickle's stream
    warm_up()
    out.write(pickle.dumps(kernel_signatures()))
    out.flush()


if __name__ == "__main__":
    if sys.argv[1:] == ["--late"]:  # a child of `meris-ortho map`: a process of ours
        tune_process()
        start_numba_without_blas()
        compile_late()
    elif sys.argv[1:] == ["--child"]:  # a child of the napari widget's warm-up
        _child()
    else:
        print(f"numba kernels compiled in {warm_up():.1f} s")

"""Index ranges of serial kernels on threads (engine.threads): every index once, and the engine's
results equal to one whole-range call."""

from __future__ import annotations

import os

import numpy as np
import pytest

from napari_meris_ortho.engine import predcorr, threads
from napari_meris_ortho.engine.boundary import row_spans, segment_boundary
from napari_meris_ortho.engine.location import direct_location
from napari_meris_ortho.engine.resample import gather, nearest_pixel
from napari_meris_ortho.geometry.grid import OutputGrid
from napari_meris_ortho.geometry.tiepoints import analytic_swath


@pytest.mark.parametrize("n, pieces, min_size", [(10, 3, 1), (7, 8, 1), (100, 8, 30),
                                                 (5, 4, 10), (1, 4, 1), (0, 4, 1)])
def test_ranges_cover_every_index_once_in_order(n, pieces, min_size):
    parts = threads.ranges(n, pieces, min_size)
    assert [i for lo, hi in parts for i in range(lo, hi)] == list(range(n))
    assert all(hi > lo for lo, hi in parts)
    assert len(parts) <= pieces
    sizes = [hi - lo for lo, hi in parts]
    if sizes:
        assert max(sizes) - min(sizes) <= 1
        assert len(parts) == 1 or min(sizes) >= min_size


@pytest.mark.parametrize("n_threads", [1, 2, 3])
def test_split_range_calls_the_kernel_once_per_index(n_threads):
    seen = np.zeros(1001, np.int64)
    calls = []

    def kernel(lo, hi):
        calls.append((lo, hi))
        seen[lo:hi] += 1

    threads.split_range(kernel, seen.size, threads=n_threads)
    assert np.all(seen == 1)
    assert len(calls) == (1 if n_threads == 1 else n_threads * 4)
    threads.split_range(kernel, 0, threads=n_threads)  # nothing to do: no call
    assert np.all(seen == 1)


def test_split_range_raises_the_kernels_error():
    def kernel(lo, hi):
        if lo > 0:
            raise ValueError("boom")

    with pytest.raises(ValueError, match="boom"):
        threads.split_range(kernel, 100, threads=2)


def test_usable_cores_is_the_affinity():
    from napari_meris_ortho.cores import usable_cores

    assert usable_cores() == len(os.sched_getaffinity(0)) >= 1


@pytest.mark.parametrize("env, expected", [
    ({}, None), ({"NUMBA_NUM_THREADS": "1"}, 1), ({"OMP_NUM_THREADS": "1"}, 1),
    ({"NUMBA_NUM_THREADS": "3", "OMP_NUM_THREADS": "1"}, 3),  # numba's own first
    ({"NUMBA_NUM_THREADS": "0", "OMP_NUM_THREADS": "2"}, 2),  # not positive: the next one
    ({"OMP_NUM_THREADS": "four"}, None), ({"NUMBA_NUM_THREADS": " 2 "}, 2)])
def test_the_environment_limits_the_engine_threads(monkeypatch, env, expected):
    """``NUMBA_NUM_THREADS``, else ``OMP_NUM_THREADS`` (what a dask nanny gives its workers)
    cap the engine's threads at the usable cores; the cores themselves stay the affinity."""
    from napari_meris_ortho.cores import thread_limit, usable_cores, usable_threads

    for name in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS"):
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    cores = len(os.sched_getaffinity(0))
    assert thread_limit() == expected
    assert usable_cores() == cores
    assert usable_threads() == (cores if expected is None else min(cores, expected))


def test_one_thread_asked_for_runs_every_range_on_the_calling_thread(monkeypatch):
    import threading

    monkeypatch.delenv("NUMBA_NUM_THREADS", raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    callers = set()

    def kernel(lo, hi):
        callers.add(threading.get_ident())

    threads.split_range(kernel, 1000)
    assert callers == {threading.get_ident()}
    monkeypatch.delenv("OMP_NUM_THREADS")
    if len(os.sched_getaffinity(0)) > 1:  # no limit: the pool's threads run the ranges
        callers.clear()
        threads.split_range(kernel, 1000)
        assert threading.get_ident() not in callers and len(callers) >= 1


@pytest.fixture(scope="module")
def scene():
    tp = analytic_swath(height=200, width=513, lon0=11.0)
    b = segment_boundary(tp.latitude, tp.longitude)
    d = np.degrees(260.0 / 6370997.0)
    x0, x1 = b.lon.min(), b.lon.max()
    grid = OutputGrid("EPSG:4326", x0, b.lat.max(), d * 1.4, d, int((x1 - x0) / (d * 1.4)) + 1,
                      int((b.lat.max() - b.lat.min()) / d) + 1)
    lon, lat = grid.lonlat()
    spans = row_spans(b, grid, margin=10)
    h = (800.0 + 700.0 * np.sin(np.radians(lon) * 40.0)).astype(np.float32)
    return tp, grid, lon, lat, h, (spans.ptr, spans.start, spans.stop)


def _run_all(scene):
    tp, grid, lon, lat, h, spans = scene
    out = {}
    for method in ("primary", "handbook"):
        res = predcorr.solve(tp, grid, lon, lat, h, predcorr.HEIGHT_GIVEN, spans,
                             method=method, diagnostics=True, geo=1, model=1)
        for k in ("line", "col", "iterations", "elevation", "shift_east_m", "shift_north_m"):
            out[method, k] = res[k]
        out[method, "search"] = res["search"]
    ok = out["primary", "iterations"] >= 0
    line = out["primary", "line"][ok]
    col = out["primary", "col"][ok]
    out["direct"] = direct_location(tp, line, col, h[ok], "ellipsoid")
    index = nearest_pixel(out["primary", "line"], out["primary", "col"], 150, tp.width,
                          line_offset=20)
    out["index"] = index
    images = np.arange(2 * 150 * tp.width, dtype=np.uint16).reshape(2, 150, tp.width)
    values = np.empty((2, index.size), np.uint16)
    gather(images, index, values)
    out["gather"] = values
    return out


def test_engine_results_equal_one_whole_range_call(scene, monkeypatch):
    """Rows and points split over 1, 2 or 3 threads (ranges as small as the kernels allow)
    give the same numbers, bit for bit."""
    monkeypatch.setattr(threads, "usable_threads", lambda: 1)
    ref = _run_all(scene)
    assert np.count_nonzero(ref["primary", "iterations"] >= 0) > 10000
    assert np.count_nonzero(ref["index"] >= 0) > 10000
    assert ref["index"].size > 1 << 17  # points in more than one gather/nearest range
    for n in (2, 3):
        monkeypatch.setattr(threads, "usable_threads", lambda n=n: n)
        got = _run_all(scene)
        assert got.keys() == ref.keys()
        for k, v in ref.items():
            if isinstance(v, dict):
                assert got[k] == v
            elif isinstance(v, tuple):
                for a, b in zip(got[k], v, strict=True):
                    np.testing.assert_array_equal(a, b)
            else:
                np.testing.assert_array_equal(got[k], v)


def test_nearest_pixel_float32_with_offset_equals_the_float64_shifted_call():
    rng = np.random.default_rng(3)
    line = rng.uniform(-5, 60, 5000).astype(np.float32)
    col = rng.uniform(-5, 40, 5000).astype(np.float32)
    line[::50] = np.nan
    got = nearest_pixel(line, col, 30, 35, line_offset=17)
    ref = nearest_pixel(line.astype(np.float64) - 17, col.astype(np.float64), 30, 35)
    np.testing.assert_array_equal(got, ref)
    x = line.astype(np.float64) - 17
    inside = (x >= -0.5) & (x < 29.5) & (col >= -0.5) & (col < 34.5)
    assert np.all((ref >= 0) == inside)
    np.testing.assert_array_equal(
        ref[inside], np.floor(x[inside] + 0.5) * 35 + np.floor(col[inside] + 0.5))

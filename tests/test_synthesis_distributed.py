"""Synthesis on dask.distributed workers (synthesis/: api, run): a real LocalCluster
gives the bytes of the in-process run in any product order, MERIS and OLCI products mixed;
an unreachable scheduler, two concurrent runs on one store and a corrupt product among many
end cleanly."""

from __future__ import annotations

import ctypes
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from napari_meris_ortho.cli import main
from napari_meris_ortho.synthesis.api import synthesize
from napari_meris_ortho.synthesis.reading import open_synthesis
from test_synthesis import GRID, layers, scene_product

COMMON = dict(grid=GRID, bands=(7, 13), tile=256, elevation="tiepoints")
GRID_ARGS = ["--crs", "EPSG:4326", "--ul", "13.45", "46.70", "--lr", "14.26", "46.19",
             "--pixel-size", "0.0015", "--bands", "7,13", "--elevation", "tiepoints",
             "--tile", "256"]
#: a test cluster serves no dashboard, and its scheduler's HTTP endpoints take a free port: at
#: 8787 (distributed's default) a second cluster beside the module's would find it taken
NO_DASHBOARD = dict(dashboard_address=None, scheduler_kwargs={"dashboard_address": ":0"})


@pytest.fixture(scope="module")
def products() -> list[str]:
    """4 small simulated products of one area: cloudy dates (distinct product names)."""
    return [scene_product({"fraction": 0.4, "scale_km": 12.0, "seed": 10 * k})
            for k in (1, 2, 3, 4)]


@pytest.fixture(scope="module")
def cluster():
    """A real LocalCluster: 2 worker processes, one thread each."""
    from distributed import LocalCluster

    from napari_meris_ortho.synthesis.run import WORKER_ENV

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      **NO_DASHBOARD, env=WORKER_ENV) as c:
        yield c


def _same(a: Path, b: Path) -> None:
    left, right = layers(a), layers(b)
    assert left.keys() == right.keys()
    for key in left:
        assert left[key].tobytes() == right[key].tobytes(), key


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", ["max-ndvi", "min-radiance"])
def test_workers_give_the_bytes_of_one_process_in_any_order(products, cluster, tmp_path,
                                                            algorithm) -> None:
    single = tmp_path / "single"
    result = synthesize(products, single, algorithm=algorithm, **COMMON)
    assert len(result.merged) == 4 and not result.failed
    winners = open_synthesis(single).read("product")
    assert set(np.unique(winners)) == {0, 1, 2, 3, 4}  # every product wins somewhere
    orders = [products[::-1], [products[k] for k in (2, 0, 3, 1)]]
    for k, order in enumerate(orders):
        out = tmp_path / f"cluster{k}"
        result = synthesize(order, out, algorithm=algorithm,
                            scheduler=cluster.scheduler_address, **COMMON)
        assert len(result.merged) == 4
        _same(single, out)
    # and in two runs on the cluster (an update adds two products), same bytes again
    update = tmp_path / "update"
    synthesize(products[2:], update, algorithm=algorithm, scheduler=cluster.scheduler_address,
               **COMMON)
    synthesize(products[:2], update, input=update, scheduler=cluster.scheduler_address,
               elevation="tiepoints")
    for key, value in layers(update).items():
        if key != "product":  # indices follow the order products came in
            assert value.tobytes() == layers(single)[key].tobytes(), key


def test_one_task_per_tile_and_nothing_moves_between_workers(products, cluster,
                                                             tmp_path) -> None:
    """A tile's pieces are orthorectified in the tile's own task and merged as they come, so the
    cluster runs one task per tile touched and no data travels between workers (no (product,
    tile) task per piece, no piece shipped to its tile task)."""
    from distributed import Client, get_task_stream

    from napari_meris_ortho.synthesis.tiling import tiles

    with Client(cluster.scheduler_address) as client, get_task_stream(client) as stream:
        result = synthesize(products, tmp_path / "s", scheduler=cluster.scheduler_address,
                            **COMMON)
    assert len(result.merged) == 4
    records = [r for r in stream.data if str(r["key"]).startswith(("tile-", "segment-"))]
    keys = {str(r["key"]) for r in records}
    grid_tiles = len(list(tiles((0, GRID.height, 0, GRID.width), 256)))
    assert keys and all(k.startswith("tile-") for k in keys)
    assert 2 <= len(keys) <= grid_tiles
    moved = [ss for r in records for ss in r["startstops"] if ss["action"] == "transfer"]
    assert not moved, moved


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", ["max-ndvi", "min-radiance"])
def test_mixed_meris_olci_synthesis_is_the_same_bytes_on_workers_in_any_order(
        products, cluster, tmp_path, algorithm) -> None:
    """Two MERIS and two OLCI dates (a store of MERIS bands): the layers of the in-process run
    in one order are those of the cluster in two others and of an embedded cluster
    (``workers=2``); both sensors win pixels. A kill-safe update on the cluster (two runs) gives
    the same bands, NDVI and counts."""
    from test_synthesis_olci import write_olci_over_grid

    olci = [str(write_olci_over_grid(tmp_path, seed=k, day=10 + k)) for k in (1, 2)]
    mixed = [products[0], olci[0], products[1], olci[1]]
    single = tmp_path / "single"
    result = synthesize(mixed, single, algorithm=algorithm, **COMMON)
    assert len(result.merged) == 4 and not result.failed
    store = open_synthesis(single)
    sensors = store.sensor_of_pixels()
    assert (sensors == 1).sum() > 1000 and (sensors == 2).sum() > 1000  # MERIS, OLCI
    runs = [(mixed[::-1], dict(scheduler=cluster.scheduler_address)),
            ([mixed[k] for k in (1, 3, 0, 2)], dict(scheduler=cluster.scheduler_address)),
            ([mixed[k] for k in (3, 2, 1, 0)], dict(workers=2))]
    for k, (order, where) in enumerate(runs):
        out = tmp_path / f"run{k}"
        assert len(synthesize(order, out, algorithm=algorithm, **where, **COMMON).merged) == 4
        _same(single, out)
    update = tmp_path / "update"
    synthesize(mixed[1::2], update, algorithm=algorithm, band_set="MERIS",
               scheduler=cluster.scheduler_address, **COMMON)
    synthesize(mixed[::2], update, input=update, scheduler=cluster.scheduler_address,
               elevation="tiepoints")
    for key, value in layers(update).items():
        if key != "product":  # indices follow the order products came in
            assert value.tobytes() == layers(single)[key].tobytes(), key


@pytest.mark.slow
def test_embedded_local_cluster(products, tmp_path) -> None:
    """``workers=2`` starts its own LocalCluster (worker processes) and closes it."""
    synthesize(products[:2], tmp_path / "single", **COMMON)
    result = synthesize(products[:2][::-1], tmp_path / "two", workers=2, **COMMON)
    assert len(result.merged) == 2
    _same(tmp_path / "single", tmp_path / "two")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.timeout(60)
@pytest.mark.slow
def test_unreachable_scheduler_is_one_message_exit_2(products, tmp_path, capsys) -> None:
    address = f"tcp://127.0.0.1:{_free_port()}"  # nobody listens there
    out = tmp_path / "syn"
    assert main(["-q", "synthesize", products[0], "--out", str(out), "--scheduler", address,
                 *GRID_ARGS]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("meris-ortho: error: cannot reach the dask "
                                               f"scheduler at {address}")
    assert not out.exists()
    assert main(["-q", "synthesize", products[0], "--out", "relative/syn", "--scheduler",
                 address, *GRID_ARGS]) == 2
    assert "absolute path" in capsys.readouterr().err


def test_store_that_is_not_a_synthesis(products, tmp_path, capsys) -> None:
    for path in (tmp_path, tmp_path / "missing"):
        assert main(["-q", "synthesize", products[0], "--input", str(path), "--out",
                     str(path), "--workers", "0"]) == 2
        assert "not a synthesis store" in capsys.readouterr().err
        assert main(["-q", "synthesis-log", str(path)]) == 2
        assert "not a synthesis store" in capsys.readouterr().err


def test_corrupt_product_among_many(products, tmp_path, caplog) -> None:
    """Reported, skipped, exit 1; the others merged as if it were not there."""
    bad = tmp_path / "corrupt.N1"
    bad.write_bytes(Path(products[1]).read_bytes()[:20000])
    out, ref = tmp_path / "syn", tmp_path / "ref"
    assert main(["-q", "synthesize", products[0], str(bad), *products[2:], "--out", str(out),
                 "--workers", "0", *GRID_ARGS]) == 1
    assert "corrupt.N1" in caplog.text
    synthesize([products[0], *products[2:]], ref, **COMMON)
    _same(out, ref)
    commit = open_synthesis(out).history()[0]
    assert [p["status"] for p in commit.products] == ["merged", "failed", "merged", "merged"]
    assert "corrupt.N1" in commit.products[1]["product"]


@pytest.mark.slow
def test_two_concurrent_runs_on_one_store(products, tmp_path) -> None:
    """Two processes start the same new synthesis at once: one commits, the other ends with
    one message (exit 2): the lock is held from the "is there a synthesis" check to the
    commit. Then two concurrent updates: never a corrupted store."""
    out = tmp_path / "syn"
    cmd = [sys.executable, "-m", "napari_meris_ortho.cli", "-q", "synthesize", *products[:2],
           "--out", str(out), "--workers", "0", *GRID_ARGS]
    procs = [subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    outcomes = sorted((p.wait(timeout=300), p.stderr.read()) for p in procs)
    for p in procs:
        p.stderr.close()
    assert [code for code, _ in outcomes] == [0, 2], outcomes
    message = outcomes[1][1].strip().splitlines()
    assert len(message) == 1 and message[0].startswith("meris-ortho: error:")
    assert "another synthesis run is using it" in message[0] or \
        "already holds a synthesis" in message[0]
    assert len(open_synthesis(out).history()) == 1
    synthesize(products[:2], tmp_path / "ref", **COMMON)
    _same(out, tmp_path / "ref")
    update = [sys.executable, "-m", "napari_meris_ortho.cli", "-q", "synthesize",
              "--input", str(out), "--out", str(out), "--workers", "0",
              "--elevation", "tiepoints"]
    procs = [subprocess.Popen([*update, p], stderr=subprocess.PIPE, text=True)
             for p in products[2:]]
    codes = [p.wait(timeout=300) for p in procs]
    errors = [p.stderr.read() for p in procs]
    for p in procs:
        p.stderr.close()
    assert sorted(codes) in ([0, 0], [0, 2]), errors
    store = open_synthesis(out)
    assert len(store.history()) == 1 + codes.count(0)
    merged = [products[2 + k] for k, c in enumerate(codes) if c == 0]
    synthesize(merged, tmp_path / "ref", input=tmp_path / "ref", elevation="tiepoints")
    for key, value in layers(tmp_path / "ref").items():
        if key != "product":
            assert value.tobytes() == layers(out)[key].tobytes(), key


@pytest.mark.slow
def test_embedded_workers_are_held_to_a_core_each_when_they_fit() -> None:
    """As many embedded workers as cores: each worker process is held to a core of its own,
    every thread it runs and the threads it starts later (Icechunk's, zstd's); fewer workers
    than cores are left free (``run.hold_workers_to_cores``)."""
    import os
    import threading

    from napari_meris_ortho.synthesis.run import engine

    def thread_cores() -> list[tuple[int, ...]]:
        later: list[tuple[int, ...]] = []
        t = threading.Thread(target=lambda: later.append(tuple(sorted(os.sched_getaffinity(0)))))
        t.start()
        t.join()
        now = [tuple(sorted(os.sched_getaffinity(int(tid))))
               for tid in os.listdir("/proc/self/task")]
        return now + later

    cores = tuple(sorted(os.sched_getaffinity(0)))
    if len(cores) <= 4:  # the CLI's own path: one embedded worker per core
        with engine(len(cores), None) as runner:
            held = runner.client.run(thread_cores)
    else:  # a bigger machine: 2 workers held as ``every`` holds them, not 1 per core
        from distributed import Client, LocalCluster

        from napari_meris_ortho.synthesis.run import WORKER_ENV, hold_workers_to_cores

        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                          **NO_DASHBOARD, env=WORKER_ENV) as cluster, \
                Client(cluster, set_as_default=False) as client:
            assert hold_workers_to_cores(client) == {}  # fewer workers than cores: free
            assert sorted(hold_workers_to_cores(client, every=True).values()) == [*cores[:2]]
            held = client.run(thread_cores)
        cores = cores[:2]
    assert len(held) == len(cores)
    per_worker = [set(threads) for threads in held.values()]
    assert all(len(s) == 1 and len(next(iter(s))) == 1 for s in per_worker), per_worker
    assert sorted(next(iter(s))[0] for s in per_worker) == list(cores)
    all_cores = tuple(sorted(os.sched_getaffinity(0)))
    if len(all_cores) > 1:
        with engine(1, None) as runner:
            free = runner.client.run(thread_cores)
        assert [set(threads) for threads in free.values()] == [{all_cores}]


@pytest.mark.slow
def test_a_one_thread_worker_runs_the_engine_on_one_thread() -> None:
    """A worker of one thread runs its task's kernels on that thread, not on every core (N
    workers on N cores: N x N busy threads): our embedded workers (``WORKER_ENV``) and a dask
    nanny's worker as ``dask worker --nthreads 1`` starts it (its ``OMP_NUM_THREADS=1``)."""
    from distributed import Client, LocalCluster

    from napari_meris_ortho.cores import usable_cores, usable_threads
    from napari_meris_ortho.synthesis.run import WORKER_ENV, engine

    def threads_and_cores() -> tuple[int, int]:
        return usable_threads(), usable_cores()

    cores = len(os.sched_getaffinity(0))
    with engine(1, None) as runner:  # one free worker: every core usable, one thread used
        assert list(runner.client.run(threads_and_cores).values()) == [(1, cores)]
    assert WORKER_ENV["NUMBA_NUM_THREADS"] == "1"
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      **NO_DASHBOARD) as cluster, \
            Client(cluster, set_as_default=False) as client:  # no env of ours: the nanny's
        assert list(client.run(threads_and_cores).values()) == [(1, cores)]


def _mapped_bytes_of_an_array() -> int:
    """Bytes glibc maps on their own (``mallinfo2().hblkhd``) for an 8 MiB array held."""

    class Mallinfo2(ctypes.Structure):
        _fields_ = [(name, ctypes.c_size_t) for name in (
            "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
            "fordblks", "keepcost")]

    mallinfo2 = ctypes.CDLL(None).mallinfo2
    mallinfo2.restype = Mallinfo2
    before = mallinfo2().hblkhd
    array = np.ones(1 << 20, np.float64)
    mapped = mallinfo2().hblkhd - before
    del array
    return int(mapped)


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(ctypes.CDLL(None), "mallinfo2"),
                    reason="glibc's malloc (2.33 or later: mallinfo2)")
def test_a_worker_keeps_its_arrays_in_its_heap_once_it_runs_a_tile(products, tmp_path) -> None:
    """A dask nanny starts its worker with ``MALLOC_TRIM_THRESHOLD_=65536``, which holds glibc's
    mmap threshold at 128 KiB: every array of a tile is mapped on fresh pages and unmapped when
    freed. Once the worker has run a tile task, an array under 32 MiB comes from its heap
    (``_process.keep_task_arrays``). The client's own process is left as it is."""
    from distributed import Client, LocalCluster

    from napari_meris_ortho.synthesis.run import WORKER_ENV, _tune_worker

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      **NO_DASHBOARD, env=WORKER_ENV) as cluster, \
            Client(cluster, set_as_default=False) as client:
        fresh = list(client.run(_mapped_bytes_of_an_array).values())
        synthesize(products[:2], tmp_path / "s", scheduler=cluster.scheduler_address, **COMMON)
        tuned = list(client.run(_mapped_bytes_of_an_array).values())
    assert fresh[0] >= 8 << 20, fresh  # the nanny's setting: mapped on its own
    assert tuned == [0], tuned
    assert _tune_worker() is False  # not a worker: this process untouched


def _keep_band_7(path: str) -> int:
    """On a worker: band 7 of ``path`` decoded into the worker's product cache and kept, as a
    run's tasks keep it; the bytes the worker then keeps."""
    from napari_meris_ortho.products.sen3.kept import keep_decoded_bands, kept_bytes
    from napari_meris_ortho.synthesis.run import _product

    keep_decoded_bands()
    _product(path).counts(7)
    return kept_bytes()


@pytest.mark.slow
def test_workers_free_the_decoded_sen3_bands_at_the_end_of_a_run(cluster, tmp_path) -> None:
    """A run's tasks keep the .SEN3 bands they decode (once per worker, not per tile); an
    external cluster's workers outlive the run, which frees them on every worker."""
    from distributed import Client

    from napari_meris_ortho.products.sen3.kept import kept_bytes
    from napari_meris_ortho.simulate.geocorrected import write_geocorrected
    from napari_meris_ortho.simulate.scene import generate_scene

    sen3 = write_geocorrected(generate_scene("fr-small"), fsg=False, out_dir=tmp_path)["sen3"]
    with Client(cluster.scheduler_address, set_as_default=False) as client:
        held = client.run(_keep_band_7, str(sen3))
        assert list(held.values()) == [320 * 513 * 2] * 2, held  # an fr-small band each
        result = synthesize([str(sen3)], tmp_path / "s", scheduler=cluster.scheduler_address,
                            bands=(7, 13), tile=256, elevation="tiepoints")
        assert len(result.merged) == 1
        assert client.run(kept_bytes) == dict.fromkeys(held, 0)


_SEEN = {"read": 0, "decoded": 0}


def _observe_sen3() -> None:
    """On a worker: count the bands its .SEN3 products read and those they decode (from now)."""
    from napari_meris_ortho.products.sen3.reader import MerisSen3Product

    _SEEN.update(read=0, decoded=0)
    if getattr(MerisSen3Product, "_observed", False):
        return
    read, decode = MerisSen3Product.counts, MerisSen3Product._counts

    def counts(self, band):
        _SEEN["read"] += 1
        return read(self, band)

    def decoded(self, band):
        _SEEN["decoded"] += 1
        return decode(self, band)

    MerisSen3Product.counts, MerisSen3Product._counts = counts, decoded
    MerisSen3Product._observed = True


def _seen() -> dict[str, int]:
    return dict(_SEEN)


@pytest.mark.slow
def test_the_workers_of_a_host_decode_each_sen3_band_once_between_them(cluster,
                                                                       tmp_path) -> None:
    """Both workers read the product's bands; each band is decoded once on the host (by
    one worker, mapped by the other), and the run's shared directory is gone after the run;
    the layers are those of one process."""
    import tempfile

    from distributed import Client

    from napari_meris_ortho.products.sen3.kept import RUN_PREFIX
    from napari_meris_ortho.simulate.geocorrected import write_geocorrected
    from napari_meris_ortho.simulate.scene import generate_scene

    sen3 = write_geocorrected(generate_scene("fr-small"), fsg=False, out_dir=tmp_path)["sen3"]
    options = dict(bands=(7, 13), tile=256, elevation="tiepoints")
    with Client(cluster.scheduler_address, set_as_default=False) as client:
        client.run(_observe_sen3)
        result = synthesize([str(sen3)], tmp_path / "s", scheduler=cluster.scheduler_address,
                            **options)
        seen = list(client.run(_seen).values())
    assert len(result.merged) == 1
    assert len(seen) == 2 and all(s["read"] >= 2 for s in seen), seen  # both workers read
    assert sum(s["decoded"] for s in seen) == 2, seen  # bands 7 and 13, once
    assert not list(Path(tempfile.gettempdir()).glob(f"{RUN_PREFIX}*"))
    synthesize([str(sen3)], tmp_path / "one", **options)
    _same(tmp_path / "s", tmp_path / "one")


_VIEWER_RUN = """
import json, sys
sys.path.insert(0, sys.argv[1])
from test_synthesis_distributed import COMMON, _mapped_bytes_of_an_array
from napari_meris_ortho import _process
from napari_meris_ortho.synthesis.api import synthesize

_process.return_freed_memory()  # as the plugin sets the viewer's malloc
before = _mapped_bytes_of_an_array()
during = []
synthesize(sys.argv[3:], sys.argv[2], workers=0,
           progress=lambda done, total: during.append(_mapped_bytes_of_an_array()), **COMMON)
print(json.dumps({"before": before, "during": during, "after": _mapped_bytes_of_an_array()}))
"""


@pytest.mark.skipif(not hasattr(ctypes.CDLL(None), "mallinfo2"),
                    reason="glibc's malloc (2.33 or later: mallinfo2)")
@pytest.mark.slow
def test_a_viewer_keeps_a_runs_arrays_in_its_heap_for_the_run_only(products, tmp_path) -> None:
    """The viewer's malloc maps a block of 256 KiB or more on its own, so that removed layers
    give their memory back (``_process.return_freed_memory``). A synthesis run in that process
    (the Orthorectify widget's, ``workers=0``) takes its arrays from the heap while it runs, as
    a worker does (``_process.task_arrays_kept``), and the viewer's setting is back after it."""
    env = {k: v for k, v in os.environ.items() if k != "MERIS_ORTHO_NO_TUNING"}
    done = subprocess.run([sys.executable, "-c", _VIEWER_RUN, str(Path(__file__).parent),
                           str(tmp_path / "s"), *products[:2]],
                          capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    seen = json.loads(done.stdout.strip().splitlines()[-1])
    assert seen["before"] >= 8 << 20, seen  # the viewer's setting: mapped on its own
    assert seen["during"] and set(seen["during"]) == {0}, seen
    assert seen["after"] >= 8 << 20, seen

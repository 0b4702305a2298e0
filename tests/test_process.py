"""Process tuning (``_process``): one switch turns it off; numba's private hooks checked."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from napari_meris_ortho import _process

_PROBE = """
import gc, json, os
from napari_meris_ortho import _process
before = gc.get_threshold()
_process.tune_process()
with _process.few_collections(last=False):
    inside = gc.get_threshold()
print(json.dumps({"hugepage": os.environ.get("NUMPY_MADVISE_HUGEPAGE"),
                  "blas": os.environ.get("OPENBLAS_NUM_THREADS"),
                  "changed": inside != before, "after": gc.get_threshold() == before}))
"""


@pytest.mark.parametrize("switch", [None, "1"])
def test_one_switch_turns_the_tuning_off(switch):
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMPY_MADVISE_HUGEPAGE", "OPENBLAS_NUM_THREADS", _process.SWITCH)}
    if switch:
        env[_process.SWITCH] = switch
    out = json.loads(subprocess.run([sys.executable, "-c", _PROBE], env=env, check=True,
                                    capture_output=True, text=True).stdout)
    if switch:
        assert out == {"hugepage": None, "blas": None, "changed": False, "after": True}
    else:
        assert out == {"hugepage": "0", "blas": "1", "changed": True, "after": True}


_HEAP = """
import ctypes, json, sys, threading
import numpy as np, psutil
from napari_meris_ortho import _process

viewer = _process.return_freed_memory() if sys.argv[1] == "viewer" else None


def rss():
    ctypes.CDLL(None).malloc_trim(0)
    return psutil.Process().memory_info().rss


# as in a session: a big block freed raises glibc's thresholds (to 30 MiB, and twice that)
big = np.ones(30 << 20, np.uint8)
del big
arrays = []  # a run's two bands, made in a worker thread, freed when their layers go
worker = threading.Thread(target=lambda: arrays.extend(np.ones(20 << 20, np.uint8)
                                                        for _ in range(2)))
worker.start()
worker.join()
held = rss()
arrays.clear()
print(json.dumps({"viewer": viewer, "returned_mb": (held - rss()) / 2**20}))
"""


@pytest.mark.skipif(not (os.confstr("CS_GNU_LIBC_VERSION") or "").startswith("glibc"),
                    reason="glibc's malloc only")
def test_a_viewer_gets_back_the_blocks_a_worker_thread_made():
    """In the viewer (``return_freed_memory``), two 20 MiB bands made by a worker thread are
    handed back when freed; with glibc's raised thresholds they stayed in that thread's heap,
    out of ``malloc_trim``'s reach (the control: 0 MB back): 57 MB of four fr-alps runs stayed
    resident in half the sessions."""
    # glibc reads MALLOC_*_ at start (dask's nanny puts MALLOC_TRIM_THRESHOLD_ in its own
    # process's environment when it spawns workers: an earlier test's LocalCluster)
    env = {k: v for k, v in os.environ.items() if k != _process.SWITCH
           and not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}
    out = {mode: json.loads(subprocess.run([sys.executable, "-c", _HEAP, mode], env=env,
                                           check=True, capture_output=True,
                                           text=True).stdout)
           for mode in ("viewer", "control")}
    assert out["viewer"]["viewer"] is True
    assert out["viewer"]["returned_mb"] > 38
    # the case the viewer's setting is for: without it, at least one band stays. 0 MB or 20 MB
    # come back, from one process to the next: the thread's heap kept its 40 MiB (malloc_info) and
    # malloc_trim handed back the pages of one band's free block inside it, not merged into the
    # heap's top (which it never hands back)
    assert out["viewer"]["returned_mb"] - out["control"]["returned_mb"] > 15


def test_numba_private_hooks_are_still_there():
    """Fails loudly (naming the numba version) when a numba release moves the private
    attributes ``_process`` relies on."""
    from napari_meris_ortho.engine import predcorr

    _process.check_numba_hooks(predcorr._antecedent_rows)
    index = _process.numba_cache_index(predcorr._antecedent_rows)
    assert index is not None and index.endswith(".nbi")


def test_the_hook_check_names_what_changed():
    class NotAKernel:
        pass

    with pytest.raises(RuntimeError, match=r"numba .* changed .*_index_path"):
        _process.check_numba_hooks(NotAKernel())


_UNITS = """
import json, sys, time
import pint
from napari_meris_ortho import _process
if sys.argv[1] == "used":
    pint.get_application_registry().metre  # someone used the lazy default first
t = time.perf_counter()
done = _process.unit_registry_from_disk()
registry = pint.get_application_registry()
metres = (3 * registry.kilometre).to(registry.metre).magnitude
print(json.dumps({"done": done, "folder": str(registry.get().cache_folder),
                  "metres": metres, "pixel": str(registry.pixel)}))
"""


def _units(mode: str, cache: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k != _process.SWITCH}
    env["XDG_CACHE_HOME"] = cache
    run = subprocess.run([sys.executable, "-c", _UNITS, mode], env=env, capture_output=True,
                         text=True)
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


@pytest.mark.slow
def test_the_unit_registry_comes_from_pints_disk_cache(tmp_path):
    """napari's units (pint's application registry) from pint's disk cache: written by the
    first session, read by the next; same units. Never a registry already in use; a cache
    folder that cannot be made or a broken cache leaves pint as it was."""
    first = _units("fresh", str(tmp_path))
    cached = sorted((tmp_path / "pint").glob("*.pickle"))
    assert first["done"] and first["folder"] == str(tmp_path / "pint") and cached
    written = {p: p.stat().st_mtime_ns for p in cached}
    second = _units("fresh", str(tmp_path))
    assert second["done"] and {p: p.stat().st_mtime_ns for p in cached} == written  # read only
    assert first["metres"] == second["metres"] == 3000 and second["pixel"] == "pixel"
    assert not _units("used", str(tmp_path))["done"]  # in use: kept
    blocked = tmp_path / "file"
    blocked.write_text("")  # the cache folder would be inside a regular file
    as_before = _units("fresh", str(blocked))
    assert not as_before["done"] and as_before["folder"] == "None" and as_before["metres"] == 3000
    for p in cached:
        p.write_bytes(b"\x80\x05 truncated")
    broken = _units("fresh", str(tmp_path))
    assert not broken["done"] and broken["metres"] == 3000

"""The ``meris-ortho`` process tuning (``cli.console_main`` -> ``_process``): freed memory kept
for reuse, no collection on the way out; a library user's process is left as it is."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

_PROBE = """
import ctypes, gc, json, sys
import numpy as np
from napari_meris_ortho import _process, cli

class MallInfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd",
                "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]

libc = ctypes.CDLL(None)
libc.mallinfo2.restype = MallInfo2
if sys.argv[1] == "tuned":
    _process._keep_freed_memory()
start = libc.mallinfo2()
a = np.ones(64 * 2 ** 20, np.uint8)
live = libc.mallinfo2()
del a
freed = libc.mallinfo2()
print(json.dumps({"mmapped_live": live.hblkhd - start.hblkhd,
                  "heap_free_after": freed.fordblks - start.fordblks,
                  "gc_enabled": gc.isenabled()}))
"""


def _probe(mode: str) -> dict:
    env = {**os.environ, "MALLOC_MMAP_THRESHOLD_": "", "MALLOC_TRIM_THRESHOLD_": ""}
    out = subprocess.run([sys.executable, "-c", _PROBE, mode], capture_output=True, text=True,
                         check=True, env=env).stdout
    return json.loads(out)


@pytest.mark.skipif(not (os.confstr("CS_GNU_LIBC_VERSION") or "").startswith("glibc"),
                    reason="glibc malloc only")
def test_freed_band_sized_arrays_stay_in_the_heap():
    plain, tuned = _probe("plain"), _probe("tuned")
    # glibc's default: a 64 MiB array is a fresh mmap, unmapped (and zeroed again) when freed
    assert plain["mmapped_live"] >= 64 * 2 ** 20
    assert plain["heap_free_after"] < 64 * 2 ** 20
    # tuned: it comes from the heap and stays there, free for the next band
    assert tuned["mmapped_live"] < 2 ** 20
    assert tuned["heap_free_after"] >= 64 * 2 ** 20
    assert tuned["gc_enabled"]  # the tuning itself leaves the collector alone


def test_main_restores_the_collector_for_a_library_caller(tmp_path, capsys):
    import gc

    from napari_meris_ortho.cli import main

    before = gc.get_threshold()
    assert main(["info", str(tmp_path / "missing.N1")]) == 2
    assert gc.isenabled() and gc.get_threshold() == before


def test_a_map_process_does_not_import_scipy_linalg(tmp_path):
    import rasterio

    from ortho_samples import make_product

    prod = make_product(tmp_path / "p.N1", height=60, width=129)
    out = tmp_path / "out.tif"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    done = subprocess.run([sys.executable, "-X", "importtime", "-m", "napari_meris_ortho.cli",
                           "-q", "map", str(prod), "-o", str(out), "--elevation", "tiepoints"],
                          capture_output=True, text=True, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    imported = {line.split("|")[-1].strip() for line in done.stderr.splitlines()
                if line.startswith("import time:")}
    assert "numba.np.arraymath" in imported and "scipy.linalg" not in imported
    with rasterio.open(out) as ds:  # and the map is whole: band 2 = product column
        assert ds.count == 15 and ds.read(2).max() > 100


_HUGEPAGES = """
import sys
from napari_meris_ortho import _process, cli

def probe(argv=None, *, last=False):
    import numpy._core.multiarray as m  # numpy first imported here, as in a real run
    print(m._get_madvise_hugepage(), last)
    return 0

cli.main = probe
cli.console_main()
"""


@pytest.mark.parametrize(("setting", "switch", "expected"),
                         [(None, None, "False True"), ("1", None, "True True"),
                          (None, "1", "True True")])
def test_the_process_keeps_numpy_arrays_off_huge_pages_unless_asked(setting, switch, expected):
    """Off huge pages unless the user sets NUMPY_MADVISE_HUGEPAGE or turns the tuning off."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMPY_MADVISE_HUGEPAGE", "MERIS_ORTHO_NO_TUNING")}
    if setting is not None:
        env["NUMPY_MADVISE_HUGEPAGE"] = setting
    if switch is not None:
        env["MERIS_ORTHO_NO_TUNING"] = switch
    done = subprocess.run([sys.executable, "-c", _HUGEPAGES], capture_output=True, text=True,
                          env=env, check=True)
    assert done.stdout.strip() == expected

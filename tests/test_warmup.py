"""warmup: the numba kernels of every mapping configuration compiled ahead of a first run."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho import warmup


def test_warm_up_runs_every_configuration(monkeypatch):
    from napari_meris_ortho import ortho

    calls = []
    real = ortho.orthorectify

    def spy(product, **kw):
        res = real(product, **kw)
        calls.append((kw["elevation"], kw["sampling"], kw["method"], res.stats.crs,
                      int(res.valid.sum()), float(np.max(res.bands[2]))))
        return res

    monkeypatch.setattr(ortho, "orthorectify", spy)
    assert warmup.warm_up() > 0
    assert [c[:3] for c in calls] == [r[:3] for r in warmup.RUNS]
    assert calls[3][3].startswith("EPSG:326")  # the UTM grid
    for c in calls:  # every run maps the tiny product (counts 101 x sf_rad of band 2)
        assert c[4] > 1000 and c[5] > 0


def test_no_background_warm_up_when_disabled(monkeypatch):
    monkeypatch.setenv("MERIS_ORTHO_NO_WARMUP", "1")
    assert warmup.warm_up_in_background() is None


LATE = ("_linear", "_antecedent_rows", "_solved_counts", "_inside_range", "_finite_extent",
        "_nearest_range", "_gather_range", "_halve_average")
_COMPILED = """
import json, sys
from numba.core import event
names = []
class Listener(event.Listener):
    def on_start(self, e): pass
    def on_end(self, e): names.append(e.data["dispatcher"].py_func.__name__)
event.register("numba:compile", Listener())
from napari_meris_ortho.cli import main
code = main(sys.argv[1:])
print(json.dumps(names))
sys.exit(code)
"""


@pytest.mark.slow
def test_late_kernels_compiled_by_the_child_are_not_compiled_again_by_map(tmp_path):
    """A first ``map`` (cold cache) starts ``compile_late`` in a child: with the child's cache,
    the map itself compiles none of the late kernels (same types), only the early ones."""
    import json
    import os
    import subprocess
    import sys

    product, dem = warmup._tiny_product(tmp_path)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"),
           "MERIS_ORTHO_NO_WARMUP": "1"}
    cold = [sys.executable, "-c", "from napari_meris_ortho import warmup; "
            "print(warmup.cache_is_cold())"]
    assert subprocess.run(cold, env=env, capture_output=True, text=True).stdout.strip() == "True"
    subprocess.run([sys.executable, "-m", "napari_meris_ortho.warmup", "--late"], env=env,
                   check=True)
    assert subprocess.run(cold, env=env, capture_output=True, text=True).stdout.strip() == "False"
    out = subprocess.run([sys.executable, "-c", _COMPILED, "-q", "map", str(product), "-o",
                          str(tmp_path / "o.tif"), "--dem", f"{dem}:ellipsoid"], env=env,
                         capture_output=True, text=True, check=True)
    compiled = set(json.loads(out.stdout.strip().splitlines()[-1]))
    assert "_primary_nodes" in compiled  # the map compiled its early kernels itself
    assert not compiled & set(LATE), compiled & set(LATE)


def test_no_background_compilation_on_a_warm_cache_or_when_disabled(monkeypatch):
    monkeypatch.setattr(warmup, "cache_is_cold", lambda: False)
    assert warmup.compile_late_in_background() is None
    monkeypatch.setattr(warmup, "cache_is_cold", lambda: True)
    monkeypatch.setenv("MERIS_ORTHO_NO_WARMUP", "1")
    assert warmup.compile_late_in_background() is None
    warmup.stop(None)


_NO_BLAS = """
import json, sys
import numpy as np
from numba import njit
from napari_meris_ortho._process import start_numba_without_blas
from napari_meris_ortho.engine.resample import overview_level

start_numba_without_blas()
after_start = "scipy.linalg" in sys.modules
half = overview_level(np.array([[1, 3], [5, 7]], np.uint16), 0.0)  # a kernel of ours runs
dot = njit(lambda a, b: np.dot(a, b))(np.ones(3), np.ones(3))  # BLAS still there on demand
print(json.dumps({"after_start": after_start, "half": int(half[0, 0]), "dot": float(dot),
                  "linalg_after_dot": "scipy.linalg" in sys.modules}))
"""


@pytest.mark.slow
def test_numba_starts_without_scipy_linalg_and_blas_still_works(tmp_path):
    import json
    import os
    import subprocess
    import sys

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}  # np.dot compiles here
    out = subprocess.run([sys.executable, "-c", _NO_BLAS], capture_output=True, text=True,
                         check=True, env=env).stdout
    got = json.loads(out)
    assert got == {"after_start": False, "half": 4, "dot": 3.0, "linalg_after_dot": True}

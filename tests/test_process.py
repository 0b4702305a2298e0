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

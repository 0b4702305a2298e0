"""warmup: the numba kernels of every mapping configuration compiled ahead of a first run."""

from __future__ import annotations

import numpy as np

from napari_meris_ortho import warmup


def test_warm_up_runs_every_configuration(monkeypatch):
    from napari_meris_ortho import ortho

    calls = []
    real = ortho.orthorectify

    def spy(product, **kw):
        res = real(product, **kw)
        calls.append((kw["elevation"], kw["sampling"], kw["method"], res.stats["crs"],
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

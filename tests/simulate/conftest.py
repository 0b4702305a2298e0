"""Shared simulated scenes of the simulator tests (generated once per session, in tmp dirs)."""

from __future__ import annotations

import pytest

from napari_meris_ortho.simulate import generate_scene

#: a tiny RR piece across the antimeridian (geometry, pyepr, truth)
TINY_RR = {"base": "rr-antimeridian", "lines": 49, "dem": {"spacing_deg": 0.01},
           "exports": {"getasse30": False, "getasse30_beam": False, "srtm30": False,
                       "geotiff_utm": False, "reference": False}}


@pytest.fixture(scope="session")
def fr_small(tmp_path_factory):
    return generate_scene("fr-small", out_dir=tmp_path_factory.mktemp("fr-small"))


@pytest.fixture(scope="session")
def tiny_rr(tmp_path_factory):
    return generate_scene(TINY_RR, out_dir=tmp_path_factory.mktemp("tiny-rr"))

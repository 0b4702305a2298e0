"""Fixtures shared across test rooms."""

import pytest


@pytest.fixture(scope="session")
def fr_small():
    """The simulated ``fr-small`` scene (cached on disk by the simulator)."""
    from napari_meris_ortho.simulate.scene import generate_scene

    return generate_scene("fr-small")


@pytest.fixture(scope="session")
def geolocated(fr_small, tmp_path_factory):
    """FRG N1 and .SEN3 products of ``fr-small`` with the per-pixel truth geolocation (read only:
    tests that break a product copy it first)."""
    from napari_meris_ortho.simulate.geocorrected import write_geocorrected

    return write_geocorrected(fr_small, out_dir=tmp_path_factory.mktemp("geolocated"))

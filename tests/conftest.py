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


#: a reduced-resolution piece of ``rr-segment``: the full 1121-column RR line, 160 lines
RR_SMALL = {"base": "rr-segment", "lines": 160}


@pytest.fixture(scope="session")
def rr_small():
    """The simulated RR scene ``RR_SMALL`` (cached on disk by the simulator)."""
    from napari_meris_ortho.simulate.scene import generate_scene

    return generate_scene(RR_SMALL)


@pytest.fixture(scope="session")
def rrg(rr_small, tmp_path_factory):
    """The AMORGOS-like MER_RRG_1P N1 of ``rr_small`` (per-pixel truth geolocation; read only)."""
    from napari_meris_ortho.simulate.geocorrected import write_geocorrected

    out = tmp_path_factory.mktemp("rrg")
    return write_geocorrected(rr_small, sen3=False, out_dir=out)["fsg"]

"""Shared fixtures of the analysis tests."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def fr_small_scene(tmp_path_factory):
    """The simulated ``fr-small`` scene, generated in a private directory (no shared cache)."""
    from napari_meris_ortho.simulate.scene import generate_scene

    return generate_scene("fr-small", out_dir=tmp_path_factory.mktemp("fr-small"))

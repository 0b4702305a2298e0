"""Parallax vectors readable at the whole-scene view: with the widget's defaults (automatic
spacing, exaggeration 10) no arrow reaches a neighbouring arrow's tail, on the default runs of
fr-small and fr-alps."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from napari_meris_ortho._napari.ortho_run import RunSettings, run_layers, run_orthorectify


def arrows_of_default_run(scene_name: str) -> tuple[np.ndarray, float]:
    """The parallax vectors of the widget's default run of a scene, and their step (px)."""
    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene(scene_name)
    settings = RunSettings(products=[scene.product_path], dems=[scene.dem_paths["geotiff"]])
    layers = run_layers(run_orthorectify(settings))
    (vectors, kwargs, _), = [layer for layer in layers if layer[1]["name"].startswith("parallax")]
    return np.asarray(vectors, np.float64), float(kwargs["metadata"]["step"])


def longest_arrow_and_tail_spacing(vectors: np.ndarray) -> tuple[float, float, float]:
    """Longest arrow, shortest and median distance from a tail to its nearest neighbour (world
    units: metres on the default UTM grid)."""
    tails, directions = vectors[:, 0], vectors[:, 1]
    distance, _ = cKDTree(tails).query(tails, k=2)
    nearest = distance[:, 1]
    return float(np.hypot(*directions.T).max()), float(nearest.min()), float(np.median(nearest))


@pytest.mark.parametrize("scene_name", ["fr-small", pytest.param("fr-alps",
                                                                 marks=pytest.mark.slow)])
def test_no_arrow_reaches_the_next_tail(scene_name):
    vectors, step = arrows_of_default_run(scene_name)
    longest, nearest, median = longest_arrow_and_tail_spacing(vectors)
    print(f"{scene_name}: {len(vectors)} arrows every {step:.0f} px, longest {longest:.0f} m, "
          f"tails {nearest:.0f} m apart at least (median {median:.0f} m)")
    assert len(vectors) >= 50  # still a field, not a handful of arrows
    assert longest > 1000.0  # exaggerated shifts of the scene's relief: the check has teeth
    assert longest <= nearest

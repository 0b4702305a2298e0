"""A synthesis store opened in napari (_napari/synthesis_layers.py): multiscale layers from the
store's overviews, and the winning product as a labels layer whose tooltip names the product."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho._napari.reader import get_reader, read_store
from napari_meris_ortho._napari.world import layer_scale
from napari_meris_ortho.synthesis.api import synthesize
from napari_meris_ortho.synthesis.reading import open_synthesis
from test_synthesis import GRID, scene_product


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    products = [scene_product({"fraction": 0.4, "scale_km": 12.0, "seed": 10 * k})
                for k in (1, 2)]
    out = tmp_path_factory.mktemp("store") / "syn"
    synthesize(products, out, grid=GRID, bands=(7, 13), tile=256, algorithm="max-ndvi",
               elevation="tiepoints", codec="delta-zstd")  # delta in the bands and NDVI
    return out


def test_store_opens_as_multiscale_layers(store, tmp_path) -> None:
    assert get_reader(str(store)) is read_store
    assert get_reader(str(tmp_path)) is None  # a plain directory is not ours
    layers = read_store(str(store))
    names = [kwargs["name"] for _, kwargs, _ in layers]
    assert names == [f"syn {n}" for n in ("band_07", "band_13", "ndvi", "count", "product")]
    synthesis = open_synthesis(store)
    for data, kwargs, kind in layers:
        assert kwargs["multiscale"] and [level.shape for level in data] == [(340, 540),
                                                                            (170, 270)]
        assert kwargs["scale"] == layer_scale(GRID)
        name = kwargs["name"].split()[-1]
        np.testing.assert_array_equal(np.asarray(data[1][:]), synthesis.read(name, level=2))
        np.testing.assert_array_equal(np.asarray(data[0][:]), synthesis.read(name))
        assert kind == ("labels" if name == "product" else "image")


def test_winning_product_tooltip_names_the_product(store, make_napari_viewer) -> None:
    viewer = make_napari_viewer()
    layers = viewer.open(str(store), plugin="napari-meris-ortho")
    labels = next(layer for layer in layers if layer.name == "syn product")
    synthesis = open_synthesis(store)
    winner = synthesis.read("product")
    names = synthesis.product_names()
    assert not labels.visible  # shown on demand (over the bands)
    labels.visible = True
    for index in (1, 2):
        row, col = np.argwhere(winner == index)[len(np.argwhere(winner == index)) // 2]
        world = labels.data_to_world((row, col))
        text = labels._get_tooltip_text(np.asarray(world), world=True)
        assert f"product: {names[index]}" in text
    row, col = np.argwhere(winner == 0)[0]
    assert "product: (none)" in labels._get_tooltip_text(
        np.asarray(labels.data_to_world((row, col))), world=True)

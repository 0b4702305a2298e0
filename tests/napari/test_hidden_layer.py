"""The hidden-ground layer of a run and the widget's mask/keep choice."""

from __future__ import annotations

import numpy as np
from napari.layers import Labels

from napari_meris_ortho._napari.geometry_layers import HIDDEN_COLOUR, hidden_layer_data
from napari_meris_ortho._napari.ortho_run import RunSettings
from napari_meris_ortho._napari.widget_ortho import OrthorectifyWidget
from napari_meris_ortho.geometry.grid import OutputGrid
from napari_meris_ortho.options import Hidden


def test_the_hidden_ground_layer_shows_the_hidden_points_only(make_napari_viewer) -> None:
    """A labels layer: label 1 (magenta, semi-transparent) on the hidden points, transparent
    elsewhere, placed on the run's grid, its legend counting the points."""
    grid = OutputGrid("EPSG:32632", 600_000.0, 5_100_000.0, 260.0, 260.0, 40, 30)
    hidden = np.zeros(grid.shape, bool)
    hidden[10:14, 5:9] = True
    viewer = make_napari_viewer()
    data, kwargs, kind = hidden_layer_data(grid, hidden, name="hidden ground · t")
    assert kind == "labels" and data.dtype == np.uint8
    assert np.array_equal(data == 1, hidden) and data.sum() == 16
    layer = viewer.add_labels(data, **kwargs)
    assert isinstance(layer, Labels) and 0 < layer.opacity < 1
    assert layer.metadata["hidden_points"] == 16 and "16 points" in layer.metadata["legend"]
    assert np.allclose(layer.colormap.map(np.array([1]))[0], [1.0, 0.0, 1.0, 1.0])
    assert layer.colormap.map(np.array([0]))[0][3] == 0.0  # transparent background
    assert np.allclose(layer.scale, (260.0, 260.0))
    assert HIDDEN_COLOUR == "magenta"


def test_the_widget_offers_mask_and_keep(make_napari_viewer) -> None:
    viewer = make_napari_viewer()
    widget = OrthorectifyWidget(viewer)
    assert list(widget.hidden.choices) == ["mask", "keep"] and widget.hidden.value == "mask"
    widget.hidden.value = "keep"
    settings = RunSettings(products=[], hidden=widget.hidden.value)
    assert settings.options().hidden is Hidden.KEEP
    assert RunSettings(products=[]).options().hidden is Hidden.MASK


def test_category_layers_draw_without_compiling_in_the_qt_thread() -> None:
    """The hidden-ground and elevation-source labels use napari's cyclic label colormap, whose
    uint8 mapping is numpy (a dict colormap builds a numba typed dict, compiled in the Qt
    thread at the first draw): labels 1..n get their own colours, 0 stays transparent."""
    from napari.utils.colormaps import CyclicLabelColormap

    from napari_meris_ortho._napari.product_layers import category_colormap, source_colours

    grid = OutputGrid("EPSG:32632", 600_000.0, 5_100_000.0, 260.0, 260.0, 4, 3)
    _, kwargs, _ = hidden_layer_data(grid, np.ones(grid.shape, bool))
    assert isinstance(kwargs["colormap"], CyclicLabelColormap)
    cmap = category_colormap(source_colours(2))  # orange, deepskyblue, red (tie points)
    assert isinstance(cmap, CyclicLabelColormap)
    rgba = cmap.map(np.arange(4, dtype=np.uint8))
    assert rgba[0][3] == 0.0
    assert np.allclose(rgba[1:, :3], [[1.0, 0.647, 0.0], [0.0, 0.749, 1.0], [1.0, 0.0, 0.0]],
                       atol=0.01)

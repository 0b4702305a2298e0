"""A run's rasters go into the viewer as pyramids (issue 24, items 1 and 2): inserting a layer
uploads a canvas-sized level, not the full-resolution result, and the layers go in without
switching the layer controls at every insertion.

Before, the 2241 x 2241 x 3 RGB of fr-alps went to the canvas whole (0.5-0.9 s stalls) and
every insertion made the new layer the active one.
"""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho._napari.widget_ortho import OrthorectifyWidget
from napari_meris_ortho.engine.resample import overview_level
from napari_meris_ortho.simulate.scene import generate_scene


@pytest.fixture(scope="module")
def fr_small():
    return generate_scene("fr-small")


def test_run_layers_are_pyramids_shown_at_canvas_size(make_napari_viewer, qtbot, fr_small):
    viewer = make_napari_viewer(show=True)
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [fr_small.product_path]
    widget.elevation.value = "tiepoints"
    widget.pixel_size.value = 100.0  # about 1400 x 1400 output pixels: levels 1, 2
    activated = []
    viewer.layers.selection.events.active.connect(lambda e: activated.append(e.value))
    assert widget.start() is not None, widget.status.value
    qtbot.waitUntil(lambda: not widget.running, timeout=120_000)
    assert widget.status.value.startswith("done"), widget.status.value
    viewer.screenshot(canvas_only=True)
    rgb = viewer.layers[next(n for n in viewer.layers if n.name.startswith("ortho RGB")).name]
    b7 = next(layer for layer in viewer.layers if layer.name.startswith("ortho b7"))
    rows, cols = b7.data.shape
    assert max(rows, cols) > 1024
    assert rgb.multiscale and b7.multiscale
    assert [level.shape for level in b7.data] == [(rows, cols), ((rows + 1) // 2,
                                                                  (cols + 1) // 2)]
    # level 1: the mean of each 2 x 2 block of radiances, background (0) left out, as a COG's
    full = np.asarray(b7.data[0])
    np.testing.assert_array_equal(b7.data[1], overview_level(full, 0.0))
    i, j = rows // 4, cols // 4  # the middle of the scene
    block = full[2 * i:2 * i + 2, 2 * j:2 * j + 2]
    assert (block > 0).all()
    assert b7.data[1][i, j] == pytest.approx(block.mean(), rel=1e-6)
    assert rgb.data[1].shape == ((rows + 1) // 2, (cols + 1) // 2, 3)
    # what the canvas shows: the decimated level, not 1400 x 1400 x 3
    assert rgb.data_level == 1
    shown = rgb._slice.image.raw
    assert shown.shape[0] * shown.shape[1] <= rows * cols / 4 + cols
    # the layers went in without becoming active one by one; the last one is active at the end,
    # as napari leaves it
    last = viewer.layers[-1]
    assert activated == [last]
    assert viewer.layers.selection.active is last

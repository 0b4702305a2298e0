"""A run's rasters go into the viewer as pyramids: inserting a layer uploads a canvas-sized
level, not the full-resolution result (the 2241 x 2241 x 3 RGB of fr-alps uploaded whole stalls
the window 0.5-0.9 s), and the layers go in without switching the layer controls at every
insertion (no new layer is made the active one).
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


@pytest.mark.slow
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


def test_band_limits_come_once_from_a_decimation_and_drive_the_quick_look():
    """A run's band layers take their 1-99 % contrast limits from every f-th line and column
    (at most ``LIMIT_SAMPLES`` pixels; a full-size band took 0.13 s per limit, twice for the
    quick-look's bands) within 1 % of the full band's, and the RGB quick-look is stretched by
    the very limits of its grey layers."""
    from napari_meris_ortho._napari.product_layers import band_layers
    from napari_meris_ortho.display import LIMIT_SAMPLES, contrast_limits, stretch_channel
    from napari_meris_ortho.geometry.grid import OutputGrid

    rng = np.random.default_rng(5)
    rows, cols = 2400, 2300  # 5.5 Mpixel, background in a corner
    y, x = np.mgrid[0:rows, 0:cols]
    bands = {b: (40.0 + 10 * b + 30 * np.sin(x / (70.0 + b)) * np.cos(y / 90.0)
                 + rng.normal(0, 3, (rows, cols))).astype(np.float32) for b in (2, 5, 7)}
    valid = (x + y) > 600
    for band in bands.values():
        band[~valid] = 0
    f = int(np.ceil(np.sqrt(rows * cols / LIMIT_SAMPLES)))
    assert f == 3
    frame = OutputGrid("EPSG:32632", 400_000.0, 5_100_000.0, 300.0, 300.0, cols, rows)
    layers = band_layers(bands, frame, "ortho", valid=valid)
    rgb = layers[0][0]
    for c, b in enumerate((7, 5, 2)):
        grey = next(kw for _, kw, _ in layers if kw["name"] == f"ortho b{b}")
        limits = grey["contrast_limits"]
        assert limits == contrast_limits(bands[b][::f, ::f], samples=rows * cols)
        full = contrast_limits(bands[b], samples=rows * cols)
        np.testing.assert_allclose(limits, full, rtol=0.01)
        np.testing.assert_array_equal(rgb[..., c],
                                      np.where(valid, stretch_channel(bands[b], limits), 0))

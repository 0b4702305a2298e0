"""A screenshot of a shown viewer has real content, rendered under Xvfb (Qt's offscreen platform
has no OpenGL context, and a viewer never shown gives black screenshots)."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho._napari.widget_flicker import FlickerWidget, show_viewer

pytestmark = pytest.mark.slow


def test_screenshot_of_shown_viewer_has_content(make_napari_viewer):
    viewer = make_napari_viewer()
    show_viewer(viewer)
    viewer.open_sample("napari-meris-ortho", "fr-small")
    for layer in viewer.layers:
        layer.visible = layer.name in ("ortho RGB 7-5-2", "footprint")
    viewer.reset_view()
    shot = viewer.screenshot(canvas_only=True, flash=False)
    assert shot.ndim == 3 and shot.shape[2] == 4 and min(shot.shape[:2]) > 200
    rgb = shot[..., :3].astype(np.int32)
    assert rgb.std() > 20.0
    assert (rgb.sum(axis=-1) > 60).mean() > 0.2  # a large part of the canvas is lit
    colours = np.unique(rgb.reshape(-1, 3) // 8, axis=0)
    assert len(colours) > 200  # an image, not a flat fill
    yellow = (rgb[..., 0] > 200) & (rgb[..., 1] > 200) & (rgb[..., 2] < 80)
    assert yellow.sum() > 100  # the footprint boundary is drawn


def test_flicker_gif_of_sample(make_napari_viewer, tmp_path):
    import imageio.v3 as iio

    viewer = make_napari_viewer()
    show_viewer(viewer)
    viewer.open_sample("napari-meris-ortho", "fr-small")
    widget = FlickerWidget(viewer)
    widget.layer_a.value = viewer.layers["ortho b7"]
    widget.layer_b.value = viewer.layers["reference b7"]
    for layer in viewer.layers:
        layer.visible = layer.name in ("ortho b7", "reference b7")
    viewer.reset_view()
    out = widget.export_gif(tmp_path / "snap_ortho_anim.gif")
    frames = iio.imread(out, index=None)
    assert frames.shape[0] == 4
    a, b = frames[0, ..., :3].astype(float), frames[1, ..., :3].astype(float)
    assert a.std() > 10 and b.std() > 10
    # orthorectified vs reference: same scene, nearly the same picture
    assert np.corrcoef(a.ravel(), b.ravel())[0, 1] > 0.8

"""A first view that tells one thing at a time: after a run one image is shown (the newest),
the others hidden, the geometry above; the key of the selected layer on the canvas; layers
transparent outside the footprint; the Flicker's GIF beside the data; the layer list's tooltip
names the product and its time."""

from __future__ import annotations

import numpy as np
from napari.layers import Image, Labels, Vectors

from napari_meris_ortho._napari.product_layers import one_image_shown

STAMP = " · 09-21 09:23"


def test_one_image_shown_keeps_the_newest_and_puts_geometry_on_top():
    layers = [(None, {"name": "a"}, "image"), (None, {"name": "v"}, "vectors"),
              (None, {"name": "b", "visible": False}, "image"),
              (None, {"name": "c"}, "image"), (None, {"name": "l"}, "labels")]
    out = one_image_shown(layers)
    assert [kw["name"] for _, kw, _ in out] == ["a", "b", "c", "l", "v"]
    shown = [kw["name"] for _, kw, kind in out if kw.get("visible", True)]
    assert shown == ["c", "v"]


def test_a_run_opens_on_its_newest_image_with_keys(make_napari_viewer, qtbot, tiny_n1,
                                                   tiny_dem):
    from napari_meris_ortho._napari.widget_flicker import GIF_NAME, FlickerWidget
    from napari_meris_ortho._napari.widget_ortho import OrthorectifyWidget

    viewer = make_napari_viewer(show=True)
    viewer.open(str(tiny_n1), plugin="napari-meris-ortho")
    quicklook, = [x for x in viewer.layers if x.name.startswith("RGB 7-5-2")]
    assert quicklook.visible
    widget = OrthorectifyWidget(viewer)
    widget.products.value = [tiny_n1]
    widget.add_dem(tiny_dem)
    assert widget.start() is not None, widget.status.value
    qtbot.waitUntil(lambda: not widget.running, timeout=120_000)
    shown = [x.name for x in viewer.layers if isinstance(x, Image | Labels) and x.visible]
    assert shown == [f"ortho RGB 7-5-2{STAMP}"]  # the product's quick-look hidden
    last_image = max(k for k, x in enumerate(viewer.layers) if isinstance(x, Image | Labels))
    vectors = [k for k, x in enumerate(viewer.layers) if isinstance(x, Vectors)]
    assert vectors and min(vectors) > last_image  # geometry above the images
    # every coloured layer has its key; the selected one's is on the canvas
    overlay = viewer.canvas.overlays.text
    for name in ("iterations", "elevation", "elevation source"):
        layer = viewer.layers[f"{name}{STAMP}"]
        assert layer.metadata["legend"]
        layer.visible = True
        viewer.layers.selection.active = layer
        qtbot.waitUntil(lambda layer=layer: overlay.text.startswith(f"{layer.name}: "),
                        timeout=20_000)
        assert overlay.visible and overlay.position == "top_left"
    assert "orange " + tiny_dem.name in viewer.layers[f"elevation source{STAMP}"].metadata[
        "legend"]
    # outside the footprint: transparent
    iterations = np.asarray(viewer.layers[f"iterations{STAMP}"].data)
    assert np.isnan(iterations).any() and np.nanmin(iterations) >= 0
    # the layer list's tooltip: the product and its time, which the short name leaves out
    tooltip = viewer.layers[f"ortho b7{STAMP}"].get_source_str()
    assert "acquired 2003-09-21 09:23" in tooltip
    # the Flicker's GIF goes beside the data of layer A
    flicker = FlickerWidget(viewer)
    assert flicker.gif_path.value == tiny_n1.parent / GIF_NAME

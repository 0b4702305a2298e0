"""napari and per-pixel geolocated products: the reader opens a ``.SEN3`` directory, the
Orthorectify widget maps it with the tie points (DEM) and with its own pixel geolocation, and
the Flicker widget finds the two superimposable (disparity ~ 0)."""

from __future__ import annotations

import numpy as np
import pytest
from napari.layers import Image

from napari_meris_ortho._napari.reader import get_reader
from napari_meris_ortho._napari.widget_flicker import FlickerWidget
from napari_meris_ortho._napari.widget_ortho import OrthorectifyWidget

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def scene():
    from napari_meris_ortho.simulate.scene import generate_scene

    return generate_scene("fr-small")


@pytest.fixture(scope="module")
def sen3(scene, tmp_path_factory):
    from napari_meris_ortho.simulate.geocorrected import write_geocorrected

    return write_geocorrected(scene, fsg=False, out_dir=tmp_path_factory.mktemp("nap"))["sen3"]


def test_reader_opens_a_sen3_directory(sen3):
    for path in (str(sen3), str(sen3 / "xfdumanifest.xml")):
        reader = get_reader(path)
        assert reader is not None
    layers = reader(str(sen3))
    kinds = [kind for _, _, kind in layers]
    assert kinds == ["image", "image", "labels"]
    stack, meta, _ = layers[0]
    assert stack.shape == (15, 320, 513)
    assert meta["metadata"]["product_type"] == "ME_1_FRG___"
    assert meta["metadata"]["pixel_geolocation"] is True
    assert get_reader(str(sen3.parent)) is None  # a plain directory is not a product


def _run(widget, qtbot):
    worker = widget.start()
    assert worker is not None, widget.status.value
    qtbot.waitUntil(lambda: not widget.running, timeout=120_000)
    assert widget.status.value.startswith("done"), widget.status.value


def test_flicker_tiepoint_against_pixel_geolocation(make_napari_viewer, qtbot, scene, sen3):
    viewer = make_napari_viewer()
    ortho = OrthorectifyWidget(viewer)
    ortho.products.value = [sen3 / "xfdumanifest.xml"]
    ortho.bands.value = "7"
    ortho.geometry.value = False
    ortho.add_dem(scene.dem_paths["geotiff"])
    _run(ortho, qtbot)
    ortho.geolocation.value = "pixel"
    _run(ortho, qtbot)
    (tie,) = [x for x in viewer.layers if x.name.startswith("ortho b7 · ")]
    (pix,) = [x for x in viewer.layers if x.name.startswith("ortho b7 (pixel geolocation) · ")]
    assert isinstance(tie, Image) and isinstance(pix, Image)
    assert tie.data.shape == pix.data.shape
    both = (tie.data > 0) & (pix.data > 0)
    assert both.mean() > 0.5 and np.mean(tie.data[both] == pix.data[both]) > 0.95
    flicker = FlickerWidget(viewer)
    flicker.layer_a.value, flicker.layer_b.value = tie, pix
    result = flicker.measure_disparity()
    dx, dy = result.global_displacement
    assert np.count_nonzero(result.candidate) > 50
    assert abs(dx) < 0.05 and abs(dy) < 0.05
    assert "global displacement" in flicker.disparity_label.value

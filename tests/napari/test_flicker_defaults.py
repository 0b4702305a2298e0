"""Flicker defaults know their job: the newest orthorectified band against
the reference image, not the two top-most layers ("elevation source" / "elevation")."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho._napari.widget_flicker import FlickerWidget, default_pair
from napari_meris_ortho._napari.widget_ortho import OrthorectifyWidget
from napari_meris_ortho.simulate.scene import generate_scene


@pytest.mark.slow
def test_sample_then_run_pairs_newest_ortho_with_reference(make_napari_viewer, qtbot):
    viewer = make_napari_viewer()
    viewer.open_sample("napari-meris-ortho", "fr-small")
    flicker = FlickerWidget(viewer)
    assert flicker.layer_a.value is viewer.layers["ortho b7"]
    assert flicker.layer_b.value is viewer.layers["reference b7"]

    ortho = OrthorectifyWidget(viewer)
    scene = generate_scene("fr-small")  # the sample's scene (cached)
    ortho.products.value = [scene.product_path]
    ortho.add_dem(scene.dem_paths["geotiff"])
    ortho.geometry.value = False
    assert ortho.start() is not None, ortho.status.value
    qtbot.waitUntil(lambda: not ortho.running, timeout=120_000)
    assert ortho.status.value.startswith("done"), ortho.status.value
    newest = [layer for layer in viewer.layers if layer.name.startswith("ortho b7 ·")]
    assert len(newest) == 1
    assert flicker.layer_a.value is newest[0]  # the run's band 7, the newest
    assert flicker.layer_b.value is viewer.layers["reference b7"]
    # the pair is the check of section 4.4: the same scene, pixel on pixel
    a, b = flicker.layer_a.value.data, flicker.layer_b.value.data
    both = (a > 0) & (b > 0)
    assert both.sum() > 100_000 and np.corrcoef(a[both], b[both])[0, 1] > 0.95


@pytest.mark.slow
def test_without_reference_the_previous_product_then_the_uncorrected(make_napari_viewer):
    viewer = make_napari_viewer()
    img = np.ones((8, 8), np.float32)
    uncorrected = viewer.add_image(img, name="uncorrected b7", metadata={"band": 7})
    first = viewer.add_image(img, name="ortho b7 · 2003-09-21 09:23",
                             metadata={"band": 7, "path": "/a.N1"})
    viewer.add_image(img, name="elevation · 2003-09-21 09:23")
    viewer.add_labels(np.zeros((8, 8), np.uint8), name="elevation source · 2003-09-21 09:23")
    assert default_pair(list(viewer.layers)) == (first, uncorrected)
    second = viewer.add_image(img, name="ortho b7 · 2003-10-07 09:30",
                              metadata={"band": 7, "path": "/b.N1"})
    viewer.add_image(img, name="ortho b5 · 2003-10-07 09:30", metadata={"band": 5,
                                                                          "path": "/b.N1"})
    assert default_pair(list(viewer.layers)) == (second, first)


@pytest.mark.slow
def test_a_reference_geotiff_pairs_by_its_meris_band(make_napari_viewer):
    """A GeoTIFF layer's band is its MERIS band, not its place in the file: "ortho b7" pairs
    with the reference's band 7, not its third band (13)."""
    viewer = make_napari_viewer()
    reference = generate_scene("fr-small").reference_path  # bands 5, 7, 13
    layers = viewer.open(reference, plugin="napari-meris-ortho")
    assert [layer.metadata.get("band") for layer in layers] == [5, 7, 13]
    assert [layer.metadata["file_band"] for layer in layers] == [1, 2, 3]
    ortho = viewer.add_image(np.ones((8, 8), np.float32), name="ortho b7 · 2003-09-21 09:23",
                             metadata={"band": 7, "path": "/a.N1"})
    a, b = default_pair(list(viewer.layers))
    assert a is ortho and b.name.endswith("band 7 radiance") and b in layers


def test_meris_band_of_a_geotiff_band():
    from napari_meris_ortho._napari.reader import meris_band_of

    assert meris_band_of("MERIS band 7 (664.6 nm)") == 7
    assert meris_band_of("band 13 radiance") == 13
    assert meris_band_of("b2") == 2 and meris_band_of("B09") == 9
    assert meris_band_of(None, {"meris_band": "11"}) == 11
    assert meris_band_of("band 2", {"meris_band": "5"}) == 5  # the tag first
    for description in (None, "", "height above WGS84", "band 16", "band 0", "bands", "rgb",
                        "blue"):
        assert meris_band_of(description) is None, description


@pytest.mark.slow
def test_a_synthesis_band_counts_as_orthorectified(make_napari_viewer):
    """A synthesis store's band counts as orthorectified, not only layers named "ortho...": a
    store's band 7 against the reference pairs with the reference's band 7 (not its bands 13
    and 7)."""
    viewer = make_napari_viewer()
    img = np.ones((8, 8), np.float32)
    reference = [viewer.add_image(img, name=f"reference band {b} radiance",
                                  metadata={"band": b}) for b in (5, 7, 13)]
    store_b7 = viewer.add_image(img, name="syn band_07", metadata={"band": 7, "synthesis": "/s"})
    viewer.add_image(img, name="syn count", metadata={"synthesis": "/s"})
    assert default_pair(list(viewer.layers)) == (store_b7, reference[1])

"""An OLCI Level 1B product in napari (the simulated ``olci-err-andes`` scene): its 21 bands as
one stack, the true-colour quick-look from Oa08/Oa06/Oa03, the band axis naming the Oa band,
the one world frame; the Orthorectify widget maps it with the DEM and with ESA's per-pixel
("DEM corrected") geolocation, and the Flicker pairs the two maps of the same band."""

from __future__ import annotations

import numpy as np
import pytest
from napari.layers import Image, Vectors

from napari_meris_ortho._napari.reader import get_reader
from napari_meris_ortho._napari.widget_flicker import FlickerWidget, default_pair
from napari_meris_ortho._napari.world import WORLD_KEY, viewer_frame
from napari_meris_ortho.geometry.grid import footprint_utm
from napari_meris_ortho.products.open import read_product

pytestmark = pytest.mark.slow

STAMP = " · 08-31 13:58"


@pytest.fixture(scope="module")
def scene():
    from napari_meris_ortho.simulate.scene import generate_scene

    return generate_scene("olci-err-andes")


def _level0(layer):
    return np.asarray(layer.data[0] if layer.multiscale else layer.data)


def test_olci_product_opens_with_21_bands_and_an_8_6_3_quicklook(make_napari_viewer, scene):
    path = str(scene.product_path)
    assert get_reader(path) is not None
    viewer = make_napari_viewer()
    viewer.open(path, plugin="napari-meris-ortho")
    product = read_product(path)
    radiance, rgb = viewer.layers[f"radiance{STAMP}"], viewer.layers[f"RGB 8-6-3{STAMP}"]
    assert radiance.data[0].shape == (21, product.height, product.width) == (21, 1000, 1217)
    assert radiance.metadata["sensor"] == "OLCI"
    assert rgb.rgb and rgb.metadata["true_colour"] == (8, 6, 3)
    # each channel of the quick-look follows its own band: red Oa08, green Oa06, blue Oa03
    image = _level0(rgb)
    for channel, band, other in ((0, 8, 3), (2, 3, 17)):
        values = image[::4, ::4, channel].astype(np.float64).ravel()
        own = np.nan_to_num(product.radiance(band)[::4, ::4]).ravel()
        far = np.nan_to_num(product.radiance(other)[::4, ::4]).ravel()
        unclipped = (values > 0) & (values < 255)
        r_own = np.corrcoef(values[unclipped], own[unclipped])[0, 1]
        r_far = np.corrcoef(values[unclipped], far[unclipped])[0, 1]
        assert r_own > 0.99 and r_own > r_far, (channel, r_own, r_far)
    # the band slider names the Oa band (world band = band number 1..21)
    for step, label in ((7, "OLCI Oa08 (665 nm)"), (0, "OLCI Oa01 (400 nm)"),
                        (20, "OLCI Oa21 (1020 nm)")):
        viewer.dims.set_current_step(0, step)
        assert viewer.dims.axis_labels[0] == label
    # the world: the UTM zone of the footprint (southern hemisphere), founded by the product
    frame = viewer_frame(viewer.layers)
    assert frame is not None
    tie = product.tie_points
    assert frame.crs == footprint_utm(tie["latitude"], tie["longitude"])
    assert str(frame.crs.to_epsg()).startswith("327")
    assert rgb.metadata[WORLD_KEY] == radiance.metadata[WORLD_KEY]


def _run(widget, qtbot):
    assert widget.start() is not None, widget.status.value
    qtbot.waitUntil(lambda: not widget.running, timeout=600_000)
    assert widget.status.value.startswith("done"), widget.status.value


def test_olci_dem_and_pixel_geolocation_maps_flicker(make_napari_viewer, qtbot, scene):
    viewer = make_napari_viewer()
    _, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    assert widget.bands.value == "7,5,2"
    widget.products.value = [scene.product_path]
    assert widget.bands.value == "8,6,3"  # the OLCI quick-look bands
    widget.add_dem(scene.dem_paths["geotiff"])
    widget.bands.value = "8,21"
    assert widget.settings().bands == (8, 21)  # OLCI band numbers up to 21
    widget.bands.value = "8"
    _run(widget, qtbot)
    for name in ("footprint", "facets"):
        assert isinstance(viewer.layers[f"{name}{STAMP}"], Vectors)
    # tie points on every row (1176 m apart in ERR): facet edges a quarter of that, not a fill
    facets = viewer.layers[f"facets{STAMP}"]
    assert 0 < float(np.max(facets.edge_width)) <= 0.25 * 1176 * 1.05
    assert [x for x in viewer.layers if x.name.startswith("parallax ×")
            and isinstance(x, Vectors) and len(x.data) > 10]
    widget.geolocation.value = "pixel"
    for dem in list(widget.dems):
        widget.remove_dem(dem)
    widget.geometry.value = False
    _run(widget, qtbot)
    dem_map = viewer.layers[f"ortho Oa08{STAMP}"]
    pixel_map = viewer.layers[f"ortho Oa08 (pixel geolocation){STAMP}"]
    assert isinstance(dem_map, Image) and isinstance(pixel_map, Image)
    assert dem_map.metadata["band"] == pixel_map.metadata["band"] == 8
    assert set(default_pair(list(viewer.layers))) == {dem_map, pixel_map}
    flicker = FlickerWidget(viewer)
    assert {flicker.layer_a.value, flicker.layer_b.value} == {dem_map, pixel_map}
    # one world frame: the same grid, pixel for pixel
    a, b = _level0(dem_map), _level0(pixel_map)
    assert a.shape == b.shape
    np.testing.assert_allclose(dem_map.scale, pixel_map.scale)
    np.testing.assert_allclose(dem_map.translate, pixel_map.translate)
    both = (a > 0) & (b > 0)
    assert both.mean() > 0.5
    # both models put the pixels where the truth has them: superimposable
    result = flicker.measure_disparity()
    dx, dy = result.global_displacement
    assert abs(dx) < 0.1 and abs(dy) < 0.1, (dx, dy)
    assert np.mean(a[both] == b[both]) > 0.9  # the same input pixel almost everywhere


def test_olci_zip_is_claimed_by_name_and_read(make_napari_viewer, scene, tmp_path):
    import zipfile
    from fnmatch import fnmatch

    import npe2

    product = scene.product_path
    archive = tmp_path / f"{product.name}.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_STORED) as zf:
        for member in sorted(product.rglob("*")):
            zf.write(member, member.relative_to(product.parent).as_posix())
    # the manifest's first reader claims it by name, as npe2 matches (fnmatch, lower case)
    make_napari_viewer()
    manager = npe2.PluginManager.instance()
    manager.discover()
    patterns = manager.get_manifest("napari-meris-ortho").contributions.readers[0]
    assert [p for p in patterns.filename_patterns
            if fnmatch(str(archive).lower(), p.lower())] == ["*S3?_OL_1_E?R*.zip"]
    assert not fnmatch(str(tmp_path / "S3B_SL_1_RBT____x.zip").lower(), "*s3?_ol_1_e?r*.zip")
    reader = get_reader(str(archive))
    assert reader is not None
    layers = {kwargs["name"]: data for data, kwargs, _ in reader(str(archive))}
    stack = layers[f"radiance{STAMP}"]
    assert (stack[0] if isinstance(stack, list) else stack).shape == (21, 1000, 1217)
    assert f"RGB 8-6-3{STAMP}" in layers

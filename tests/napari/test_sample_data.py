"""Sample data "fr-small": layers in one world frame; the orthorectified mapping matches the
reference image far better than the uncorrected one (handbook section 4.4)."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho.geometry.grid import OutputGrid


def test_sample_small_in_viewer(make_napari_viewer):
    viewer = make_napari_viewer()
    layers = viewer.open_sample("napari-meris-ortho", "fr-small")
    names = [layer.name for layer in layers]
    for name in ("reference b7", "DEM", "uncorrected RGB 7-5-2", "orthorectified RGB 7-5-2",
                 "uncorrected b7", "orthorectified b7", "footprint",
                 "facets", "parallax ×10"):
        assert name in names, name
    ref = viewer.layers["reference b7"]
    frame = OutputGrid.from_transform(**ref.metadata["geo"])

    assert frame.crs.to_epsg() == 32633  # UTM zone of the footprint (~15 E)
    assert frame.dx == 260.0
    for name in ("DEM", "uncorrected b7", "orthorectified b7", "orthorectified RGB 7-5-2"):
        layer = viewer.layers[name]
        assert OutputGrid.from_transform(**layer.metadata["geo"]) == frame
        np.testing.assert_allclose(layer.scale[-2:], ref.scale)
        np.testing.assert_allclose(layer.translate[-2:], ref.translate)
    r = ref.data
    o = viewer.layers["orthorectified b7"].data
    u = viewer.layers["uncorrected b7"].data
    m = (r > 0) & (o > 0) & (u > 0)
    assert m.sum() > 100_000
    corr_ortho = np.corrcoef(r[m], o[m])[0, 1]
    corr_flat = np.corrcoef(r[m], u[m])[0, 1]
    assert corr_ortho > 0.95 and corr_flat < 0.7
    dem = viewer.layers["DEM"].data
    assert dem[m].max() > 2000.0  # the high range is in the small scene
    vec = viewer.layers["parallax ×10"]
    assert len(vec.data) > 100
    # shift lengths (x10) against heights: higher points move further
    length = np.hypot(vec.data[:, 1, 0], vec.data[:, 1, 1])
    h = vec.features["height"].to_numpy()
    assert np.corrcoef(length, h)[0, 1] > 0.8
    assert length.max() == pytest.approx(10 * h.max() * np.tan(np.radians(30)), rel=0.4)


def test_disparity_of_sample_ortho_against_reference(make_napari_viewer):
    from napari_meris_ortho._napari.widget_flicker import FlickerWidget

    viewer = make_napari_viewer()
    viewer.open_sample("napari-meris-ortho", "fr-small")
    widget = FlickerWidget(viewer)
    widget.layer_a.value = viewer.layers["reference b7"]
    widget.layer_b.value = viewer.layers["orthorectified b7"]
    result = widget.measure_disparity()
    dx, dy = result.global_displacement
    n = int(np.count_nonzero(result.candidate))
    assert n > 500
    assert abs(dx) < 0.25 and abs(dy) < 0.25  # orthorectified: superimposable
    vec = viewer.layers["disparity ×10 reference b7"]
    assert 0 < len(vec.data) < n / 4  # thinned to a readable density
    np.testing.assert_allclose(vec.scale, viewer.layers["reference b7"].scale)
    widget.layer_b.value = viewer.layers["uncorrected b7"]
    flat = widget.measure_disparity()
    # uncorrected: features sit at their ellipsoid position, west of the true one (the
    # satellite is east): B is displaced by -dX, several pixels on the high range
    assert np.nanpercentile(flat.dx[flat.candidate], 5) < -2.0
    assert flat.global_displacement[0] < dx - 0.2

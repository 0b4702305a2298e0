"""Flicker widget's "Measure disparity" on geocoded layers: the
matched-point vectors are drawn a pixel or two wide, and the analysis runs in a worker."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine

pytestmark = pytest.mark.slow

PIXEL = 260.0
X0, Y0 = 400_000.0, 5_100_000.0  # UTM 32N, upper-left corner


def _write(path, data):
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0],
                       count=1, dtype="float32", crs="EPSG:32632",
                       transform=Affine(PIXEL, 0, X0, 0, -PIXEL, Y0)) as ds:
        ds.write(data.astype(np.float32)[None])
    return path


@pytest.fixture
def shifted_pair(tmp_path):
    """Two geocoded 120 x 160 textures, B = A moved by +2 columns (east)."""
    from scipy.ndimage import gaussian_filter

    texture = gaussian_filter(np.random.default_rng(7).random((120, 164)), 1.5) * 100 + 10
    return (_write(tmp_path / "ortho.tif", texture[:, 2:162]),
            _write(tmp_path / "reference.tif", texture[:, 0:160]))


def _flicker(viewer, a_path, b_path):
    (a,) = viewer.open(str(a_path), plugin="napari-meris-ortho")
    (b,) = viewer.open(str(b_path), plugin="napari-meris-ortho")
    _, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Flicker")
    widget.layer_a.value, widget.layer_b.value = a, b
    return widget, a, b


def _measure(widget, qtbot, viewer):
    n_before = len(viewer.layers)
    widget.disparity_button.clicked.emit()
    # the button returns at once: the analysis runs in a worker, the GUI thread is free
    assert len(viewer.layers) == n_before
    assert "measuring" in widget.disparity_label.value
    qtbot.waitUntil(lambda: len(viewer.layers) == n_before + 1, timeout=120_000)
    return viewer.layers[-1]


def test_disparity_runs_in_a_worker(make_napari_viewer, qtbot, shifted_pair):
    viewer = make_napari_viewer()
    widget, a, _ = _flicker(viewer, *shifted_pair)
    vectors = _measure(widget, qtbot, viewer)
    assert vectors.name.startswith("disparity")
    assert "dX = +2.00 px" in widget.disparity_label.value, widget.disparity_label.value
    # vectors in world metres on layer A's grid: dX = 2 px = 520 m east, x10 exaggeration
    world_dx = vectors.data[:, 1, 1] * vectors.scale[1]
    assert np.median(world_dx) == pytest.approx(10 * 2 * PIXEL, rel=0.02)
    np.testing.assert_allclose(vectors.scale, a.scale)
    np.testing.assert_allclose(vectors.translate, a.translate)
    # over the vectors the status bar gives easting and northing, not raw world numbers
    # (a negative northing)
    x, y = X0 + 10.5 * PIXEL, Y0 - 20.5 * PIXEL
    coords = vectors.get_status((-y, x), view_direction=None, dims_displayed=[0, 1],
                                world=True)["coords"]
    assert f"E {x:.0f} m" in coords and f"N {y:.0f} m" in coords and "EPSG:32632" in coords


def test_disparity_reads_and_warps_its_layers_off_the_qt_thread(make_napari_viewer, qtbot,
                                                                 tmp_path, monkeypatch):
    """Reading the layers whole and warping B onto A's grid are the worker's, not the Qt
    thread's (there "Measure disparity" would hold the window about 0.5 s on fr-alps; the
    kernels are ``nogil``). GDAL's warp runs without a pyproj object (one crashes PROJ in a
    pooled Qt thread); B on a grid of its own (10 columns more to the west) measures +2 pixels,
    twice (the pool's thread used again)."""
    import threading

    from scipy.ndimage import gaussian_filter

    from napari_meris_ortho._napari import widget_flicker

    texture = gaussian_filter(np.random.default_rng(7).random((120, 174)), 1.5) * 100 + 10
    ortho = _write(tmp_path / "ortho.tif", texture[:, 12:172])
    with rasterio.open(tmp_path / "wide.tif", "w", driver="GTiff", width=170, height=120,
                       count=1, dtype="float32", crs="EPSG:32632",
                       transform=Affine(PIXEL, 0, X0 - 10 * PIXEL, 0, -PIXEL, Y0)) as ds:
        ds.write(texture[None, :, 0:170].astype(np.float32))
    warped_in: list[threading.Thread] = []
    warp = widget_flicker.warp

    def recorded(*args, **kwargs):
        warped_in.append(threading.current_thread())
        return warp(*args, **kwargs)

    monkeypatch.setattr(widget_flicker, "warp", recorded)
    viewer = make_napari_viewer()
    widget, a, b = _flicker(viewer, ortho, tmp_path / "wide.tif")
    assert b.data.shape != a.data.shape  # a grid of its own: the disparity warps it
    assert widget.start_disparity() is not None
    assert not warped_in  # nothing warped before the worker
    qtbot.waitUntil(lambda: widget.disparity_button.enabled, timeout=30_000)
    assert warped_in and warped_in[0] is not threading.main_thread()
    assert "dX = +2.0" in widget.disparity_label.value, widget.disparity_label.value
    widget.disparity_label.value = ""
    assert widget.start_disparity() is not None
    qtbot.waitUntil(lambda: widget.disparity_button.enabled, timeout=30_000)
    assert len(warped_in) == 2 and "dX = +2.0" in widget.disparity_label.value


def test_disparity_vectors_are_thin_on_screen(make_napari_viewer, qtbot, shifted_pair, tmp_path):
    import imageio.v3 as iio

    viewer = make_napari_viewer()
    viewer.window.show()
    widget, a, b = _flicker(viewer, *shifted_pair)
    widget.measure_disparity()  # the synchronous API (scripts)
    vectors = viewer.layers[-1]
    # edge width in world units = data units x scale: one or two pixels of A, not 260 pixels
    assert vectors.edge_width * vectors.scale[0] <= 2 * PIXEL
    viewer.reset_view()
    for layer in viewer.layers:
        layer.visible = layer is vectors
    shot = viewer.screenshot(canvas_only=True, flash=False)[..., :3].astype(int)
    magenta = (shot[..., 0] > 150) & (shot[..., 1] < 100) & (shot[..., 2] > 150)
    assert 0.0 < magenta.mean() < 0.25, magenta.mean()
    # a GIF exported afterwards still shows the images (the two frames differ)
    a.visible = b.visible = True
    out = widget.export_gif(tmp_path / "after_disparity.gif")
    frames = iio.imread(out, index=None)[..., :3].astype(float)
    assert np.abs(frames[0] - frames[1]).mean() > 5.0


def test_an_rgb_layer_is_named_as_the_reason(make_napari_viewer, shifted_pair):
    """An RGB composite against a band on the same grid is refused as an RGB layer (not as
    "different shapes and no georeference")."""
    viewer = make_napari_viewer()
    widget, a, _ = _flicker(viewer, *shifted_pair)
    rgb = viewer.add_image(np.zeros((*a.data.shape, 3), np.float32), rgb=True, name="an RGB",
                           scale=a.scale, translate=a.translate, metadata=dict(a.metadata))
    widget.layer_a.value = rgb
    assert widget.start_disparity() is None
    assert widget.disparity_label.value == ("'an RGB' is an RGB composite: the disparity "
                                            "compares two single bands (choose a grey band layer)")


def test_a_labels_layer_is_named_as_the_reason(make_napari_viewer, shifted_pair):
    """A labels layer (flags, elevation source) is refused as labels, not correlated as if it
    were radiances (which ends in "no candidate point above the confidence threshold")."""
    viewer = make_napari_viewer()
    widget, a, _ = _flicker(viewer, *shifted_pair)
    labels = viewer.add_labels(np.ones(a.data.shape, np.uint8), name="flags",
                               scale=a.scale, translate=a.translate, metadata=dict(a.metadata))
    widget.layer_b.value = labels
    assert widget.start_disparity() is None
    assert widget.disparity_label.value.startswith("'flags' is a labels layer")

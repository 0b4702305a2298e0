"""Flicker widget: alternates two layers, key binding, GIF export (handbook section 4.4)."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest

from napari_meris_ortho._napari.widget_flicker import FLICKER_KEY, FlickerWidget, export_flicker_gif
from napari_meris_ortho.errors import OptionsError


def _two_layers(viewer):
    yy, xx = np.mgrid[0:64, 0:64]
    a = viewer.add_image(((xx // 8 + yy // 8) % 2).astype(np.float32), name="A",
                         contrast_limits=(0, 1))
    b = viewer.add_image(((xx // 8 + yy // 8 + 1) % 2).astype(np.float32), name="B",
                         contrast_limits=(0, 1))
    return a, b


def test_flicker_alternates_visibility(make_napari_viewer, qtbot):
    viewer = make_napari_viewer()
    a, b = _two_layers(viewer)
    widget = FlickerWidget(viewer)
    assert widget.layer_a.value is b and widget.layer_b.value is a  # two top-most images
    widget.layer_a.value, widget.layer_b.value = a, b
    widget.rate.value = 25.0
    seen = []

    def record(event=None):
        seen.append((a.visible, b.visible))

    b.events.visible.connect(record)  # fires after both layers are set
    widget.start()
    assert widget.running
    assert widget._timer.interval() == 40
    qtbot.waitUntil(lambda: len(seen) >= 8, timeout=3000)
    widget.stop()
    assert not widget.running
    seen = seen[:8]
    states = set(seen)
    assert (True, False) in states and (False, True) in states
    # every recorded state shows exactly one of the pair
    assert all(va != vb for va, vb in seen)
    assert a.visible and b.visible  # visibility restored on stop
    assert widget.status.value == "stopped"


@pytest.mark.slow
def test_key_binding_toggles(make_napari_viewer, qtbot):
    viewer = make_napari_viewer()
    _two_layers(viewer)
    widget = FlickerWidget(viewer)
    from napari.utils.key_bindings import coerce_keybinding

    bound = viewer.keymap[coerce_keybinding(FLICKER_KEY)]  # KeyError when not bound
    bound(viewer)
    assert widget.running
    bound(viewer)
    assert not widget.running


@pytest.mark.slow
def test_same_layer_is_refused(make_napari_viewer):
    viewer = make_napari_viewer()
    a, _ = _two_layers(viewer)
    widget = FlickerWidget(viewer)
    widget.layer_a.value = a
    widget.layer_b.value = a
    widget.start()
    assert not widget.running
    assert "two different layers" in widget.status.value
    with pytest.raises(OptionsError):
        widget.export_gif()


@pytest.mark.slow
def test_removing_a_layer_stops_flicker(make_napari_viewer, qtbot):
    viewer = make_napari_viewer()
    a, b = _two_layers(viewer)
    widget = FlickerWidget(viewer)
    widget.start()
    assert widget.running
    viewer.layers.remove(a)
    assert not widget.running
    assert b.visible


@pytest.mark.slow
def test_the_layer_left_gets_its_visibility_back(make_napari_viewer, qtbot):
    """A layer removed while its pair flickers: the other one is shown again as it was before
    the flicker, whichever frame the flicker was on (it never stays hidden)."""
    viewer = make_napari_viewer()
    a, b = _two_layers(viewer)
    widget = FlickerWidget(viewer)
    widget.layer_a.value, widget.layer_b.value = a, b
    widget.start()
    widget.step()  # the frame that shows B, A hidden
    assert not a.visible and b.visible
    viewer.layers.remove(b)
    assert not widget.running
    assert a.visible


@pytest.mark.slow
def test_gif_has_alternating_frames(make_napari_viewer, tmp_path):
    viewer = make_napari_viewer()
    a, b = _two_layers(viewer)
    out = export_flicker_gif(viewer, a, b, tmp_path / "flicker_anim.gif", rate=4.0, cycles=3)
    frames = iio.imread(out, index=None)
    assert frames.shape[0] == 6
    gray = frames[..., :3].astype(float).mean(axis=-1)
    # frames 0, 2, 4 show A and 1, 3, 5 show B: the checkerboards are complementary
    assert np.array_equal(gray[0], gray[2]) and np.array_equal(gray[1], gray[3])
    differ = np.abs(gray[0] - gray[1])
    assert (differ > 200).mean() > 0.1  # large areas switch from black to white
    meta = iio.immeta(out, index=0)
    assert meta["duration"] == 250
    assert a.visible and b.visible
    assert not list(tmp_path.glob("*.part"))


@pytest.mark.slow
def test_images_covering_the_pair_are_hidden_while_it_flickers(make_napari_viewer, qtbot,
                                                                tmp_path):
    """A shown image above the pair (another band of the reference) would hide layer A whenever
    B is off, in the flicker and in its GIF. Such images are hidden meanwhile; thin geometry
    stays; everything is as before once it stops."""
    viewer = make_napari_viewer()
    a, b = _two_layers(viewer)
    cover = viewer.add_image(np.full((64, 64), 0.5, np.float32), name="cover",
                             contrast_limits=(0, 1))
    boundary = viewer.add_shapes([[[0, 0], [0, 63], [63, 63]]], shape_type="path",
                                 name="boundary")
    hidden_before = viewer.add_image(np.zeros((64, 64), np.float32), name="off", visible=False)
    widget = FlickerWidget(viewer)
    widget.layer_a.value, widget.layer_b.value = a, b
    widget.start()
    assert not cover.visible and boundary.visible and not hidden_before.visible
    widget.step()
    assert a.visible != b.visible and not cover.visible
    widget.stop()
    assert cover.visible and boundary.visible and not hidden_before.visible
    assert a.visible and b.visible
    out = export_flicker_gif(viewer, a, b, tmp_path / "covered.gif", rate=4.0, cycles=1)
    gray = iio.imread(out, index=None)[..., :3].astype(float).mean(axis=-1)
    assert (np.abs(gray[0] - gray[1]) > 200).mean() > 0.1  # A and B, not the grey cover
    assert cover.visible


@pytest.mark.slow
def test_gif_export_rejects_bad_rate(make_napari_viewer, tmp_path):
    viewer = make_napari_viewer()
    a, b = _two_layers(viewer)
    with pytest.raises(OptionsError, match="rate"):
        export_flicker_gif(viewer, a, b, tmp_path / "x.gif", rate=0.0)
    assert not (tmp_path / "x.gif").exists()


@pytest.mark.slow
def test_measure_disparity_finds_known_shift(make_napari_viewer):
    from scipy.ndimage import gaussian_filter

    viewer = make_napari_viewer()
    rng = np.random.default_rng(4)
    texture = gaussian_filter(rng.random((80, 90)), 1.5) * 100 + 10
    a = viewer.add_image(texture[:, 5:85].astype(np.float32), name="ortho")
    b = viewer.add_image(texture[:, 3:83].astype(np.float32), name="reference")
    widget = FlickerWidget(viewer)
    widget.layer_a.value, widget.layer_b.value = a, b
    result = widget.measure_disparity()
    dx, dy = result.global_displacement
    # a feature at column c of A is at column c + 2 of B
    assert dx == pytest.approx(2.0, abs=0.05) and dy == pytest.approx(0.0, abs=0.05)
    vec = viewer.layers["disparity ×10 ortho"]
    n = int(np.count_nonzero(result.candidate))
    assert n > 1000
    # thinned: one vector per candidate on a grid as coarse as the arrows are long (20 px)
    spacing = vec.metadata["spacing_px"]
    rows, cols = np.nonzero(result.candidate)
    assert spacing == 20
    assert len(vec.data) == int(np.sum((rows % spacing == 0) & (cols % spacing == 0)))
    assert np.median(vec.data[:, 1, 1]) == pytest.approx(20.0, abs=0.5)  # dX x 10 exaggeration
    label = widget.disparity_label.value
    assert f"dX = {dx:+.2f} px" in label and f"({n} points)" in label

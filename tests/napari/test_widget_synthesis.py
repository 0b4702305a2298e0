"""The Orthorectify widget's synthesis modes (MERSYN use cases 1-2, handbook section 3.1) with
their layer values: cancel, NDVI and count layers, status, temporary directory, a bad product
skipped."""

from __future__ import annotations

import datetime as dt
import tempfile

import numpy as np
import pytest

from napari_meris_ortho.ortho import orthorectify
from napari_meris_ortho.products.n1 import read_product, write_product

pytestmark = pytest.mark.slow

BANDS = (7, 13)


@pytest.fixture(scope="module")
def second_n1(tmp_path_factory, tiny_n1):
    """The tiny product seen again: darker east half; band 13 brighter in the east half,
    darker in the west half (NDVI higher east, lower west)."""
    path = tmp_path_factory.mktemp("second") / "MER_FR__1PTINY2.N1"
    first = read_product(tiny_n1)
    TINY_H, TINY_W = first.height, first.width
    tie_points = {k: v for k, v in first.tie_points.items()
                  if k in ("latitude", "longitude", "dem_alt", "view_zenith", "view_azimuth",
                           "sun_zenith", "sun_azimuth")}
    rows, cols = np.mgrid[0:TINY_H, 0:TINY_W]
    checker = ((rows // 8 + cols // 8) % 2) * 400
    base = 1000 + rows * 2 + cols + checker
    counts = []
    for b in range(1, 16):
        c = (base + 10 * (b - 1)).astype(np.float64)
        c = np.where(cols > TINY_W // 2, 0.8 * c, 1.1 * c)
        if b == 13:  # NDVI higher in the east half, lower in the west half
            c = np.where(cols > TINY_W // 2, 1.6 * c, 0.7 * c)
        counts.append(c.astype(np.uint16))
    write_product(path, product_type="MER_FR__1P", tie_points=tie_points, counts=counts,
                  flags=np.zeros((TINY_H, TINY_W), np.uint8),
                  detector_index=(cols % 740).astype(np.int16),
                  first_line_time=dt.datetime(2003, 9, 24, 9, 41, 2))
    return path


def _widget(viewer, products, algorithm):
    _, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    widget.products.value = list(products)
    widget.elevation.value = "tiepoints"
    widget.algorithm.value = algorithm
    widget.bands.value = ",".join(str(b) for b in BANDS)
    widget.geometry.value = False
    return widget


def _run(widget, qtbot):
    assert widget.start() is not None, widget.status.value
    qtbot.waitUntil(lambda: not widget.running, timeout=300_000)


def _mapped(paths, grid):
    """Each product orthorectified alone on the synthesis grid."""
    return [orthorectify(read_product(p), grid=grid, elevation="tiepoints", bands=BANDS)
            for p in paths]


def _layer(viewer, suffix):
    (layer,) = [x for x in viewer.layers if x.name.endswith(suffix)]
    return layer


def _agree(a, b, where):
    return np.isclose(a[where], b[where], rtol=1e-6).mean()


def test_min_radiance_layers(make_napari_viewer, qtbot, tiny_n1, second_n1, monkeypatch,
                             tmp_path):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    viewer = make_napari_viewer()
    widget = _widget(viewer, [tiny_n1, second_n1], "min-radiance")
    _run(widget, qtbot)
    assert widget.status.value.startswith("done"), widget.status.value
    assert "2 products" in widget.status.value
    # the bands asked for, no others (not all 15 merged and shown), the first shown (no RGB
    # quick-look without bands 5 and 2)
    bands = [x.name for x in viewer.layers if x.name.startswith("synthesis min-radiance b")]
    assert sorted(bands) == ["synthesis min-radiance b13", "synthesis min-radiance b7"]
    band7 = _layer(viewer, "b7")
    assert band7.visible
    grid = widget.last_run.items[0]["grid"]
    one, two = _mapped([tiny_n1, second_n1], grid)
    both = one.valid & two.valid
    assert both.sum() > 1000
    for b in BANDS:
        expected = np.minimum(one.bands[b], two.bands[b])
        assert _agree(_layer(viewer, f"b{b}").data, expected, both) > 0.999
    # each product wins somewhere (the second one is darker in its east half)
    wins = band7.data[both] == two.bands[7][both]
    assert 0.2 < wins.mean() < 0.8
    count = _layer(viewer, "count")
    np.testing.assert_array_equal(count.data[both], 2)
    assert set(np.unique(count.data)) <= {0, 1, 2}
    assert not list(tmp_path.glob("synthesis-*"))  # no temporary directory left


def test_max_ndvi_layers(make_napari_viewer, qtbot, tiny_n1, second_n1):
    viewer = make_napari_viewer()
    widget = _widget(viewer, [tiny_n1, second_n1], "max-ndvi")
    _run(widget, qtbot)
    assert widget.status.value.startswith("done"), widget.status.value
    grid = widget.last_run.items[0]["grid"]
    one, two = _mapped([tiny_n1, second_n1], grid)
    both = one.valid & two.valid

    def ndvi(r):
        with np.errstate(invalid="ignore"):  # NaN where a product has no data (0 / 0)
            return (r.bands[13] - r.bands[7]) / (r.bands[13] + r.bands[7])

    n1, n2 = ndvi(one), ndvi(two)
    layer = _layer(viewer, "NDVI")
    np.testing.assert_allclose(layer.data[both], np.maximum(n1, n2)[both], atol=2e-4)
    # all bands come from the product of highest NDVI (the second one in the east half)
    winner_two = n2 > n1 + 1e-3
    assert 0.2 < winner_two[both].mean() < 0.8
    band7 = _layer(viewer, "b7").data
    pick = both & winner_two
    assert _agree(band7, two.bands[7], pick) > 0.999
    pick = both & (n1 > n2 + 1e-3)
    assert _agree(band7, one.bands[7], pick) > 0.999
    np.testing.assert_array_equal(_layer(viewer, "count").data[both], 2)
    # the NDVI is NaN where no product is (transparent, not 0: opaque over the whole grid) and
    # hidden until asked for (not shown on top of the RGB)
    outside = _layer(viewer, "count").data == 0
    assert outside.any() and np.isnan(layer.data[outside]).all()
    shown = [x.name for x in viewer.layers if x.visible]
    assert not layer.visible and shown == [_layer(viewer, "b7").name]


def test_one_product_one_result_and_bad_product_skipped(make_napari_viewer, qtbot, tiny_n1,
                                                        tmp_path):
    bad = tmp_path / "MER_FR__1PBROKEN.N1"
    bad.write_bytes(tiny_n1.read_bytes()[:6000])
    viewer = make_napari_viewer()
    widget = _widget(viewer, [bad, tiny_n1], "min-radiance")
    _run(widget, qtbot)
    status = widget.status.value
    assert status.startswith("done"), status
    assert "1 product" in status and "2 products" not in status
    assert "skipped" in status and bad.name in status
    assert _layer(viewer, "b7").data.max() > 0


def test_cancel_between_tiles(make_napari_viewer, qtbot, tiny_n1, second_n1, tmp_path):
    viewer = make_napari_viewer()
    widget = _widget(viewer, [tiny_n1, second_n1, tiny_n1, second_n1], "min-radiance")
    widget.output.value = tmp_path / "synthesis"
    seen = []

    def cancel_at_first_report(done, total):
        seen.append((done, total))
        widget.cancel()

    widget.progress_hook = cancel_at_first_report
    _run(widget, qtbot)
    assert widget.status.value == "cancelled by the user"
    assert seen and seen[0][0] < seen[0][1]
    assert len(viewer.layers) == 0
    from napari_meris_ortho.synthesis.reading import is_synthesis

    assert not is_synthesis(tmp_path / "synthesis")

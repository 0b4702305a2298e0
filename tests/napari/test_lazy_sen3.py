"""A ``.SEN3`` opens like an N1: multiscale layers read on demand, the quick-look stretched from
the coarsest level, a band read whole when first shown and the last few kept
(``pyramid.WholeBands``), the flags read when first shown. Not one level read eagerly: four full
float32 bands (band 7 for the contrast limits, 7, 5 and 2 for the quick-look), its quality flags
decoded whole, and every tile napari draws reading its band whole again.
"""

from __future__ import annotations

import datetime as dt
import tracemalloc

import numpy as np
import pytest

from napari_meris_ortho._napari.reader import read_layers
from napari_meris_ortho.display import contrast_limits, stretch_channel
from napari_meris_ortho.products.n1 import tie_columns, tie_lines, write_product
from napari_meris_ortho.products.open import read_product
from napari_meris_ortho.products.sen3 import write_sen3

#: a full-width FR product (2241 columns), 1409 lines (22 tie intervals, ending on a tie row
#: as ESA's): levels 2241, 1121 and 561 columns wide
H, W = 1409, 2241
#: SEN3 fill value of the radiances (``layout.RADIANCE_FILL``): no data, NaN radiance
FILL = 65535


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """An N1 and a ``.SEN3`` of the same counts, flags and tie points; the SEN3 has a block
    of fill values (no data) in band 1."""
    out = tmp_path_factory.mktemp("sen3big")
    nt, nc = tie_lines(H, 64), tie_columns(W, 64)
    i, k = np.mgrid[0:nt, 0:nc].astype(np.float64)
    tie_points = {"latitude": 46.0 - 0.16 * i + 0.03 * k,
                  "longitude": 8.0 - 0.06 * i - 0.21 * k,
                  "dem_alt": 100.0 * k, "view_zenith": np.linspace(0, 40.7, nc) + 0 * i,
                  "view_azimuth": 99.6 + 0 * i, "sun_zenith": 48.0 + 0 * i,
                  "sun_azimuth": 153.0 + 0 * i}
    rows, cols = np.mgrid[0:H, 0:W]
    counts = [(500 + (rows * 3 + cols * (b + 1)) % 4000).astype(np.uint16) for b in range(15)]
    flags = np.where(cols < 100, 16, 0).astype(np.uint8)
    flags[rows > 1300] |= 128
    det = (cols % 740).astype(np.int16)
    start = dt.datetime(2003, 9, 21, 9, 23, 41)
    n1 = out / "MER_FR__1PBIG.N1"
    write_product(n1, product_type="MER_FR__1P", tie_points=tie_points, counts=counts,
                  flags=flags, detector_index=det, first_line_time=start)
    scaling = read_product(n1).scaling
    counts[0][200:260, 300:420] = FILL
    lat = np.linspace(46.0, 42.0, H)[:, None] + 0.0 * cols
    lon = np.linspace(8.0, 1.0, W)[None, :] + 0.0 * rows
    sen3 = write_sen3(out / "ENV_ME_1_FRG____BIG.SEN3", resolution="FR",
                      tie_points=tie_points, counts=counts, flags=flags, detector_index=det,
                      pixel_geolocation={"longitude": lon, "latitude": lat,
                                         "altitude": np.zeros((H, W), np.float32)},
                      first_line_time=np.datetime64(start), line_interval_s=0.044,
                      scaling=scaling)
    return n1, sen3


@pytest.mark.slow
def test_sen3_opens_as_multiscale_levels_of_its_bands(pair):
    """Every level of the SEN3's layers is its eager array decimated (every 2nd, 4th line and
    column): radiances (no data NaN), the quick-look stretched by the coarsest level's 1-99 %
    limits, the flags."""
    product = read_product(pair[1])
    (radiance, kw, _), (rgb, rgb_kw, _), (flags, flags_kw, _) = read_layers(str(pair[1]))
    assert kw["multiscale"] and rgb_kw["multiscale"] and flags_kw["multiscale"]
    assert [level.shape for level in radiance] == [(15, H, W), (15, 705, 1121),
                                                   (15, 353, 561)]
    assert [level.shape for level in rgb] == [(H, W, 3), (705, 1121, 3), (353, 561, 3)]
    for b in (1, 7, 15):
        full = product.radiance(b)
        for level, f in zip(radiance, (1, 2, 4), strict=True):
            np.testing.assert_array_equal(np.asarray(level[b - 1]), full[::f, ::f])
    r1 = product.radiance(1)
    assert np.isnan(r1[200:260, 300:420]).all() and np.isfinite(r1[:200]).all()
    np.testing.assert_array_equal(np.asarray(radiance[0][0, 190:270, 290:430]),
                                  r1[190:270, 290:430])
    r7 = product.radiance(7)
    np.testing.assert_array_equal(np.asarray(radiance[1][:, 5, 7]),
                                  [product.radiance(b)[10, 14] for b in range(1, 16)])
    assert kw["contrast_limits"] == contrast_limits(r7[::4, ::4], None)
    for c, b in enumerate((7, 5, 2)):
        band = product.radiance(b)
        limits = contrast_limits(band[::4, ::4])
        for level, f in zip(rgb, (1, 2, 4), strict=True):
            np.testing.assert_array_equal(np.asarray(level[..., c]),
                                          stretch_channel(band[::f, ::f], limits))
    for level, f in zip(flags, (1, 2, 4), strict=True):
        np.testing.assert_array_equal(np.asarray(level), product.flags[::f, ::f])
    names = dict(zip(flags_kw["features"]["index"], flags_kw["features"]["flags"],
                     strict=True))
    assert names[16] == "LAND_OCEAN" and names[144] == "LAND_OCEAN|INVALID"


def test_sen3_layers_equal_the_n1_layers(pair):
    """Same counts, same layers: every level of the radiances (where the SEN3 has data), of
    the quick-look and of the flags, and the same placement in the world."""
    n1, s3 = read_layers(str(pair[0])), read_layers(str(pair[1]))
    valid = np.ones((H, W), bool)
    valid[200:260, 300:420] = False
    for f, a, b in zip((1, 2, 4), n1[0][0], s3[0][0], strict=True):
        for band in (3, 6, 14):
            np.testing.assert_array_equal(np.asarray(a[band]), np.asarray(b[band]))
        np.testing.assert_array_equal(np.asarray(a[0])[valid[::f, ::f]],
                                      np.asarray(b[0])[valid[::f, ::f]])
    for k in (1, 2):
        for a, b in zip(n1[k][0][1:], s3[k][0][1:], strict=True):  # decimated levels
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        np.testing.assert_array_equal(np.asarray(n1[k][0][0][600:700, 1000:1200]),
                                      np.asarray(s3[k][0][0][600:700, 1000:1200]))
    for k in range(3):
        np.testing.assert_allclose(n1[k][1]["affine"], s3[k][1]["affine"])


def test_opening_a_sen3_reads_the_quicklook_bands_only(pair):
    """Opening reads the three quick-look bands' counts (uint16, kept) and decimates them:
    less than three full float32 bands allocated at the peak (about 30 MB; reading four
    float32 bands, stretching three full ones and decoding the uint32 quality flags would take
    117 MB)."""
    read_layers(str(pair[1]))  # imports and the headers' own allocations are not the reader's
    tracemalloc.start()
    try:
        read_layers(str(pair[1]))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 3 * H * W * 4, f"peak {peak / 2**20:.1f} MB"


def test_whole_bands_keeps_the_last_bands_read(pair):
    """Scrolling the 15 bands keeps the last ``CACHED_BANDS`` (memory bounded), reads each band
    once while it is kept, and gives the product's radiances of any selection."""
    from napari_meris_ortho.pyramid import CACHED_BANDS, WholeBands

    product = read_product(pair[1])
    bands = WholeBands(product)
    every = range(0, H, 4), range(0, W, 4)
    for b in range(1, 16):
        np.testing.assert_array_equal(bands.radiance(b, *every), product.radiance(b)[::4, ::4])
    assert bands.reads == list(range(1, 16))
    assert len(bands._counts) == CACHED_BANDS == 6
    bands.radiance(15, range(10, 20), 7)
    np.testing.assert_array_equal(bands.radiance(10, 5, range(3, 2000, 3)),
                                  product.radiance(10)[5, 3:2000:3])
    assert bands.reads == list(range(1, 16))  # kept: not read again
    np.testing.assert_array_equal(bands.radiance(1, range(190, 270), range(290, 430)),
                                  product.radiance(1)[190:270, 290:430])  # with no data
    assert bands.reads == [*range(1, 16), 1]  # dropped long ago: read again
    assert list(bands._counts) == [12, 13, 14, 15, 10, 1]  # the oldest (11) dropped


@pytest.mark.slow
def test_viewer_shows_a_decimated_level_of_the_sen3(make_napari_viewer, pair):
    """In a real viewer: every layer multiscale, the canvas shows a decimated level, and the
    band slider shows each band's values at that level."""
    product = read_product(pair[1])
    viewer = make_napari_viewer(show=True)
    layers = viewer.open(str(pair[1]), plugin="napari-meris-ortho")
    viewer.screenshot(canvas_only=True)
    assert all(layer.multiscale for layer in layers)
    rgb = next(layer for layer in layers if layer.name.startswith("RGB"))
    radiance = next(layer for layer in layers if layer.name.startswith("radiance"))
    assert rgb.data_level > 0
    shown = rgb._slice.image.raw
    assert shown.shape[0] * shown.shape[1] <= H * W / 4
    np.testing.assert_array_equal(shown, np.asarray(rgb.data[rgb.data_level])[
        tuple(slice(lo, hi + 1) for lo, hi in rgb.corner_pixels.T)])
    # the radiances open hidden under the quick-look: shown as a user shows them
    assert not radiance.visible
    rgb.visible, radiance.visible = False, True
    viewer.screenshot(canvas_only=True)
    assert radiance.data_level > 0
    for b in (3, 7, 12):
        viewer.dims.set_current_step(0, b - 1)
        viewer.screenshot(canvas_only=True)
        f = 2 ** radiance.data_level
        window = tuple(slice(lo, hi + 1) for lo, hi in radiance.corner_pixels[:, 1:].T)
        np.testing.assert_array_equal(radiance._slice.image.raw,
                                      product.radiance(b)[::f, ::f][window])

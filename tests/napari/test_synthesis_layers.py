"""A synthesis store opened in napari (_napari/synthesis_layers.py): multiscale layers from the
store's overviews, and the winning product as a labels layer whose tooltip names the product."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho._napari.layout import camera_of
from napari_meris_ortho._napari.reader import get_reader, read_store
from napari_meris_ortho._napari.world import layer_scale
from napari_meris_ortho.engine.synthesis import ndvi_decode
from napari_meris_ortho.synthesis.api import synthesize
from napari_meris_ortho.synthesis.reading import open_synthesis
from test_synthesis import GRID, scene_product


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    products = [scene_product({"fraction": 0.4, "scale_km": 12.0, "seed": 10 * k})
                for k in (1, 2)]
    out = tmp_path_factory.mktemp("store") / "syn"
    synthesize(products, out, grid=GRID, bands=(7, 13), tile=256, algorithm="max-ndvi",
               elevation="tiepoints", codec="delta-zstd")  # delta in the bands and NDVI
    return out


def test_store_opens_as_multiscale_layers(store, tmp_path) -> None:
    assert get_reader(str(store)) is read_store
    assert get_reader(str(tmp_path)) is None  # a plain directory is not ours
    layers = read_store(str(store))
    names = [kwargs["name"] for _, kwargs, _ in layers]
    assert names == [f"syn {n}" for n in ("radiance", "ndvi", "count", "product")]
    synthesis = open_synthesis(store)
    radiance, kwargs, kind = layers[0]
    # bands 7 and 13: one stack whose band axis is the MERIS band number (world 7, 13)
    assert kind == "image" and kwargs.get("visible", True)
    assert kwargs["scale"] == (6.0, *layer_scale(GRID)) and kwargs["translate"][0] == 7.0
    assert [level.shape for level in radiance] == [(2, 340, 540), (2, 170, 270)]
    for k, band in enumerate((7, 13)):
        np.testing.assert_array_equal(radiance[0][k], synthesis.band(band))
        np.testing.assert_array_equal(radiance[1][k, 10:20, 30:40],
                                      synthesis.read(f"band_{band:02d}", level=2)[10:20, 30:40])
    np.testing.assert_array_equal(np.asarray(radiance[1]),
                                  np.stack([synthesis.read(f"band_{b:02d}", level=2)
                                            for b in (7, 13)]))
    assert radiance[0][1:, ..., :5].shape == (1, 340, 5)
    assert radiance[0][[1, 0], 0, :3].shape == (2, 3) and radiance[0][2:].shape == (0, 340, 540)
    for data, kwargs, kind in layers[1:]:
        assert kwargs["multiscale"] and [level.shape for level in data] == [(340, 540),
                                                                            (170, 270)]
        assert kwargs["scale"] == layer_scale(GRID)
        name = kwargs["name"].split()[-1]
        # the NDVI decoded (not its 16-bit codes), NaN = background
        decode = ndvi_decode if name == "ndvi" else np.asarray
        np.testing.assert_array_equal(np.asarray(data[1][:]),
                                      decode(synthesis.read(name, level=2)))
        np.testing.assert_array_equal(np.asarray(data[0][:]), decode(synthesis.read(name)))
        if name == "ndvi":
            values = np.asarray(data[0][:])
            assert values.dtype == np.float32 and np.isnan(values).any()
            assert -1 <= np.nanmin(values) < np.nanmax(values) <= 1
            assert kwargs["contrast_limits"] == (-1.0, 1.0)
            np.testing.assert_array_equal(data[0][0:5, 0:5], np.asarray(data[0])[0:5, 0:5])
        assert kind == ("labels" if name == "product" else "image")
        assert kwargs["visible"] is False  # under the radiance


@pytest.mark.slow
def test_uneven_bands_open_as_a_layer_each(tmp_path) -> None:
    """Bands 2, 7, 13 have no common spacing for a band axis: a layer per band, the top one
    visible."""
    out = tmp_path / "uneven"
    synthesize([scene_product()], out, grid=GRID, bands=(2, 7, 13), tile=256,
               elevation="tiepoints")
    layers = read_store(str(out))
    assert [kwargs["name"] for _, kwargs, _ in layers] == [
        f"uneven {n}" for n in ("band_02", "band_07", "band_13", "count", "product")]
    assert [kwargs["visible"] for _, kwargs, _ in layers] == [False, False, True, False, False]
    # their MERIS band in the metadata (the flicker pairs them by it)
    assert [kwargs["metadata"].get("band") for _, kwargs, _ in layers] == [2, 7, 13, None, None]


@pytest.mark.slow
def test_the_band_slider_names_the_meris_band(store, make_napari_viewer) -> None:
    viewer = make_napari_viewer()
    (radiance, *_) = viewer.open(str(store), plugin="napari-meris-ortho")
    assert radiance.name == "syn radiance" and radiance.visible
    axis = viewer.dims.ndim - radiance.ndim
    viewer.dims.set_point(axis, 13)
    assert radiance.axis_labels[0] == "MERIS band 13 (865 nm)"
    viewer.dims.set_point(axis, 7)
    assert radiance.axis_labels[0] == "MERIS band 7 (665 nm)"
    np.testing.assert_array_equal(np.asarray(radiance._slice.image.raw)[:5, :5] >= 0, True)


@pytest.mark.slow
def test_winning_product_tooltip_names_the_product(store, make_napari_viewer) -> None:
    viewer = make_napari_viewer()
    layers = viewer.open(str(store), plugin="napari-meris-ortho")
    labels = next(layer for layer in layers if layer.name == "syn product")
    synthesis = open_synthesis(store)
    winner = synthesis.read("product")
    names = synthesis.product_names()
    assert not labels.visible  # shown on demand (over the bands)
    labels.visible = True
    for index in (1, 2):
        row, col = np.argwhere(winner == index)[len(np.argwhere(winner == index)) // 2]
        world = labels.data_to_world((row, col))
        text = labels._get_tooltip_text(np.asarray(world), world=True)
        assert f"product: {names[index]}" in text
    row, col = np.argwhere(winner == 0)[0]
    assert "product: (none)" in labels._get_tooltip_text(
        np.asarray(labels.data_to_world((row, col))), world=True)


def test_a_sparse_store_is_read_only_where_it_holds_values(tmp_path) -> None:
    """A grid three times the product's footprint each way: every level knows the box of the
    written chunks, reads only where a window meets it (the rest is background), and gives
    what zarr reads."""
    from napari_meris_ortho._napari.synthesis_layers import pyramids
    from napari_meris_ortho.geometry.grid import OutputGrid

    big = OutputGrid(GRID.crs, GRID.x0 - GRID.width * GRID.dx, GRID.y0 + GRID.height * GRID.dy,
                     GRID.dx, GRID.dy, 3 * GRID.width, 3 * GRID.height)
    out = tmp_path / "sparse"
    synthesize([scene_product()], out, grid=big, bands=(7, 13), tile=256,
               elevation="tiepoints")
    synthesis = open_synthesis(out)
    levels = pyramids(synthesis)
    full = levels["band_07"][0]
    r0, r1, c0, c1 = full.written
    assert (r1 - r0) * (c1 - c0) < big.width * big.height / 3
    stored = synthesis.read("band_07")
    assert stored[:r0].max() == 0 and stored[r1:].max() == 0  # nothing outside the box
    for window in ((slice(r0 - 100, r0 + 100), slice(c0 - 50, c1 + 50)),
                   (slice(0, 200), slice(0, 300)), (slice(None), slice(None))):
        np.testing.assert_array_equal(full[window], stored[window])
    coarse = levels["count"][-1]
    factor = synthesis.overviews[-1]
    np.testing.assert_array_equal(np.asarray(coarse), synthesis.read("count", level=factor))


@pytest.mark.slow
def test_a_sparse_store_opened_into_an_empty_viewer_frames_its_data(tmp_path, make_napari_viewer,
                                                                    qtbot) -> None:
    """napari frames the whole grid of a store it opens; the plugin then frames the pixels the
    store holds (a Europe-size store of one product: the product, not a speck in the black)."""
    from napari_meris_ortho.geometry.grid import OutputGrid

    big = OutputGrid(GRID.crs, GRID.x0 - 4 * GRID.width * GRID.dx,
                     GRID.y0 + 4 * GRID.height * GRID.dy, GRID.dx, GRID.dy,
                     9 * GRID.width, 9 * GRID.height)
    out = tmp_path / "sparse"
    synthesize([scene_product()], out, grid=big, bands=(7,), tile=256, elevation="tiepoints")
    viewer = make_napari_viewer(show=True)
    (radiance, *_) = viewer.open(str(out), plugin="napari-meris-ortho")
    qtbot.wait(200)
    framed, centre = camera_of(viewer).zoom, radiance.world_to_data(camera_of(viewer).center)[-2:]
    r0, r1, c0, c1 = radiance.metadata["data_window"]
    assert r0 <= centre[0] <= r1 and c0 <= centre[1] <= c1
    viewer.reset_view()  # napari's view: the whole grid
    whole = camera_of(viewer).zoom
    assert framed > 4 * whole
    # into a viewer that already shows something, the camera stays where the user put it
    viewer.open(str(out), plugin="napari-meris-ortho")
    qtbot.wait(200)
    assert camera_of(viewer).zoom == whole


def test_an_olci_store_names_its_bands_oa(tmp_path) -> None:
    """A store of OLCI bands opens with its band axis named Oa01.. at OLCI's centres."""
    from test_synthesis_olci import write_olci_over_grid

    product = write_olci_over_grid(tmp_path, seed=1, day=11)
    out = tmp_path / "olci"
    synthesize([str(product)], out, grid=GRID, bands=(8, 9, 10), tile=256,
               elevation="tiepoints")
    radiance, kwargs, _ = read_store(str(out))[0]
    labels = kwargs["metadata"]["band_names"]
    assert len(labels) == 21 and labels[7] == "Oa08 (665 nm)" and labels[20] == "Oa21 (1020 nm)"
    assert kwargs["translate"][0] == 8.0  # the band axis is the Oa band number

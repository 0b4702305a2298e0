"""The npe2 writer: an orthorectified layer saved as a GeoTIFF with its CRS and transform."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine


@pytest.mark.slow
def test_save_geocoded_layer_as_geotiff(make_napari_viewer, tmp_path):
    src = tmp_path / "ortho.tif"
    data = np.arange(1, 1 + 30 * 40, dtype=np.float32).reshape(30, 40)
    transform = Affine(260.0, 0, 402_000.0, 0, -260.0, 5_101_000.0)
    with rasterio.open(src, "w", driver="GTiff", width=40, height=30, count=1,
                       dtype="float32", crs="EPSG:32632", transform=transform, nodata=0) as ds:
        ds.write(data[None])
    viewer = make_napari_viewer()
    (layer,) = viewer.open(str(src), plugin="napari-meris-ortho")
    out = tmp_path / "saved.tif"
    written = viewer.layers.save(str(out), selected=True, plugin="napari-meris-ortho")
    assert [str(p) for p in written] == [str(out)]
    with rasterio.open(out) as ds:
        assert ds.crs.to_epsg() == 32632
        assert tuple(ds.transform)[:6] == pytest.approx(tuple(transform)[:6])
        np.testing.assert_array_equal(ds.read(1), data)
        assert ds.nodata == 0
    assert not list(tmp_path.glob("*.part")) and not list(tmp_path.glob(".*tmp*"))


@pytest.mark.slow
def test_writer_refuses_a_layer_without_georeference(make_napari_viewer, tmp_path):
    viewer = make_napari_viewer()
    viewer.add_image(np.ones((4, 4), np.float32), name="plain")
    out = tmp_path / "plain.tif"
    with pytest.raises(Exception, match="georeference"):
        viewer.layers.save(str(out), selected=True, plugin="napari-meris-ortho")
    assert not out.exists()


def _geotiff(path, data, nodata):
    transform = Affine(260.0, 0, 402_000.0, 0, -260.0, 5_101_000.0)
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0],
                       count=1, dtype=data.dtype.name, crs="EPSG:32632", transform=transform,
                       nodata=nodata) as ds:
        ds.write(data[None])
    return path


@pytest.mark.slow
def test_writer_refuses_the_file_a_layer_reads_from(make_napari_viewer, tmp_path):
    """napari's lazy layers read their file as the view moves: saving another layer over it
    replaced the file under them and the viewer aborted at its next draw."""
    big = _geotiff(tmp_path / "big.tif", np.ones((30, 40), np.float32), None)
    small = _geotiff(tmp_path / "small.tif", np.full((10, 12), 7, np.float32), None)
    viewer = make_napari_viewer()
    viewer.open(str(big), plugin="napari-meris-ortho")
    (layer,) = viewer.open(str(small), plugin="napari-meris-ortho")
    viewer.layers.selection = {layer}
    before = big.read_bytes()
    for target in (big, small):
        with pytest.raises(Exception, match="reads from this file"):
            viewer.layers.save(str(target), selected=True, plugin="napari-meris-ortho")
    assert big.read_bytes() == before
    out = tmp_path / "copy.tif"
    viewer.layers.save(str(out), selected=True, plugin="napari-meris-ortho")
    assert out.exists()


def test_writer_keeps_the_layers_nodata(make_napari_viewer, tmp_path):
    """A GeoTIFF's no-data value goes back out with its layer, not nodata 0 for every layer
    (which would make -9999 pixels data and a real 0 no data)."""
    data = np.arange(1, 1 + 30 * 40, dtype=np.float32).reshape(30, 40)
    data[:5] = -9999.0
    data[10, 10] = 0.0
    viewer = make_napari_viewer()
    viewer.open(str(_geotiff(tmp_path / "src.tif", data, -9999.0)), plugin="napari-meris-ortho")
    out = tmp_path / "saved.tif"
    viewer.layers.save(str(out), selected=True, plugin="napari-meris-ortho")
    with rasterio.open(out) as ds:
        assert ds.nodata == -9999.0
        mask = ds.read_masks(1)
    assert (mask[:5] == 0).all() and mask[10, 10] == 255 and (mask[5:] == 255).all()


@pytest.mark.slow
def test_a_geocoded_labels_layer_is_saved_with_its_classes(make_napari_viewer, tmp_path):
    """A run's "elevation source" or a synthesis's winning product is a labels layer: saved as
    a GeoTIFF of its classes, 0 (napari's background) as no data: the plugin's writer is
    offered for labels too."""
    src = _geotiff(tmp_path / "band.tif", np.ones((30, 40), np.float32), None)
    viewer = make_napari_viewer()
    (band,) = viewer.open(str(src), plugin="napari-meris-ortho")
    classes = np.zeros((30, 40), np.uint8)
    classes[5:20, 10:30] = 2
    classes[20:, :] = 3
    labels = viewer.add_labels(classes, name="elevation source", scale=band.scale,
                               translate=band.translate, metadata={"geo": band.metadata["geo"]})
    viewer.layers.selection = {labels}
    out = tmp_path / "source.tif"
    viewer.layers.save(str(out), selected=True, plugin="napari-meris-ortho")
    with rasterio.open(out) as ds, rasterio.open(src) as ref:
        assert ds.crs == ref.crs and ds.transform == ref.transform
        assert ds.dtypes[0] == "uint8" and ds.nodata == 0
        np.testing.assert_array_equal(ds.read(1), classes)

"""The npe2 writer: an orthorectified layer saved as a GeoTIFF with its CRS and transform."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine


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


def test_writer_refuses_a_layer_without_georeference(make_napari_viewer, tmp_path):
    viewer = make_napari_viewer()
    viewer.add_image(np.ones((4, 4), np.float32), name="plain")
    out = tmp_path / "plain.tif"
    with pytest.raises(Exception, match="georeference"):
        viewer.layers.save(str(out), selected=True, plugin="napari-meris-ortho")
    assert not out.exists()

"""GeoTIFF output: georeferencing, nodata, descriptions, metadata, tiling, atomic writes."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import rasterio

from napari_meris_ortho.errors import OutputError
from napari_meris_ortho.geometry.grid import OutputGrid
from napari_meris_ortho.io.geotiff import meris_band_description, read_geotiff, write_geotiff


def bands_for(grid, n=2):
    base = np.arange(grid.width * grid.height, dtype=np.float32).reshape(grid.shape)
    return [base * (i + 1) for i in range(n)]


def test_gdal_reopens_crs_transform_nodata_descriptions(tmp_path):
    g = OutputGrid.from_extent("EPSG:32631", (500000, 5000000), (600100, 4920000), 260.0)
    bands = bands_for(g)
    calls = []
    out = write_geotiff(
        tmp_path / "ortho.tif", bands, g,
        descriptions=[meris_band_description(7, 664.73), meris_band_description(13)],
        metadata={"sf_rad_7": 0.0123, "product": "MER_FR__1P"},
        band_metadata=[{"band": 7, "wavelength_nm": 664.73}, {"band": 13}],
        progress=lambda d, t: calls.append((d, t)))
    assert out == tmp_path / "ortho.tif" and calls == [(1, 2), (2, 2)]
    with rasterio.open(out) as ds:
        assert ds.crs.to_epsg() == 32631
        assert tuple(ds.transform)[:6] == (260.0, 0.0, 500000.0, 0.0, -260.0, 5000000.0)
        assert (ds.width, ds.height, ds.count) == (g.width, g.height, 2)
        assert ds.nodata == 0
        assert ds.descriptions == ("MERIS band 7 (664.7 nm)", "MERIS band 13")
        assert ds.tags()["sf_rad_7"] == "0.0123"
        assert ds.tags(1)["wavelength_nm"] == "664.73"
        assert ds.profile["tiled"] and ds.block_shapes[0] == (256, 256)
        assert ds.compression.name.lower() == "deflate"
        np.testing.assert_array_equal(ds.read(2), bands[1])
    assert [p.name for p in tmp_path.iterdir()] == ["ortho.tif"]


def test_read_geotiff_round_trip_geographic_past_180(tmp_path):
    g = OutputGrid("EPSG:4326", 175.0, -20.0, 0.01, 0.01, 900, 300)
    bands = [b.astype(np.uint16) for b in bands_for(g, 1)]
    write_geotiff(tmp_path / "geo.tif", bands, g, descriptions=["b1"], dtype=np.uint16)
    arrays, g2, meta = read_geotiff(tmp_path / "geo.tif")
    assert g2 == g and g2.is_lonlat
    assert g2.x0 + g2.width * g2.dx == pytest.approx(184.0)
    assert arrays[0].dtype == np.uint16
    np.testing.assert_array_equal(arrays[0], bands[0])
    assert meta["descriptions"] == ["b1"] and meta["nodata"] == 0
    assert meta["dtype"] == "uint16"


def test_unwritable_directory_raises_and_leaves_no_file(tmp_path):
    g = OutputGrid("EPSG:4326", 0.0, 1.0, 0.1, 0.1, 10, 10)
    with pytest.raises(OutputError, match="does not exist"):
        write_geotiff(tmp_path / "missing" / "x.tif", bands_for(g), g)
    ro = tmp_path / "ro"
    ro.mkdir()
    os.chmod(ro, 0o555)
    try:
        # root ignores permission bits: /proc refuses new files to everyone
        target = ro if not os.access(ro, os.W_OK) else Path("/proc")
        with pytest.raises(OutputError, match="not writable|cannot write"):
            write_geotiff(target / "x.tif", bands_for(g), g)
        assert not (target / "x.tif").exists()
        assert list(ro.iterdir()) == []
    finally:
        os.chmod(ro, 0o755)


def test_failed_write_keeps_previous_file(tmp_path):
    g = OutputGrid("EPSG:4326", 0.0, 1.0, 0.1, 0.1, 10, 10)
    path = write_geotiff(tmp_path / "x.tif", bands_for(g, 1), g)
    before = path.read_bytes()
    with pytest.raises(OutputError, match="shape"):
        write_geotiff(path, [np.zeros((3, 3), np.float32)], g)
    with pytest.raises(OutputError, match="descriptions"):
        write_geotiff(path, bands_for(g, 2), g, descriptions=["only one"])
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["x.tif"]


def test_read_geotiff_errors(tmp_path):
    (tmp_path / "bad.tif").write_bytes(b"garbage")
    with pytest.raises(OutputError, match="cannot read"):
        read_geotiff(tmp_path / "bad.tif")

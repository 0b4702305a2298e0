"""Every output of a mapped product says the same thing the same way: ``map``'s COG, its
``--stats-json`` and ``export``'s bands list the bands in file order with wavelengths, units
and GDAL scale/offset, the options, the DEMs with their vertical datums and the software
version; ``export --layer ndvi`` gives NDVI in -1..1, directly or through scale/offset."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio

from napari_meris_ortho import __version__
from napari_meris_ortho.cli import main
from napari_meris_ortho.engine.synthesis import NDVI_FACTOR, NDVI_SHIFT
from napari_meris_ortho.synthesis import store as st
from napari_meris_ortho.synthesis.reading import open_synthesis


@pytest.fixture(scope="module")
def scene(fr_small):
    return str(fr_small.product_path), str(fr_small.dem_paths["geotiff"])


@pytest.fixture(scope="module")
def store(scene, tmp_path_factory):
    """A maximum-NDVI synthesis of fr-small's bands 7 and 13, DEM heights."""
    product, dem = scene
    out = tmp_path_factory.mktemp("described") / "syn"
    assert main(["-q", "synthesize", product, "--out", str(out), "--algorithm", "max-ndvi",
                 "--bands", "7,13", "--dem", dem, "--workers", "0"]) == 0
    return out


def test_stats_json_lists_the_bands_in_file_order(scene, tmp_path):
    product, dem = scene
    out, stats = tmp_path / "rgb.tif", tmp_path / "t.json"
    assert main(["-q", "map", product, "-o", str(out), "--bands", "7,5,2", "--dem", dem,
                 "--stats-json", str(stats)]) == 0
    doc = json.loads(stats.read_text())
    assert doc["bands"] == [7, 5, 2] == doc["output"]["bands"]
    assert list(doc["wavelengths"]) == ["7", "5", "2"]
    facts = doc["output"]["band_facts"]
    assert [f["wavelength_nm"] for f in facts] == [664.64, 559.634, 442.401]
    assert [f["description"] for f in facts] == ["MERIS band 7 (664.6 nm)",
                                                 "MERIS band 5 (559.6 nm)",
                                                 "MERIS band 2 (442.4 nm)"]
    assert doc["output"]["dems"] == [{"path": dem, "name": "dem_truth.tif",
                                      "datum": "ellipsoid"}]
    assert doc["output"]["software_version"] == __version__
    with rasterio.open(out) as ds:
        assert list(ds.descriptions) == [f["description"] for f in facts]
        assert list(ds.scales) == [f["scale"] for f in facts]
        assert list(ds.offsets) == [f["offset"] for f in facts] == [0.0, 0.0, 0.0]
        assert list(ds.units) == [f["units"] for f in facts] == ["W m-2 sr-1 um-1"] * 3
        assert ds.nodata == doc["output"]["nodata"] == 0
        tags = ds.tags()
    assert tags["bands"] == "7,5,2" and tags["dems"] == "dem_truth.tif (ellipsoid)"
    assert tags["software_version"] == __version__ and tags["search"] == "primary"
    assert tags["tolerance_px"] == "0.01" and tags["elevation"] == "dem"


def test_export_writes_bands_as_map_does(store, tmp_path):
    syn = open_synthesis(store)
    out = tmp_path / "b.tif"
    assert main(["-q", "export", str(store), "-o", str(out), "--bands", "13,7"]) == 0
    with rasterio.open(out) as ds:
        assert ds.dtypes == ("uint16", "uint16") and ds.nodata == 0
        assert list(ds.scales) == [st.BAND_SCALES[13], st.BAND_SCALES[7]] == [0.003546, 0.006815]
        assert list(ds.offsets) == [0.0, 0.0]
        assert list(ds.descriptions) == ["MERIS band 13 (864.8 nm)", "MERIS band 7 (664.6 nm)"]
        assert list(ds.units) == ["W m-2 sr-1 um-1"] * 2
        assert ds.tags(1)["wavelength_nm"] == "864.833" and ds.tags(2)["meris_band"] == "7"
        tags = ds.tags()
        counts = ds.read()
    for k, b in enumerate((13, 7)):
        radiance = counts[k].astype(np.float32) * np.float32(st.BAND_SCALES[b])
        assert radiance.tobytes() == syn.band(b).tobytes()  # the store's values, exactly
    assert tags["bands"] == "13,7" and tags["dems"] == "dem_truth.tif (ellipsoid)"
    assert tags["elevation"] == "dem" and tags["software_version"] == __version__
    assert tags["software"] == "napari-meris-ortho export"
    assert main(["-q", "export", str(store), "-o", str(out), "--bands", "7",
                 "--dtype", "float32"]) == 0
    with rasterio.open(out) as ds:
        assert ds.dtypes == ("float32",) and ds.descriptions == ("MERIS band 7 (664.6 nm)",)
        assert ds.read(1).tobytes() == syn.band(7).tobytes()


def test_export_ndvi_reads_as_ndvi(store, tmp_path):
    ndvi = open_synthesis(store).ndvi()
    valid = np.isfinite(ndvi)
    assert 0.3 < valid.mean() <= 1.0
    codes = tmp_path / "ndvi.tif"
    assert main(["-q", "export", str(store), "-o", str(codes), "--layer", "ndvi"]) == 0
    with rasterio.open(codes) as ds:
        assert ds.dtypes == ("uint16",) and ds.nodata == 0
        assert ds.scales == (NDVI_FACTOR,) and ds.offsets == (NDVI_SHIFT,)
        assert ds.scales[0] == pytest.approx(2 / 65534) and ds.offsets[0] == pytest.approx(-1.0,
                                                                                     abs=1e-4)
        assert "NDVI = code x scale + offset" in ds.tags()["ndvi"]
        read = ds.read(1, masked=True)
        unscaled = read.astype(np.float64) * ds.scales[0] + ds.offsets[0]
    assert np.array_equal(~read.mask, valid)
    assert -1.0 <= unscaled.min() < 0.0 < unscaled.max() <= 1.0
    assert np.abs(unscaled.filled(np.nan)[valid] - ndvi[valid]).max() < 1e-6
    direct = tmp_path / "ndvi_f.tif"
    assert main(["-q", "export", str(store), "-o", str(direct), "--layer", "ndvi",
                 "--dtype", "float32"]) == 0
    with rasterio.open(direct) as ds:
        assert ds.dtypes == ("float32",) and np.isnan(ds.nodata)
        assert ds.scales == (1.0,) and ds.offsets == (0.0,)
        assert "NaN = background" in ds.tags()["ndvi"]
        assert ds.tags()["dems"] == "dem_truth.tif (ellipsoid)"
        values = ds.read(1)
    assert np.array_equal(values, ndvi, equal_nan=True)


def test_export_dtype_of_an_integer_layer_is_refused(store, tmp_path, capsys):
    out = tmp_path / "count.tif"
    assert main(["-q", "export", str(store), "-o", str(out), "--layer", "count",
                 "--dtype", "float32"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("meris-ortho: error: the count layer keeps")
    assert not out.exists()


def test_xarray_of_the_store_and_of_a_result_say_the_same(store, scene):
    pytest.importorskip("xarray")
    from napari_meris_ortho.ortho import orthorectify

    ds = open_synthesis(store).to_xarray()
    assert list(ds.band.values) == [7, 13]
    assert ds.attrs["dems"] == "dem_truth.tif (ellipsoid)" and ds.attrs["elevation"] == "dem"
    assert ds.attrs["software_version"] == __version__ and ds.attrs["tolerance_px"] == 0.01
    product, dem = scene
    result = orthorectify(product, dems=[dem], bands=[7], crs="utm")
    attrs = result.to_xarray().attrs
    assert attrs["dems"] == "dem_truth.tif (ellipsoid)" and attrs["search"] == "primary"
    assert attrs["software_version"] == __version__ and attrs["tolerance_px"] == 0.01

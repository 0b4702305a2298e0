"""Results as ``xarray.Dataset``: ``OrthoResult.to_xarray()`` and
``SynthesisStore.to_xarray()`` against the Cloud-Optimized GeoTIFFs the CLI writes of the same
runs, read back with rioxarray (CRS, transform, values), lazily (dask) for stores."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import rasterio

from napari_meris_ortho.cli import main
from napari_meris_ortho.errors import MissingDependencyError
from napari_meris_ortho.ortho import orthorectify
from napari_meris_ortho.products.open import read_product
from napari_meris_ortho.synthesis.reading import open_synthesis
from test_synthesis import scene_product

xr = pytest.importorskip("xarray")

MAP = ["--elevation", "tiepoints", "--crs", "EPSG:32633", "--pixel-size", "300",
       "--bands", "7,13"]


@pytest.fixture(scope="module")
def product() -> str:
    return scene_product()


@pytest.fixture(scope="module")
def mapped(product, tmp_path_factory):
    """``meris-ortho map`` of the product (uint16 COG + diagnostics) and the same run through
    the API, as a Dataset."""
    cog = tmp_path_factory.mktemp("xr") / "map.tif"
    assert main(["-q", "map", product, "-o", str(cog), *MAP]) == 0
    result = orthorectify(product, elevation="tiepoints", crs="EPSG:32633", pixel_size=300,
                          bands=[7, 13], diagnostics=True)
    return cog, result, result.to_xarray()


def test_ortho_result_dataset_layout(product, mapped) -> None:
    _, result, ds = mapped
    grid = result.grid
    assert ds.radiance.dims == ("band", "y", "x")
    assert ds.radiance.shape == (2, grid.height, grid.width)
    assert list(ds.band.values) == [7, 13]
    wl = read_product(product).wavelengths
    assert list(ds.wavelength.values) == [wl[6], wl[12]]
    assert 664 < ds.wavelength.values[0] < 666 and 864 < ds.wavelength.values[1] < 866
    # pixel centres: x0 + (j + 0.5) dx, y0 - (i + 0.5) dy
    assert ds.x.values[0] == grid.x0 + 150.0 and ds.x.values[-1] == grid.x0 + 300.0 * (
        grid.width - 0.5)
    assert ds.y.values[0] == grid.y0 - 150.0 and np.all(np.diff(ds.y.values) == -300.0)
    assert ds.x.attrs["standard_name"] == "projection_x_coordinate"
    # fill as NaN exactly where no antecedent is inside the product; radiances elsewhere
    valid = np.asarray(result.valid)
    assert 0.2 < valid.mean() < 0.95
    for k, b in enumerate((7, 13)):
        band = ds.radiance.values[k]
        assert np.array_equal(np.isnan(band), ~valid)
        assert np.array_equal(band[valid], result.bands[b][valid])
    assert np.array_equal(ds.flags.values, result.flags) and ds.flags.dtype == np.uint8
    assert list(ds.flags.attrs["flag_masks"]) == [1, 2, 4, 8, 16, 32, 64, 128]
    for name, values in result.diagnostics.items():
        assert np.array_equal(ds[name].values, values, equal_nan=True), name
    assert {"line", "col", "elevation", "iterations"} <= set(ds.data_vars)
    for name in ds.data_vars:
        assert ds[name].attrs["grid_mapping"] == "spatial_ref"
    assert ds.spatial_ref.attrs["grid_mapping_name"] == "transverse_mercator"
    assert ds.spatial_ref.attrs["projected_crs_name"] == "WGS 84 / UTM zone 33N"


# the COG has one scale per band (its sf_rad): rioxarray says it sets no single scale_factor
@pytest.mark.filterwarnings("ignore:Scales differ across bands:UserWarning")
def test_ortho_result_round_trip_with_the_cli_cog(mapped) -> None:
    """rioxarray reads the same CRS and transform from the Dataset as from the COG that
    ``meris-ortho map`` wrote of the same run; the radiances agree within one count."""
    rioxarray = pytest.importorskip("rioxarray")
    cog, result, ds = mapped
    tif = rioxarray.open_rasterio(cog, mask_and_scale=True)
    assert ds.rio.crs == tif.rio.crs and ds.rio.crs.to_epsg() == 32633
    assert ds.rio.transform() == tif.rio.transform() == result.grid.transform
    assert np.array_equal(ds.x.values, tif.x.values) and np.array_equal(ds.y.values, tif.y.values)
    with rasterio.open(cog) as src:
        scales = src.scales
    for k in range(2):
        ours, theirs = ds.radiance.values[k], tif.values[k]
        both = ~np.isnan(ours) & ~np.isnan(theirs)
        assert both.sum() > 0.99 * (~np.isnan(ours)).sum()
        assert np.abs(ours[both] - theirs[both]).max() <= scales[k] * 1.0001
    # written as netCDF (CF) and opened again: the grid mapping stays readable
    nc = cog.with_suffix(".nc")
    ds.to_netcdf(nc)
    with xr.open_dataset(nc, decode_coords="all") as back:
        assert back.rio.crs == tif.rio.crs and back.rio.transform() == tif.rio.transform()
        assert np.array_equal(back.radiance.values, ds.radiance.values, equal_nan=True)


@pytest.mark.parametrize("codec", ["zstd", "delta-zstd"])
def test_synthesis_as_a_lazy_dataset(product, tmp_path, codec) -> None:
    """The store as dask arrays chunked by its tile; values equal ``open_synthesis`` reads (0 ->
    NaN for radiances, NDVI decoded); CRS and transform equal those of ``meris-ortho export``;
    for both store codecs."""
    import dask.array as da

    out = tmp_path / "syn"
    assert main(["-q", "synthesize", product, "--out", str(out), "--bands", "7,13",
                 "--algorithm", "max-ndvi", "--crs", "EPSG:4326", "--ul", "13.45", "46.70",
                 "--lr", "14.26", "46.19", "--pixel-size", "0.0015", "--elevation", "tiepoints",
                 "--tile", "256", "--workers", "0", "--codec", codec]) == 0
    store = open_synthesis(out)
    ds = store.to_xarray()
    for name in ("radiance", "count", "product", "ndvi"):
        assert isinstance(ds[name].data, da.Array), name
    assert ds.radiance.data.chunksize == (1, 256, 256)
    assert ds.radiance.shape == (2, 340, 540) and list(ds.band.values) == [7, 13]
    assert ds.wavelength.values[0] == pytest.approx(664.64)
    for k, b in enumerate(store.bands):
        stored = store.band(b)
        assert 0.2 < (stored > 0).mean() < 1.0
        assert np.array_equal(ds.radiance.values[k], np.where(stored == 0, np.nan, stored),
                              equal_nan=True)
    assert np.array_equal(ds.ndvi.values, store.ndvi(), equal_nan=True)
    assert np.array_equal(ds["count"].values, store.read("count"))
    assert np.array_equal(ds["product"].values, store.read("product"))
    assert ds.attrs["products"] == [store.products[0]["product_name"]]
    assert ds.attrs["snapshot"] == store.snapshot
    rioxarray = pytest.importorskip("rioxarray")
    cog = tmp_path / "export.tif"
    assert main(["-q", "export", str(out), "-o", str(cog), "--bands", "7,13",
                 "--dtype", "float32"]) == 0
    tif = rioxarray.open_rasterio(cog)
    assert ds.rio.crs == tif.rio.crs and ds.rio.crs.to_epsg() == 4326
    assert ds.rio.transform() == tif.rio.transform()
    assert np.array_equal(np.nan_to_num(ds.radiance.values), tif.values)


def test_missing_xarray_is_one_clear_message(mapped, monkeypatch) -> None:
    _, result, _ = mapped
    monkeypatch.setitem(sys.modules, "xarray", None)  # import xarray -> ImportError
    with pytest.raises(MissingDependencyError, match=r"pip install 'napari-meris-ortho\[xarray"):
        result.to_xarray()

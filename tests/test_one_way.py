"""One way to do each thing: one writer of mapped products, one option check, one
band parser, one default grid, one DEM-order walk, typed contracts."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio

from napari_meris_ortho.cli import main
from napari_meris_ortho.errors import GeometryError, OptionsError
from napari_meris_ortho.geometry.tiepoints import TiePoints
from napari_meris_ortho.options import OrthoOptions, parse_band_list
from napari_meris_ortho.ortho import RunStats, orthorectify, precompute, product_grid
from napari_meris_ortho.products.open import read_product
from napari_meris_ortho.products.protocol import MerisProduct
from ortho_samples import make_dem, make_product


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("one_way")
    prod = make_product(d / "p.N1", height=130, width=321, lon0=15.0, nadir_col=-800.0)
    tp = read_product(prod).tie_points
    dem = make_dem(d / "dem.tif", tp["longitude"].min() - 0.3, tp["latitude"].min() - 0.3,
                   tp["longitude"].max() + 0.3, tp["latitude"].max() + 0.3)
    far = make_dem(d / "far.tif", 100.0, 10.0, 101.0, 11.0)  # nowhere near the product
    return d, prod, dem, far


def _cog(path):
    with rasterio.open(path) as ds:
        tags = ds.tags()
        tags.pop("software")
        return (ds.read(), ds.scales, ds.offsets, ds.dtypes, ds.descriptions, ds.overviews(1),
                tags, [ds.tags(i) for i in range(1, ds.count + 1)], ds.transform, ds.crs)


def test_the_widget_writes_the_cog_of_the_cli(files, tmp_path):
    """The napari widget's output (``ortho_run``) and ``meris-ortho map`` go through the one
    ``write_map``: uint16 counts with sf_rad as GDAL scale, overviews, band tags; same pixels."""
    from napari_meris_ortho._napari.ortho_run import CRS_GEOGRAPHIC, RunSettings, run_orthorectify

    _, prod, dem, _ = files
    cli_out, widget_out = tmp_path / "cli.tif", tmp_path / "widget.tif"
    grid = product_grid(prod, "EPSG:4326")
    assert main(["map", str(prod), "-o", str(cli_out), "--dem", str(dem), "--bands", "7,5,2",
                 "--pixel-size", str(grid.dx)]) == 0
    run = run_orthorectify(RunSettings([prod], dems=[dem], bands=(7, 5, 2), crs=CRS_GEOGRAPHIC,
                                       output=widget_out, geometry=False))
    assert run.written == [widget_out]
    cli, widget = _cog(cli_out), _cog(widget_out)
    assert widget[3] == ("uint16",) * 3 and widget[1][0] > 0 and widget[5]
    for a, b in zip(cli, widget, strict=True):
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
        else:
            assert a == b


def test_the_widget_refuses_to_overwrite_its_input_and_warns_of_an_unused_dem(files, tmp_path):
    from napari_meris_ortho._napari.ortho_run import CRS_GEOGRAPHIC, RunSettings, run_orthorectify

    _, prod, dem, far = files
    before = prod.read_bytes()
    for output in (prod, dem):
        with pytest.raises(OptionsError, match="refusing to overwrite"):
            RunSettings([prod], dems=[dem], output=output).check()
    assert prod.read_bytes() == before
    run = run_orthorectify(RunSettings([prod], dems=[far, dem], bands=(7,), crs=CRS_GEOGRAPHIC,
                                       geometry=False))
    assert run.warnings and "far.tif" in run.warnings[0] and "warning" in run.summary()


def test_one_option_check_for_the_api_the_cli_the_synthesis_and_the_widget(files, tmp_path):
    from napari_meris_ortho._napari.ortho_run import RunSettings
    from napari_meris_ortho.synthesis.api import synthesize

    _, prod, dem, _ = files
    message = "DEMs are only used with elevation 'dem'"
    with pytest.raises(OptionsError, match=message):
        precompute(prod, dems=[dem], elevation="none")
    with pytest.raises(OptionsError, match=message):
        synthesize([prod], tmp_path / "s", dems=[dem], elevation="tiepoints")
    with pytest.raises(OptionsError, match=message):
        RunSettings([prod], dems=[dem], elevation="none").check()
    assert main(["map", str(prod), "-o", str(tmp_path / "o.tif"), "--dem", str(dem),
                 "--elevation", "none"]) == 2
    assert not (tmp_path / "s").exists() and not (tmp_path / "o.tif").exists()
    # options passed whole, keywords replacing fields
    opts = OrthoOptions.of(sampling="bilinear", bands=(7,))
    r = orthorectify(prod, options=opts, elevation="tiepoints", grid=product_grid(prod))
    assert (r.stats.sampling, r.stats.elevation, r.stats.bands) == ("bilinear", "tiepoints", [7])


def test_one_band_parser():
    assert parse_band_list("7, 5,2") == (7, 5, 2) == parse_band_list("7 5 2")
    assert parse_band_list("all") is None and parse_band_list(" ") is None
    for bad in ("0", "16", "x", "7,,q"):
        with pytest.raises(OptionsError, match="bands"):
            parse_band_list(bad)
    from napari_meris_ortho._commands._options import parse_bands
    from napari_meris_ortho._napari.ortho_run import parse_bands as widget_parse

    assert widget_parse is parse_band_list and parse_bands("3,5,7") == [3, 5, 7]


def test_one_default_grid(files, tmp_path):
    """``orthorectify`` without a grid, a new synthesis and the widget use ``product_grid``."""
    from napari_meris_ortho.synthesis.api import synthesize

    _, prod, _, _ = files
    grid = product_grid(prod, "EPSG:4326")
    assert orthorectify(prod, elevation="tiepoints", bands=[7]).grid == grid
    result = synthesize([prod], tmp_path / "s", elevation="tiepoints", bands=[7], tile=256)
    assert result.grid == grid


def test_typed_contracts(files):
    _, prod, _, _ = files
    p = read_product(prod)
    assert isinstance(p, MerisProduct)
    tp = p.tie_points
    assert isinstance(tp, TiePoints) and tp.latitude is tp["latitude"]
    assert set(tp) >= {"latitude", "longitude", "dem_alt", "view_zenith", "view_azimuth"}
    with pytest.raises(GeometryError, match="lack dem_alt"):
        TiePoints.from_mapping({k: v for k, v in tp.items() if k != "dem_alt"})
    with pytest.raises(GeometryError, match="unknown quantities humidity"):
        TiePoints.from_mapping({**tp, "humidity": tp.latitude})
    stats = orthorectify(p, elevation="tiepoints", bands=[7]).stats
    assert isinstance(stats, RunStats)
    lines = stats.log_lines()
    assert lines[0].startswith("PIXEL HEIGHT") and any("ITERATION [ 0]" in ln for ln in lines)
    assert json.loads(json.dumps(stats.to_dict()))["processed_points"] == stats.processed_points


def test_one_dem_walk(files):
    """``DemStack.sample`` and the compiled heights of ``orthorectify`` are the one walk: a DEM
    that misses the points sends them to the next, the same index and heights either way."""
    from napari_meris_ortho.dem.stack import DemStack
    from napari_meris_ortho.ortho.heights import dem_heights

    _, prod, dem, far = files
    tp = read_product(prod).tie_points
    lon, lat = np.meshgrid(np.linspace(tp.longitude.min(), tp.longitude.max(), 50),
                           np.linspace(tp.latitude.min(), tp.latitude.max(), 40))
    stack = DemStack([far, dem])
    h, index = stack.sample(lon, lat)
    assert set(np.unique(index).tolist()) == {1}
    stack.prepare(float(lon.min()), float(lat.min()), float(lon.max()), float(lat.max()))
    hc, src = dem_heights(stack, lon, lat, np.ones(lon.shape, bool))
    np.testing.assert_array_equal(src, index)
    np.testing.assert_allclose(hc, h, rtol=1e-6)

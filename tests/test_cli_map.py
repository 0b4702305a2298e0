"""``meris-ortho map``: GeoTIFF output, Appendix B log, stats JSON and bad inputs (exit code 2)."""

from __future__ import annotations

import json
import logging
import os

import numpy as np
import pytest

from napari_meris_ortho.cli import main
from napari_meris_ortho.output.geotiff import read_geotiff
from napari_meris_ortho.products.n1 import read_product
from ortho_samples import make_dem, make_product


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli_map")
    prod = make_product(d / "p.N1", height=130, width=321, lon0=15.0, nadir_col=-800.0)
    tp = read_product(prod).tie_points
    dem = make_dem(d / "dem.tif", tp["longitude"].min() - 0.3, tp["latitude"].min() - 0.3,
                   tp["longitude"].max() + 0.3, tp["latitude"].max() + 0.3)
    return d, prod, dem


def test_map_writes_geotiff_log_and_stats(files, tmp_path, caplog):
    _, prod, dem = files
    out = tmp_path / "out.tif"
    stats = tmp_path / "stats.json"
    caplog.set_level(logging.INFO, logger="napari_meris_ortho")
    rc = main(["map", str(prod), "-o", str(out), "--dem", str(dem), "--bands", "1,2,7",
               "--stats-json", str(stats), "--diagnostics"])
    assert rc == 0
    err = caplog.text
    for text in ("SETTING PIXEL SIZE DEFAULT VALUES", "COMPUTING IMAGE SIZE AND ORIGIN",
                 "LINE NUMBER", "PIXEL NUMBER", "facet search", "-same=",
                 "PREDICTION/CORRECTION LOOP STATISTICS", ". ITERATION [10] =",
                 "ORTHORECTIFICATION PROCESSING = YES", "NUMBER OF PROCESSED POINTS IN SEGMENT",
                 "Total elapsed time="):
        assert text in err
    arrays, grid, meta = read_geotiff(out)
    assert len(arrays) == 3 and grid.crs.to_epsg() == 4326
    assert meta["descriptions"][2].startswith("MERIS band 7")
    s = json.loads(stats.read_text())
    assert s["output_lines"] == grid.height and s["output_columns"] == grid.width
    assert sum(s["iterations_histogram"]) == s["processed_points"] > 10000
    assert s["processed_points"] == int(np.count_nonzero(arrays[0] > 0) + np.count_nonzero(
        (arrays[0] == 0) & (arrays[1] > 0)) + np.count_nonzero((arrays[0] == 0) & (arrays[1] == 0)
                                                              & (arrays[2] > 0)))
    diag, dgrid, dmeta = read_geotiff(tmp_path / "out_diagnostics.tif")
    assert dmeta["descriptions"][:2] == ["line", "col"] and len(diag) == 8
    assert dmeta["descriptions"][7] == "hidden"
    ok = arrays[2] > 0
    assert np.all(diag[4][ok] >= 1)  # iterations


def test_map_explicit_extent_and_options(files, tmp_path, caplog):
    _, prod, _ = files
    tp = read_product(prod).tie_points
    lon, lat = float(tp["longitude"][1, 2]), float(tp["latitude"][1, 2])
    out = tmp_path / "box.tif"
    rc = main(["-q", "map", str(prod), "-o", str(out), "--elevation", "tiepoints",
               "--ul", f"{lon - 0.1}", f"{lat + 0.1}", "--lr", f"{lon + 0.1}", f"{lat - 0.1}",
               "--pixel-size", "0.005", "--bands", "2", "--sampling", "bilinear",
               "--tolerance", "0.1", "--parallax", "ellipsoid", "--search", "handbook",
               "--geolocation", "bilinear"])
    assert rc == 0
    arrays, grid, meta = read_geotiff(out)
    assert meta["tags"]["geolocation"] == "bilinear" and meta["tags"]["parallax"] == "ellipsoid"
    assert arrays[0].shape == (40, 40)
    assert grid.x0 == pytest.approx(lon - 0.1)
    assert np.count_nonzero(arrays[0]) > 800
    assert not [r for r in caplog.records if r.levelno < logging.WARNING]  # -q: warnings only


def test_map_crs_utm_is_the_zone_of_the_footprint(files, tmp_path):
    """``--crs utm``: the UTM zone of the footprint centre (the widget's default), the same
    grid and pixels as that zone named; -q/-v also after the command."""
    import subprocess
    import sys

    from napari_meris_ortho.cli import build_parser

    _, prod, _ = files
    word, named = tmp_path / "utm.tif", tmp_path / "epsg.tif"
    run = subprocess.run([sys.executable, "-m", "napari_meris_ortho.cli", "map", str(prod), "-o",
                          str(word), "--crs", "UTM", "--bands", "7", "--elevation", "tiepoints",
                          "-q"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and run.stderr == ""  # -q after "map": no log, no bar
    tp = read_product(prod).tie_points
    zone = int((np.mean(tp["longitude"]) + 180.0) // 6.0) + 1  # far from the antimeridian
    assert np.mean(tp["latitude"]) > 0 and zone == 32  # the footprint lies west of lon0 = 15 E
    assert main(["-q", "map", str(prod), "-o", str(named), "--crs", f"EPSG:326{zone}",
                 "--bands", "7", "--elevation", "tiepoints"]) == 0
    (a,), grid, _ = read_geotiff(word)
    (b,), grid_named, _ = read_geotiff(named)
    assert grid.crs.to_epsg() == 32632 and grid == grid_named
    assert np.count_nonzero(a) > 10000 and np.array_equal(a, b)
    parse = build_parser().parse_args
    assert parse(["map", "p", "-o", "o.tif", "-v"]).verbose
    assert parse(["-v", "map", "p", "-o", "o.tif"]).verbose
    plain = parse(["map", "p", "-o", "o.tif"])
    assert not plain.verbose and not plain.quiet


def test_map_geotiff_carries_band_and_scaling_metadata(files, tmp_path):
    """Band descriptions (number, wavelength); uint16 counts with
    GDAL scale = sf_rad in a valid Cloud-Optimized GeoTIFF; nearest output = the counts."""
    import rasterio
    from rio_cogeo.cogeo import cog_validate

    from napari_meris_ortho import orthorectify

    _, prod, _ = files
    product = read_product(prod)
    out = tmp_path / "meta.tif"
    assert main(["-q", "map", str(prod), "-o", str(out), "--elevation", "none",
                 "--bands", "13,7"]) == 0
    assert cog_validate(out, quiet=True)[0]
    with rasterio.open(out) as ds:
        tags, band_tags = ds.tags(), [ds.tags(1), ds.tags(2)]
        # in the order given (an RGB composite is its bands' order)
        assert ds.descriptions == (f"MERIS band 13 ({product.wavelengths[12]:.1f} nm)",
                                   f"MERIS band 7 ({product.wavelengths[6]:.1f} nm)")
        assert ds.dtypes == ("uint16", "uint16") and ds.nodata == 0 and ds.overviews(1)
        assert ds.scales == (product.scaling.radiance[12], product.scaling.radiance[6])
        assert ds.offsets == (0.0, 0.0)
        band7 = ds.read(2)
    assert tags["product_name"] == product.product_name != ""
    assert tags["product"] == str(prod) and "sf_rad" in tags["radiance"]
    for tag, b in zip(band_tags, (13, 7), strict=True):
        assert tag["meris_band"] == str(b) and tag["units"] == "W m-2 sr-1 um-1"
        assert float(tag["sf_rad"]) == product.scaling.radiance[b - 1]
        assert float(tag["wavelength_nm"]) == pytest.approx(product.wavelengths[b - 1])
        assert float(tag["bandwidth_nm"]) == pytest.approx(product.bandwidths[b - 1])
    # nearest neighbour: the written counts are the product's counts at the antecedents
    res = orthorectify(prod, elevation="none", bands=[7], diagnostics=True)
    ok = res.valid
    line = np.floor(res.diagnostics["line"][ok] + 0.5).astype(int)
    col = np.floor(res.diagnostics["col"][ok] + 0.5).astype(int)
    assert ok.sum() > 10000
    np.testing.assert_array_equal(band7[ok], product.counts(7)[line, col])
    assert np.all(band7[~ok] == 0)
    f32 = tmp_path / "f32.tif"
    assert main(["-q", "map", str(prod), "-o", str(f32), "--elevation", "none", "--bands", "7",
                 "--dtype", "float32", "--compress", "deflate"]) == 0
    with rasterio.open(f32) as ds:
        assert ds.dtypes == ("float32",) and ds.scales == (1.0,)
        assert ds.compression.name.lower() == "deflate"
        np.testing.assert_array_equal(ds.read(1), res.bands[7])


def _bad(args, tmp_path, capsys, match):
    rc = main(args)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and err[0].startswith("meris-ortho: error:")
    assert match in err[0]
    assert not [f for f in os.listdir(tmp_path) if f.endswith((".tif", ".part", ".json"))]


def test_bad_inputs_exit_2_without_output(files, tmp_path, capsys):
    d, prod, dem = files
    out = str(tmp_path / "o.tif")
    foreign = tmp_path / "foreign.N1"
    foreign.write_bytes(b"not a product" * 200)
    bad_dem = tmp_path / "bad.dem.tiff"
    bad_dem.write_bytes(b"garbage")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    cases = [
        (["map", str(tmp_path / "none.N1"), "-o", out], "none.N1"),
        (["map", str(foreign), "-o", out], "foreign.N1"),
        (["map", str(prod), "-o", out, "--dem", str(bad_dem)], "bad.dem.tiff"),
        (["map", str(prod), "-o", out, "--dem", str(dem), "--elevation", "none"],
         "DEMs given with elevation"),
        (["map", str(prod), "-o", out, "--ul", "100", "10", "--lr", "101", "9",
          "--pixel-size", "0.01"], "misses"),
        (["map", str(prod), "-o", out, "--ul", "11", "40", "--lr", "10", "45",
          "--pixel-size", "0.01"], "upper-left"),
        (["map", str(prod), "-o", out, "--pixel-size", "0"], "pixel-size"),
        (["map", str(prod), "-o", out, "--pixel-size", "-3"], "pixel-size"),
        (["map", str(prod), "-o", out, "--crs", "EPSG:999999"], "CRS"),
        (["map", str(prod), "-o", out, "--crs", "utm", "--ul", "11", "45", "--lr", "12", "44",
          "--pixel-size", "0.01"], "name the zone"),
        (["map", str(prod), "-o", str(tmp_path / "nodir" / "o.tif")], "does not exist"),
        (["map", str(prod), "-o", out, "--tolerance", "0"], "tolerance"),
    ]
    if os.geteuid() != 0:  # root writes anywhere
        cases.append((["map", str(prod), "-o", str(ro / "o.tif")], "not writable"))
    try:
        for args, match in cases:
            _bad(args, tmp_path, capsys, match)
    finally:
        ro.chmod(0o700)

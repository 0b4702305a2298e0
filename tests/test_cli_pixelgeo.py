"""The CLI on per-pixel geolocated products (FRG, RRG, SEN3): ``sample --fsg --sen3``, ``info``,
``map --geolocation pixel``, ``synthesize --geolocation pixel``; bad inputs end in exit code 2."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from napari_meris_ortho.cli import main
from napari_meris_ortho.output.geotiff import read_geotiff


def _run(capsys, *argv):
    code = main(["-q", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.slow
def test_sample_writes_the_geolocated_products(tmp_path, capsys):
    code, out, _ = _run(capsys, "sample", "fr-small", "--out", tmp_path, "--fsg", "--sen3",
                        "--set", '{"lines": 130}')
    assert code == 0
    fsg = next(line.split()[1] for line in out.splitlines() if line.startswith("fsg "))
    sen3 = next(line.split()[1] for line in out.splitlines() if line.startswith("sen3 "))
    assert "MER_FRG_1P" in fsg and sen3.endswith(".SEN3") and "ME_1_FRG" in sen3
    code, out, _ = _run(capsys, "sample", "rr-segment", "--out", tmp_path / "rr", "--fsg",
                        "--set", '{"lines": 40}')
    assert code == 0  # an RR scene: the reduced-resolution AMORGOS product
    rrg = next(line.split()[1] for line in out.splitlines() if line.startswith("fsg "))
    assert Path(rrg).name.startswith("MER_RRG_1P") and Path(rrg).is_file()


def test_info_describes_both(geolocated, capsys):
    code, out, _ = _run(capsys, "info", geolocated["fsg"])
    assert code == 0
    assert "Product type   MER_FRG_1P" in out and "33 DSDs" in out
    assert "Corrected Longitude MDS(17)" in out and "Altitude MDS(19)" in out
    assert "Geolocation    per pixel, terrain-corrected" in out
    code, out, _ = _run(capsys, "info", geolocated["sen3"])
    assert code == 0
    assert "Product type   ME_1_FRG___" in out and "Format         SAFE .SEN3" in out
    assert "geo_coordinates.nc" in out and "Size           513 columns x 320 lines" in out
    assert "Geolocation    per pixel" in out and "No.  Date" in out


def test_map_with_the_pixel_geolocation(geolocated, tmp_path, capsys):
    out = tmp_path / "pixel.tif"
    code, _, _ = _run(capsys, "map", geolocated["sen3"], "-o", out, "--geolocation", "pixel",
                      "--bands", "7", "--crs", "EPSG:32632", "--pixel-size", "300")
    assert code == 0
    arrays, grid, _ = read_geotiff(out)
    assert grid.crs.to_epsg() == 32632 and np.count_nonzero(arrays[0]) > 100_000


def test_map_with_the_pixel_geolocation_and_a_dem(fr_small, geolocated, tmp_path, capsys):
    """``--geolocation pixel --dem``: the per-pixel geolocation with the DEM's parallax (not
    refused with "DEMs given with geolocation 'pixel'"); on fr-small's gentle relief the
    same pixels as without the DEM almost everywhere, not everywhere."""
    args = ("--geolocation", "pixel", "--bands", "7", "--crs", "EPSG:32632", "--pixel-size",
            "300")
    code, _, err = _run(capsys, "map", geolocated["sen3"], "-o", tmp_path / "dem.tif", *args,
                        "--dem", fr_small.dem_paths["geotiff"])
    assert code == 0, err
    with_dem, grid, _ = read_geotiff(tmp_path / "dem.tif")
    assert _run(capsys, "map", geolocated["sen3"], "-o", tmp_path / "bare.tif", *args)[0] == 0
    bare, grid_bare, _ = read_geotiff(tmp_path / "bare.tif")
    assert grid.crs.to_epsg() == 32632
    assert (grid.x0, grid.y0, grid.shape) == (grid_bare.x0, grid_bare.y0, grid_bare.shape)
    both = (with_dem[0] > 0) & (bare[0] > 0)
    assert both.sum() > 100_000 and abs(int((with_dem[0] > 0).sum()) - int(both.sum())) < 100
    same = np.mean(with_dem[0][both] == bare[0][both])
    assert 0.95 < same < 1.0, same


@pytest.mark.slow
def test_synthesize_with_the_pixel_geolocation(geolocated, tmp_path, capsys):
    from napari_meris_ortho.synthesis.reading import open_synthesis

    out = tmp_path / "syn"
    code, _, _ = _run(capsys, "synthesize", geolocated["fsg"], geolocated["sen3"], "--out", out,
                      "--geolocation", "pixel", "--bands", "7")
    assert code == 0
    count = open_synthesis(out).read("count")
    assert count.max() == 2 and np.count_nonzero(count == 2) > 100_000


def test_bad_inputs_exit_2(fr_small, geolocated, tmp_path, capsys):
    code, _, err = _run(capsys, "map", geolocated["sen3"], "-o", tmp_path / "a.tif",
                        "--geolocation", "pixel", "--elevation", "none", "--dem",
                        fr_small.dem_paths["geotiff"])
    assert code == 2 and "DEMs are only used with elevation 'dem'" in err
    code, _, err = _run(capsys, "map", fr_small.product_path, "-o", tmp_path / "b.tif",
                        "--geolocation", "pixel")
    assert code == 2 and "per-pixel geolocation" in err and err.count("\n") == 1
    broken = tmp_path / geolocated["sen3"].name
    shutil.copytree(geolocated["sen3"], broken)
    (broken / "time_coordinates.nc").unlink()
    for argv in (["info", broken], ["map", broken, "-o", tmp_path / "c.tif"]):
        code, _, err = _run(capsys, *argv)
        assert code == 2 and err.count("\n") == 1
        assert err.startswith(f"meris-ortho: error: {broken}: missing member file(s): "
                              "time_coordinates.nc")
    assert not list(tmp_path.glob("*.tif"))


def test_broken_fsg_and_misshapen_sen3_exit_2(geolocated, tmp_path, capsys):
    import netCDF4

    data = bytearray(geolocated["fsg"].read_bytes())
    i = data.index(b'DS_NAME="Corrected Latitude MDS(18)')
    data[i + 9: i + 36] = b"Corrected Latitude MDS(99)"[:27].ljust(27)
    bad = tmp_path / geolocated["fsg"].name
    bad.write_bytes(bytes(data))
    code, _, err = _run(capsys, "info", bad)
    assert code == 2 and err.count("\n") == 1
    assert err.startswith(f"meris-ortho: error: {bad}: MER_FRG_1P product without Corrected "
                          "Latitude MDS(18)")
    broken = tmp_path / geolocated["sen3"].name
    shutil.copytree(geolocated["sen3"], broken)
    with netCDF4.Dataset(broken / "qualityFlags.nc", "a") as ds:
        ds.createDimension("few", 3)
        ds.renameVariable("quality_flags", "old")
        ds.createVariable("quality_flags", "u4", ("few", "columns"))
    code, _, err = _run(capsys, "map", broken, "-o", tmp_path / "d.tif", "--geolocation",
                        "pixel")
    assert code == 2 and err.count("\n") == 1
    assert "qualityFlags.nc: variable 'quality_flags' has shape (3, 513)" in err
    assert not (tmp_path / "d.tif").exists()


def test_map_of_an_rrg_in_pixel_mode_against_the_truth(rr_small, rrg, tmp_path, capsys):
    """``map MER_RRG_1P --geolocation pixel`` end to end: the antecedents it writes
    (``--diagnostics``) are those of the simulator's lines of sight, as for the FSG
    (``test_ortho_pixel``): about 0.0034 RR px RMS (1 km pixels: little relief per pixel)."""
    out = tmp_path / "rrg.tif"
    code, _, err = _run(capsys, "map", rrg, "-o", out, "--geolocation", "pixel", "--bands", "7",
                        "--crs", "EPSG:32632", "--diagnostics")
    assert code == 0, err
    arrays, grid, _ = read_geotiff(out)
    diag, _, _ = read_geotiff(out.with_name("rrg_diagnostics.tif"))
    valid = arrays[0] > 0
    assert valid.sum() > 0.9 * 1121 * 160  # ~1 km output pixels: about one per product pixel
    lon, lat = grid.lonlat()
    pick = np.flatnonzero(valid.ravel())[::7]
    lon, lat = lon.ravel()[pick], lat.ravel()[pick]
    tl, tc = rr_small.true_antecedent(lon, lat, rr_small.dem_height(lon, lat))
    e = np.hypot(diag[0].ravel()[pick] - tl, diag[1].ravel()[pick] - tc)
    rms = float(np.sqrt(np.mean(e ** 2)))
    assert rms <= 0.02, rms
    assert np.percentile(e, 99) < 0.05 and e.max() < 0.5

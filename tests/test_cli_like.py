"""``--like REFERENCE.tif``: a map (or a new synthesis) on a raster's grid, so that it compares
pixel for pixel with the reference; ``disparity`` on two grids says how to get there."""

from __future__ import annotations

import re

import numpy as np
import pytest
import rasterio

from napari_meris_ortho.cli import main
from napari_meris_ortho.synthesis.reading import open_synthesis


@pytest.fixture(scope="module")
def scene(fr_small):
    """fr-small's product, truth DEM and reference image (the truth radiances of bands 5, 7
    and 13 on the DEM posts, as ``meris-ortho sample fr-small`` writes them)."""
    folder = fr_small.product_path.parent
    return str(fr_small.product_path), str(fr_small.dem_paths["geotiff"]), folder / "reference.tif"


def _grid(path):
    with rasterio.open(path) as ds:
        return ds.crs, ds.transform, (ds.height, ds.width)


def _one_error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("meris-ortho: error: "), err
    return err


def test_map_like_the_reference_then_disparity_at_once(scene, tmp_path, capsys):
    product, dem, reference = scene
    out = tmp_path / "out.tif"
    assert main(["-q", "map", product, "-o", str(out), "--like", str(reference), "--dem", dem,
                 "--bands", "7"]) == 0
    crs, transform, shape = _grid(out)
    assert (crs, transform, shape) == _grid(reference)
    assert shape == (627, 1068) and transform.a == pytest.approx(0.0025)
    capsys.readouterr()
    # band 2 of the reference is band 7
    assert main(["-q", "disparity", str(reference), str(out), "--band", "2", "1"]) == 0
    text = capsys.readouterr().out
    found = re.search(r"GLOBAL DISPLACEMENT \(dX, dY\) = \((\S+), (\S+)\) pixels = "
                      r"\((\S+), (\S+)\) m, MODULUS = (\S+) m", text)
    assert found, text
    dx, dy, dx_m, dy_m, modulus = (float(v) for v in found.groups())
    # the truth DEM's map lands on the truth within a few hundredths of a pixel
    assert dx == pytest.approx(0.032, abs=0.01) and dy == pytest.approx(0.010, abs=0.01)
    assert modulus == pytest.approx(6.8, abs=2.0) and np.hypot(dx_m, dy_m) == pytest.approx(
        modulus, abs=1e-3)


def test_disparity_on_two_grids_says_how_to_get_there(scene, tmp_path, capsys):
    product, _, reference = scene
    out = tmp_path / "own.tif"
    assert main(["-q", "map", product, "-o", str(out), "--bands", "7", "--elevation",
                 "tiepoints"]) == 0
    capsys.readouterr()
    assert main(["-q", "disparity", str(reference), str(out)]) == 2
    err = _one_error(capsys)
    assert "differs from" in err and f"--like {reference}" in err


@pytest.mark.parametrize("extra", [["--crs", "utm"], ["--pixel-size", "0.01"],
                                   ["--ul", "12", "47", "--lr", "13", "46"]])
def test_like_with_another_grid_option_is_one_error(scene, tmp_path, capsys, extra):
    product, _, reference = scene
    out = tmp_path / "x.tif"
    assert main(["-q", "map", product, "-o", str(out), "--like", str(reference), *extra]) == 2
    err = _one_error(capsys)
    assert f"--like takes the CRS, transform and size from {reference}: leave out" in err
    assert extra[0] in err
    assert not out.exists()


def test_like_a_file_that_is_no_raster_is_one_error(scene, tmp_path, capsys):
    product, _, reference = scene
    text = tmp_path / "notes.tif"
    text.write_text("not a raster")
    out = tmp_path / "x.tif"
    for like, words in ((text, "cannot read the grid reference raster"),
                        (tmp_path / "missing.tif", "missing.tif"),
                        (reference, "is the grid reference")):
        target = reference if like == reference else out
        before = reference.read_bytes() if like == reference else None
        assert main(["-q", "map", product, "-o", str(target), "--like", str(like)]) == 2
        assert words in _one_error(capsys)
        if before is not None:
            assert reference.read_bytes() == before
    assert not out.exists()


def test_synthesize_a_new_store_like_the_reference(scene, tmp_path, capsys):
    product, _, reference = scene
    store = tmp_path / "syn"
    assert main(["-q", "synthesize", product, "--out", str(store), "--like", str(reference),
                 "--bands", "7", "--elevation", "tiepoints", "--workers", "0"]) == 0
    grid = open_synthesis(store).grid
    _, transform, shape = _grid(reference)
    assert (grid.height, grid.width) == shape == (627, 1068)
    assert (grid.x0, grid.y0, grid.dx, -grid.dy) == (transform.c, transform.f, transform.a,
                                                     transform.e)
    assert grid.crs.to_epsg() == 4326
    capsys.readouterr()
    assert main(["-q", "synthesize", product, "--input", str(store), "--out", str(store),
                 "--like", str(reference)]) == 2
    assert "--like" in _one_error(capsys)

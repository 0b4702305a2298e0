"""``meris-ortho map --dem PATH[:datum]``: vertical datums and Copernicus tile directories on the
command line; bad DEM entries end in one error line and exit code 2."""

from __future__ import annotations

import logging
import os

import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine

from napari_meris_ortho.cli import main
from napari_meris_ortho.dem import geoid
from napari_meris_ortho.dem.copernicus import tile_name
from napari_meris_ortho.products.n1 import read_product
from ortho_samples import make_dem, make_product, terrain


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A product at 15-16 E, 44-46 N and GLO-90 tiles of ``terrain`` (heights above EGM96)."""
    d = tmp_path_factory.mktemp("cli_dem")
    prod = make_product(d / "p.N1", height=130, width=321, lon0=15.0, nadir_col=-800.0)
    tp = read_product(prod).tie_points
    tiles = d / "copernicus"
    tiles.mkdir()
    for lat0 in range(int(np.floor(tp["latitude"].min() - 0.3)),
                      int(np.ceil(tp["latitude"].max() + 0.3))):
        for lon0 in range(int(np.floor(tp["longitude"].min() - 0.3)),
                          int(np.ceil(tp["longitude"].max() + 0.3))):
            _tile(tiles, lat0, lon0)
    far = d / "far"
    far.mkdir()
    _tile(far, -30, 120)
    return d, prod, tiles, far


def _tile(path, lat0, lon0, step=3.0 / 3600):
    n = int(round(1 / step))
    lon = lon0 + np.arange(n) * step
    lat = lat0 + 1 - np.arange(n) * step
    h = terrain(lon[None, :], lat[:, None])
    h -= geoid.geoid_undulation(*np.meshgrid(lon, lat))
    t = Affine(step, 0, lon0 - 0.5 * step, 0, -step, lat0 + 1 + 0.5 * step)
    with rasterio.open(path / tile_name(lat0, lon0), "w", driver="GTiff", width=n, height=n,
                       count=1, dtype="float32", crs="EPSG:4326", transform=t) as ds:
        ds.write(h[None].astype(np.float32))


@pytest.mark.slow
def test_copernicus_directory_with_and_without_the_geoid(files, tmp_path, caplog):
    _, prod, tiles, _ = files
    caplog.set_level(logging.INFO, logger="napari_meris_ortho")
    elevation = {}
    for name, entry in (("default", str(tiles)), ("egm96", f"{tiles}:egm96"),
                        ("ellipsoid", f"{tiles}:ellipsoid")):
        out = tmp_path / f"{name}.tif"
        assert main(["map", str(prod), "-o", str(out), "--dem", entry, "--bands", "7",
                     "--diagnostics"]) == 0
        with rasterio.open(tmp_path / f"{name}_diagnostics.tif") as ds:
            assert ds.descriptions[2] == "elevation"
            elevation[name] = ds.read(3)
            rows, cols = np.indices(ds.shape)
            lon, lat = (np.reshape(a, ds.shape) for a in ds.xy(rows.ravel(), cols.ravel()))
    ok = np.isfinite(elevation["default"]) & np.isfinite(elevation["ellipsoid"])
    ok &= (elevation["default"] != 0) & (elevation["ellipsoid"] != 0)  # 0: background
    assert ok.sum() > 10000
    assert np.array_equal(elevation["default"][ok], elevation["egm96"][ok])
    n = elevation["default"][ok] - elevation["ellipsoid"][ok]
    expected = geoid.geoid_undulation(lon[ok], lat[ok])
    assert 45.0 < expected.min() and np.max(np.abs(n - expected)) < 0.01  # EGM96 at 15 E 45 N


def _bad(args, tmp_path, capsys, match):
    rc = main(args)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and err[0].startswith("meris-ortho: error:"), err
    assert match in err[0], err[0]
    assert not [f for f in os.listdir(tmp_path) if f.endswith((".tif", ".part", ".json"))]


def test_bad_dem_entries_exit_2(files, tmp_path, capsys, monkeypatch):
    _, prod, tiles, far = files
    out = str(tmp_path / "o.tif")
    _bad(["map", str(prod), "-o", out, "--dem", f"{tiles}:egm08"], tmp_path, capsys,
         "unknown vertical datum 'egm08'")
    _bad(["map", str(prod), "-o", out, "--dem", str(far)], tmp_path, capsys,
         "no Copernicus tile covers the product footprint")
    monkeypatch.setattr(geoid, "_SEARCH", ())
    monkeypatch.setenv("PROJ_DATA", str(tmp_path))
    monkeypatch.delenv("PROJ_LIB", raising=False)
    monkeypatch.delenv("MERIS_ORTHO_GEOID", raising=False)
    _bad(["map", str(prod), "-o", out, "--dem", str(tiles)], tmp_path, capsys,
         "egm96_15.gtx not found")


def test_help_tells_the_dem_entries_and_the_handbook_search(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["map", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert exc.value.code == 0
    assert "--dem PATH[:DATUM]" in out and "Copernicus GLO-30/90" in out
    assert "DATUM: egm96 or egm2008 (heights above that geoid) or ellipsoid" in out
    assert "the outer half pixel and, on high relief, terrain within one parallax shift" in out


@pytest.mark.parametrize("command", ["map", "synthesize"])
def test_help_states_the_default_grid_and_the_widgets(capsys, command):
    """Where a user chooses the grid, the help gives the default (EPSG:4326, 0.002338 deg FR),
    the widget's (the footprint's UTM zone) and why."""
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert exc.value.code == 0
    assert "Default grid: EPSG:4326, MERSYN's geographic grid" in out
    assert "0.002338 deg FR, 0.009353 deg RR" in out
    assert "The napari widget defaults to the UTM zone of the footprint" in out
    assert "rounded out to a multiple of the pixel size" in out


@pytest.mark.parametrize(("cut", "reason"), [
    (0.5, "Read error"),  # in the heights: the tile opens, its read fails
    (500, 'IO error during reading of "GeoPixelScale"'),  # in the header: half its tags
])
def test_a_copernicus_tile_cut_short_is_one_message(files, tmp_path, capsys, caplog, recwarn,
                                                    cut, reason):
    """A tile that ends early (an interrupted download): one line naming the tile, that it is
    damaged or cut short and GDAL's root reason: not "(Read failed. See previous exception for
    details.)" for a tile cut in its data, nor five GDAL warnings, rasterio's
    NotGeoreferencedWarning and "not a Copernicus DEM tile of its name (origin 0.000000,
    0.000000 ...)" for one cut in its header."""
    import shutil

    _, prod, tiles, _ = files
    cut_tiles = tmp_path / "tiles"
    shutil.copytree(tiles, cut_tiles)
    for tile in cut_tiles.iterdir():
        size = tile.stat().st_size
        os.truncate(tile, int(size * cut) if cut < 1 else int(cut))
    caplog.set_level(logging.WARNING)
    out = tmp_path / "o.tif"
    assert main(["map", str(prod), "-o", str(out), "--dem", f"{cut_tiles}:egm96",
                 "--bands", "7"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("meris-ortho: error:"), err
    assert "cannot read Copernicus tile, the file is damaged or cut short" in err[0], err[0]
    assert reason in err[0] and "See previous exception" not in err[0], err[0]
    assert not [r for r in caplog.records if "CPLE_" in r.getMessage()]
    assert not [w for w in recwarn if "NotGeoreferenced" in w.category.__name__]
    assert not out.exists()


def test_a_cog_dem_cut_in_its_heights_is_one_message(files, tmp_path, capsys):
    """A GeoTIFF DEM in COG layout (header first) cut short opens, then its read fails:
    "damaged or cut short" and GDAL's root reason, not rasterio's "Read failed"."""
    _, prod, _, _ = files
    tp = read_product(prod).tie_points
    box = (tp["longitude"].min() - 0.3, tp["latitude"].min() - 0.3,
           tp["longitude"].max() + 0.3, tp["latitude"].max() + 0.3)  # fmt: skip
    with rasterio.open(make_dem(tmp_path / "strips.tif", *box)) as src:
        profile, data = src.profile, src.read()
    profile = {k: v for k, v in profile.items()
               if k not in ("blockxsize", "blockysize", "tiled", "interleave")}
    dem = tmp_path / "dem.tif"
    with rasterio.open(dem, "w", **{**profile, "driver": "COG"}) as dst:
        dst.write(data)
    os.truncate(dem, dem.stat().st_size * 2 // 3)
    out = tmp_path / "o.tif"
    assert main(["map", str(prod), "-o", str(out), "--dem", f"{dem}:ellipsoid",
                 "--bands", "7"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot read DEM, the file is damaged or cut short" in err[0], err
    assert "Read error" in err[0] and "See previous exception" not in err[0], err[0]
    assert not out.exists()

"""``meris-ortho map`` on an OLCI Level 1B product (``products/olci_samples``: a flat earth, so
that every mode puts each product pixel where its geolocation says): the per-pixel geolocation,
the tie points (with their heights: the pixels' altitude) and a DEM. The output pixel holding
a product pixel's centre holds that pixel's count; all 21 bands by default."""

from __future__ import annotations

import json

import numpy as np
import olci_samples as samples
import pytest

from napari_meris_ortho import orthorectify
from napari_meris_ortho.cli import main
from napari_meris_ortho.options import OrthoOptions
from napari_meris_ortho.output.geotiff import read_geotiff

ROWS = 40


@pytest.fixture(scope="module")
def product(tmp_path_factory):
    return samples.write_err(tmp_path_factory.mktemp("olci"), rows=ROWS)


@pytest.fixture(scope="module")
def flat_dem(tmp_path_factory):
    import rasterio
    from rasterio.transform import from_origin

    path = tmp_path_factory.mktemp("dem") / "flat.tif"
    res, lon0, lat1 = 0.01, -10.0, 46.0
    with rasterio.open(path, "w", driver="GTiff", width=2000, height=300, count=1,
                       dtype="float32", crs="EPSG:4326", transform=from_origin(lon0, lat1, res,
                                                                               res)) as ds:
        ds.write(np.zeros((300, 2000), np.float32), 1)
    return path


def _hits(out, band: int, kind: str = "ERR", rows: int = ROWS) -> float:
    """Share of sampled product pixels whose centre falls on an output pixel holding their
    count of ``band``."""
    from pyproj import Transformer

    arrays, grid, _ = read_geotiff(out)
    geo = samples.err_geometry(rows, kind)
    width = geo["latitude"].shape[1]
    r0, c0 = np.meshgrid(np.arange(3, rows - 3, 3), np.arange(40, width - 40, width // 50),
                         indexing="ij")
    lat, lon = geo["latitude"][r0, c0], geo["longitude"][r0, c0]
    x, y = Transformer.from_crs("EPSG:4326", grid.crs, always_xy=True).transform(lon, lat)
    c = np.floor((x - grid.x0) / grid.dx).astype(int)
    r = np.floor((grid.y0 - y) / grid.dy).astype(int)
    got = arrays[0][r, c]
    expected = samples.counts_pattern(rows, band, width)[r0, c0]
    return float(np.mean(got == expected))


@pytest.mark.parametrize("mode", [
    ["--geolocation", "pixel"],
    ["--elevation", "tiepoints"],
    ["--elevation", "none"],
    "dem",
])
def test_map_puts_each_pixel_where_its_geolocation_says(product, flat_dem, tmp_path, capsys,
                                                        mode):
    out = tmp_path / "m.tif"
    extra = ["--dem", f"{flat_dem}:ellipsoid"] if mode == "dem" else mode
    rc = main(["-q", "map", str(product), "-o", str(out), "--bands", "8", "--crs",
               "EPSG:32632", "--pixel-size", "400", *extra])
    assert rc == 0, capsys.readouterr().err
    assert _hits(out, 8) == 1.0


@pytest.mark.parametrize("mode", [["--geolocation", "pixel"], ["--elevation", "tiepoints"]])
def test_map_a_full_resolution_product(tmp_path, capsys, mode):
    """EFR: 4865 columns, tie points every 64 columns and every row."""
    product = samples.write_err(tmp_path, rows=24, kind="EFR")
    out = tmp_path / "efr.tif"
    rc = main(["-q", "map", str(product), "-o", str(out), "--bands", "17", "--crs",
               "EPSG:32632", "--pixel-size", "100", *mode])
    assert rc == 0, capsys.readouterr().err
    assert _hits(out, 17, "EFR", 24) == 1.0


def test_all_21_bands_by_default_and_band_21(product, tmp_path, capsys):
    out = tmp_path / "all.tif"
    assert main(["-q", "map", str(product), "-o", str(out), "--geolocation", "pixel",
                 "--crs", "EPSG:32632", "--pixel-size", "2000"]) == 0
    arrays, _, _ = read_geotiff(out)
    assert len(arrays) == 21
    out21 = tmp_path / "b21.tif"
    assert main(["-q", "map", str(product), "-o", str(out21), "--bands", "21",
                 "--geolocation", "pixel", "--crs", "EPSG:32632", "--pixel-size", "2000"]) == 0
    assert np.array_equal(read_geotiff(out21)[0][0], arrays[20])
    import rasterio

    with rasterio.open(out21) as ds:  # the band named as the sensor names it
        assert ds.descriptions[0].startswith("Oa21 (") and "MERIS" not in ds.descriptions[0]
    x = orthorectify(product, bands=[8], geolocation="pixel", crs="EPSG:32632",
                     pixel_size=2000).to_xarray()
    assert "MERIS" not in json.dumps(x.attrs, default=str)
    with pytest.raises(SystemExit) as exc:
        main(["-q", "map", str(product), "-o", str(tmp_path / "x.tif"), "--bands", "22"])
    assert exc.value.code == 2 and "OLCI bands are 1..21" in capsys.readouterr().err


def test_band_options_of_each_sensor():
    assert OrthoOptions.of(n_bands=21).bands == tuple(range(1, 22))
    assert OrthoOptions.of().bands == tuple(range(1, 16))
    assert OrthoOptions.of(bands=[3, 21], n_bands=21).bands == (3, 21)
    with pytest.raises(Exception, match=r"MERIS bands are 1..15"):
        OrthoOptions.of(bands=[16])

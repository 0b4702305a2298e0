"""Geoid grids as PROJ ships them both EGM96 names in PROJ's search path,
EGM2008 for EGM2008 heights (Copernicus) when present, PROJ's network only when enabled, and a
message naming every way to get a missing grid. No test uses the network."""

from __future__ import annotations

import logging
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine

from napari_meris_ortho.dem import geoid
from napari_meris_ortho.dem.geoid import EGM96, EGM2008
from napari_meris_ortho.dem.stack import open_dem
from napari_meris_ortho.errors import DemError

DEBIAN_GRID = Path("/usr/share/proj/egm96_15.gtx")


def _write_grid(path: Path, offset: float, step: float = 1.0) -> Path:
    """A global geoid grid as PROJ reads a GeoTIFF: nodes at pixel centres every ``step``
    degrees from (-180, -90), N = offset + 0.05 lon + 0.1 lat (bilinear is exact on it)."""
    lon = -180.0 + step * np.arange(int(360 / step) + 1)
    lat = 90.0 - step * np.arange(int(180 / step) + 1)
    n = (offset + 0.05 * lon[None, :] + 0.1 * lat[:, None]).astype(np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=lon.size, height=lat.size, count=1,
                       dtype="float32", crs="EPSG:4326",
                       transform=Affine(step, 0, -180.0 - step / 2, 0, -step,
                                        90.0 + step / 2)) as ds:
        ds.write(n[None])
    return path


def _field(offset, lon, lat):
    return offset + 0.05 * np.asarray(lon) + 0.1 * np.asarray(lat)


@pytest.fixture
def proj_dir(tmp_path, monkeypatch):
    """pyproj's user-writable data directory (where ``projsync`` puts grids) = an empty
    directory; Debian's /usr/share/proj and the network out of sight."""
    import pyproj.datadir

    d = tmp_path / "proj"
    d.mkdir()
    monkeypatch.setattr(pyproj.datadir, "get_user_data_dir", lambda *a, **k: str(d))
    for var in ("PROJ_DATA", "PROJ_LIB", "MERIS_ORTHO_GEOID"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("PROJ_NETWORK", "OFF")
    monkeypatch.setattr(geoid, "_SEARCH", ())
    monkeypatch.setattr(geoid, "_STEPS", {})
    monkeypatch.setattr(geoid, "_WARNED", set())
    monkeypatch.setattr(geoid, "_local", type(geoid._local)())
    return d


def test_the_search_path_is_projs(tmp_path, monkeypatch):
    import pyproj.datadir

    monkeypatch.setenv("PROJ_DATA", f"{tmp_path / 'a'}{os.pathsep}{tmp_path / 'b'}")
    dirs = geoid._directories()
    assert dirs[:2] == [tmp_path / "a", tmp_path / "b"]
    assert Path(pyproj.datadir.get_user_data_dir()) in dirs
    assert Path(pyproj.datadir.get_data_dir().split(os.pathsep)[0]) in dirs
    assert dirs[-2:] == [Path("/usr/share/proj"), Path("/usr/local/share/proj")]


def test_the_proj_name_of_egm96_is_found_and_read(proj_dir):
    grid = _write_grid(proj_dir / "us_nga_egm96_15.tif", 30.0)
    assert geoid.find_geoid_grid(EGM96) == grid
    lon, lat = np.array([10.3, -75.25, 147.8]), np.array([46.2, 4.6, -42.1])
    np.testing.assert_allclose(geoid.geoid_undulation(lon, lat), _field(30.0, lon, lat),
                               atol=1e-4)


@pytest.mark.skipif(not DEBIAN_GRID.is_file(), reason="Debian proj-data's egm96_15.gtx")
def test_the_debian_name_of_egm96_is_found(proj_dir):
    shutil.copy(DEBIAN_GRID, proj_dir / "egm96_15.gtx")
    assert geoid.find_geoid_grid(EGM96) == proj_dir / "egm96_15.gtx"
    assert abs(float(geoid.geoid_undulation(10.0, 46.0)) - 48.95) < 0.01


def test_egm2008_heights_use_the_egm2008_grid_when_present(proj_dir, tmp_path, caplog):
    _write_grid(proj_dir / "us_nga_egm96_15.tif", 30.0)
    dem = tmp_path / "dem.tif"
    with rasterio.open(dem, "w", driver="GTiff", width=40, height=40, count=1, dtype="float32",
                       crs="EPSG:4326", transform=Affine(0.05, 0, 10.0, 0, -0.05, 47.0)) as ds:
        ds.write(np.full((1, 40, 40), 1000.0, np.float32))
        ds.update_tags(VERTICAL_DATUM="egm2008")
    lon, lat = np.array([10.5, 11.2]), np.array([46.5, 45.6])
    # no EGM2008 grid: EGM96 stands in, with a warning
    with caplog.at_level(logging.WARNING):
        src = open_dem(dem)
    assert src.datum == EGM96 and "EGM2008 geoid grid us_nga_egm08_25.tif not found" in caplog.text
    np.testing.assert_allclose(src.sample(lon, lat), 1000.0 + _field(30.0, lon, lat), atol=1e-3)
    # with it: EGM2008, its own values
    _write_grid(proj_dir / "us_nga_egm08_25.tif", -20.0, step=0.5)
    src = open_dem(dem)
    assert src.datum == EGM2008
    np.testing.assert_allclose(src.sample(lon, lat), 1000.0 + _field(-20.0, lon, lat),
                               atol=1e-3)
    from napari_meris_ortho.dem.copernicus import CopernicusSource

    assert CopernicusSource.datum == EGM2008 and geoid.resolve_datum(EGM2008) == EGM2008


def test_the_compiled_lookup_uses_each_grid_spacing(proj_dir):
    """``ortho.heights`` (the compiled bilinear) gives ``geoid_undulation``'s numbers on a
    0.5-degree EGM2008 grid as on the 15' EGM96 one."""
    from napari_meris_ortho.ortho.heights import geoid_at

    _write_grid(proj_dir / "us_nga_egm08_25.tif", -20.0, step=0.5)
    rng = np.random.default_rng(4)
    lon, lat = rng.uniform(-10, 30, 500), rng.uniform(30, 70, 500)
    out = geoid_at(EGM2008, lon, lat, np.ones(500, bool))
    np.testing.assert_allclose(out, geoid.geoid_undulation(lon, lat, EGM2008), atol=1e-9)
    np.testing.assert_allclose(out, _field(-20.0, lon, lat), atol=1e-4)


def test_a_missing_grid_says_the_three_ways_to_get_it(proj_dir, monkeypatch):
    with pytest.raises(DemError) as err:
        geoid.geoid_grid_path(EGM96)
    text = str(err.value)
    for way in ("proj-data", "projsync --file us_nga_egm96_15.tif", "PROJ_NETWORK=ON",
                str(proj_dir)):
        assert way in text
    # PROJ's network enabled by the user: the grid is left to PROJ to fetch (by its name)
    monkeypatch.setenv("PROJ_NETWORK", "ON")
    assert geoid.find_geoid_grid(EGM2008) == "us_nga_egm08_25.tif"


def test_a_pip_only_machine_sees_no_system_grid(monkeypatch):
    """MERIS_ORTHO_PROJ_SYSTEM_DIRS="" (scripts/pip_only.sh) takes Debian's /usr/share/proj out
    of the search; the simulator then says why it skips its geoid-referenced DEM exports."""
    from napari_meris_ortho.simulate.scene import _missing_geoid_grid

    monkeypatch.setattr(geoid, "_local", type(geoid._local)())
    monkeypatch.setenv("PROJ_NETWORK", "OFF")
    monkeypatch.delenv("MERIS_ORTHO_GEOID", raising=False)
    if DEBIAN_GRID.is_file():
        assert _missing_geoid_grid() is None
    monkeypatch.setenv("MERIS_ORTHO_PROJ_SYSTEM_DIRS", "")
    assert Path("/usr/share/proj") not in geoid._directories()
    if not any((d / n).is_file() for d in geoid._directories() for n in EGM96_NAMES):
        assert "projsync --file us_nga_egm96_15.tif" in (_missing_geoid_grid() or "")


EGM96_NAMES = ("egm96_15.gtx", "us_nga_egm96_15.tif")

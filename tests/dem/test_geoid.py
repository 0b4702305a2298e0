"""EGM96 geoid undulations and DEM vertical datums (dem.geoid)."""

from __future__ import annotations

import numpy as np
import pyproj
import pytest

from napari_meris_ortho.dem import geoid
from napari_meris_ortho.dem.geoid import (
    EGM96,
    EGM2008,
    ELLIPSOID,
    crs_datum,
    geoid_undulation,
    other_height_datum,
    split_datum,
    to_ellipsoid,
)
from napari_meris_ortho.errors import DemError


def test_undulation_at_the_alps_and_the_compound_crs_agree():
    n = geoid_undulation(10.0, 46.0)
    assert abs(float(n) - 48.95) < 0.01
    # the same grid through PROJ's compound CRS EGM96 height -> WGS84 ellipsoidal height
    before = pyproj.datadir.get_data_dir()
    pyproj.datadir.append_data_dir(str(geoid.geoid_grid_path().parent))
    try:
        tr = pyproj.Transformer.from_crs("EPSG:4326+5773", "EPSG:4979", always_xy=True)
        rng = np.random.default_rng(11)
        lon = np.r_[10.0, -75.0, 147.3, 179.9, 0.0, 78.0, rng.uniform(-180, 180, 2000)]
        lat = np.r_[46.0, 4.0, -42.9, -16.0, 0.0, -75.0, rng.uniform(-90, 90, 2000)]
        _, _, h = tr.transform(lon, lat, np.zeros(lon.size))
    finally:
        pyproj.datadir.set_data_dir(before)
    assert np.allclose(geoid_undulation(lon, lat), h, atol=1e-6)
    # +-100 m range, wrapped longitudes, NaN passes through
    assert -110 < np.min(geoid_undulation(lon + 360.0, lat)) and np.max(h) < 90
    assert np.isnan(geoid_undulation(np.nan, 3.0))
    assert np.allclose(to_ellipsoid(np.array([100.0]), 10.0, 46.0, EGM96), 148.9525, atol=1e-3)
    assert to_ellipsoid(np.array([100.0]), 10.0, 46.0, ELLIPSOID)[0] == 100.0


def test_dem_entries_name_their_datum(tmp_path):
    assert split_datum("dem.tif:egm96") == ("dem.tif", EGM96)
    assert split_datum("dir/srtm:ELLIPSOID") == ("dir/srtm", ELLIPSOID)
    assert split_datum("dem.tif") == ("dem.tif", None)
    odd = tmp_path / "a:b.tif"
    odd.write_bytes(b"")
    assert split_datum(str(odd)) == (str(odd), None)  # an existing path is taken whole
    with pytest.raises(DemError, match="unknown vertical datum 'egm08'"):
        split_datum("dem.tif:egm08")


def test_vertical_crs_gives_the_datum():
    assert crs_datum("EPSG:4326+5773") == EGM96
    assert crs_datum("EPSG:4326+3855") == EGM2008  # resolved to EGM96 only when its grid is missing
    assert crs_datum("EPSG:4979") == ELLIPSOID
    assert crs_datum("EPSG:4326") is None and crs_datum("EPSG:32632") is None
    # a national height datum (EVRF2007, NAVD88) lies within metres of the geoid, not 47 m
    # away as the ellipsoid: not "no vertical datum" with the heights taken as ellipsoidal
    assert crs_datum("EPSG:3035+5621") == EGM2008
    assert other_height_datum("EPSG:3035+5621") == "EVRF2007 height"
    assert crs_datum("EPSG:4269+5703") == EGM2008
    assert other_height_datum("EPSG:4326+5773") is None and other_height_datum("EPSG:4326") is None


def test_missing_grid_is_one_clear_error(monkeypatch, tmp_path):
    monkeypatch.setattr(geoid, "_SEARCH", ())
    monkeypatch.setenv("PROJ_DATA", str(tmp_path))
    monkeypatch.delenv("PROJ_LIB", raising=False)
    monkeypatch.delenv("MERIS_ORTHO_GEOID", raising=False)
    with pytest.raises(DemError, match="egm96_15.gtx not found.*proj-data"):
        geoid_undulation(10.0, 46.0)
    monkeypatch.setenv("MERIS_ORTHO_GEOID", str(tmp_path / "none.gtx"))
    with pytest.raises(DemError, match="MERIS_ORTHO_GEOID"):
        geoid.geoid_grid_path()

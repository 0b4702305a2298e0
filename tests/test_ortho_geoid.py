"""Orthorectification with DEM heights above the geoid: a simulated scene whose DEM
is exported as Copernicus GLO-90 tiles holding H = h - N (EGM96). With the geoid handled the
accuracy is that of the ellipsoidal DEM; read as ellipsoidal heights, the missing N (about 47 m
here, seen at 20-30 deg) shifts every antecedent by about a tenth of a pixel."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho import orthorectify
from ortho_samples import COPERNICUS_SCENE


@pytest.fixture(scope="module")
def scene():
    from napari_meris_ortho.simulate.scene import generate_scene

    return generate_scene(COPERNICUS_SCENE)


def _error(scene, dem, **kw):
    r = orthorectify(scene.product_path, dems=[dem], parallax="ellipsoid", bands=[7],
                     diagnostics=True, **kw)
    ok = r.valid.copy()
    ok.ravel()[np.arange(ok.size) % 3 != 0] = False  # every 3rd point: the truth is slow
    lon, lat = r.grid.lonlat()
    tl, tc = scene.true_antecedent(lon[ok], lat[ok], scene.dem_height(lon[ok], lat[ok]))
    e = np.hypot(r.diagnostics["line"][ok] - tl, r.diagnostics["col"][ok] - tc)
    return r, e


def _rms(e):
    return float(np.sqrt(np.mean(e ** 2)))


@pytest.mark.slow
def test_geoid_tiles_are_as_accurate_as_the_ellipsoidal_dem(scene):
    tiles = scene.dem_paths["copernicus"]
    r_ell, e_ell = _error(scene, scene.dem_paths["geotiff"])
    r_geo, e_geo = _error(scene, tiles)  # Copernicus: EGM96 by default
    r_raw, e_raw = _error(scene, f"{tiles}:ellipsoid")  # the geoid ignored
    print(f"\nRMS / max antecedent error (px): ellipsoidal GeoTIFF {_rms(e_ell):.4f} / "
          f"{e_ell.max():.3f}; Copernicus + EGM96 {_rms(e_geo):.4f} / {e_geo.max():.3f}; "
          f"Copernicus without the geoid {_rms(e_raw):.4f} / {e_raw.max():.3f}")
    assert _rms(e_ell) <= 0.05 and _rms(e_geo) <= 0.05 and e_geo.max() <= 0.25
    assert abs(_rms(e_geo) - _rms(e_ell)) < 0.01
    assert r_geo.valid.sum() > 0.99 * r_ell.valid.sum()
    # the DEM is all Copernicus (no fall back to the tie points) and the heights are ellipsoidal
    assert r_geo.stats.elevation_sources["tiepoints"] == 0
    both = r_geo.valid & r_ell.valid & r_raw.valid
    dh = r_geo.diagnostics["elevation"][both] - r_ell.diagnostics["elevation"][both]
    assert np.abs(np.median(dh)) < 0.5
    n = r_geo.diagnostics["elevation"][both] - r_raw.diagnostics["elevation"][both]
    assert 45.0 < n.min() and n.max() < 50.0  # the EGM96 undulation over the scene
    assert _rms(e_raw) > 2 * _rms(e_geo) and _rms(e_raw) > 0.06

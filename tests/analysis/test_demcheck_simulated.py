"""DEMCHK (section 5.2) of the simulated ``fr-small`` scene's DEM exports against GPS points taken
on its truth terrain: each DEM format the simulator exports (GeoTIFF, GETASSE30) read through
``dem``."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio

from napari_meris_ortho.analysis.demcheck import GroundControlPoints, demcheck

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def gps(fr_small_scene):
    """200 points on the truth terrain (exact ellipsoidal heights) and 10 far outside."""
    with rasterio.open(fr_small_scene.dem_paths["geotiff"]) as ds:
        b = ds.bounds
    rng = np.random.default_rng(0)
    lon = rng.uniform(b.left + 0.05, b.right - 0.05, 200)
    lat = rng.uniform(b.bottom + 0.05, b.top - 0.05, 200)
    h = fr_small_scene.dem_height(lon, lat)
    return GroundControlPoints.from_arrays(np.r_[lon, np.full(10, 30.0)],
                                           np.r_[lat, np.full(10, 10.0)], np.r_[h, np.zeros(10)])


def test_truth_dem_bilinear_is_exact(fr_small_scene, gps):
    """The truth heights are bilinear between the truth DEM's posts: bilinear DEMCHK gives 0."""
    r = demcheck(gps, [fr_small_scene.dem_paths["geotiff"]])
    for check in r.methods.values():
        assert check.statistics.n == 200 and not check.inside[200:].any()
    assert r.methods["bilinear"].statistics.quadratic_mean < 1e-3
    assert r.methods["nearest"].statistics.quadratic_mean > 10.0
    assert r.methods["bicubic"].statistics.quadratic_mean < \
        r.methods["nearest"].statistics.quadratic_mean


def test_getasse30_variants_agree(fr_small_scene, gps):
    """Handbook float32 tiles and BEAM int16 tiles of the same 30" resampling: same statistics
    to the int16 rounding; coarser posts than the truth, so larger differences."""
    float32 = demcheck(gps, [fr_small_scene.dem_paths["getasse30"]])
    int16 = demcheck(gps, [fr_small_scene.dem_paths["getasse30_beam"]])
    truth = demcheck(gps, [fr_small_scene.dem_paths["geotiff"]])
    for method in ("nearest", "bilinear", "bicubic"):
        a, b = float32.methods[method].statistics, int16.methods[method].statistics
        assert a.n == b.n == 200
        assert a.quadratic_mean == pytest.approx(b.quadratic_mean, abs=0.1)
        assert a.arithmetic_mean == pytest.approx(b.arithmetic_mean, abs=0.1)
        assert a.quadratic_mean > truth.methods[method].statistics.quadratic_mean
    assert float32.methods["bilinear"].statistics.quadratic_mean < \
        float32.methods["nearest"].statistics.quadratic_mean

"""``orthorectify(..., geolocation="pixel")`` of per-pixel geolocated products (FRG N1, SEN3)
against the simulator's truth, and beside the tie-point orthorectification of the same scene."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.ortho import orthorectify


@pytest.fixture(scope="module")
def tiepoint_result(fr_small):
    return orthorectify(fr_small.product_path, dems=[fr_small.dem_paths["geotiff"]], bands=[7],
                        parallax="ellipsoid", diagnostics=True)


def _truth_error(fr_small, r, stride=5):
    """Antecedent error (product pixels) against the simulator's line of sight, every
    ``stride``-th valid point."""
    ok = r.valid.copy()
    ok.ravel()[np.arange(ok.size) % stride != 0] = False
    lon, lat = r.grid.lonlat()
    tl, tc = fr_small.true_antecedent(lon[ok], lat[ok], fr_small.dem_height(lon[ok], lat[ok]))
    return np.hypot(r.diagnostics["line"][ok] - tl, r.diagnostics["col"][ok] - tc)


@pytest.mark.parametrize("kind", ["fsg", "sen3"])
def test_pixel_geolocation_accuracy_against_the_truth(fr_small, geolocated, tiepoint_result, kind):
    """The per-pixel truth geolocation inverted on the tie-point run's grid: <= 0.05 px RMS
    (bilinear between terrain points of pixel centres; the error is where relief folds)."""
    r = orthorectify(geolocated[kind], grid=tiepoint_result.grid, geolocation="pixel", bands=[7],
                     diagnostics=True)
    e = _truth_error(fr_small, r)
    rms = float(np.sqrt(np.mean(e ** 2)))
    assert rms <= 0.05, rms
    assert np.percentile(e, 99) < 0.25 and e.max() < 2.0
    # the same points are mapped as by the tie-point model with the DEM (no hole, no parallax)
    assert abs(int(r.valid.sum()) - int(tiepoint_result.valid.sum())) < 0.01 * r.valid.sum()
    both = r.valid & tiepoint_result.valid
    dl = r.diagnostics["line"][both] - tiepoint_result.diagnostics["line"][both]
    dc = r.diagnostics["col"][both] - tiepoint_result.diagnostics["col"][both]
    assert np.sqrt(np.mean(dl ** 2 + dc ** 2)) < 0.06
    # the product altitude at the antecedent is the diagnostics' elevation
    h = fr_small.dem_height(*[a[both] for a in r.grid.lonlat()])
    assert np.median(np.abs(r.diagnostics["elevation"][both] - h)) < 5.0
    assert r.stats.geolocation == "pixel"
    # nearest neighbour: the same product pixel almost everywhere (flicker: nothing moves)
    assert np.mean(r.bands[7][both] == tiepoint_result.bands[7][both]) > 0.95


def test_pixel_geolocation_without_terrain_correction_would_be_wrong(fr_small, geolocated,
                                                                     tiepoint_result):
    """Re-applying the parallax to terrain points (tie-point model on the same radiances with
    elevation none) is pixels off: the pixel model is what removes it."""
    r = orthorectify(geolocated["sen3"], grid=tiepoint_result.grid, elevation="none", bands=[7],
                     diagnostics=True)
    e = _truth_error(fr_small, r)
    assert np.sqrt(np.mean(e ** 2)) > 1.0


def test_pixel_geolocation_needs_a_geolocated_product(fr_small, geolocated):
    with pytest.raises(OptionsError, match="per-pixel geolocation"):
        orthorectify(fr_small.product_path, geolocation="pixel", bands=[7])
    with pytest.raises(OptionsError, match="DEMs given with geolocation 'pixel'"):
        orthorectify(geolocated["fsg"], geolocation="pixel", dems=[fr_small.dem_paths["geotiff"]])

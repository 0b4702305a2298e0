"""Simulated OLCI products read back: ESA's layout of the truth (tie points on the ellipsoid,
per-pixel geolocation on the terrain, 21 bands, detectors, both flag baselines)."""

from __future__ import annotations

import netCDF4
import numpy as np
import pytest
from pyproj import Geod

from napari_meris_ortho.bands import Sensor
from napari_meris_ortho.products.olci.layout import FlagBaseline
from napari_meris_ortho.products.open import read_product
from napari_meris_ortho.simulate import generate_scene, olci
from napari_meris_ortho.simulate.olci_product import column_detectors

GEOD = Geod(ellps="WGS84")
#: a 48-row piece of olci-err-andes (the Andes under the western part of the swath)
NO_EXPORTS = {"getasse30": False, "getasse30_beam": False, "srtm30": False,
              "geotiff_utm": False, "reference": False}
SMALL_ERR = {"base": "olci-err-andes", "lines": 48, "saturated_fraction": 5e-4,
             "orbit": {"nadir_lat": -16.0, "nadir_lon": -63.0}, "exports": NO_EXPORTS}


@pytest.fixture(scope="module")
def err(tmp_path_factory):
    return generate_scene(SMALL_ERR, out_dir=tmp_path_factory.mktemp("olci-err"))


@pytest.fixture(scope="module")
def err_per_band(tmp_path_factory):
    return generate_scene({**SMALL_ERR, "processing_baseline": "2.23"},
                          out_dir=tmp_path_factory.mktemp("olci-err-2.23"))


def test_the_product_is_an_olci_err_of_21_bands(err):
    p = read_product(err.product_path)
    assert err.product_path.name.startswith("S3B_OL_1_ERR____")
    assert p.sensor == Sensor.OLCI and p.n_bands == 21 and p.product_type == "OL_1_ERR___"
    assert (p.height, p.width) == (48, 1217)
    assert (p.lines_per_tie_point, p.samples_per_tie_point) == (1, 16)
    assert p.tie_points["latitude"].shape == (48, 77)
    assert abs(p.scaling.radiance[0] - 0.013946459628641605) < 1e-12


def test_tie_points_lie_on_the_ellipsoid_and_pixels_on_the_terrain(err):
    """ESA's layout: tie-point latitude/longitude not orthorectified, the per-pixel ones where
    the line of sight meets the DEM; the difference is the terrain displacement."""
    p = read_product(err.product_path)
    g = err.geometry
    truth = err.pixel_geometry(g.tie_lines, g.tie_cols)
    tp = p.tie_points
    # to the storage step (1e-6 deg) and the linear half-pixel move of ESA's tie-point
    # position and back (0.5 m here)
    assert np.max(np.abs(tp["latitude"] - truth["e_lat"])) < 1e-5
    assert np.max(np.abs(tp["longitude"] - truth["e_lon"])) < 1e-5
    # angles too, but beside the nadir, where the view zenith turns (its linear move across
    # the turn is off by up to 0.1 deg)
    off_nadir = np.abs(g.tie_cols + g.first_column) > 2 * g.tie_step
    assert np.max(np.abs(tp["view_zenith"] - truth["view_zenith"])[:, off_nadir]) < 0.01
    lat = p.pixel_latitude()
    lon = p.pixel_longitude()
    cols = np.arange(g.columns, dtype=np.float64)
    t = err.pixel_geometry(np.array([0.0, 47.0]), cols)
    for row, k in ((0, 0), (47, 1)):
        assert np.max(np.abs(lat[row] - t["t_lat"][k])) < 1e-6
        assert np.max(np.abs(lon[row] - t["t_lon"][k])) < 1e-6
        assert np.max(np.abs(p.pixel_altitude()[row] - t["t_h"][k])) <= 0.5
    # over the Andes (3-6 km, 45-57 deg view zenith) the pixels lie kilometres from the
    # ellipsoid point of their line of sight, towards the sensor
    _, _, d = GEOD.inv(truth["e_lon"], truth["e_lat"], lon[:, ::16], lat[:, ::16])
    high = p.pixel_altitude()[:, ::16] > 3000.0
    assert high.sum() > 50
    assert np.median(d[high]) > 3000.0 and np.median(d[~high & (tp["dem_alt"] < 300)]) < 400.0


def test_radiances_are_the_truth_at_the_terrain_points(err):
    p = read_product(err.product_path)
    lat, lon = p.pixel_latitude(), p.pixel_longitude()
    for band in (1, 8, 13, 17, 20, 21):
        rad = p.radiance(band)
        truth = err.truth_radiance(lon, lat, band)
        ok = np.isfinite(rad)
        assert ok.mean() > 0.99
        step = p.scaling.radiance[band - 1]
        assert np.max(np.abs(rad[ok] - truth[ok])) <= 0.5 * step + 1e-3 * truth[ok].max()


def test_detector_index_and_duplicated_pixels(err):
    p = read_product(err.product_path)
    det = np.asarray(p.detector_index)
    assert det.shape == (48, 1217)
    assert np.array_equal(det[0], column_detectors(err.geometry))
    assert np.all(det == det[0])
    with netCDF4.Dataset(err.product_path / "instrument_data.nc") as ds:
        for key in ("lambda0", "FWHM", "solar_flux"):
            assert ds[key].shape == (21, 3700)
        assert abs(float(ds["lambda0"][16].mean()) - 865.0) < 1.0


@pytest.mark.parametrize("baseline", ["2.24", "2.23"])
def test_both_flag_baselines(err, err_per_band, baseline):
    """2.24 on: saturated samples hold the fill value, one ``saturated`` and one
    ``partially_saturated`` flag; before: the counts kept at the largest value and one flag
    per band (``saturated`` bits of the product)."""
    scene = err if baseline == "2.24" else err_per_band
    p = read_product(scene.product_path)
    with netCDF4.Dataset(scene.product_path / "qualityFlags.nc") as ds:
        meanings = ds["quality_flags"].flag_meanings.split()
        qf = ds["quality_flags"][:].data[:, ::-1]  # ESA's west-to-east columns
    if baseline == "2.24":
        assert p.baseline is FlagBaseline.SINCE_2_24
        assert "saturated" in meanings and "saturated_Oa01" not in meanings
        sat = (qf & np.uint32(1 << 20)) != 0
        assert sat.sum() >= 3
        assert np.all(np.asarray(p.counts(1))[sat] == 65535)
        assert not np.any(np.asarray(p.saturated))
    else:
        assert p.baseline is FlagBaseline.PER_BAND
        assert "saturated_Oa21" in meanings
        bits = np.asarray(p.saturated)
        oa01 = (bits & 1) != 0
        assert oa01.sum() >= 3
        assert np.all(np.asarray(p.counts(1))[oa01] == 65534)
        # a quarter saturate in every band, the others in the blue bands from Oa01 on
        assert np.any(bits == (1 << 21) - 1)
        assert not np.any((bits != 0) & ~oa01)
    dup = (qf & np.uint32(1 << 23)) != 0
    assert np.array_equal(dup, olci.duplicated(np.asarray(p.detector_index)))


def test_true_antecedent_of_the_pixel_geolocation_is_the_pixel(err):
    p = read_product(err.product_path)
    rows = np.array([5, 20, 40])
    cols = np.array([3, 600, 1210])
    lon = p.pixel_longitude()[rows[:, None], cols]
    lat = p.pixel_latitude()[rows[:, None], cols]
    h = np.asarray(err.pixel_geometry(rows.astype(float), cols.astype(float))["t_h"])
    line, col = err.true_antecedent(lon, lat, h)
    assert np.max(np.abs(line - rows[:, None])) < 0.01
    assert np.max(np.abs(col - cols[None, :])) < 0.01

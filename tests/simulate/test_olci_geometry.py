"""OLCI geometry of the simulator: the Sentinel-3 orbit, the tilted swath, the sampling, the
cameras and detectors, the 21-band spectra (no product written)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pyproj import Geod

from napari_meris_ortho.bands import OLCI
from napari_meris_ortho.simulate import olci, resolve_config, scene_geometry
from napari_meris_ortho.simulate.olci_product import camera_fan, column_detectors
from napari_meris_ortho.simulate.orbit import SENTINEL3, ecef_to_geodetic
from napari_meris_ortho.simulate.radiometry import SPECTRA
from napari_meris_ortho.simulate.scene import locate

GEOD = Geod(ellps="WGS84")


def _geometry(resolution: str, lines: int = 8):
    name = "olci-efr-alps" if resolution == "EFR" else "olci-err-andes"
    return scene_geometry(resolve_config({"base": name, "lines": lines}))


@pytest.fixture(scope="module")
def efr():
    return _geometry("EFR")


@pytest.fixture(scope="module")
def err():
    return _geometry("ERR")


def test_sentinel3_flies_about_814_km_high_on_a_sun_synchronous_10_00_orbit(efr):
    pos, _ = efr.orbit.state(np.array([efr.t0]))
    lon, lat, h = ecef_to_geodetic(*pos[0])
    assert abs(lat - 46.8) < 1e-6 and abs(lon - 19.6) < 1e-6
    assert 800e3 < h < 820e3  # 814.5 km above a sphere of 6371 km; 811 km at 47 N
    assert math.isclose(efr.orbit.inclination, math.radians(98.65))
    assert efr.orbit.radius == SENTINEL3.radius


@pytest.mark.parametrize("resolution", ["EFR", "ERR"])
def test_the_swath_is_tilted_west_57_deg_to_24_deg_view_zenith(resolution, efr, err):
    """Descending pass, N1 column order: column 0 on the east edge (about 24.3 deg), the last
    column on the west edge (about 56.6 deg), nadir a quarter of the way across."""
    g = efr if resolution == "EFR" else err
    e = locate(g, np.array([0.0, g.lines - 1.0]), np.arange(g.columns, dtype=np.float64))
    vz, lon = e[..., 2], e[..., 0]
    assert np.all(np.abs(vz[:, 0] - 24.3) < 0.4)
    assert np.all(np.abs(vz[:, -1] - 56.6) < 0.8)  # 56.9 at 47 N, 57.2 at 13 S
    nadir = -g.first_column
    assert np.all(vz[:, nadir] < 1e-6)
    assert np.all(np.diff(lon, axis=1) < 0)  # east to west
    # the view azimuth (towards the satellite) points east on the western part
    assert np.all(np.abs(e[:, -1, 3] - 100.0) < 8.0)


@pytest.mark.parametrize(("resolution", "across", "along"),
                         [("EFR", 270.0, 294.0), ("ERR", 1080.0, 1176.0)])
def test_sampling_across_and_along_track_at_nadir(resolution, across, along, efr, err):
    g = efr if resolution == "EFR" else err
    nadir = float(-g.first_column)
    e = locate(g, np.array([3.0, 4.0]), np.array([nadir, nadir + 1.0]))
    _, _, d_across = GEOD.inv(e[0, 0, 0], e[0, 0, 1], e[0, 1, 0], e[0, 1, 1])
    _, _, d_along = GEOD.inv(e[0, 0, 0], e[0, 0, 1], e[1, 0, 0], e[1, 0, 1])
    assert abs(d_across - across) < 0.01 * across
    assert abs(d_along - along) < 0.01 * along


def test_the_tie_points_lie_on_every_row_and_every_64_or_16_columns(efr, err):
    assert efr.lines_per_tie_point == 1 and err.lines_per_tie_point == 1
    assert efr.tie_cols.size == 77 and efr.tie_cols[-1] == 4864 and efr.tie_cols[1] == 64
    assert err.tie_cols.size == 77 and err.tie_cols[-1] == 1216 and err.tie_cols[1] == 16
    assert efr.n_tie_lines == efr.lines and np.array_equal(efr.tie_lines, np.arange(efr.lines))


def test_five_cameras_see_about_69_deg_tilted_away_from_the_sun(efr, err):
    fan = camera_fan(efr)
    assert abs(fan.field_of_view_deg - 68.5) < 1.5
    tilt = math.degrees(0.5 * (fan.psi_east + fan.psi_west))
    assert abs(tilt - 12.6) < 1.0  # to the right of the flight direction: west
    assert abs(camera_fan(err).field_of_view_deg - 68.5) < 2.0  # wider where S3 flies lower


def test_detector_index_runs_over_3700_detectors_and_repeats_towards_the_west_edge(efr, err):
    det = column_detectors(efr)
    assert det.dtype == np.int16 and det.shape == (4865,)
    assert det.min() == 0 and det.max() == 3699  # every pixel seen, west edge detector 0
    assert np.all(np.diff(det.astype(int)) <= 0)  # numbered from the west edge
    cams = det // olci.DETECTORS_PER_CAMERA
    assert set(cams.tolist()) == {0, 1, 2, 3, 4}
    repeats = olci.duplicated(det[None, :])[0]
    west, east = repeats[-800:].mean(), repeats[:800].mean()
    assert west > 0.5 and east < 0.2  # up to ~3 columns per detector at 57 deg
    # near nadir a detector sees about one 270 m column: few repeats, a few skipped detectors
    nadir = -efr.first_column
    assert repeats[nadir - 200:nadir + 200].mean() < 0.1
    # ERR: 1080 m columns, each from another (full-resolution) detector
    d_err = column_detectors(err)
    assert d_err.max() == 3699 and d_err.min() == 0 and np.all(np.diff(d_err.astype(int)) < 0)


def test_instrument_data_is_21_bands_by_3700_detectors():
    inst = olci.instrument_data(seed=1)
    for key in ("lambda0", "FWHM", "solar_flux"):
        assert inst[key].shape == (21, 3700) and inst[key].dtype == np.float32
    centres = np.asarray(OLCI.centres)
    assert np.all(np.abs(inst["lambda0"] - centres[:, None]) < 1.6)
    assert abs(float(inst["lambda0"][0].mean()) - 400.0) < 1.0
    assert np.all(inst["solar_flux"] > 600.0)


def test_olci_spectra_continue_the_meris_ones_with_absorption_bands():
    spectra = olci.OLCI_SPECTRA
    assert spectra.shape == (4, 21)
    # Oa02..Oa08, Oa10, Oa11, Oa12, Oa16..Oa19: the MERIS bands of the same centre
    same = {2: 1, 3: 2, 4: 3, 5: 4, 6: 5, 7: 6, 8: 7, 10: 8, 11: 9, 12: 10, 16: 12, 17: 13,
            18: 14, 19: 15}
    for oa, m in same.items():
        assert np.allclose(spectra[:, oa - 1], SPECTRA[:, m - 1])
    vegetation = spectra[1]
    # the O2 A band (Oa13 deepest, Oa15 weakest) and water vapour at 940 nm
    assert vegetation[12] < vegetation[13] < vegetation[14] < vegetation[15]
    assert vegetation[12] < 0.5 * vegetation[11]
    assert vegetation[19] < 0.7 * min(vegetation[18], vegetation[20])
    # the red edge: vegetation bright in the near infrared, water dark at 1020 nm
    assert vegetation[16] > 3 * vegetation[7] and spectra[0, 20] < 5.0
    assert olci.SCALE_FACTORS[0] == 0.013946459628641605


def test_flag_baseline_of_a_config():
    assert olci.baseline_of({"processing_baseline": "2.23"}) == "per-band"
    assert olci.baseline_of({"processing_baseline": "2.24"}) == "2.24"
    assert olci.baseline_of({"processing_baseline": "3.01"}) == "2.24"


@pytest.mark.parametrize(("override", "message"), [
    ({"sensor": "MSI"}, "scene sensor must be MERIS or OLCI, not 'MSI'"),
    ({"sensor": "MERIS"}, "scene resolution EFR is not one of sensor MERIS"),
    ({"platform": "Envisat"}, "an OLCI scene's platform is S3A or S3B, not 'Envisat'"),
])
def test_a_config_naming_another_sensor_is_refused(override, message):
    from napari_meris_ortho.errors import OptionsError

    with pytest.raises(OptionsError, match=message):
        resolve_config({"base": "olci-efr-alps", **override})

"""The reduced-resolution AMORGOS N1 product MER_RRG_1P (SNAP's DDDB: the MDS 17-19 of
MER_FSG_1P/MER_FRG_1P on the RR geometry), as the simulator writes it (``sample rr-... --fsg``):
read like FRG/FSG, per pixel against the simulator's truth, and what pyepr makes of it."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho.products.n1 import read_product
from napari_meris_ortho.products.n1.format import GEOLOCATION_MDS
from napari_meris_ortho.simulate.geocorrected import pixel_truth


@pytest.mark.slow
def test_rrg_read_with_the_rr_geometry(rrg, rr_small):
    p = read_product(rrg)
    assert p.product_type == "MER_RRG_1P" and p.has_pixel_geolocation
    assert (p.width, p.height) == (1121, 160)
    assert (p.lines_per_tie_point, p.samples_per_tie_point) == (16, 16)
    assert p.tie_points.shape == (11, 71)
    assert p.resolution.name == "RR" and p.line_interval_s == pytest.approx(0.176)
    assert p.mph["NUM_DSD"] == 33
    names = [d.name for d in p.dsds]
    assert names[19:22] == [m.name for m in GEOLOCATION_MDS]
    assert [d.dsr_size for d in p.dsds[19:22]] == [13 + 4 * 1121, 13 + 4 * 1121, 13 + 2 * 1121]
    # the same radiances, flags and tie points as the scene's MER_RR__1P
    rr = read_product(rr_small.product_path)
    for b in (1, 7, 15):
        np.testing.assert_array_equal(p.counts(b), rr.counts(b))
    np.testing.assert_array_equal(p.flags, rr.flags)
    for name in ("latitude", "longitude", "dem_alt", "view_zenith", "lon_corr"):
        np.testing.assert_array_equal(p.tie_points[name], rr.tie_points[name])


def test_rrg_pixel_geolocation_is_the_truth(rrg, rr_small):
    """Every pixel's terrain point as the simulator traced it: 1e-6 deg, 1 m."""
    p = read_product(rrg)
    truth = pixel_truth(rr_small)
    assert np.abs(p.pixel_longitude() - truth["longitude"]).max() <= 5.1e-7
    assert np.abs(p.pixel_latitude() - truth["latitude"]).max() <= 5.1e-7
    assert np.abs(p.pixel_altitude() - truth["altitude"]).max() <= 0.51
    # RR pixels: about 1.04 km apart across track at nadir, lines 1.2 km apart
    lat = p.pixel_latitude()
    step_km = np.median(np.abs(np.diff(lat[:, 560]))) * 111.2
    assert 1.0 < step_km < 1.4, step_km
    assert np.ptp(p.pixel_altitude()) > 500.0  # relief in the sample


def test_pyepr_does_not_know_rrg_but_reads_its_rr_layout(rrg, tmp_path):
    """EPR-API 2.3 (pyepr) has no MER_RRG_1P in its DDDB and refuses the product, as it refuses
    MER_FRG_1P. Announced as MER_RR__1P the same bytes open: 1121 x 160 pixels, the 19 data
    sets of an RR product (the three geolocation MDS are not in its table), the radiances
    and flags our reader gives (EPR mirrors the columns) and the tie points."""
    import epr

    with pytest.raises(ValueError, match="unable to open"):
        epr.Product(str(rrg))
    data = bytearray(rrg.read_bytes())
    assert data[9:19] == b"MER_RRG_1P"
    data[9:19] = b"MER_RR__1P"
    renamed = tmp_path / "renamed.N1"
    renamed.write_bytes(bytes(data))
    ours = read_product(rrg)
    prod = epr.Product(str(renamed))
    try:
        assert (prod.get_scene_width(), prod.get_scene_height()) == (1121, 160)
        assert prod.get_num_datasets() == 19 and "Flags" in prod.get_dataset_names()
        np.testing.assert_allclose(prod.get_band("radiance_7").read_as_array()[:, ::-1],
                                   ours.radiance(7), rtol=1e-6)
        np.testing.assert_array_equal(prod.get_band("l1_flags").read_as_array()[:, ::-1],
                                      ours.flags)
        # tie-point grids interpolated to pixels: exact on the tie points (every 16th)
        dem = prod.get_band("dem_alt").read_as_array()[::16, ::-1][:, ::16]
        np.testing.assert_allclose(dem, ours.tie_points["dem_alt"][:dem.shape[0]], atol=1e-3)
    finally:
        prod.close()

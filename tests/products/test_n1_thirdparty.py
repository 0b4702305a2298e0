"""Independent checks of our N1 files with real third-party readers:
pyepr (EPR-API, as BEAM/SNAP read them) and GDAL's ESAT driver (through rasterio)."""

from __future__ import annotations

import epr
import numpy as np
import pytest
import rasterio
from n1_samples import sample_inputs

from napari_meris_ortho.products.n1 import read_product, write_product
from napari_meris_ortho.products.n1.format import TIE_POINT_FIELDS

CASES = {
    # standard widths; line counts that are not a multiple of the tie-point spacing
    "FR": ("MER_FR__1P", 130, 0),
    "RR": ("MER_RR__1P", 70, 1),
}


@pytest.fixture(scope="module", params=sorted(CASES))
def written(request, tmp_path_factory):
    product_type, height, seed = CASES[request.param]
    inputs = sample_inputs(product_type, height=height, seed=seed)
    path = write_product(tmp_path_factory.mktemp(request.param) / "p.N1", **inputs)
    return path, read_product(path)


def test_pyepr_opens_and_agrees_on_the_headers(written):
    path, ours = written
    with epr.open(str(path)) as product:
        assert product.id_string[:10] == ours.product_type
        assert product.get_scene_width() == ours.width
        assert product.get_scene_height() == ours.height
        assert product.get_num_datasets() == 19
        # MPH NUM_DSD=30; EPR skips the spare DSD, as the Appendix A log prints 29
        assert ours.mph["NUM_DSD"] == 30
        assert product.get_num_dsds() == 29 == sum(not d.is_spare for d in ours.dsds)
        mph, sph = product.get_mph(), product.get_sph()
        assert mph.get_field("PRODUCT").get_elem().decode() == ours.mph["PRODUCT"]
        assert mph.get_field("TOT_SIZE").get_elem() == path.stat().st_size
        assert sph.get_field("LINES_PER_TIE_PT").get_elem() == ours.lines_per_tie_point
        wavelengths = sph.get_field("BAND_WAVELEN").get_elems() / 1000.0
        np.testing.assert_allclose(wavelengths, ours.wavelengths)
        for i, dsd in enumerate(ours.dsds):
            if dsd.is_spare:
                continue
            theirs = product.get_dsd_at(i)
            assert theirs.ds_name.strip() == dsd.name
            assert (theirs.ds_offset, theirs.ds_size) == (dsd.offset, dsd.size)
            assert (theirs.num_dsr, theirs.dsr_size) == (dsd.num_dsr, dsd.dsr_size)


def test_pyepr_tie_point_records_and_scaling_factors(written):
    path, ours = written
    with epr.open(str(path)) as product:
        gads = product.get_dataset("Scaling_Factor_GADS").read_record(0)
        np.testing.assert_array_equal(
            gads.get_field("sf_rad").get_elems(), np.float32(ours.scaling.radiance)
        )
        assert gads.get_field("sf_ozone").get_elem() == np.float32(ours.scaling.ozone)
        tie = product.get_dataset("Tie_points_ADS")
        assert tie.get_num_records() == ours.n_tie_lines
        for i in range(ours.n_tie_lines):
            record = tie.read_record(i)
            t = record.get_field("dsr_time").get_elem()
            seconds = t.days * 86400.0 + t.seconds + t.microseconds * 1e-6
            assert seconds == pytest.approx(ours.tie_point_times[i], abs=1e-6)
            for field in TIE_POINT_FIELDS:  # raw values, stored (east-to-west) order
                raw = record.get_field(field.dddb_name).get_elems()
                physical = raw.astype(np.float64) * ours.scaling.factor(field)
                np.testing.assert_array_equal(physical, ours.tie_points[field.name][i])


def test_pyepr_tie_point_bands_are_our_grids_mirrored(written):
    path, ours = written
    df, dj = ours.lines_per_tie_point, ours.samples_per_tie_point
    rows = np.arange(ours.n_tie_lines) * df
    rows = rows[rows < ours.height]
    cols = np.arange(ours.n_tie_columns) * dj
    with epr.open(str(path)) as product:
        for name, epr_name in [
            ("latitude", "latitude"), ("longitude", "longitude"), ("dem_alt", "dem_alt"),
            ("view_zenith", "view_zenith"), ("view_azimuth", "view_azimuth"),
            ("lat_corr", "lat_corr"), ("lon_corr", "lon_corr"), ("atm_pressure", "atm_press"),
        ]:  # fmt: skip
            raster = product.get_band(epr_name).read_as_array()
            # EPR mirrors every line (x grows west to east): stored column c is W-1-c
            at_tie_points = raster[rows][:, ours.width - 1 - cols]
            np.testing.assert_allclose(
                at_tie_points, ours.tie_points[name][: len(rows)], rtol=1e-6, atol=1e-6,
                err_msg=name,
            )  # fmt: skip


def test_pyepr_reads_our_counts_radiances_and_flags(written):
    path, ours = written
    with epr.open(str(path)) as product:
        for band in (1, 8, 15):
            rad = product.get_band(f"radiance_{band}").read_as_array()
            np.testing.assert_array_equal(rad[:, ::-1], ours.radiance(band))
            raw = product.get_dataset(f"Radiance_{band}").read_record(5).get_field("toa_rad")
            np.testing.assert_array_equal(raw.get_elems(), ours.counts(band)[5])
        flags = product.get_band("l1_flags").read_as_array()
        np.testing.assert_array_equal(flags[:, ::-1], ours.flags)
        detector = product.get_band("detector_index").read_as_array()
        np.testing.assert_array_equal(detector[:, ::-1], ours.detector_index)


def test_gdal_esat_driver_reads_our_raw_counts(written):
    path, ours = written
    with rasterio.open(path) as ds:
        assert ds.driver == "ESAT"
        assert (ds.width, ds.height) == (ours.width, ours.height)
        assert ds.count == 17  # 15 radiances, flags, detector index (3-byte view of MDS(16))
        for band in (1, 2, 9, 15):
            assert ds.descriptions[band - 1].strip() == f"Radiance MDS({band})"
            np.testing.assert_array_equal(ds.read(band), ours.counts(band))  # not mirrored
        tags = ds.tags()
        assert tags["MPH_PRODUCT"] == ours.mph["PRODUCT"]
        assert int(tags["SPH_LINE_LENGTH"]) == ours.width


def test_gdal_gcps_are_our_tie_points_plus_corrections(written):
    path, ours = written
    df, dj = ours.lines_per_tie_point, ours.samples_per_tie_point
    with rasterio.open(path) as ds:
        gcps, _ = ds.gcps
    tp = ours.tie_points
    assert len(gcps) == tp["latitude"].size
    for n, gcp in enumerate(gcps):
        i, k = divmod(n, ours.n_tie_columns)
        assert (gcp.row, gcp.col) == (i * df + 0.5, k * dj + 0.5)
        assert gcp.x == pytest.approx(tp["longitude"][i, k] + tp["lon_corr"][i, k], abs=1e-9)
        assert gcp.y == pytest.approx(tp["latitude"][i, k] + tp["lat_corr"][i, k], abs=1e-9)

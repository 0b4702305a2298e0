"""ESA's fourth-reprocessing ``.SEN3`` as it is: a product written from the documented
facts of ``ENV_ME_1_RRG____20120406T085654`` (``sen3_real``) read back with the values a user
sees in SNAP at the given pixels; orientation, fill values, per-variable CF scales, the file's
own flag coding, optional meteo, zip archives and ESA's other names, bad content."""

from __future__ import annotations

import logging
import shutil
import zipfile

import netCDF4
import numpy as np
import pytest
import sen3_real as real

from napari_meris_ortho import flags as fl
from napari_meris_ortho.errors import Sen3FormatError
from napari_meris_ortho.products.open import is_product_path, read_product
from napari_meris_ortho.products.sen3.layout import product_type_of


@pytest.fixture(scope="module")
def product_dir(tmp_path_factory):
    return real.write_real_like(tmp_path_factory.mktemp("real"))


@pytest.fixture
def copy(product_dir, tmp_path):
    dst = tmp_path / product_dir.name
    shutil.copytree(product_dir, dst)
    return dst


def _n1_column(x: int) -> int:
    """Our products expose the N1 column order: file column x is column W - 1 - x."""
    return real.WIDTH - 1 - x


def test_the_real_product_reads_with_snaps_values(product_dir):
    p = read_product(product_dir)
    assert p.product_type == "ME_1_RRG___" and (p.width, p.height) == (1121, 1617)
    assert (p.lines_per_tie_point, p.samples_per_tie_point) == (16, 16)
    assert (p.n_tie_lines, p.n_tie_columns) == (102, 71)
    lat, lon = p.pixel_latitude(), p.pixel_longitude()
    for (x, y), (want_lat, want_lon) in real.KNOWN.items():
        assert abs(lat[y, _n1_column(x)] - want_lat) < 1e-6
        assert abs(lon[y, _n1_column(x)] - want_lon) < 1e-6
    # N1 order: on this descending pass longitude falls with the column, as in an N1 file
    assert (np.diff(lon, axis=1) < 0).all()
    assert (np.diff(p.tie_points["longitude"], axis=1) < 0).all()
    # OAA about 102 deg in the western half (file columns < 560 = our columns > 560)
    oaa = p.tie_points["view_azimuth"]
    assert np.allclose(oaa[:, -10:], 102.0) and np.allclose(oaa[:, :10], 282.0)
    # SNAP's no-data value of M01 is 65535 x its scale factor
    assert abs(65535 * p.scaling.radiance[0] - 620.943) < 1e-3


def test_a_fill_pixel_is_no_data_never_a_radiance(product_dir):
    p = read_product(product_dir)
    x, y = real.FILL_PIXEL
    for b in (1, 7):
        r = p.radiance(b)
        assert np.isnan(r[y, _n1_column(x)]) and np.isfinite(np.delete(r.ravel(), y * 1121 +
                                                                      _n1_column(x))).all()
        assert p.no_data_count(b) == 65535 and p.counts(b)[y, _n1_column(x)] == 65535
    assert np.isfinite(p.radiance(2)[y, _n1_column(x)])
    assert p.flags[y, _n1_column(x)] & fl.FLAG_INVALID


def test_quality_flags_follow_the_files_own_coding(product_dir, copy):
    p = read_product(product_dir)
    x, y = real.SATURATED_PIXEL
    assert p.quality_coding["fresh_inland_water"] == 1 << 29
    assert p.quality_coding["saturated_M01"] == 1 << 20
    assert p.quality_coding["saturated_M21"] == 1
    assert p.saturated[y, _n1_column(x)] == 1 << 6  # band 7 only
    assert int(np.count_nonzero(p.saturated)) == 1
    assert (p.flags & fl.FLAG_LAND_OCEAN).all()
    # a file with its own (other) coding is read with it, not with a fixed table
    with netCDF4.Dataset(copy / "qualityFlags.nc", "a") as ds:
        q = ds.variables["quality_flags"]
        q.set_auto_maskandscale(False)
        q[...] = np.full(q.shape, np.uint32(1 << 3))
        q.flag_masks = np.array([1 << 3, 1 << 4], np.uint32)
        q.flag_meanings = "invalid land"
    moved = read_product(copy)
    assert (moved.flags == fl.FLAG_INVALID).all()


def test_each_variable_is_decoded_with_its_own_scale(copy):
    """Latitude stored at scale_factor 1e-5 is read 46.25, not 4.63."""
    with netCDF4.Dataset(copy / "geo_coordinates.nc", "a") as ds:
        v = ds.variables["latitude"]
        v.set_auto_maskandscale(False)
        v[...] = np.round(v[...] / 10).astype(np.int32)
        v.scale_factor = 1e-5
    with netCDF4.Dataset(copy / "tie_geo_coordinates.nc", "a") as ds:
        v = ds.variables["latitude"]
        v.set_auto_maskandscale(False)
        v[...] = np.round(v[...] / 10).astype(np.int32)
        v.scale_factor = 1e-5
        v.add_offset = 10.0
        v[...] = np.round((v[...] * 1e-5 - 10.0) / 1e-5).astype(np.int32)
    p = read_product(copy)
    (x, y), (lat, _) = next(iter(real.KNOWN.items()))
    assert abs(p.pixel_latitude()[y, _n1_column(x)] - lat) < 1e-5
    tlat, _ = real.geolocation(np.array([real.WIDTH - 1.0]), np.array([0.0]))
    assert abs(p.tie_points["latitude"][0, 0] - tlat[0]) < 1e-5


def test_meteo_variables_are_optional_one_by_one(tmp_path):
    d = real.write_real_like(tmp_path, meteo=("total_ozone", "sea_level_pressure"))
    p = read_product(d)
    assert np.isnan(p.tie_points["rel_humidity"]).all()
    assert np.isnan(p.tie_points["zonal_wind"]).all()
    assert np.allclose(p.tie_points["atm_pressure"], 1013.0)
    (d / "tie_meteo.nc").unlink()
    assert np.isnan(read_product(d).tie_points["ozone"]).all()


@pytest.mark.slow
def test_zip_archives_and_esas_other_names_open(product_dir, tmp_path):
    archive = tmp_path / (product_dir.name + ".zip")
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_STORED) as z:
        for f in sorted(product_dir.iterdir()):
            z.write(f, f"{product_dir.name}/{f.name}")
    assert is_product_path(archive)
    zp, dp = read_product(archive), read_product(product_dir)
    assert zp.product_name == dp.product_name and zp.product_type == "ME_1_RRG___"
    np.testing.assert_array_equal(zp.counts(7), dp.counts(7))
    np.testing.assert_array_equal(zp.pixel_latitude(), dp.pixel_latitude())
    np.testing.assert_array_equal(zp.tie_points["view_azimuth"], dp.tie_points["view_azimuth"])
    # EN1_MDSI names, the type from the manifest, or from the name when the manifest has none
    en1 = real.write_real_like(tmp_path / "a", name="EN1_MDSI_MER_RR__1P_20120406T085654.SEN3")
    assert read_product(en1).product_type == "ME_1_RRG___"
    rr = real.write_real_like(tmp_path / "b", manifest_type=None,
                              name="EN1_MDSI_MER_RR__1P_20120406T085654.SEN3")
    assert read_product(rr).product_type == "ME_1_RRG___"
    # (an FR name over this RR product's 925 detectors is refused: test_sen3_hostile)
    assert product_type_of("EN1_MDSI_MER_FRS_1P_20120406T085654.SEN3") == "ME_1_FRG___"
    # the bare 8-character type (as ocssw matches it), not only ESA's padded ME_1_RRG___
    assert product_type_of("ME_1_RRG") == "ME_1_RRG___"
    assert product_type_of("OL_1_EFR___") is None
    plain = tmp_path / "product.zip"
    plain.write_bytes(b"PK\x05\x06" + b"\0" * 18)
    assert not is_product_path(plain)
    with pytest.raises(Sen3FormatError, match="not a zip archive of a .SEN3 product"):
        read_product(plain)


def test_bad_content_is_one_error_or_masked_with_a_count(copy, caplog):
    (copy / "xfdumanifest.xml").write_text("<xfdu:XFDU><unclosed>")
    with pytest.raises(Sen3FormatError, match="manifest cannot be parsed"):
        read_product(copy)
    shutil.copy(real.write_real_like(copy.parent / "again") / "xfdumanifest.xml", copy)
    # 2000 deg in the per-pixel latitudes: masked, with a warning that counts them
    with netCDF4.Dataset(copy / "geo_coordinates.nc", "a") as ds:
        v = ds.variables["latitude"]
        v.set_auto_maskandscale(False)
        v[10:12, 0:50] = np.int32(2_000_000_000)
    p = read_product(copy)
    with caplog.at_level(logging.WARNING):
        lat = p.pixel_latitude()
    assert np.isnan(lat).sum() == 100 and "100 of 1812657 latitudes" in caplog.text
    # in the tie points, where no pixel can be located without them: one error
    with netCDF4.Dataset(copy / "tie_geometries.nc", "a") as ds:
        v = ds.variables["OZA"]
        v.set_auto_maskandscale(False)
        v[3, 4] = np.uint32(120_000_000)
    with pytest.raises(Sen3FormatError, match=r"1 tie points of OZA .* \[0, 90\]"):
        read_product(copy)

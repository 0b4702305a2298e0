"""Fourth-reprocessing ``.SEN3`` MERIS Level 1 products: the simulator's directory read back like
its N1 sibling, opened by xarray with CF attributes, broken copies refused with one error."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from napari_meris_ortho.errors import Sen3FormatError
from napari_meris_ortho.products.n1 import FLAG_INVALID, read_product
from napari_meris_ortho.products.sen3 import (
    GEO_FILE,
    QUALITY_FILE,
    is_sen3,
    l1b_to_quality,
    manifest_summary,
    quality_to_l1b,
    read_sen3,
    required_files,
)


@pytest.fixture(scope="module")
def scene():
    from napari_meris_ortho.simulate.scene import generate_scene

    return generate_scene("fr-small")


@pytest.fixture(scope="module")
def products(scene, tmp_path_factory):
    from napari_meris_ortho.simulate.geocorrected import pixel_truth, write_geocorrected

    out = tmp_path_factory.mktemp("geocorrected")
    paths = write_geocorrected(scene, out_dir=out)
    return paths, pixel_truth(scene)


def test_quality_flag_mapping_round_trips():
    flags = np.arange(256, dtype=np.uint8)
    assert np.array_equal(quality_to_l1b(l1b_to_quality(flags)), flags)
    assert l1b_to_quality(np.array([FLAG_INVALID]))[0] == 1 << 25


@pytest.mark.parametrize("coding", ["esa", "own"])
def test_quality_flags_translate_flag_by_flag(coding):
    """``quality_to_l1b`` and ``saturated_bands`` (one byte table per byte of the flags) set
    each output bit where its mask meets the flags, for ESA's coding (the real RR product's:
    land 2^31 ... saturated_M01 2^20 ... saturated_M21 2^0) and for a product's own (masks
    of several bits, in any byte, a flag missing)."""
    from napari_meris_ortho.products.sen3 import layout

    rng = np.random.default_rng(5)
    q = (rng.integers(0, 2**32, (37, 53), dtype=np.uint64)
         & rng.integers(0, 2**32, (37, 53), dtype=np.uint64)).astype(np.uint32)
    codes = layout.flag_coding({})
    if coding == "own":
        codes = {name: int(rng.integers(1, 2**32)) & int(rng.integers(1, 2**32))
                 for name in codes}
        codes.pop("land", None)
        codes.pop("saturated_M07", None)
    else:
        assert codes["land"] == 1 << 31 and codes["saturated_M01"] == 1 << 20
        assert codes["saturated_M15"] == 1 << 6 and codes["invalid"] == 1 << 25
    flags, saturated = quality_to_l1b(q, codes), layout.saturated_bands(q, codes)
    expected_flags = np.zeros(q.shape, np.uint8)
    for name, bit in layout.L1B_OF_QUALITY.items():
        if name in codes:
            expected_flags[(q & np.uint32(codes[name])) != 0] |= np.uint8(bit)
    expected_saturated = np.zeros(q.shape, np.uint16)
    for b in range(1, 16):
        if f"saturated_M{b:02d}" in codes:
            hit = (q & np.uint32(codes[f"saturated_M{b:02d}"])) != 0
            expected_saturated[hit] |= np.uint16(1 << (b - 1))
    assert flags.dtype == np.uint8 and saturated.dtype == np.uint16
    assert np.array_equal(flags, expected_flags) and flags.any()
    assert np.array_equal(saturated, expected_saturated) and saturated.any()
    assert np.array_equal(quality_to_l1b(q.astype(">u4"), codes), expected_flags)  # big-endian


def test_sen3_reads_like_the_n1_product(scene, products):
    paths, truth = products
    n1 = read_product(scene.product_path)
    s3 = read_sen3(paths["sen3"])
    assert is_sen3(paths["sen3"]) and s3.product_type == "ME_1_FRG___"
    assert (s3.width, s3.height) == (n1.width, n1.height) == (513, 320)
    assert (s3.lines_per_tie_point, s3.samples_per_tie_point) == (64, 64)
    for b in (1, 7, 15):
        np.testing.assert_array_equal(s3.counts(b), n1.counts(b))
        np.testing.assert_allclose(s3.radiance(b), n1.radiance(b), rtol=1e-6)
    np.testing.assert_array_equal(s3.flags, n1.flags)
    np.testing.assert_array_equal(s3.detector_index, n1.detector_index)
    np.testing.assert_allclose(s3.line_times, n1.line_times, atol=1e-6)
    for key in ("latitude", "longitude", "view_zenith", "sun_zenith", "dem_alt"):
        np.testing.assert_allclose(s3.tie_points[key], n1.tie_points[key], atol=1e-6)
    for key in ("view_azimuth", "sun_azimuth"):
        d = (s3.tie_points[key] - n1.tie_points[key] + 180) % 360 - 180
        assert np.max(np.abs(d)) < 1e-6
    np.testing.assert_allclose(s3.tie_points["lat_corr"], n1.tie_points["lat_corr"], atol=2e-6)
    np.testing.assert_allclose(s3.tie_points["ozone"], n1.tie_points["ozone"], rtol=1e-5)
    np.testing.assert_allclose(s3.pixel_longitude(), truth["longitude"], atol=5.1e-7)
    np.testing.assert_allclose(s3.pixel_latitude(), truth["latitude"], atol=5.1e-7)
    np.testing.assert_allclose(s3.pixel_altitude(), truth["altitude"], atol=0.51)
    np.testing.assert_allclose(s3.wavelengths, n1.wavelengths, atol=1e-3)


def test_sen3_derives_the_corrections_as_operational_n1_products_store_them(products):
    """The format has no lat_corr/lon_corr: the reader derives them from its own tie points as
    operational N1 products store them (lat_corr the dlat of ``geodetic_correction``, lon_corr
    minus its dlon: Appendix E) and 0 where the tie-point altitude is the seabed (< 0)."""
    from napari_meris_ortho import geodetic_correction

    tp = read_sen3(products[0]["sen3"]).tie_points
    h = tp["dem_alt"]
    dlon, dlat = geodetic_correction(h, tp["view_zenith"], tp["view_azimuth"], tp["latitude"])
    land, sea = h > 0, h < 0
    assert land.any() and sea.any()
    np.testing.assert_allclose(tp["lat_corr"][land], dlat[land], rtol=1e-12, atol=0)
    np.testing.assert_allclose(tp["lon_corr"][land], -dlon[land], rtol=1e-12, atol=0)
    assert np.abs(tp["lon_corr"][land]).max() > 0.005
    assert np.all(tp["lat_corr"][sea] == 0.0) and np.all(tp["lon_corr"][sea] == 0.0)


def test_fsg_n1_reads_the_same_pixel_geolocation(scene, products):
    paths, truth = products
    frg = read_product(paths["fsg"])
    s3 = read_sen3(paths["sen3"])
    assert frg.product_type == "MER_FRG_1P"
    np.testing.assert_array_equal(frg.pixel_latitude(), s3.pixel_latitude())
    np.testing.assert_array_equal(frg.pixel_longitude(), s3.pixel_longitude())
    np.testing.assert_array_equal(frg.pixel_altitude(), s3.pixel_altitude())
    np.testing.assert_array_equal(frg.counts(9), read_product(scene.product_path).counts(9))
    # the truth terrain points really differ from the ellipsoid points (there is relief)
    assert np.ptp(truth["altitude"]) > 1000.0


def test_xarray_opens_the_members_with_cf_attributes(products):
    import xarray as xr
    d = products[0]["sen3"]
    with xr.open_dataset(d / GEO_FILE) as geo:
        lat = geo["latitude"]
        assert lat.dtype == np.float64 and lat.attrs["units"] == "degrees_north"
        assert lat.attrs["standard_name"] == "latitude"
        assert lat.encoding["scale_factor"] == 1e-6 and lat.encoding["dtype"] == np.int32
        # stored west to east (a descending pass), as ESA's products: the reader mirrors
        np.testing.assert_allclose(lat.values[:, ::-1], read_sen3(d).pixel_latitude())
        lon = geo["longitude"].values
        assert (np.diff(lon, axis=1) > 0).all()
    with xr.open_dataset(d / "M07_radiance.nc") as rad:
        v = rad["M07_radiance"]
        assert v.attrs["units"] == "mW.m-2.sr-1.nm-1"
        assert v.attrs["standard_name"] == "toa_upwelling_spectral_radiance"
        np.testing.assert_allclose(v.values[:, ::-1], read_sen3(d).radiance(7), rtol=1e-6)
    with xr.open_dataset(d / "time_coordinates.nc") as t:
        assert np.issubdtype(t["time_stamp"].dtype, np.datetime64)
    with xr.open_dataset(d / QUALITY_FILE, decode_cf=True) as q:
        meanings = q["quality_flags"].attrs["flag_meanings"].split()
        assert meanings[:6] == ["land", "coastline", "fresh_inland_water", "tidal_region",
                                "bright", "invalid"]
        assert meanings[10:12] == ["saturated_M01", "saturated_M02"] and len(meanings) == 31
        assert len(q["quality_flags"].attrs["flag_masks"]) == len(meanings)


def test_manifest_lists_every_member(products):
    d = products[0]["sen3"]
    info = manifest_summary(d)
    assert info["productType"] == "ME_1_FRG___"
    assert (info["rows"], info["columns"], info["rowsPerTiePoint"]) == ("320", "513", "64")
    listed = set(info["files"].split())
    assert set(required_files()[1:]) <= listed
    assert all((d / f).is_file() for f in listed)


@pytest.fixture
def copy(products, tmp_path):
    dst = tmp_path / products[0]["sen3"].name
    shutil.copytree(products[0]["sen3"], dst)
    return dst


def test_missing_member_file(copy):
    (copy / GEO_FILE).unlink()
    with pytest.raises(Sen3FormatError, match=r"missing member file\(s\): geo_coordinates.nc"):
        read_sen3(copy)


def test_wrong_variable_shape(copy):
    import netCDF4

    with netCDF4.Dataset(copy / GEO_FILE, "a") as ds:
        ds.createDimension("short_rows", 10)
        ds.renameVariable("altitude", "old_altitude")
        ds.createVariable("altitude", "i2", ("short_rows", "columns"))
    with pytest.raises(Sen3FormatError, match=r"'altitude' has shape \(10, 513\)"):
        read_sen3(copy)


def test_member_that_is_not_netcdf(copy):
    (copy / "M03_radiance.nc").write_bytes(b"not a netCDF file")
    with pytest.raises(Sen3FormatError, match="M03_radiance.nc: not a netCDF file"):
        read_sen3(copy)


def test_foreign_directory(tmp_path):
    with pytest.raises(Sen3FormatError, match="missing member file"):
        read_sen3(tmp_path)
    with pytest.raises(Sen3FormatError, match="not a directory"):
        read_sen3(tmp_path / "nothing.SEN3")


@pytest.mark.parametrize(("dtype", "attrs", "expected"), [
    # ESA's radiances: uint16, fill 65535, valid 0..65534 (the bounds at the type's own
    # range are not compared; the fill is no data)
    (np.uint16, {"_FillValue": np.uint16(65535), "valid_min": np.uint16(0),
                 "valid_max": np.uint16(65534)}, [0, 0, 0, 0, 1]),
    (np.uint16, {"valid_min": 10, "valid_max": 65535}, [1, 0, 0, 0, 0]),
    (np.uint16, {"valid_range": [10, 40000]}, [1, 0, 0, 1, 1]),
    (np.uint16, {}, [0, 0, 0, 0, 0]),
    (np.uint16, {"_FillValue": 70000.0}, [0, 0, 0, 0, 0]),  # no uint16 value
    (np.int16, {"_FillValue": np.int16(-1), "valid_min": np.int16(-32768)}, [0, 1, 0, 0, 0]),
    (np.float32, {"valid_max": 100.0}, [0, 0, 0, 1, 1]),
])
def test_no_data_of_a_packed_variable(dtype, attrs, expected):
    """CF no-data (fill, outside the valid range) of each storage type, bounds at the type's
    own range included (``layout.no_data``)."""
    from napari_meris_ortho.products.sen3.layout import no_data

    values = {np.uint16: [0, 11, 5000, 50000, 65535], np.int16: [0, -1, 5000, 20000, 32767],
              np.float32: [0.0, -1.0, 50.0, 150.0, np.nan]}[dtype]
    np.testing.assert_array_equal(no_data(np.array(values, dtype), attrs),
                                  np.array(expected, bool))


def test_sen3_name_and_geolocation_labels_are_esas(products):
    """The product name has the 99 characters and fields of ESA's (17 underscores between the
    stop time and the duration, as ``ENV_ME_1_RRG____20111230T102706_20111230T111042____...``);
    the tie points are labelled as on the ellipsoid, the pixels as terrain-corrected."""
    import re

    import netCDF4

    from napari_meris_ortho.products.sen3 import TIE_GEO_FILE

    name = products[0]["sen3"].name
    assert len(name) == 99, name
    assert re.fullmatch(r"ENV_ME_1_FRG____\d{8}T\d{6}_\d{8}T\d{6}_{17}\d{4}_\d{3}_\d{3}_{6}"
                        r"[A-Z]{3}_R_NT_{4}\.SEN3", name), name
    with netCDF4.Dataset(products[0]["sen3"] / TIE_GEO_FILE) as ds:
        assert ds["latitude"].long_name == "Latitude"
        assert ds["longitude"].long_name == "Longitude"
        assert ds["altitude"].long_name == "DEM corrected altitude"
    with netCDF4.Dataset(products[0]["sen3"] / GEO_FILE) as ds:
        assert ds["latitude"].long_name == "DEM corrected latitude"

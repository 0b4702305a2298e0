"""``products.olci``: the writer's products read back (bands, scale factors, flags of both
baselines, tie points where ESA has them and back on the pixel centres, zip archives, ESA's
names), the band tables, and the writer's refusals."""

from __future__ import annotations

import re
import zipfile

import netCDF4
import numpy as np
import olci_samples as samples
import pytest

from napari_meris_ortho.bands import (
    MERIS,
    MERIS_TO_OLCI,
    OLCI,
    Sensor,
    band_table,
    meris_band_of_olci,
    olci_band_of_meris,
)
from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.flags import FLAG_LAND_OCEAN
from napari_meris_ortho.products.olci import (
    TIE_COLUMN_SHIFT,
    FlagBaseline,
    OlciL1bProduct,
    flag_table,
    tie_points_as_esa,
    tie_points_on_pixels,
)
from napari_meris_ortho.products.olci.layout import ERR
from napari_meris_ortho.products.open import read_product

ROWS = 24


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    return samples.write_err(tmp_path_factory.mktemp("err"), rows=ROWS)


@pytest.fixture(scope="module")
def product(written):
    return read_product(written)


def test_band_tables():
    assert MERIS.n_bands == 15 and OLCI.n_bands == 21
    assert MERIS.names[0] == "M01" and OLCI.names[20] == "Oa21"
    assert OLCI.true_colour == (8, 6, 3) and MERIS.true_colour == (7, 5, 2)
    assert [OLCI.centres[b - 1] for b in OLCI.ndvi] == [665.0, 865.0]
    assert [round(MERIS.centres[b - 1]) for b in MERIS.ndvi] == [665, 865]
    assert band_table("OLCI") is OLCI and band_table(Sensor.MERIS) is MERIS
    # every matched pair within 2 nm of each other (M11 ~ Oa13: 0.4 nm, its width differs)
    for m, o in enumerate(MERIS_TO_OLCI, start=1):
        assert abs(MERIS.centres[m - 1] - OLCI.centres[o - 1]) < 2.0
    assert olci_band_of_meris(13) == 17 and meris_band_of_olci(17) == 13
    assert meris_band_of_olci(1) is None and meris_band_of_olci(21) is None
    with pytest.raises(ValueError, match="1..21"):
        OLCI.name(22)


def test_default_name_is_esas(written):
    assert re.fullmatch(r"S3B_OL_1_ERR____20210831T091011_20210831T091015_\d{8}T\d{6}_0004_000_"
                        r"000_0000_PS2_O_NT_004\.SEN3", written.name)


def test_members_variables_and_attributes(written):
    names = {p.name for p in written.iterdir()}
    assert {f"Oa{b:02d}_radiance.nc" for b in range(1, 22)} <= names
    assert {"geo_coordinates.nc", "tie_geo_coordinates.nc", "tie_geometries.nc",
            "tie_meteo.nc", "instrument_data.nc", "qualityFlags.nc", "time_coordinates.nc",
            "xfdumanifest.xml"} <= names
    assert "removed_pixels.nc" not in names  # EFR only
    with netCDF4.Dataset(written / "Oa08_radiance.nc") as ds:
        v = ds["Oa08_radiance"]
        assert v.dtype == np.uint16 and v.dimensions == ("rows", "columns")
        assert v._FillValue == 65535 and "add_offset" not in v.ncattrs()
        assert v.scale_factor.dtype == np.float32 and v.units == "mW.m-2.sr-1.nm-1"
    with netCDF4.Dataset(written / "tie_geo_coordinates.nc") as ds:
        assert set(ds.variables) == {"latitude", "longitude"}  # no tie-point altitude
        assert ds["latitude"].dtype == np.int32 and ds.ac_subsampling_factor == 16
    with netCDF4.Dataset(written / "tie_geometries.nc") as ds:
        assert ds["OZA"].dtype == np.uint32 and ds["OAA"].dtype == np.int32
    with netCDF4.Dataset(written / "instrument_data.nc") as ds:
        assert ds["lambda0"].shape == (21, 3700) and ds["detector_index"].dtype == np.int16
    manifest = (written / "xfdumanifest.xml").read_text()
    assert "<sentinel3:productType>OL_1_ERR___</sentinel3:productType>" in manifest
    assert "<olci:columnsPerTiePoint>16</olci:columnsPerTiePoint>" in manifest
    assert 'href="./Oa21_radiance.nc"' in manifest


def test_bands_read_back(product):
    assert isinstance(product, OlciL1bProduct) and product.n_bands == 21
    for b in (1, 8, 21):
        np.testing.assert_array_equal(product.counts(b), samples.counts_pattern(ROWS, b))
        assert product.scaling.radiance[b - 1] == float(np.float32(0.01 + 0.001 * (b - 1)))
    with pytest.raises(ValueError, match="1..21"):
        product.counts(22)


def test_columns_are_stored_west_to_east(written, product):
    with netCDF4.Dataset(written / "geo_coordinates.nc") as ds:
        lon = ds["longitude"][0, :]  # scaled by netCDF4
    assert lon[0] < lon[-1]  # ESA's order: west to east
    np.testing.assert_allclose(product.pixel_longitude()[0], lon[::-1], atol=1e-9)


def test_tie_points_where_esa_has_them_and_back(written, product):
    """Stored half a pixel towards ESA's column 0 (``TIE_COLUMN_SHIFT``), read back on the
    pixel centres: exact for the fixture's linear geolocation."""
    geo = samples.err_geometry(ROWS)
    with netCDF4.Dataset(written / "tie_geo_coordinates.nc") as ds:
        stored = ds["latitude"][:, :]  # scaled by netCDF4
    esa_lat = geo["latitude"][:, ::-1]
    expected = esa_lat[:, ::16] + TIE_COLUMN_SHIFT * (esa_lat[:, 1] - esa_lat[:, 0])[:, None]
    np.testing.assert_allclose(stored, expected, atol=1.1e-6)
    np.testing.assert_allclose(product.tie_points["latitude"], geo["latitude"][:, ::16],
                               atol=1.1e-6)
    np.testing.assert_allclose(product.tie_points["longitude"], geo["longitude"][:, ::16],
                               atol=1.1e-6)


def test_tie_shift_round_trip_and_azimuths():
    rng = np.random.default_rng(1)
    lin = np.linspace(0, 10, 77)[None, :] + rng.normal(size=(3, 1))
    az = np.full((3, 77), 179.9)
    az[:, 40:] = -179.9  # across the antimeridian of azimuths
    tp = {"latitude": lin, "view_azimuth": az % 360.0}
    back = tie_points_on_pixels(tie_points_as_esa(tp, 64), 64)
    np.testing.assert_allclose(back["latitude"], lin, atol=1e-12)
    d = (back["view_azimuth"] - tp["view_azimuth"] + 180.0) % 360.0 - 180.0
    assert np.abs(d).max() < 0.01


def test_flags_and_saturation_of_both_baselines(tmp_path):
    for baseline in FlagBaseline:
        (tmp_path / baseline.value).mkdir()
        p = read_product(samples.write_err(tmp_path / baseline.value, rows=8,
                                           baseline=baseline))
        assert p.baseline is baseline and p.quality_coding == flag_table(baseline)
        assert p.flags[0, 0] == FLAG_LAND_OCEAN and p.flags[0, 400] == 0
        expected = 1 << 16 if baseline is FlagBaseline.PER_BAND else 0
        assert p.saturated[5, 7] == expected and p.saturated.dtype == np.uint32


def test_zip_archive_and_its_folder(tmp_path):
    out = samples.write_err(tmp_path / "x.SEN3.zip", rows=8)
    with zipfile.ZipFile(out) as z:
        assert "x.SEN3/Oa01_radiance.nc" in z.namelist()
    p = read_product(out)
    assert p.product_type == "OL_1_ERR___" and p.product_name == "x"
    assert [f.name for f in tmp_path.iterdir()] == ["x.SEN3.zip"]


def test_bad_arguments_write_nothing(tmp_path):
    good = dict(rows=8)
    with pytest.raises(OptionsError, match="EFR or ERR|OL_1_EFR___ or OL_1_ERR___"):
        from napari_meris_ortho.products.olci import write_olci

        write_olci(tmp_path / "a.SEN3", product_type="WFR", counts=[], scale_factors=[],
                   quality_flags=np.zeros(1), pixel_geolocation={}, tie_points={},
                   detector_index=np.zeros(1), lambda0=np.zeros(1), fwhm=np.zeros(1),
                   solar_flux=np.zeros(1), start_time=np.datetime64("2020-01-01"))
    with pytest.raises(OptionsError, match="S3A or S3B"):
        samples.write_err(tmp_path / "b.SEN3", platform="S3C", **good)
    with pytest.raises(OptionsError, match=".SEN3 directory or a .zip"):
        samples.write_err(tmp_path / "c.nc", **good)
    assert not any(tmp_path.iterdir())
    assert ERR.width == 1217


def test_flags_without_their_coding_take_the_per_band_table(tmp_path):
    (tmp_path / "p").mkdir()
    written = samples.write_err(tmp_path / "p", rows=8)
    with netCDF4.Dataset(written / "qualityFlags.nc", "a") as ds:
        ds["quality_flags"].delncattr("flag_masks")
        ds["quality_flags"].delncattr("flag_meanings")
    p = read_product(written)
    assert p.quality_coding == flag_table(FlagBaseline.PER_BAND)
    assert p.flags[0, 0] == FLAG_LAND_OCEAN and p.saturated[5, 7] == 1 << 16

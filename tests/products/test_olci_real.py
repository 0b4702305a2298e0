"""OLCI Level 1B products written from ESA's documented facts with netCDF4 (``olci_real``, not
our writer) read back: SNAP's pixel coordinates within 1e-6 deg in ESA's column order and in the
N1 order the engine uses, the fill value masked, the scale factors, the view zeniths of the
tilted swath, the tie-point heights taken from the pixels, both flag baselines; and the CLI on
them. Bad inputs (an OLCI Level 2, an SLSTR, a SYNERGY product, a truncated member, a corrupt
member of a zip): one error line, exit 2, nothing written."""

from __future__ import annotations

import shutil
import zipfile
from pathlib import Path

import numpy as np
import olci_real as real
import pytest

from napari_meris_ortho.bands import OLCI, Sensor
from napari_meris_ortho.cli import main
from napari_meris_ortho.errors import OlciFormatError, Sen3FormatError
from napari_meris_ortho.flags import FLAG_BRIGHT, FLAG_INVALID, FLAG_LAND_OCEAN
from napari_meris_ortho.products.olci import FlagBaseline, OlciL1bProduct
from napari_meris_ortho.products.open import is_product_path, read_product


@pytest.fixture(scope="module")
def efr_dir(tmp_path_factory):
    return real.write_product(tmp_path_factory.mktemp("efr"), "EFR")


@pytest.fixture(scope="module")
def err_dir(tmp_path_factory):
    return real.write_product(tmp_path_factory.mktemp("err"), "ERR")


@pytest.fixture(scope="module")
def efr(efr_dir):
    return read_product(efr_dir)


@pytest.fixture(scope="module")
def err(err_dir):
    return read_product(err_dir)


def _cli(capsys, *argv) -> tuple[int, str, str]:
    rc = main(["-q", *map(str, argv)])
    out, err = capsys.readouterr()
    return rc, out, err


def test_the_products_are_olci_level_1b(efr, err, efr_dir):
    assert isinstance(efr, OlciL1bProduct) and is_product_path(efr_dir)
    assert efr.sensor is Sensor.OLCI and efr.n_bands == 21 and efr.band_names[7] == "Oa08"
    assert (efr.product_type, efr.width, efr.height) == ("OL_1_EFR___", 4865, real.EFR_ROWS)
    assert (err.product_type, err.width, err.height) == ("OL_1_ERR___", 1217, real.ERR_ROWS)
    assert (efr.lines_per_tie_point, efr.samples_per_tie_point, efr.n_tie_columns) == (1, 64, 77)
    assert (err.lines_per_tie_point, err.samples_per_tie_point, err.n_tie_columns) == (1, 16, 77)
    assert efr.n_tie_lines == efr.height and efr.mirrored


@pytest.mark.parametrize("kind", ["EFR", "ERR"])
def test_snap_pixels_within_a_microdegree(kind, efr, err):
    """SNAP's pixel (x, y) is ESA column x: N1 column width - 1 - x, and the same pixel of
    ``esa_columns``."""
    product, known = (efr, real.EFR_KNOWN) if kind == "EFR" else (err, real.ERR_KNOWN)
    for (x, y), (lat, lon) in known.items():
        rows = slice(y, y + 1)
        la, lo = product.pixel_latitude(rows)[0], product.pixel_longitude(rows)[0]
        n1 = product.width - 1 - x
        assert abs(la[n1] - lat) < 1e-6 and abs(lo[n1] - lon) < 1e-6
        assert abs(product.esa_columns(la[None])[0, x] - lat) < 1e-6
        assert abs(product.esa_columns(lo[None])[0, x] - lon) < 1e-6


def test_the_n1_order_runs_east_to_west_on_a_descending_pass(efr):
    y = 2199
    lon = efr.pixel_longitude(slice(y, y + 1))[0]
    assert lon[efr.width - 1 - 2098] < lon[efr.width - 1 - 2099]  # west of its ESA neighbour
    assert np.nanmedian(np.diff(efr.tie_points["longitude"][y])) < 0


def test_radiance_scale_and_fill(efr, err):
    assert efr.scaling.radiance[0] == real.OA01_SCALE
    assert len(efr.scaling.radiance) == 21 and efr.scaling.radiance[1] != real.OA01_SCALE
    for product, (x, y) in ((efr, real.EFR_FILL), (err, real.ERR_FILL)):
        n1 = product.width - 1 - x
        assert product.no_data_count(1) == 65535 and product.counts(1)[y, n1] == 65535
        rad = product.radiance(1, slice(y, y + 1))[0]
        assert np.isnan(rad[n1])
        assert rad[n1 - 1] == pytest.approx(3000 * real.OA01_SCALE, rel=1e-6)


def test_view_zenith_of_the_tilted_swath(efr, err):
    """OZA from its own scale factor: 56.6 deg at the west edge (the last N1 column), 24.3 at
    the east edge, moved by the tie points' half pixel: half a pixel's change of OZA there."""
    for product in (efr, err):
        oza = product.tie_points["view_zenith"]
        half = 0.5 / product.samples_per_tie_point
        west, east = oza[:, -1], oza[:, 0]
        # ESA's tie column k sits at its column 64k - 0.5: the pixel centre is half a pixel
        # east of it (towards the next ESA column, the previous N1 one)
        assert np.allclose(west, real.OZA_WEST - half * (oza[:, -1] - oza[:, -2]), atol=2e-6)
        assert np.allclose(east, real.OZA_EAST + half * (oza[:, 0] - oza[:, 1]), atol=2e-6)
        assert np.abs(west - real.OZA_WEST).max() < 0.02
        assert oza.min() < 1.0


def test_tie_points_on_the_pixel_centres(efr):
    """ESA's tie points sit half a pixel towards its column 0: read, tie point k is N1 pixel
    k x 64, where the affine field of the fixture puts that pixel's centre."""
    y = np.arange(0, efr.height, 97)
    k = np.arange(efr.n_tie_columns)
    x_esa = efr.width - 1 - 64 * k
    lat, lon = real.EFR_FIELD(x_esa[None, :], y[:, None])
    assert np.abs(efr.tie_points["latitude"][y] - lat).max() < 2e-6
    assert np.abs(efr.tie_points["longitude"][y] - lon).max() < 2e-6


def test_tie_point_heights_are_the_pixels_altitude(efr):
    """The tie files carry no altitude: ``dem_alt`` is geo_coordinates.nc ``altitude``."""
    assert efr.tie_points["dem_alt"].shape == (efr.height, 77)
    assert np.all(efr.tie_points["dem_alt"] == 0.0)


def test_flags_of_both_baselines(efr, err):
    assert efr.baseline is FlagBaseline.PER_BAND and err.baseline is FlagBaseline.SINCE_2_24
    assert efr.quality_coding == {n: 1 << b for n, b in real.CODING_PER_BAND}
    assert err.quality_coding == {n: 1 << b for n, b in real.CODING_2_24}
    assert efr.quality_coding["land"] == 2**31 and efr.quality_coding["saturated_Oa01"] == 2**20
    assert efr.quality_coding["saturated_Oa21"] == 1 and efr.quality_coding["invalid"] == 2**25
    for product, (x, y) in ((efr, real.EFR_SATURATED), (err, real.ERR_SATURATED)):
        n1 = product.width - 1 - x
        assert product.flags[y, n1] == FLAG_LAND_OCEAN
        assert product.flags[y, n1 - 5] == FLAG_BRIGHT and product.flags[y, n1 - 6] == FLAG_INVALID
    x, y = real.EFR_SATURATED
    sat = efr.saturated
    assert sat.dtype == np.uint32 and sat[y, efr.width - 1 - x] == 1 << 7  # Oa08
    assert np.count_nonzero(sat) == 1
    assert not err.saturated.any()  # 2.24: saturated samples are the fill value


def test_wavelengths_from_instrument_data_and_the_band_table(efr):
    assert efr.wavelengths[0] == 400.0 and len(efr.wavelengths) == 21
    assert OLCI.centres[16] == 865.0


def test_a_zip_archive_reads_the_same(efr_dir, efr, tmp_path):
    archive = tmp_path / (efr_dir.name + ".zip")
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(efr_dir.iterdir()):
            z.write(f, f"{efr_dir.name}/{f.name}")
    p = read_product(archive)
    assert isinstance(p, OlciL1bProduct) and p.product_name == efr.product_name
    np.testing.assert_array_equal(p.tie_points["latitude"], efr.tie_points["latitude"])


def test_info_describes_an_olci_product(err_dir, capsys):
    rc, out, _ = _cli(capsys, "info", err_dir)
    assert rc == 0
    assert "Product type   OL_1_ERR___ (OLCI Level 1B (Sentinel-3B), 21 bands" in out
    assert "Size           1217 columns x 8040 lines" in out
    assert "Tie points     77 columns x 8040 lines, every 16 samples and 1 lines" in out
    assert "  21  1020.000 nm" not in out and "  21   400.000 nm" in out  # instrument_data
    assert "Quality flags  saturated, partially_saturated" in out
    assert "Oa21_radiance.nc" in out
    assert len([line for line in out.splitlines() if line[:1].isdigit()]) == 17  # every 512


# ------------------------------------------------------------------------------------------
# what is not OLCI Level 1B
# ------------------------------------------------------------------------------------------


def _foreign(tmp_path: Path, name: str, ptype: str, member: str) -> Path:
    d = tmp_path / name
    d.mkdir()
    (d / "xfdumanifest.xml").write_text(
        '<?xml version="1.0"?><xfdu:XFDU xmlns:xfdu="urn:ccsds:schema:xfdu:1" xmlns:sentinel3='
        '"http://www.esa.int/safe/sentinel/sentinel-3/1.0"><sentinel3:productType>'
        f'{ptype}</sentinel3:productType></xfdu:XFDU>')
    (d / member).write_bytes(b"\x89HDF\r\n\x1a\n")
    return d


@pytest.mark.parametrize(("name", "ptype", "member", "what"), [
    ("S3A_OL_2_WFR____20240526T011231_20240526T011531_20240527T083340_0179_112_302_2160_MAR_O"
     "_NT_003.SEN3", "OL_2_WFR___", "Oa01_reflectance.nc", "an OLCI Level 2 product"),
    ("S3B_OL_2_LFR____20210831T064316_20210831T064616_20210901T114422_0179_056_234_2160_LN1_O"
     "_NT_002.SEN3", "OL_2_LFR___", "gifapar.nc", "an OLCI Level 2 product"),
    ("S3A_SL_1_RBT____20240526T011231_20240526T011531_20240527T083340_0179_112_302_2160_PS1_O"
     "_NT_004.SEN3", "SL_1_RBT___", "S1_radiance_an.nc", "an SLSTR product"),
    ("S3A_SL_2_LST____20240526T011231_20240526T011531_20240527T083340_0179_112_302_2160_PS1_O"
     "_NT_004.SEN3", "SL_2_LST___", "LST_in.nc", "an SLSTR product"),
    ("S3A_SY_2_SYN____20240526T011231_20240526T011531_20240527T083340_0179_112_302_2160_PS1_O"
     "_NT_002.SEN3", "SY_2_SYN___", "Syn_Oa01_reflectance.nc", "a SYNERGY product"),
])
def test_other_sentinel3_products_are_one_error(tmp_path, capsys, name, ptype, member, what):
    d = _foreign(tmp_path, name, ptype, member)
    with pytest.raises(OlciFormatError, match="not an OLCI Level 1B product"):
        read_product(d)
    out = tmp_path / "m.tif"
    for argv in (("info", d), ("map", d, "-o", out)):
        rc, _, err = _cli(capsys, *argv)
        lines = err.strip().splitlines()
        assert rc == 2 and len(lines) == 1 and what in lines[0] and "Traceback" not in err
    assert not out.exists()


def test_a_renamed_level_2_product_is_told_by_its_manifest(tmp_path):
    d = _foreign(tmp_path, "product.SEN3", "OL_2_WFR___", "Oa01_reflectance.nc")
    with pytest.raises(OlciFormatError, match="an OLCI Level 2 product"):
        read_product(d)


def test_a_truncated_member_is_one_error(err_dir, tmp_path, capsys):
    d = tmp_path / err_dir.name
    shutil.copytree(err_dir, d)
    member = d / "Oa05_radiance.nc"
    member.write_bytes(member.read_bytes()[: member.stat().st_size // 2])
    with pytest.raises(Sen3FormatError, match="Oa05_radiance.nc"):
        read_product(d)
    out = tmp_path / "m.tif"
    rc, _, err = _cli(capsys, "map", d, "-o", out, "--bands", "5")
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "Oa05_radiance.nc" in err
    assert not out.exists()


def test_a_corrupt_member_of_a_zip_is_one_error(err_dir, tmp_path, capsys):
    archive = tmp_path / (err_dir.name + ".zip")
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(err_dir.iterdir()):
            z.write(f, f"{err_dir.name}/{f.name}")
        info = z.getinfo(f"{err_dir.name}/qualityFlags.nc")
    data = bytearray(archive.read_bytes())
    start = info.header_offset + 30 + len(info.filename.encode()) + 100
    data[start:start + 200] = bytes(b ^ 0x5A for b in data[start:start + 200])
    archive.write_bytes(bytes(data))
    out = tmp_path / "m.tif"
    rc, _, err = _cli(capsys, "map", archive, "-o", out, "--bands", "8")
    assert rc == 2 and len(err.strip().splitlines()) == 1
    assert "qualityFlags.nc: cannot read" in err
    assert not out.exists()

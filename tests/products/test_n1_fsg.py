"""AMORGOS geo-corrected N1 products (MER_FRG_1P / MER_FSG_1P): Corrected Longitude/Latitude and
Altitude MDS(17..19) written, read back, refused when broken."""

from __future__ import annotations

import numpy as np
import pytest
from n1_samples import sample_inputs

from napari_meris_ortho.errors import N1FormatError, OptionsError
from napari_meris_ortho.products.n1 import read_product, write_product
from napari_meris_ortho.products.n1.format import GEOLOCATION_MDS, plan_layout


def _geolocation(height, width, seed=3):
    rng = np.random.default_rng(seed)
    line, col = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    return {"longitude": 18.0 - 0.0031 * col - 0.0009 * line + rng.normal(0, 1e-4, line.shape),
            "latitude": 45.9 - 0.0024 * line + 0.0004 * col,
            "altitude": rng.integers(-30, 3500, line.shape).astype(np.float64)}


@pytest.fixture(scope="module")
def frg(tmp_path_factory):
    kw = sample_inputs("MER_FRG_1P", height=70, width=257)
    geo = _geolocation(70, 257)
    path = write_product(tmp_path_factory.mktemp("frg") / "frg.N1", pixel_geolocation=geo, **kw)
    return path, kw, geo


def test_layout_has_33_dsds_with_the_geolocation_mds_after_the_flags():
    dsds = plan_layout("MER_FSG_1P", 4481, 100, 3)
    assert len(dsds) == 33
    assert [d.name for d in dsds[19:22]] == [m.name for m in GEOLOCATION_MDS]
    assert [d.dsr_size for d in dsds[19:22]] == [13 + 4 * 4481, 13 + 4 * 4481, 13 + 2 * 4481]
    assert dsds[19].offset == dsds[18].offset + dsds[18].size


def test_round_trip(frg):
    path, kw, geo = frg
    p = read_product(path)
    assert p.product_type == "MER_FRG_1P" and p.has_pixel_geolocation
    assert p.mph["NUM_DSD"] == 33 and p.mph["SPH_SIZE"] == 1542 + 33 * 280
    np.testing.assert_allclose(p.pixel_longitude(), geo["longitude"], atol=5.1e-7)
    np.testing.assert_allclose(p.pixel_latitude(), geo["latitude"], atol=5.1e-7)
    np.testing.assert_array_equal(p.pixel_altitude(), geo["altitude"].astype(np.float32))
    np.testing.assert_array_equal(p.pixel_latitude(slice(10, 12)), p.pixel_latitude()[10:12])
    for b in (1, 15):
        np.testing.assert_array_equal(p.counts(b), kw["counts"][b - 1])
    np.testing.assert_array_equal(p.flags, kw["flags"])


def test_standard_products_have_no_pixel_geolocation(tmp_path):
    p = read_product(write_product(tmp_path / "fr.N1", **sample_inputs(height=65, width=129)))
    assert not p.has_pixel_geolocation
    with pytest.raises(N1FormatError, match="no per-pixel geolocation"):
        p.pixel_latitude()


def test_writer_refuses_missing_or_misshapen_geolocation(tmp_path):
    kw = sample_inputs("MER_FRG_1P", height=65, width=129)
    with pytest.raises(OptionsError, match="required for MER_FRG_1P"):
        write_product(tmp_path / "a.N1", **kw)
    geo = _geolocation(65, 129)
    geo["altitude"] = geo["altitude"][:, :-1]
    with pytest.raises(OptionsError, match=r"altitude.*shape"):
        write_product(tmp_path / "b.N1", pixel_geolocation=geo, **kw)
    assert not list(tmp_path.iterdir())


def _patch_dsd(data: bytearray, name: str, new_name: str) -> bytearray:
    i = data.index(f'DS_NAME="{name}'.encode())
    data[i + 9: i + 9 + len(new_name)] = new_name.encode()
    return data


def test_reader_refuses_a_missing_geolocation_mds(frg, tmp_path):
    data = _patch_dsd(bytearray(frg[0].read_bytes()), "Altitude MDS(19)", "Altitude MDS(99)")
    bad = tmp_path / "bad.N1"
    bad.write_bytes(bytes(data))
    with pytest.raises(N1FormatError, match=r"without Altitude MDS\(19\)"):
        read_product(bad)


def test_reader_refuses_a_wrong_record_size(frg, tmp_path):
    data = bytearray(frg[0].read_bytes())
    i = data.index(b'DS_NAME="Corrected Latitude MDS(18)')
    j = data.index(b"DSR_SIZE=", i)
    size = int(data[j + 9: j + 20])
    data[j + 9: j + 20] = f"{size - 4:+011d}".encode()
    k = data.index(b"DS_SIZE=", i)
    data[k + 8: k + 29] = f"{70 * (size - 4):+021d}".encode()
    bad = tmp_path / "bad.N1"
    bad.write_bytes(bytes(data))
    with pytest.raises(N1FormatError, match=r"Corrected Latitude MDS\(18\): 70 records"):
        read_product(bad)


def test_pyepr_does_not_know_the_amorgos_types(frg, tmp_path):
    """EPR-API 2.3 (pyepr) has no MER_FRG_1P / MER_FSG_1P in its DDDB and refuses the product
    (BEAM/SNAP have them). The same bytes announced as MER_FR__1P open in pyepr, with the
    radiances our reader gives: the rest of the layout is the standard one."""
    import epr
    with pytest.raises(ValueError, match="unable to open"):
        epr.Product(str(frg[0]))
    data = bytearray(frg[0].read_bytes())
    assert data[9:19] == b"MER_FRG_1P"
    data[9:19] = b"MER_FR__1P"
    renamed = tmp_path / "renamed.N1"
    renamed.write_bytes(bytes(data))
    prod = epr.Product(str(renamed))
    try:
        rad = prod.get_band("radiance_7").read_as_array()
        ours = read_product(frg[0]).radiance(7)
        np.testing.assert_allclose(rad[:, ::-1], ours, rtol=1e-6)  # EPR mirrors the columns
    finally:
        prod.close()


def test_pixel_geolocation_outside_its_physical_range_is_masked_with_a_count(frg, tmp_path,
                                                                               caplog):
    """A corrected latitude of 2000 deg or an altitude of -32768 m (held-out hostile FSG): no
    data (NaN) with one warning per variable that counts the pixels, never a position."""
    import logging

    from napari_meris_ortho.products.n1.format import geolocation_dtype

    path, kw, geo = frg
    bad = tmp_path / "bad.N1"
    bad.write_bytes(path.read_bytes())
    p = read_product(bad)
    by_name = {d.name: d for d in p.dsds}
    for mds, rows, value in ((GEOLOCATION_MDS[1], slice(5, 7), 2_000_000_000),
                             (GEOLOCATION_MDS[2], slice(0, 1), -32768)):
        records = np.memmap(bad, dtype=geolocation_dtype(mds, 257), mode="r+",
                            offset=by_name[mds.name].offset, shape=(70,))
        records["values"][rows, :50] = value
        records.flush()
        del records
    p = read_product(bad)
    with caplog.at_level(logging.WARNING):
        lat, alt, lon = p.pixel_latitude(), p.pixel_altitude(), p.pixel_longitude()
        p.pixel_latitude()
    assert np.isnan(lat).sum() == 100 and np.isnan(lat[5:7, :50]).all()
    assert np.isnan(alt).sum() == 50 and not np.isnan(lon).any()
    np.testing.assert_allclose(lat[7:], geo["latitude"][7:], atol=5.1e-7)
    assert caplog.text.count("100 of 17990 corrected latitudes") == 1
    assert "50 of 17990 altitudes" in caplog.text

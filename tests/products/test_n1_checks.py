"""Plausibility checks (io/n1_checks.py): products that are well formed but physically impossible
or forged end in one N1FormatError naming the field and the value,
before anything big is allocated."""

from __future__ import annotations

import numpy as np
import pytest
from n1_mutants import (
    patch_dsd,
    patch_text,
    set_scaling,
    set_tie_point,
    sparse_with_counts,
    tie_records,
)
from n1_samples import sample_inputs

from napari_meris_ortho.errors import N1FormatError
from napari_meris_ortho.products.n1 import read_product, write_product
from napari_meris_ortho.products.n1.checks import max_lines


@pytest.fixture(scope="module")
def rr(tmp_path_factory):
    path = write_product(
        tmp_path_factory.mktemp("rr") / "rr.N1", **sample_inputs("MER_RR__1P", 40, 33)
    )
    return path.read_bytes(), read_product(path)


@pytest.fixture(scope="module")
def fr(tmp_path_factory):
    path = write_product(
        tmp_path_factory.mktemp("fr") / "fr.N1", **sample_inputs("MER_FR__1P", 130, 129)
    )
    return path.read_bytes(), read_product(path)


def expect_error(tmp_path, data: bytes, *fragments) -> str:
    path = tmp_path / "bad.N1"
    path.write_bytes(data)
    return expect_file_error(path, *fragments)


def expect_file_error(path, *fragments) -> str:
    with pytest.raises(N1FormatError) as info:
        read_product(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and "\n" not in message
    for fragment in fragments:
        assert fragment in message, message
    return message


@pytest.mark.parametrize(
    ("field", "raw", "where", "fragments"),
    [
        ("latitude", 1_970_000_000, (2, 1), ["latitude[2, 1] = 1970", "[-90, 90]"]),
        ("longitude", -181_000_000, (0, 0), ["longitude[0, 0] = -181", "[-180, 180]"]),
        ("view_zenith", 1_250_000_000, (1, 2), ["view_zenith[1, 2] = 1250", "[0, 90)"]),
        ("view_zenith", 90_000_000, None, ["view_zenith[0, 0] = 90", "(12 tie points)"]),
        ("dem_alt", 12_000, (3, 0), ["dem_alt[3, 0] = 12000", "[-11500, 9000]"]),
        ("dem_alt", -12_000, (2, 1), ["dem_alt[2, 1] = -12000", "[-11500, 9000]"]),
        ("lat_corr", 2**31 - 1, (0, 1), ["lat_corr[0, 1] = 2147.48"]),
        ("sun_zenith", 2**32 - 1, (0, 0), ["sun_zenith[0, 0] = 4294.97", "[0, 180]"]),
        ("view_azimuth", -400_000_000, (0, 0), ["view_azimuth[0, 0] = -400"]),
    ],
)
def test_impossible_tie_points(tmp_path, rr, field, raw, where, fragments):
    data, product = rr
    bad = set_tie_point(data, product, field, raw, where)
    expect_error(tmp_path, bad, "Tie points ADS", *fragments)


@pytest.mark.parametrize("depth", [-228, -5103, -11_000])
def test_seabed_heights_are_read(tmp_path, rr, depth):
    """Real products store bathymetry as negative dem_alt over sea (-228 m off Portugal in
    MER_FRS_1PNMAP20070709, -5103 m over the Pacific in MER_RR__1PRACR20060116); the deepest
    seabed is about -10 935 m. Such a product is read, with its values."""
    data, product = rr
    path = tmp_path / "sea.N1"
    path.write_bytes(set_tie_point(data, product, "dem_alt", depth, (1, 2)))
    assert read_product(path).tie_points["dem_alt"][1, 2] == depth


@pytest.mark.parametrize(
    ("name", "value", "index", "fragments"),
    [
        ("altitude", -3.0, None, ["altitude=-3 is not positive"]),
        ("roughness", 0.0, None, ["roughness=0 is not positive"]),
        ("ozone", np.inf, None, ["ozone=inf is non-finite"]),
        ("radiance", np.nan, 4, ["radiance[5]=nan is non-finite"]),
        ("radiance", -1e-3, 14, ["radiance[15]=-0.001 is not positive"]),
    ],
)
def test_scaling_factors_finite_and_positive(tmp_path, rr, name, value, index, fragments):
    data, product = rr
    bad = set_scaling(data, product, name, value, index)
    expect_error(tmp_path, bad, "Scaling Factor GADS", *fragments)


def test_altitude_factor_out_of_range_heights(tmp_path, rr):
    data, product = rr  # a huge but finite factor scales the stored heights out of range
    bad = set_scaling(data, product, "altitude", 3e30)
    expect_error(tmp_path, bad, "dem_alt", "[-11500, 9000]")


def test_record_times_beyond_plausible_dates(tmp_path, rr):
    data, product = rr
    bad = set_tie_point(data, product, "days", -(2**31), 1)
    expect_error(tmp_path, bad, "Tie points ADS record 1 time", "-2147483648 days")


def test_header_numbers_beyond_int64(tmp_path, rr):
    data, product = rr
    d = product.dsd("Radiance MDS(3)")
    huge = 10**20 - 1  # 20 digits fit the DS_OFFSET field; beyond int64
    expect_error(tmp_path, patch_dsd(data, product, d.name, offset=huge), "outside the file")
    bad = patch_dsd(data, product, d.name, num_dsr=9_999_999_999, size=d.size)
    expect_error(tmp_path, bad, "NUM_DSR 9999999999")
    bad = patch_text(data, b"LINE_TIME_INTERVAL=+0000175988",
                     b"LINE_TIME_INTERVAL=+9999999999")  # fmt: skip
    expect_error(tmp_path, bad, "LINE_TIME_INTERVAL=9999999999")


def test_widened_header_field_shifts_every_offset(tmp_path, rr):
    data, _ = rr
    # one more digit in an MPH field: every following byte moves by one
    at = data.index(b"ABS_ORBIT=") + len(b"ABS_ORBIT=")
    bad = data[:at] + b"+" + data[at:]
    expect_error(tmp_path, bad)
    at = data.index(b"LINE_LENGTH=") + len(b"LINE_LENGTH=")
    bad = data[:at] + b"0" + data[at:]  # in the SPH: the DSD table moves
    expect_error(tmp_path, bad)


def test_fr_product_relabelled_rr(tmp_path, fr):
    data, _ = fr
    bad = patch_text(data, b'PRODUCT="MER_FR__1P', b'PRODUCT="MER_RR__1P')
    expect_error(tmp_path, bad, "LINES_PER_TIE_PT=64", "MER_RR__1P product has tie points every 16")


def test_line_length_beyond_the_product_type(tmp_path, rr):
    path = write_product(tmp_path / "wide.N1", **sample_inputs("MER_FR__1P", 65, 4545))
    data = patch_text(path.read_bytes(), b'PRODUCT="MER_FR__1P', b'PRODUCT="MER_RR__1P')
    expect_error(tmp_path, data, "LINES_PER_TIE_PT=64")
    data = patch_text(path.read_bytes(), b'PRODUCT="MER_FR__1P', b'PRODUCT="MER_FRS_1P')
    expect_error(tmp_path, data, "LINE_LENGTH=4545", "at most 4481")


def test_tie_point_records_claimed_by_millions_in_a_sparse_file(tmp_path, rr):
    data, product = rr
    path = sparse_with_counts(tmp_path / "bomb.N1", data, product, tie_lines=3_000_000)
    assert path.stat().st_size > 400_000_000 and path.stat().st_blocks * 512 < 10_000_000
    expect_file_error(path, "Tie points ADS has 3000000 tie-point lines", "need 4")


def test_product_lines_beyond_one_orbit_in_a_sparse_file(tmp_path, rr):
    data, product = rr
    lines = max_lines(product.resolution) + 1
    path = sparse_with_counts(tmp_path / "long.N1", data, product, height=lines)
    expect_file_error(path, f"NUM_DSR={lines}", "more lines than one orbit")


def test_one_extra_tie_point_line_is_tolerated(tmp_path, rr):
    data, product = rr
    d = product.dsd("Tie points ADS")
    bad = patch_dsd(data, product, d.name, num_dsr=d.num_dsr + 2, size=d.size + 2 * d.dsr_size)
    expect_error(tmp_path, bad, "has 6 tie-point lines", "need 4")
    records, _ = tie_records(data, product)  # moved to the end with its last line repeated
    moved = records.tobytes() + records[-1:].tobytes()
    ok = patch_dsd(data, product, d.name, offset=len(data), num_dsr=d.num_dsr + 1,
                   size=d.size + d.dsr_size) + moved  # fmt: skip
    path = tmp_path / "ok.N1"
    path.write_bytes(ok)
    assert read_product(path).n_tie_lines == 5

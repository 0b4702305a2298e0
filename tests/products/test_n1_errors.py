"""Bad N1 files: every problem ends in one N1FormatError naming the file and the problem."""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest
from n1_samples import sample_inputs

from napari_meris_ortho.errors import MerisOrthoError, N1FormatError
from napari_meris_ortho.products.n1 import read_product, write_product
from napari_meris_ortho.products.n1.format import DSD_SIZE, MPH_SIZE, SPH_TEXT_SIZE
from napari_meris_ortho.products.n1.writer import format_dsd


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    path = write_product(
        tmp_path_factory.mktemp("good") / "good.N1", **sample_inputs("MER_RR__1P", 40, 33)
    )
    return path.read_bytes(), read_product(path)


def write(tmp_path, data: bytes, name="bad.N1"):
    path = tmp_path / name
    path.write_bytes(data)
    return path


def expect_error(path, *fragments):
    with pytest.raises(N1FormatError) as info:
        read_product(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    for fragment in fragments:
        assert fragment in message, message
    assert isinstance(info.value, MerisOrthoError) and "\n" not in message
    return message


def patch_dsd(data: bytes, product, ds_name: str, **changes) -> bytes:
    index = next(i for i, d in enumerate(product.dsds) if d.name == ds_name)
    start = MPH_SIZE + SPH_TEXT_SIZE + index * DSD_SIZE
    block = format_dsd(dataclasses.replace(product.dsds[index], **changes))
    return data[:start] + block + data[start + DSD_SIZE :]


def patch_text(data: bytes, old: bytes, new: bytes) -> bytes:
    assert len(old) == len(new) and data.count(old) == 1
    return data.replace(old, new)


def test_missing_file_directory_and_fifo(tmp_path):
    expect_error(tmp_path / "nope.N1", "cannot read", "No such file")
    expect_error(tmp_path, "not a regular file")
    fifo = tmp_path / "fifo.N1"
    os.mkfifo(fifo)
    expect_error(fifo, "not a regular file")  # and no hang on open()


@pytest.mark.parametrize(
    "content",
    [b"", b"\x89PNG\r\n\x1a\n" + bytes(3000), b"hello world\n" * 200, b"PRODUCX=" + b" " * 2000],
)
def test_not_envisat(tmp_path, content):
    expect_error(write(tmp_path, content), "not an ENVISAT product")


def test_truncated(tmp_path, good):
    data, _ = good
    expect_error(write(tmp_path, data[:600]), "truncated", f"{MPH_SIZE}")
    expect_error(write(tmp_path, data[:5000]), "truncated", "headers")
    expect_error(write(tmp_path, data[:-1]), "truncated", "TOT_SIZE")


def test_dsd_pointing_outside_the_file(tmp_path, good):
    data, product = good
    d = product.dsd("Radiance MDS(7)")
    bad = patch_dsd(data, product, d.name, offset=len(data) - d.size + 1)
    expect_error(write(tmp_path, bad), "Radiance MDS(7)", "outside the file")
    bad = patch_dsd(data, product, d.name, offset=100)
    expect_error(write(tmp_path, bad), "into the headers")


def test_unsupported_product_types(tmp_path, good):
    data, _ = good
    for other in (b"MER_RR__2P", b"ASA_IMP_1P", b"MER_LRC_2P"):
        bad = patch_text(data, b'PRODUCT="MER_RR__1P', b'PRODUCT="' + other)
        expect_error(write(tmp_path, bad), "unsupported product type", other.decode())


def test_tie_point_record_size_must_be_13_plus_50n(tmp_path, good):
    data, product = good
    d = product.dsd("Tie points ADS")
    size = d.dsr_size - 1
    bad = patch_dsd(data, product, d.name, dsr_size=size, size=d.num_dsr * size)
    expect_error(write(tmp_path, bad), "Tie points ADS record size", "13 + 50 x 3")


def test_inconsistent_dsd_sizes(tmp_path, good):
    data, product = good
    bad = patch_dsd(data, product, "Radiance MDS(2)", size=product.dsd("Radiance MDS(2)").size - 1)
    expect_error(write(tmp_path, bad), "NUM_DSR", "DS_SIZE")


def test_flags_layout_of_old_products_is_refused(tmp_path, good):
    data, product = good
    d = product.dsd("Flags MDS(16)")
    bad = patch_dsd(data, product, d.name, dsr_size=13 + 2 * 33, size=d.num_dsr * (13 + 2 * 33))
    expect_error(write(tmp_path, bad), "Flags MDS(16) record size", "IODD5")


def test_missing_dataset_and_short_tie_grid(tmp_path, good):
    data, product = good
    bad = patch_dsd(data, product, "Flags MDS(16)", name="Flogs MDS(16)")
    expect_error(write(tmp_path, bad), "missing data sets: Flags MDS(16)")
    d = product.dsd("Tie points ADS")
    bad = patch_dsd(data, product, d.name, num_dsr=2, size=2 * d.dsr_size)
    expect_error(write(tmp_path, bad), "Tie points ADS has 2 tie-point lines", "need 4")


def test_bands_of_different_heights(tmp_path, good):
    data, product = good
    d = product.dsd("Radiance MDS(4)")
    bad = patch_dsd(data, product, d.name, num_dsr=d.num_dsr - 1, size=d.size - d.dsr_size)
    expect_error(write(tmp_path, bad), "Radiance MDS(4) has 39 lines, band 1 has 40")


def test_header_garbage(tmp_path, good):
    data, product = good
    bad = patch_text(data, b"SPH_SIZE=+0000009942", b"SPH_SIZE=+00000099x2")
    expect_error(write(tmp_path, bad), "SPH_SIZE")
    bad = patch_text(data, b"SPH_SIZE=+0000009942", b"SPH_SIZE=+9999999942")
    expect_error(write(tmp_path, bad), "SPH_SIZE")
    bad = patch_text(data, b"DSD_SIZE=+0000000280", b"DSD_SIZE=+0000000281")
    expect_error(write(tmp_path, bad), "DSD_SIZE")
    bad = patch_text(data, b"LINE_LENGTH=+00033", b"LINE_LENGTH=+00000")
    expect_error(write(tmp_path, bad), "LINE_LENGTH")
    bad = patch_text(data, b"PROC_STAGE=N\n", b"PROC_STAGE=N\xff")
    expect_error(write(tmp_path, bad), "MPH is not ASCII")
    bad = patch_text(data, b"NUM_BANDS=+015\n", b"NUM_BANDS +015\n")
    expect_error(write(tmp_path, bad), "SPH line", "not KEY=value")
    bad = patch_text(data, b'PROC_CENTER="MORTHO"', b'PROC_CENTER="MORTHO ')
    expect_error(write(tmp_path, bad), "PROC_CENTER", "unterminated")


def test_non_finite_scaling_factors(tmp_path, good):
    data, product = good
    at = product.dsd("Scaling Factor GADS").offset + 4 * 7  # sf_rad[0]
    bad = data[:at] + np.array([np.nan], ">f4").tobytes() + data[at + 4 :]
    expect_error(write(tmp_path, bad), "Scaling Factor GADS", "non-finite")

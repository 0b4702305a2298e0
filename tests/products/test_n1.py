"""Round trips of products.n1: write_product -> read_product (FR and RR, several sizes)."""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest
from n1_samples import APPENDIX_A_FIRST_LINE, sample_inputs

from napari_meris_ortho import read_product as lazy_read_product
from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.products.n1 import (
    FLAG_INVALID,
    MerisL1bProduct,
    ScalingFactors,
    read_product,
    tie_lines,
    west_to_east,
    write_product,
)
from napari_meris_ortho.products.n1.format import MPH_SIZE, NUM_DSD, sph_size


@pytest.fixture(scope="module")
def fr_product(tmp_path_factory):
    inputs = sample_inputs("MER_FR__1P", height=130)
    path = write_product(tmp_path_factory.mktemp("fr") / "fr.N1", **inputs)
    return inputs, read_product(path)


@pytest.fixture(scope="module")
def rr_product(tmp_path_factory):
    inputs = sample_inputs("MER_RR__1P", height=70, seed=1)
    path = write_product(tmp_path_factory.mktemp("rr") / "rr.N1", **inputs)
    return inputs, read_product(path)


@pytest.mark.parametrize("which", ["fr_product", "rr_product"])
def test_round_trip(which, request):
    inputs, product = request.getfixturevalue(which)
    assert isinstance(product, MerisL1bProduct)
    height, width = inputs["counts"][0].shape
    assert product.product_type == inputs["product_type"]
    assert (product.height, product.width) == (height, width)
    assert product.width == (2241 if which == "fr_product" else 1121)
    spacing = 64 if which == "fr_product" else 16
    assert product.lines_per_tie_point == product.samples_per_tie_point == spacing
    for name, values in inputs["tie_points"].items():
        np.testing.assert_array_equal(product.tie_points[name], values, err_msg=name)
        assert product.tie_points[name].dtype == np.float64
    for band in range(1, 16):
        np.testing.assert_array_equal(product.counts(band), inputs["counts"][band - 1])
    np.testing.assert_array_equal(product.flags, inputs["flags"])
    np.testing.assert_array_equal(product.detector_index, inputs["detector_index"])
    assert product.flags.dtype == np.uint8
    assert product.detector_index.dtype == np.dtype(">i2")
    assert product.scaling == ScalingFactors.from_record(inputs["scaling"].to_record())


def test_counts_is_a_strided_memmap_over_the_records(fr_product):
    _, product = fr_product
    counts = product.counts(7)
    assert isinstance(counts, np.memmap)
    assert counts.dtype == np.dtype(">u2")
    assert counts.strides == (4495, 2)  # 13-byte header + 2 x 2241 per line
    assert counts.base is not None and not counts.flags.writeable


def test_radiance_is_counts_times_the_gads_factor(fr_product):
    inputs, product = fr_product
    factor = np.float32(inputs["scaling"].radiance[4])
    rad = product.radiance(5)
    assert rad.dtype == np.float32
    np.testing.assert_array_equal(rad, inputs["counts"][4].astype(np.float32) * factor)
    np.testing.assert_array_equal(product.radiance(5, lines=slice(10, 20)), rad[10:20])
    assert product.scaling.radiance[0] == pytest.approx(0.009333, rel=1e-6)  # Appendix A
    with pytest.raises(ValueError):
        product.counts(16)
    with pytest.raises(ValueError):
        product.radiance(0)


def test_line_times_and_headers(fr_product):
    _, product = fr_product
    # Appendix E.4: the first line of this product is 117451421.714409 s after 2000-01-01
    assert product.line_times[0] == pytest.approx(117451421.714409, abs=1e-6)
    np.testing.assert_allclose(np.diff(product.line_times), 0.043997, atol=2e-6)
    assert product.line_times.shape == (product.height,)
    np.testing.assert_allclose(
        product.tie_point_times, product.line_times[0] + 64 * 0.043997 * np.arange(4), atol=2e-6
    )
    mph, sph = product.mph, product.sph
    assert mph["SPH_SIZE"] == sph_size() == 9942
    assert mph["NUM_DSD"] == NUM_DSD == 30 and mph["DSD_SIZE"] == 280
    assert mph["NUM_DATA_SETS"] == 19
    assert mph["TOT_SIZE"] == product.path.stat().st_size
    assert sph["FIRST_LINE_TIME"] == "21-SEP-2003 09:23:41.714409"
    assert sph["LINE_LENGTH"] == 2241 and sph["LINE_TIME_INTERVAL"] == 43997
    assert sph["FIRST_FIRST_LAT"] == 45909863 and sph["FIRST_FIRST_LONG"] == 18014693
    assert product.first_line_time == np.datetime64("2003-09-21T09:23:41.714409")
    assert product.wavelengths[0] == pytest.approx(412.545)
    assert product.wavelengths[14] == pytest.approx(899.860)
    assert len(product.wavelengths) == 15
    assert product.dsds[0].offset == MPH_SIZE + 9942 == 11189  # Appendix A, Quality ADS


def test_west_to_east_mirrors_columns(fr_product):
    _, product = fr_product
    lat = product.tie_points["latitude"]
    np.testing.assert_array_equal(west_to_east(lat)[:, 0], lat[:, -1])
    counts = product.counts(1)
    view = west_to_east(counts)
    assert view[3, 0] == counts[3, -1] and view.shape == counts.shape
    assert np.shares_memory(view, counts)


@pytest.mark.parametrize(
    ("product_type", "height"),
    [
        ("MER_FR__1P", 1),  # a single line: one tie line
        ("MER_FR__1P", 65),  # exactly on a tie line: 2 tie lines
        ("MER_FR__1P", 66),  # one line past: 3 tie lines, the last beyond the product
        ("MER_FR__1P", 1136),  # Appendix E.8: 19 tie-point lines
        ("MER_RR__1P", 17),
        ("MER_RR__1P", 100),  # not a multiple of 16
    ],
)
def test_round_trip_over_sizes(tmp_path, product_type, height):
    width = 129 if product_type == "MER_FR__1P" else 33
    inputs = sample_inputs(product_type, height=height, width=width, seed=height)
    product = read_product(write_product(tmp_path / "p.N1", **inputs))
    df = product.lines_per_tie_point
    assert product.height == height and product.width == width
    assert product.tie_points["latitude"].shape[0] == tie_lines(height, df)
    assert (product.tie_points["latitude"].shape[0] - 1) * df >= height - 1
    if height == 1136:
        assert product.tie_points["latitude"].shape == (19, 3)
    for name, values in inputs["tie_points"].items():
        np.testing.assert_array_equal(product.tie_points[name], values)
    np.testing.assert_array_equal(product.counts(15), inputs["counts"][14])
    np.testing.assert_array_equal(product.detector_index, inputs["detector_index"])


def test_writer_streams_memmaps_and_reports_progress(tmp_path):
    inputs = sample_inputs("MER_RR__1P", height=40, width=33)
    memmaps = []
    for b, band in enumerate(inputs["counts"]):
        m = np.lib.format.open_memmap(tmp_path / f"b{b}.npy", "w+", np.uint16, band.shape)
        m[:] = band
        memmaps.append(m)
    calls = []
    inputs["counts"] = memmaps
    path = write_product(tmp_path / "m.N1", **inputs, progress=lambda d, t: calls.append((d, t)))
    assert calls[-1] == (16 * 40, 16 * 40)
    assert [d for d, _ in calls] == sorted(d for d, _ in calls)
    np.testing.assert_array_equal(read_product(path).counts(2), inputs["counts"][1])


def test_writer_header_overrides_and_lazy_api(tmp_path):
    inputs = sample_inputs("MER_RR__1P", height=20, width=33)
    path = write_product(
        tmp_path / "o.N1",
        **inputs,
        line_interval_s=0.176,
        product_name="MER_RR__1PNPDK20030408_093303_000023202015_00208_05773_0848.N1",
        mph={"PROC_CENTER": "PDHS-K", "ABS_ORBIT": 5773, "DELTA_UT1": -0.352582},
        sph={"SLICE_POSITION": 3},
    )
    product = lazy_read_product(path)
    assert product.mph["PRODUCT"].startswith("MER_RR__1PNPDK20030408")
    assert product.mph["PROC_CENTER"] == "PDHS-K" and product.mph["ABS_ORBIT"] == 5773
    assert product.mph["DELTA_UT1"] == pytest.approx(-0.352582)
    assert product.sph["SLICE_POSITION"] == 3
    assert product.sph["LINE_TIME_INTERVAL"] == 176000
    assert product.line_interval_s == pytest.approx(0.176)
    np.testing.assert_allclose(np.diff(product.line_times), 0.176, atol=2e-6)


def test_writer_refuses_bad_arguments(tmp_path):
    inputs = sample_inputs("MER_RR__1P", height=20, width=33)
    out = tmp_path / "bad.N1"
    tie = inputs["tie_points"]
    bad = [
        {"product_type": "MER_RR__2P"},
        {"counts": inputs["counts"][:14]},
        {"flags": inputs["flags"][:-1]},
        {"tie_points": {k: v[:1] for k, v in tie.items()}},
        {"tie_points": {k: v for k, v in tie.items() if k != "latitude"}},
        {"tie_points": {**tie, "sun_zenith": -tie["sun_zenith"]}},
        {"tie_points": {**tie, "latitude": tie["latitude"] * np.nan}},
        {"tie_points": {**tie, "bogus": tie["latitude"]}},
        {"mph": {"TOT_SIZE": 5}},
        {"mph": {"NOT_A_KEY": 5}},
        {"mph": {"PROC_CENTER": "MUCH-TOO-LONG"}},
        {"line_interval_s": -1.0},
        {"counts": [c.astype(np.int32) - 70000 for c in inputs["counts"]]},
        {"detector_index": inputs["detector_index"].astype(np.float64)},
    ]
    for change in bad:
        with pytest.raises(OptionsError):
            write_product(out, **{**inputs, **change})
        assert not out.exists()
        assert list(tmp_path.iterdir()) == []  # no partial file left


def test_writer_width_must_end_on_a_tie_column(tmp_path):
    inputs = sample_inputs("MER_RR__1P", height=20, width=33)
    inputs["counts"] = [c[:, :30] for c in inputs["counts"]]
    inputs["flags"] = inputs["flags"][:, :30]
    inputs["detector_index"] = inputs["detector_index"][:, :30]
    with pytest.raises(OptionsError, match="tie-point column"):
        write_product(tmp_path / "w.N1", **inputs)


def test_invalid_flag_and_aware_datetimes(tmp_path):
    inputs = sample_inputs("MER_RR__1P", height=20, width=33)
    inputs["flags"] = inputs["flags"] | FLAG_INVALID
    tz = dt.timezone(dt.timedelta(hours=2))
    local = APPENDIX_A_FIRST_LINE.replace(tzinfo=dt.UTC).astimezone(tz)
    product = read_product(
        write_product(tmp_path / "f.N1", **{**inputs, "first_line_time": local})
    )
    assert np.all(product.flags & FLAG_INVALID)
    assert product.sph["FIRST_LINE_TIME"] == "21-SEP-2003 09:23:41.714409"


@pytest.mark.parametrize("other", ["MER_FRS_1P"])  # FRG/FSG need MDS(17..19): test_n1_fsg.py
def test_other_fr_level1b_types_are_tolerated(tmp_path, other):
    inputs = sample_inputs("MER_FR__1P", height=20, width=129)
    data = write_product(tmp_path / "fr.N1", **inputs).read_bytes()
    path = tmp_path / "other.N1"
    path.write_bytes(data.replace(b'PRODUCT="MER_FR__1P', f'PRODUCT="{other}'.encode(), 1))
    product = read_product(path)
    assert product.product_type == other
    assert product.lines_per_tie_point == 64
    np.testing.assert_array_equal(product.counts(4), inputs["counts"][3])


def test_blank_records_are_invalid(tmp_path, caplog):
    """A Flags MDS(16) record with quality indicator -1 is blank (the DDDB's "-1 for blank
    MDSR"): its line is INVALID, so no merge takes its counts; the other lines are as stored.
    Before, a blank line's counts passed as data."""
    from napari_meris_ortho.products.n1.format import FLAGS_MDS, flags_dtype

    inputs = sample_inputs("MER_RR__1P", height=20, width=33)
    path = write_product(tmp_path / "blank.N1", **inputs)
    plain = read_product(path)
    assert plain.blank_lines.size == 0 and isinstance(plain.flags, np.memmap)
    stored = np.array(plain.flags)
    ds = plain._datasets[FLAGS_MDS]
    size = flags_dtype(plain.width).itemsize
    with open(path, "r+b") as f:
        for line in (3, 4, 5, 10):
            f.seek(ds.offset + line * size + 12)  # days, seconds, microseconds, quality
            f.write(b"\xff")
    with caplog.at_level("WARNING"):
        p = read_product(path)
        flags = p.flags
    assert p.blank_lines.tolist() == [3, 4, 5, 10]
    assert np.all(flags[[3, 4, 5, 10]] & FLAG_INVALID)
    others = np.setdiff1d(np.arange(p.height), [3, 4, 5, 10])
    np.testing.assert_array_equal(flags[others], stored[others])
    keep = np.uint8(0xFF & ~FLAG_INVALID)
    np.testing.assert_array_equal(flags[3] & keep, stored[3] & keep)
    assert "4 blank record(s) (quality indicator -1), lines 3-5, 10" in caplog.text


def test_the_file_name_agrees_with_the_mph(fr_product):
    """The file name's phase, cycle and orbits are the MPH's (E.1:
    ``MER_FR__1PNUPA20030921_092217_000000982020_00079_08149_0354.N1``: phase 2, cycle 020,
    relative orbit 79, absolute 8149)."""
    _, p = fr_product
    name = p.product_name
    assert len(name) == 62 and name.endswith(".N1")
    duration, phase, cycle = name[30:38], name[38], name[39:42]
    rel, abs_ = name[43:48], name[49:54]
    assert duration.isdigit() and phase == str(p.mph["PHASE"])
    assert (int(cycle), int(rel), int(abs_)) == (p.mph["CYCLE"], p.mph["REL_ORBIT"],
                                                 p.mph["ABS_ORBIT"])

"""Appendix A of the handbook: the real FR product's MPH/SPH log, its 30 DSDs and its Scaling
Factor GADS. The writer reproduces them for a product of the same size; the parser reads them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from n1_samples import APPENDIX_A_FIRST_LINE

from napari_meris_ortho.products.n1 import ScalingFactors, plan_layout, read_product, write_product
from napari_meris_ortho.products.n1.format import SPARE_DSD, Dsd
from napari_meris_ortho.products.n1.reader import parse_dsd
from napari_meris_ortho.products.n1.writer import format_dsd

FIXTURE = Path(__file__).parent / "fixtures" / "appendix_a_dsds.txt"

#: MPH values printed in A.1 ("MAIN PRODUCT HEADER"), as file keys and values
APPENDIX_A_MPH = {
    "PRODUCT": "MER_FR__1PNUPA20030921_092341_000000982020_00079_08149_0534.N1",
    "PROC_STAGE": "N",
    "REF_DOC": "PO-RS-MDA-GS2009_11_3J",
    "ACQUISITION_STATION": "PDHS-E",
    "PROC_CENTER": "UK-PAC",
    "PROC_TIME": "26-JAN-2004 13:24:19.434677",
    "SOFTWARE_VER": "MERIS/4.07",
    "SENSING_START": "21-SEP-2003 09:22:17.265770",
    "SENSING_STOP": "21-SEP-2003 09:26:36.187634",
    "PHASE": "2",
    "CYCLE": 20,
    "REL_ORBIT": 79,
    "ABS_ORBIT": 8149,
    "STATE_VECTOR_TIME": "21-SEP-2003 09:23:00.000000",
    "DELTA_UT1": -0.352582,
    "X_POSITION": 4513681.740,
    "Y_POSITION": 1552817.947,
    "Z_POSITION": 5333228.142,
    "X_VELOCITY": 5786.205174,
    "Y_VELOCITY": -136.373816,
    "Z_VELOCITY": -4845.448794,
    "VECTOR_SOURCE": "FR",
    "UTC_SBT_TIME": "21-SEP-2003 09:10:16.414244",
    "SAT_BINARY_TIME": 4008373760,
    "CLOCK_STEP": 3906249810,
    "LEAP_UTC": "17-OCT-2001 00:00:00.000000",
    "LEAP_SIGN": 1,
    "LEAP_ERR": "0",
    "PRODUCT_ERR": "0",
}
#: the structure of the MPH printed in A.1 (computed by the writer)
APPENDIX_A_SIZES = {
    "TOT_SIZE": 166271715,
    "SPH_SIZE": 9942,
    "NUM_DSD": 30,
    "DSD_SIZE": 280,
    "NUM_DATA_SETS": 19,
}


def load_fixture() -> list[Dsd]:
    dsds = []
    for line in FIXTURE.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        number, name, kind, filename, *numbers = (v.strip() for v in line.split("|"))
        assert int(number) == len(dsds) + 1
        dsds.append(Dsd(name, kind, filename, *(int(v) for v in numbers)))
    assert len(dsds) == 29  # printed; the 30th DSD of the product is spare
    return [*dsds, SPARE_DSD]


def test_plan_layout_reproduces_appendix_a():
    expected = load_fixture()
    planned = plan_layout("MER_FR__1P", 2241, 2241, 36)
    assert len(planned) == 30
    for ours, theirs in zip(planned, expected, strict=True):
        assert ours == theirs
    assert max(d.offset + d.size for d in planned) == APPENDIX_A_SIZES["TOT_SIZE"]


def test_parser_reads_the_appendix_a_dsds():
    for dsd in load_fixture():
        block = format_dsd(dsd)
        assert len(block) == 280
        assert parse_dsd(block) == dsd
    quality = format_dsd(load_fixture()[0]).decode()
    # the line widths EPR checks: DS_NAME 39, FILENAME 74, DS_OFFSET 39, DS_SIZE 37 ...
    assert [len(line) + 1 for line in quality.split("\n")[:-1]] == [39, 10, 74, 39, 37, 20, 28, 33]
    assert quality.startswith('DS_NAME="Quality ADS                 "\nDS_TYPE=A\n')
    assert "DS_OFFSET=+00000000000000011189<bytes>\n" in quality


def test_scaling_factors_appendix_a():
    sf = ScalingFactors.appendix_a()
    assert (sf.altitude, sf.roughness) == (1.0, 1.0)
    assert (sf.zonal_wind, sf.merid_wind, sf.atm_pressure) == (0.1, 0.1, 0.1)
    assert (sf.ozone, sf.rel_humidity) == (0.01, 0.1)
    assert sf.radiance[0] == 0.009333 and sf.radiance[14] == 0.005418
    assert sf.radiance[11] == 0.003613
    assert sf.sampling_rate_us == 43997
    assert sf.sun_flux[0] == 1703.201782 and sf.sun_flux[14] == 888.092041
    assert sf.gain_settings[:16] == (9, 10, 11, 11, 11, 11, 11, 10, 11, 11, 11, 10, 9, 11, 10, 0)
    assert sf.gain_settings == sf.gain_settings[:16] * 5
    record = sf.to_record()
    assert record.nbytes == 292
    again = ScalingFactors.from_record(record)
    np.testing.assert_array_equal(np.float32(again.radiance), np.float32(sf.radiance))
    assert again.gain_settings == sf.gain_settings


def test_writer_reproduces_the_appendix_a_product_layout(tmp_path):
    """A 2241 x 2241 FR product: the DSD table, the MPH and the SPH of Appendix A."""
    height = width = 2241
    zeros = np.broadcast_to(np.uint16(0), (height, width))
    k = np.arange(36.0)[None, :]
    i = np.arange(36.0)[:, None]
    tie_points = {  # bilinear corners close to the SPH of Appendix A
        "latitude": 45.909863 + (47.028196 - 45.909863) * k / 35 - 5.767 * i / 35,
        "longitude": 18.014693 + (10.603496 - 18.014693) * k / 35 - 2.045 * i / 35,
    }
    path = write_product(
        tmp_path / "appendix_a.N1",
        product_type="MER_FR__1P",
        tie_points=tie_points,
        counts=[zeros] * 15,
        flags=np.broadcast_to(np.uint8(0), (height, width)),
        detector_index=np.broadcast_to(np.int16(0), (height, width)),
        first_line_time=APPENDIX_A_FIRST_LINE,
        product_name=APPENDIX_A_MPH["PRODUCT"],
        mph=APPENDIX_A_MPH,
    )
    try:
        assert path.stat().st_size == 166271715
        product = read_product(path)
        expected = load_fixture()
        assert product.dsds == expected
        for key, value in {**APPENDIX_A_MPH, **APPENDIX_A_SIZES}.items():
            if isinstance(value, str) and value.isdigit():
                value = int(value)
            assert product.mph[key] == pytest.approx(value), key
        sph = product.sph
        assert sph["SPH_DESCRIPTOR"] == "MER_FR__1P SPECIFIC HEADER"
        assert sph["FIRST_LINE_TIME"] == "21-SEP-2003 09:23:41.714409"
        assert sph["LAST_LINE_TIME"] == "21-SEP-2003 09:25:20.267689"  # Appendix A
        assert sph["LINE_TIME_INTERVAL"] == 43997  # "Line spacing in time: 0.043997 s."
        assert sph["LINE_LENGTH"] == 2241
        assert sph["LINES_PER_TIE_PT"] == sph["SAMPLES_PER_TIE_PT"] == 64
        assert sph["COLUMN_SPACING"] == 260.0
        assert sph["INST_FOV"] == 19159  # 0.019159 deg
        assert sph["FIRST_FIRST_LAT"] == 45909863 and sph["FIRST_LAST_LONG"] == 10603496
        assert product.wavelengths[3] == 509.700 and product.bandwidths[10] == 3.742
        assert product.n_tie_lines == 36 and product.n_tie_columns == 36
    finally:
        path.unlink()

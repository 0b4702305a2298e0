"""``meris-ortho info``: summary and Appendix A/E tie-point table; bad input -> exit code 2."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from napari_meris_ortho.cli import main
from napari_meris_ortho.products.n1 import write_product

sys.path.insert(0, str(Path(__file__).parent / "products"))  # N1 sample inputs
from n1_samples import sample_inputs


@pytest.fixture(scope="module")
def products(tmp_path_factory):
    root = tmp_path_factory.mktemp("info")
    fr = write_product(root / "fr.N1", **sample_inputs("MER_FR__1P", height=130))
    rr = write_product(root / "rr.N1", **sample_inputs("MER_RR__1P", height=70, seed=1))
    # Appendix E.8: a short FR product with 19 tie-point lines
    e8 = write_product(root / "e8.N1", **sample_inputs("MER_FR__1P", height=1136, width=129))
    return {"fr": fr, "rr": rr, "e8": e8}


def run_info(capsys, *argv):
    code = main(["info", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def table_rows(out: str) -> list[list[str]]:
    lines = out.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("No.  Date"))
    return [line.split() for line in lines[start + 1 :] if line.strip()]


@pytest.mark.parametrize(
    ("which", "product_type", "size", "tie"),
    [
        ("fr", "MER_FR__1P", "2241 columns x 130 lines", "36 columns x 4 lines"),
        ("rr", "MER_RR__1P", "1121 columns x 70 lines", "71 columns x 6 lines"),
    ],
)
def test_info_summarises_fr_and_rr(capsys, products, which, product_type, size, tie):
    code, out, err = run_info(capsys, products[which])
    assert code == 0 and err == ""
    assert f"Product type   {product_type} (MERIS Level 1b" in out
    assert f"Size           {size}" in out
    assert f"Tie points     {tie}" in out
    assert "Product        " + product_type + "NSIM20030921_092341" in out
    assert "First line     2003-09-21 09:23:41.714409 UTC  (117451421.714409 s" in out
    assert "SPH 9942 bytes, 30 DSDs, 19 data sets" in out
    assert " 19  Flags MDS(16)" in out and " 30  (spare)" in out
    assert "   1   412.545 nm  9.930 nm         0.009333" in out
    rows = table_rows(out)
    assert rows[0][:4] == ["1", "117451421.714409", "(45.909863,", "18.014693)"]


def test_tie_point_table_rows_follow_appendix_e(capsys, products):
    code, out, _ = run_info(capsys, products["e8"])
    assert code == 0
    rows = table_rows(out)
    assert [r[0] for r in rows] == ["1", "9", "17", "19"]  # as Appendix E.8
    # the date column: tie line 9 is 8 x 64 lines after line 0 (E.4: 117451444.240873)
    assert float(rows[1][1]) == pytest.approx(117451421.714409 + 512 * 0.043997, abs=2e-6)
    assert float(rows[1][1]) == pytest.approx(117451444.240873, abs=2e-6)
    # FIRST tie point at nadir (view zenith 0.0, azimuth 182.0), LAST at 40.7 deg (99.6)
    assert "(0.0, 182.0)" in " ".join(rows[0]) and "(40.7, 99.6)" in " ".join(rows[0])
    code, out, _ = run_info(capsys, products["e8"], "--every", "6")
    assert [r[0] for r in table_rows(out)] == ["1", "7", "13", "19"]


def test_corrections_are_printed_in_micro_degrees(capsys, tmp_path):
    inputs = sample_inputs("MER_RR__1P", height=20, width=33)
    inputs["tie_points"]["lat_corr"] = np.full((3, 3), -1907e-6)
    inputs["tie_points"]["lon_corr"] = np.full((3, 3), -16512e-6)
    _, out, _ = run_info(capsys, write_product(tmp_path / "c.N1", **inputs))
    assert "-1907 1e-6" in out and "-16512 1e-6" in out  # Appendix A, tie line 1, LAST


@pytest.mark.parametrize(
    ("content", "fragment"),
    [
        (None, "cannot read"),
        (b"", "not an ENVISAT product"),
        (b"just some text\n" * 100, "not an ENVISAT product"),
        ("truncate", "truncated"),
        ("level2", "unsupported product type 'MER_RR__2P'"),
    ],
)
def test_bad_input_one_message_exit_2(capsys, tmp_path, products, content, fragment):
    path = tmp_path / "bad.N1"
    if content == "truncate":
        path.write_bytes(products["rr"].read_bytes()[:20000])
    elif content == "level2":
        path.write_bytes(products["rr"].read_bytes().replace(b"MER_RR__1P", b"MER_RR__2P", 1))
    elif content is not None:
        path.write_bytes(content)
    code, out, err = run_info(capsys, path)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith(f"meris-ortho: error: {path}: ")
    assert fragment in err


def test_bad_option_exit_2(capsys, products):
    with pytest.raises(SystemExit) as info:
        main(["info", str(products["rr"]), "--every", "0"])
    assert info.value.code == 2
    assert "not a positive integer" in capsys.readouterr().err


def test_console_entry_point(products):
    done = subprocess.run(
        [sys.executable, "-m", "napari_meris_ortho.cli", "info", str(products["rr"])],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "MER_RR__1P (MERIS Level 1b, reduced resolution)" in done.stdout
    done = subprocess.run(
        [sys.executable, "-m", "napari_meris_ortho.cli", "info", str(products["rr"]) + ".nope"],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == 2 and "Traceback" not in done.stderr

"""``meris-ortho sample``: generate a named scene, print where everything is; bad input -> 2."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from napari_meris_ortho.cli import main
from napari_meris_ortho.products.n1 import read_product

SMALL = {"lines": 40, "columns": 65,
         "exports": {"getasse30": False, "getasse30_beam": True, "srtm30": False,
                     "geotiff_utm": False, "reference": True}}


def test_sample_writes_the_scene_and_prints_the_paths(tmp_path, capsys):
    out = tmp_path / "scene"
    code = main(["-q", "sample", "fr-small", "--out", str(out), "--set", json.dumps(SMALL)])
    assert code == 0
    text = capsys.readouterr().out
    lines = dict(line.split(None, 1) for line in text.splitlines() if line.strip())
    product = Path(lines["product"])
    assert product.parent == out and product.name.startswith("MER_FR__1PNSIM20030921")
    p = read_product(product)
    assert (p.height, p.width) == (40, 65)
    assert "geotiff" in text and "getasse30_beam" in text
    assert (out / "getasse30_beam" / "45N000E.GETASSE30").stat().st_size == 6_480_000
    assert Path(lines["reference"]).exists()
    # a second run reuses the complete output
    stamp = product.stat().st_mtime_ns
    assert main(["-q", "sample", "fr-small", "--out", str(out), "--set", json.dumps(SMALL)]) == 0
    assert product.stat().st_mtime_ns == stamp


def test_sample_list(capsys):
    assert main(["sample", "--list"]) == 0
    names = capsys.readouterr().out.split()
    assert {"fr-alps", "fr-small", "rr-segment", "rr-antimeridian",
            "fr-south-ascending"} <= set(names)


def test_sample_bad_input_exits_2(tmp_path, capsys):
    assert main(["sample", "no-such-scene", "--out", str(tmp_path)]) == 2
    assert "unknown scene 'no-such-scene'" in capsys.readouterr().err
    assert main(["sample", "fr-small", "--out", str(tmp_path), "--set", "{lines: 3"]) == 2
    assert "--set: not valid JSON" in capsys.readouterr().err
    assert main(["sample", "fr-small", "--out", str(tmp_path), "--set", '{"columns": 70}']) == 2
    assert "64 k + 1" in capsys.readouterr().err
    blocker = tmp_path / "file.txt"
    blocker.write_text("")
    code = main(["sample", "fr-small", "--out", str(blocker / "x"), "--set", json.dumps(SMALL)])
    assert code == 2
    assert "cannot create the output directory" in capsys.readouterr().err


def test_sample_rerun_after_the_product_was_deleted(tmp_path, capsys):
    """A rerun into a folder whose N1 was deleted regenerates it and rewrites the per-pixel
    geolocated FRG N1 and .SEN3 in place (it neither fails on the existing .SEN3 folder nor
    deletes the FRG N1 that is there)."""
    out = tmp_path / "scene"
    args = ["-q", "sample", "fr-small", "--out", str(out), "--set", json.dumps(SMALL), "--fsg",
            "--sen3"]
    assert main(args) == 0
    first = dict(line.split(None, 1) for line in capsys.readouterr().out.splitlines())
    product, fsg, sen3 = (Path(first[k]) for k in ("product", "fsg", "sen3"))
    before = {p.name: p.read_bytes() for p in (product, fsg)}
    members = sorted(p.name for p in sen3.iterdir())
    assert fsg.name.startswith("MER_FRG_1P") and sen3.suffix == ".SEN3" and len(members) > 15
    product.unlink()
    assert main(args) == 0
    again = dict(line.split(None, 1) for line in capsys.readouterr().out.splitlines())
    assert again == first
    assert {p.name: p.read_bytes() for p in (product, fsg)} == before
    assert sorted(p.name for p in sen3.iterdir()) == members
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]  # no leftovers
    shutil.rmtree(sen3)  # a .SEN3 name taken by a file is still refused with one message
    sen3.write_bytes(b"x")
    product.unlink()
    assert main(args) == 2
    assert "output exists and is a regular file, not a directory" in capsys.readouterr().err


@pytest.mark.parametrize("override, said", [
    ('{"clouds": {"fraction": 5}}', "clouds.fraction is a fraction 0..1, not 5"),
    ('{"clouds": {"fraction": "lots"}}', "clouds.fraction must be a number, not 'lots'"),
    ('{"clouds": 3}', "clouds must be a JSON object, not 3"),
    ('{"exports": "yes"}', "exports must be a JSON object, not 'yes'"),
    ('{"nonsense": 1}', "unknown scene key 'nonsense'"),
    ('{"dem": {"spacing_deg": true}}', "dem.spacing_deg must be a number, not True"),
])
def test_bad_overrides_are_one_line_and_leave_nothing(override, said, tmp_path, capsys):
    """Each bad override is one error line, not a Python error deep in the simulator, and
    leaves no empty --out directory; an unknown key is refused, not silently ignored."""
    out = tmp_path / "out"
    assert main(["-q", "sample", "fr-small", "--out", str(out), "--set", override]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"meris-ortho: error: --set: {said}" + err[0].split(said, 1)[1]], err
    assert not out.exists()


def test_sample_writes_an_olci_scene(tmp_path, capsys):
    """An olci-* scene: an OLCI .SEN3 product of ESA's name; --fsg/--sen3 (MERIS products)
    refused with one message, nothing written."""
    from napari_meris_ortho.products.open import read_product as read_any

    assert {"olci-efr-alps", "olci-err-andes"} <= set(_listed(capsys))
    out = tmp_path / "olci"
    small = {"lines": 24, "orbit": {"nadir_lat": -16.0, "nadir_lon": -63.0},
             "exports": {"getasse30": False, "srtm30": False, "reference": False}}
    code = main(["-q", "sample", "olci-err-andes", "--out", str(out), "--set",
                 json.dumps(small)])
    assert code == 0
    lines = dict(line.split(None, 1) for line in capsys.readouterr().out.splitlines())
    product = Path(lines["product"])
    assert product.name.startswith("S3B_OL_1_ERR____20210831T") and product.suffix == ".SEN3"
    p = read_any(product)
    assert (p.height, p.width, p.n_bands) == (24, 1217, 21)
    refused = tmp_path / "refused"
    assert main(["sample", "olci-err-andes", "--out", str(refused), "--set", json.dumps(small),
                 "--sen3"]) == 2
    err = capsys.readouterr().err
    assert "--fsg and --sen3 write MERIS products" in err and len(err.strip().splitlines()) == 1
    assert not refused.exists()


def _listed(capsys) -> list[str]:
    assert main(["sample", "--list"]) == 0
    return capsys.readouterr().out.split()

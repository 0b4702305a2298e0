"""An output never lands inside an input (QA of stop 43): a member of the input ``.SEN3``
directory, a chunk of the synthesis store being exported, a store inside the input synthesis
it would be copied from. Each is refused with one line before any work; the input is intact.
Before, all three were written with exit 0 (the product and the store broken)."""

from __future__ import annotations

import hashlib
from pathlib import Path

from napari_meris_ortho.cli import main
from napari_meris_ortho.synthesis.api import synthesize
from test_synthesis import BANDS, GRID, scene_product


def digest(root: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        if p.is_file():
            h.update(str(p.relative_to(root)).encode() + p.read_bytes())
    return h.hexdigest()


def one_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("meris-ortho: error: "), err
    return err[0]


def test_map_into_the_input_sen3_directory_is_refused(geolocated, capsys):
    sen3 = Path(geolocated["sen3"])
    before = digest(sen3)
    member = sen3 / "M07_radiance.nc"
    assert main(["-q", "map", str(sen3), "-o", str(member), "--bands", "7"]) == 2
    assert "is inside the input product" in one_error(capsys)
    assert main(["-q", "map", str(sen3), "-o", str(sen3 / "new.tif"), "--bands", "7"]) == 2
    one_error(capsys)
    assert digest(sen3) == before and not (sen3 / "new.tif").exists()


def test_export_into_its_store_and_a_store_inside_its_input_are_refused(tmp_path, capsys):
    store = tmp_path / "store"
    synthesize([scene_product()], store, grid=GRID, bands=BANDS, algorithm="max-ndvi",
               tile=256, elevation="tiepoints")
    before = digest(store)
    chunk = next(p for p in (store / "chunks").iterdir() if p.is_file())
    assert main(["-q", "export", str(store), "-o", str(chunk)]) == 2
    assert "is inside the synthesis store" in one_error(capsys)
    assert main(["-q", "synthesize", scene_product(), "--input", str(store),
                 "--out", str(store / "sub"), "--workers", "0"]) == 2
    assert "is inside the input synthesis" in one_error(capsys)
    assert digest(store) == before and not (store / "sub").exists()
    # an update in place is no copy into itself
    assert main(["-q", "synthesize", scene_product({"seed": 3}), "--input", str(store),
                 "--out", str(store), "--workers", "0", "--elevation", "tiepoints"]) == 0

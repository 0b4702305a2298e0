"""An output never lands inside an input: a member of the input ``.SEN3`` directory, a chunk of
the synthesis store being exported, a store inside the input synthesis it would be copied from.
Each is refused with one line before any work, never written with exit 0; the input (product or
store) is intact."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import pytest

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


@pytest.mark.slow
def test_a_damaged_store_is_one_error_line(tmp_path):
    """A chunk object of the store missing or truncated: export and an update end in one
    line naming what is wrong, exit 2, nothing else on stderr (not Icechunk's multi-line report
    in a traceback, nor at exit a panic of its Rust runtime)."""
    import shutil
    import subprocess
    import sys

    store = tmp_path / "store"
    product = scene_product()
    synthesize([product], store, grid=GRID, bands=BANDS, algorithm="max-ndvi", tile=256,
               elevation="tiepoints")
    # a truncated object: Icechunk's length check says so, but a decode error of a chunk can
    # come first (at times, in CI too): either way one line naming the damage
    for damage, said in (("truncate", r"(a chunk object is truncated|"
                                      r"(layer|chunk) \S+ does not decode \(.+\))"),
                         ("remove", "a chunk object is missing"),
                         ("scramble", r"(layer|chunk) \S+ does not decode \(.+\)")):
        copy = tmp_path / damage
        shutil.copytree(store, copy)
        for chunk in (copy / "chunks").iterdir():
            if damage == "remove":
                chunk.unlink()
            elif damage == "scramble":  # same size: only zstd can tell
                chunk.write_bytes(bytes(255 - b for b in chunk.read_bytes()))
            else:
                chunk.write_bytes(b"garbage")
        for argv in (["export", str(copy), "-o", str(tmp_path / "out.tif")],
                     ["synthesize", scene_product({"seed": 3}), "--input", str(copy),
                      "--out", str(copy), "--workers", "0", "--elevation", "tiepoints"]):
            run = subprocess.run([sys.executable, "-m", "napari_meris_ortho.cli", "-q", *argv],
                                 capture_output=True, text=True, timeout=300)
            assert run.returncode == 2, run.stderr
            lines = run.stderr.strip().splitlines()
            assert len(lines) == 1 and re.fullmatch(
                f"meris-ortho: error: the synthesis store: {said}: the store is damaged",
                lines[0]), run.stderr
        assert not (tmp_path / "out.tif").exists()


def test_a_reader_that_leaves_is_no_error(geolocated):
    """``meris-ortho info P | head -1``: the reader closes the pipe; the command ends quietly
    with the status of a SIGPIPE (141), as other tools do (not exit 2, "[Errno 32]")."""
    import subprocess
    import sys

    run = subprocess.Popen([sys.executable, "-m", "napari_meris_ortho.cli", "info",
                            str(geolocated["fsg"])], stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE)
    run.stdout.close()  # before it writes
    _, err = run.communicate(timeout=120)
    assert run.returncode == 141 and err == b""


def test_a_product_outside_the_grid_is_skipped_not_merged(tmp_path, caplog):
    """A product whose footprint misses the grid is skipped, not "merged, added 0", and a new
    synthesis of it commits no empty store (``map`` refuses the same case)."""
    from napari_meris_ortho.geometry.grid import OutputGrid

    far = OutputGrid("EPSG:4326", 0.0, 10.0, 0.01, 0.01, 100, 100)
    store = tmp_path / "far"
    result = synthesize([scene_product()], store, grid=far, bands=BANDS,
                        algorithm="max-ndvi", tile=256, elevation="tiepoints")
    assert result.snapshot is None and not result.merged
    assert [r.status for r in result.reports] == ["outside the synthesis grid"]
    assert not store.exists()
    # with one product on the grid: it is merged, the other reported; exit 1 from the CLI
    code = main(["-q", "synthesize", scene_product(), scene_product({"seed": 3}),
                 "--out", str(tmp_path / "ok"), "--ul", "13.45", "46.70", "--lr", "14.26",
                 "46.19", "--pixel-size", "0.0015", "--bands", "7,13", "--workers", "0",
                 "--elevation", "tiepoints"])
    assert code == 0
    with caplog.at_level("WARNING"):
        code = main(["-q", "synthesize", scene_product({"seed": 5}), "--out", str(store),
                     "--ul", "0", "10", "--lr", "1", "9", "--pixel-size", "0.01",
                     "--workers", "0", "--elevation", "tiepoints"])
    assert code == 1 and not store.exists()
    assert "1 product(s) outside the synthesis grid, skipped" in caplog.text

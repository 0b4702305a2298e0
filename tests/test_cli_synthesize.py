"""``meris-ortho synthesize``: exit codes, MERSYN option refusals, and an update killed halfway
that must leave the previous synthesis intact (handbook section 3.1, Appendix C)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from napari_meris_ortho.cli import main
from napari_meris_ortho.synthesis import open_synthesis
from test_synthesis import BANDS, layers, scene_product

GRID_ARGS = ["--crs", "EPSG:4326", "--ul", "13.45", "46.70", "--lr", "14.26", "46.19",
             "--pixel-size", "0.0015"]
COMMON = ["--elevation", "tiepoints", "--tile", "256"]


@pytest.fixture(scope="module")
def products() -> list[str]:
    return [scene_product({"fraction": 0.4, "scale_km": 12.0, "seed": 10 * k}) for k in (1, 2, 3)]


def _snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


def test_new_then_update_exit_codes(products, tmp_path, caplog) -> None:
    out = tmp_path / "syn"
    bands = ",".join(str(b) for b in BANDS)
    assert main(["-q", "synthesize", products[0], "--out", str(out), "--bands", bands,
                 "--algorithm", "max-ndvi", *GRID_ARGS, *COMMON]) == 0
    store = open_synthesis(out)
    assert store.bands == BANDS and store.algorithm == "max-ndvi"
    assert (store.grid.width, store.grid.height) == (540, 340)
    bad = tmp_path / "truncated.N1"
    bad.write_bytes(Path(products[1]).read_bytes()[:5000])
    code = main(["-q", "synthesize", str(bad), products[1], "--input", str(out), "--out", str(out),
                 *COMMON])
    assert code == 1
    assert "truncated.N1" in caplog.text and "1 of 2 product(s) failed" in caplog.text
    store = open_synthesis(out)
    assert store.manifest["generation"] == "gen-000002"
    assert [p["product"] for p in store.products] == [Path(p).name for p in products[:2]]
    assert store.read("count").max() == 2


def test_refusals_exit_2(products, tmp_path, capsys) -> None:
    out = tmp_path / "syn"
    assert main(["-q", "synthesize", products[0], "--out", str(out), "--bands", "7",
                 *GRID_ARGS, *COMMON]) == 0
    before = _snapshot(out)
    for extra in (["--crs", "EPSG:32633"], ["--pixel-size", "0.01"], ["--bands", "3"],
                  ["--ul", "13", "47", "--lr", "14", "46"]):
        assert main(["-q", "synthesize", products[1], "--input", str(out), "--out", str(out),
                     *extra, *COMMON]) == 2
        assert "shall not be given" in capsys.readouterr().err
    assert main(["-q", "synthesize", products[1], "--out", str(out), *COMMON]) == 2
    assert "already holds a synthesis" in capsys.readouterr().err
    assert main(["-q", "synthesize", products[1], "--input", str(tmp_path / "none"),
                 "--out", str(out), *COMMON]) == 2
    assert "not a synthesis" in capsys.readouterr().err
    assert main(["-q", "synthesize", products[1], "--input", str(out), "--out", str(out),
                 "--dem", str(tmp_path / "missing.tif")]) == 2
    assert "missing.tif" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["-q", "synthesize", products[1], "--out", str(tmp_path / "x"), "--algorithm", "mean"])
    assert exc.value.code == 2
    assert _snapshot(out) == before


def test_update_killed_halfway_leaves_previous_synthesis(products, tmp_path) -> None:
    out = tmp_path / "syn"
    assert main(["-q", "synthesize", products[0], "--out", str(out), "--bands", "7,13",
                 *GRID_ARGS, *COMMON]) == 0
    before = _snapshot(out)
    arrays = layers(out)
    cmd = [sys.executable, "-m", "napari_meris_ortho.cli", "-q", "synthesize",
           *(products[1:] * 4), "--input", str(out), "--out", str(out), *COMMON]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    killed_in = None
    copied = False
    while time.monotonic() < deadline and proc.poll() is None:
        temps = [p for p in out.iterdir() if p.name.startswith(".gen-")]
        with contextlib.suppress(FileNotFoundError):
            copied = bool(temps) and len(list(temps[0].iterdir())) == 3
        if temps and copied:  # the 3 layers are copied: merging now
            time.sleep(0.3)
            killed_in = temps[0]
            os.kill(proc.pid, signal.SIGKILL)
            break
        time.sleep(0.005)
    proc.wait(timeout=30)
    err = proc.stderr.read().decode()
    proc.stderr.close()
    assert killed_in is not None and proc.returncode == -signal.SIGKILL, err
    assert killed_in.exists()  # the half-written generation is still there ...
    after = _snapshot(out)
    leftovers = [k for k in after if k.startswith(".gen-")]
    assert leftovers
    # ... but every file of the previous synthesis is byte-identical and readable
    assert {k: v for k, v in after.items() if not k.startswith(".gen-")} == before
    for key, value in layers(out).items():
        np.testing.assert_array_equal(value, arrays[key])
    # the next update cleans the leftovers and goes through
    assert main(["-q", "synthesize", products[1], "--input", str(out), "--out", str(out),
                 *COMMON]) == 0
    assert sorted(p.name for p in out.iterdir() if p.name != ".lock") == \
        ["gen-000002", "synthesis.json"]
    assert open_synthesis(out).read("count").max() == 2


def test_synthesis_with_a_dem(products, tmp_path) -> None:
    dem = Path(products[0]).parent / "dem_truth.tif"
    out = tmp_path / "syn"
    assert main(["-q", "synthesize", products[0], "--out", str(out), "--bands", "13",
                 "--dem", str(dem), *GRID_ARGS, "--tile", "256"]) == 0
    with_dem = open_synthesis(out).read("band_13")
    assert main(["-q", "synthesize", products[0], "--out", str(tmp_path / "tp"), "--bands",
                 "13", *GRID_ARGS, *COMMON]) == 0
    tiepoints = open_synthesis(tmp_path / "tp").read("band_13")
    both = (with_dem > 0) & (tiepoints > 0)
    assert both.sum() > 0.45 * both.size  # 53 % measured
    # the DEM moves the pixels of the relief the tie-point heights miss (39 % measured)
    moved = (with_dem != tiepoints) & both
    assert 0.2 < moved.sum() / both.sum() < 0.6


@pytest.mark.parametrize("command", ["map", "synthesize"])
def test_shared_grid_and_height_options_refused_alike(products, tmp_path, capsys,
                                                      command) -> None:
    """map and synthesize parse the grid/height/band options in one place (_options.py)."""
    out = ["-o", str(tmp_path / "o.tif")] if command == "map" else ["--out", str(tmp_path / "s")]
    cases = [
        (["--ul", "13", "47"], "--ul and --lr need each other"),
        (["--ul", "13", "47", "--lr", "14", "46"], "--ul/--lr need --pixel-size"),
        (["--pixel-size", "-0.5"], "--pixel-size must be > 0, got -0.5"),
        (["--crs", "EPSG:999999"], "unknown CRS"),
        (["--dem", str(tmp_path / "d.tif"), "--elevation", "none"], "DEMs need --elevation dem"),
        (["--ul", "14", "46", "--lr", "13", "47", "--pixel-size", "0.01"], "upper-left"),
    ]
    for extra, message in cases:
        assert main(["-q", command, products[0], *out, *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("meris-ortho: error:") and message in err[0]
    with pytest.raises(SystemExit) as exc:
        main(["-q", command, products[0], *out, "--bands", "7,16"])
    assert exc.value.code == 2 and "MERIS bands are 1..15" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())

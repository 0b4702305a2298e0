"""``meris-ortho synthesize``, ``synthesis-log`` and ``export``: exit codes, MERSYN option
refusals, and updates killed at random moments that must leave the previous synthesis intact
(handbook section 3.1, Appendix C)."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from napari_meris_ortho.cli import main
from napari_meris_ortho.synthesis.reading import open_synthesis
from napari_meris_ortho.synthesis.store import open_layer
from test_synthesis import BANDS, layers, scene_product

GRID_ARGS = ["--crs", "EPSG:4326", "--ul", "13.45", "46.70", "--lr", "14.26", "46.19",
             "--pixel-size", "0.0015"]
COMMON = ["--elevation", "tiepoints", "--tile", "256", "--workers", "0"]


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
                 "--algorithm", "max-ndvi", "--codec", "delta-zstd", *GRID_ARGS, *COMMON]) == 0
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
    assert len(store.history()) == 2
    assert [p["product"] for p in store.products] == [Path(p).name for p in products[:2]]
    assert store.read("count").max() == 2
    statuses = [p["status"] for p in store.history()[0].products]
    assert statuses == ["failed", "merged"]
    codecs = open_layer(store.session.store, "band_07").metadata.to_dict()["codecs"]  # kept
    assert [c["name"] for c in codecs] == ["numcodecs.delta", "bytes", "zstd"]
    # rerun: the product is already there: reported, skipped, exit 0, no new commit
    caplog.clear()
    assert main(["synthesize", products[1], "--input", str(out), "--out", str(out),
                 *COMMON]) == 0
    assert "already in the synthesis" in caplog.text and len(open_synthesis(out).history()) == 2


def test_synthesis_log_and_export(products, tmp_path, capsys) -> None:
    out = tmp_path / "syn"
    assert main(["-q", "synthesize", products[0], "--out", str(out), "--bands", "7,13",
                 *GRID_ARGS, *COMMON]) == 0
    first = open_synthesis(out).snapshot
    assert main(["-q", "synthesize", products[1], "--input", str(out), "--out", str(out),
                 *COMMON]) == 0
    capsys.readouterr()
    assert main(["synthesis-log", str(out)]) == 0
    text = capsys.readouterr().out
    names = [p["product_name"] for p in open_synthesis(out).products]
    assert text.count("snapshot ") == 2 and all(n in text for n in names)
    assert text.splitlines()[0].endswith("2 product(s), codec zstd")
    assert text.index(names[1]) < text.index(names[0])  # newest first
    assert main(["-q", "export", str(out), "-o", str(tmp_path / "old.tif"), "--bands", "13",
                 "--at", first, "--dtype", "float32"]) == 0
    import rasterio

    with rasterio.open(tmp_path / "old.tif") as ds:
        assert ds.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG"
        old = ds.read(1)
    assert old.tobytes() == open_synthesis(out, at=first).band(13).tobytes()
    assert main(["-q", "export", str(tmp_path), "-o", str(tmp_path / "x.tif")]) == 2
    assert "not a synthesis store" in capsys.readouterr().err
    assert main(["-q", "export", str(out), "-o", str(tmp_path / "x.tif"), "--bands", "3"]) == 2
    assert "not in the synthesis" in capsys.readouterr().err
    assert not (tmp_path / "x.tif").exists()


def test_crs_utm_is_the_first_products_zone(products, tmp_path) -> None:
    """``--crs utm``: a new synthesis on the UTM zone of its product's footprint, the grid of
    that zone named."""
    import numpy as np

    from napari_meris_ortho.ortho import product_grid
    from napari_meris_ortho.products.n1 import read_product

    assert main(["-q", "synthesize", products[0], "--out", str(tmp_path / "syn"), "--bands", "7",
                 "--crs", "utm", *COMMON]) == 0
    grid = open_synthesis(tmp_path / "syn").grid
    product = read_product(products[0])
    zone = int((np.mean(product.tie_points["longitude"]) + 180.0) // 6.0) + 1
    assert grid.crs.to_epsg() == 32600 + zone
    assert grid == product_grid(product, f"EPSG:{32600 + zone}")


def test_refusals_exit_2(products, tmp_path, capsys) -> None:
    out = tmp_path / "syn"
    assert main(["-q", "synthesize", products[0], "--out", str(out), "--bands", "7",
                 *GRID_ARGS, *COMMON]) == 0
    before = _snapshot(out)
    for extra in (["--crs", "EPSG:32633"], ["--crs", "utm"], ["--pixel-size", "0.01"],
                  ["--bands", "3"],
                  ["--ul", "13", "47", "--lr", "14", "46"], ["--codec", "delta-zstd"]):
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


@pytest.mark.slow
def test_updates_killed_at_random_moments(products, tmp_path) -> None:
    """SIGKILL at random moments of an update (MERIS_ORTHO_KILL_TRIALS, default 10): the store
    opens at the previous commit with identical arrays (or, killed after its commit, at the
    new one, complete); the next run completes and gives the arrays of an update never
    killed."""
    out = tmp_path / "syn"
    assert main(["-q", "synthesize", products[0], "--out", str(out), "--bands", "7,13",
                 *GRID_ARGS, *COMMON]) == 0
    before, commits = layers(out), len(open_synthesis(out).history())
    def command(target: Path) -> list[str]:
        return [sys.executable, "-m", "napari_meris_ortho.cli", "-q", "synthesize",
                *products[1:], "--input", str(out), "--out", str(target), *COMMON]

    cmd = command(out)
    reference = tmp_path / "ref"
    t0 = time.monotonic()  # the same update, never killed, into a copy: its duration
    subprocess.run(command(reference), check=True)
    duration = time.monotonic() - t0
    expected = layers(reference)
    rng = random.Random(13)
    trials = int(os.environ.get("MERIS_ORTHO_KILL_TRIALS", "10"))
    killed_before_commit = 0
    for _ in range(trials):
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                start_new_session=True)
        try:
            proc.wait(timeout=rng.uniform(0.2, 1.0) * duration)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=60)
        store = open_synthesis(out)
        if len(store.history()) == commits:  # killed before its commit: the previous state
            killed_before_commit += proc.returncode == -signal.SIGKILL
            for key, value in layers(out).items():
                assert value.tobytes() == before[key].tobytes(), key
        else:  # the commit landed: complete, and the next run has nothing to do
            for key, value in layers(out).items():
                assert value.tobytes() == expected[key].tobytes(), key
        assert main(["-q", "synthesize", *products[1:], "--input", str(out), "--out",
                     str(out), *COMMON]) == 0
        for key, value in layers(out).items():
            assert value.tobytes() == expected[key].tobytes(), key
        assert len(open_synthesis(out).history()) == commits + 1
        # back to the previous commit for the next trial
        repo = open_synthesis(out).repo
        repo.reset_branch("main", open_synthesis(out).history()[1].snapshot)
    assert killed_before_commit >= trials // 3


def test_synthesis_with_a_dem(products, tmp_path) -> None:
    dem = Path(products[0]).parent / "dem_truth.tif"
    out = tmp_path / "syn"
    assert main(["-q", "synthesize", products[0], "--out", str(out), "--bands", "13",
                 "--dem", str(dem), *GRID_ARGS, "--tile", "256", "--workers", "0"]) == 0
    with_dem = open_synthesis(out).read("band_13")
    assert main(["-q", "synthesize", products[0], "--out", str(tmp_path / "tp"), "--bands",
                 "13", *GRID_ARGS, *COMMON]) == 0
    tiepoints = open_synthesis(tmp_path / "tp").read("band_13")
    both = (with_dem > 0) & (tiepoints > 0)
    assert both.sum() > 0.45 * both.size  # 53 % on this scene
    # the DEM moves the pixels of the relief the tie-point heights miss (39 % on this scene)
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
        (["--dem", str(tmp_path / "d.tif"), "--elevation", "none"],
         "DEMs are only used with elevation 'dem'"),
        (["--elevation", "dem"], "--elevation dem needs a DEM: name one with --dem PATH"),
        (["--ul", "14", "46", "--lr", "13", "47", "--pixel-size", "0.01"], "upper-left"),
    ]
    for extra, message in cases:
        assert main(["-q", command, products[0], *out, *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("meris-ortho: error:") and message in err[0]
    # map takes OLCI products too: band 16 is refused once the product is known (exit 2)
    try:
        code = main(["-q", command, products[0], *out, "--bands", "7,16"])
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "MERIS bands are 1..15" in err[0]
    assert not any(tmp_path.iterdir())


def test_refused_or_empty_runs_leave_nothing_behind(products, tmp_path, capsys) -> None:
    """A new synthesis refused under the lock (grid too big for --max-pixels, known only from
    the products) or that merges nothing leaves the folder as it was: no store, no
    ``.STORE.meris-ortho-lock``, an empty given directory empty again; the lock
    file of an existing synthesis stays."""
    work = tmp_path / "work"
    work.mkdir()
    (work / "given").mkdir()
    bad = tmp_path / "truncated.N1"
    bad.write_bytes(Path(products[0]).read_bytes()[:5000])
    for store in ("new", "given"):
        code = main(["-q", "synthesize", products[0], "--out", str(work / store),
                     "--pixel-size", "0.0001", "--max-pixels", "100000", *COMMON])
        assert code == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "exceeds the limit of 1e+05 pixels" in err
        assert sorted(p.name for p in work.rglob("*")) == ["given"], store
        code = main(["-q", "synthesize", str(bad), "--out", str(work / store), *GRID_ARGS,
                     *COMMON])
        assert code == 1  # the only product failed: nothing merged
        assert f"meris-ortho: error: nothing merged into {work / store}: 1 product(s) failed" in (
            capsys.readouterr().err)
        assert sorted(p.name for p in work.rglob("*")) == ["given"], store
    assert main(["-q", "synthesize", products[0], "--out", str(work / "given"), *GRID_ARGS,
                 *COMMON]) == 0
    assert (work / ".given.meris-ortho-lock").is_file()
    assert main(["-q", "synthesize", products[0], "--out", str(work / "given"), *COMMON]) == 2
    assert (work / ".given.meris-ortho-lock").is_file() and len(
        open_synthesis(work / "given").history()) == 1

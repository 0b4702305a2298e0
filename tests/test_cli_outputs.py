"""Output safety of the commands: ``-o`` naming an input, another output
or a special file is refused before any work; a failure writing any output of a run removes
every new output of the run and leaves the old files as they were."""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys

import pytest

from napari_meris_ortho.cli import main
from napari_meris_ortho.products.n1 import read_product
from ortho_samples import make_dem, make_product


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("outputs")
    prod = make_product(d / "p.N1", height=130, width=321, lon0=15.0, nadir_col=-800.0)
    tp = read_product(prod).tie_points
    dem = make_dem(d / "dem.tif", tp["longitude"].min() - 0.3, tp["latitude"].min() - 0.3,
                   tp["longitude"].max() + 0.3, tp["latitude"].max() + 0.3)  # fmt: skip
    return prod, dem


def run_map(capsys, *argv) -> tuple[int, str]:
    code = main(["map", *map(str, argv)])
    return code, capsys.readouterr().err


def test_output_equal_to_an_input_or_another_output(files, tmp_path, capsys):
    prod, dem = files
    before = prod.read_bytes(), dem.read_bytes()
    code, err = run_map(capsys, prod, "-o", prod, "--bands", "1")
    assert code == 2 and f"-o {prod} is the input product {prod}: refusing" in err
    code, err = run_map(capsys, prod, "-o", dem, "--dem", dem, "--bands", "1")
    assert code == 2 and "is the DEM" in err
    out = tmp_path / "out.tif"
    code, err = run_map(capsys, prod, "-o", out, "--stats-json", out, "--bands", "1")
    assert code == 2 and "are the same file" in err
    link = tmp_path / "alias.N1"
    link.symlink_to(prod)
    code, err = run_map(capsys, prod, "-o", link, "--bands", "1")
    assert code == 2 and "is the input product" in err
    assert (prod.read_bytes(), dem.read_bytes()) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["alias.N1"]


def test_special_files_as_output_are_refused(files, tmp_path, capsys):
    prod, _ = files
    fifo = tmp_path / "fifo.tif"
    os.mkfifo(fifo)
    for target, kind in ((fifo, "a FIFO"), ("/dev/null", "a character device"),
                         (tmp_path, "a directory")):  # fmt: skip
        code, err = run_map(capsys, prod, "-o", target, "--bands", "1")
        assert code == 2 and f"exists and is {kind}, not a regular file" in err, err
    assert fifo.exists() and not fifo.is_file()


def _fsize_limit(limit: int):
    def apply() -> None:  # in the child: EFBIG instead of SIGXFSZ beyond `limit` bytes
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return apply


def test_a_failing_second_output_removes_the_first(files, tmp_path):
    prod, dem = files
    argv = [sys.executable, "-m", "napari_meris_ortho.cli", "-q", "map", str(prod), "--dem",
            str(dem), "--bands", "1", "--diagnostics"]  # fmt: skip
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    ok = tmp_path / "ok"
    ok.mkdir()
    done = subprocess.run([*argv, "-o", str(ok / "out.tif")], capture_output=True, env=env)
    assert done.returncode == 0, done.stderr.decode()
    main_size = (ok / "out.tif").stat().st_size
    diag_size = (ok / "out_diagnostics.tif").stat().st_size
    assert diag_size > 2 * main_size  # 7 float32 bands against one
    full = tmp_path / "full"
    full.mkdir()
    (full / "out.tif").write_bytes(b"old output")
    failed = subprocess.run(
        [*argv, "-o", str(full / "out.tif")], capture_output=True, env=env,
        preexec_fn=_fsize_limit((main_size + diag_size) // 2),
    )  # fmt: skip
    err = failed.stderr.decode()
    assert failed.returncode == 2 and "out_diagnostics.tif: cannot write" in err, err
    # libtiff may print its own "File too large" lines first; ours is one line, the last
    assert "Traceback" not in err and err.strip().splitlines()[-1].startswith("meris-ortho: error")
    assert sorted(p.name for p in full.iterdir()) == ["out.tif"]
    assert (full / "out.tif").read_bytes() == b"old output"


def test_band_order_and_unneeded_dems(files, tmp_path, caplog):
    """``--bands 7,5,2`` writes planes 7, 5, 2 in that order (an RGB composite in any viewer,
    not planes 2, 5, 7); a DEM after one that answered every point is not warned about as
    "contributed no height"; a DEM that misses the product, before it, is."""
    import logging

    import rasterio

    prod, dem = files
    out = tmp_path / "rgb.tif"
    far = make_dem(tmp_path / "far.tif", -60.0, -10.0, -59.5, -9.5)
    dem, far = f"{dem}:ellipsoid", f"{far}:ellipsoid"
    with caplog.at_level(logging.WARNING):
        assert main(["-q", "map", str(prod), "-o", str(out), "--bands", "7,5,2,7",
                     "--dem", dem, "--dem", far, "--elevation", "dem"]) == 0
    with rasterio.open(out) as ds:
        assert ds.count == 3
        assert [d.split()[2] for d in ds.descriptions] == ["7", "5", "2"], ds.descriptions
        band7 = ds.read(1)
    assert "far.tif" not in caplog.text  # not needed: the first DEM answered every point
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert main(["-q", "map", str(prod), "-o", str(out), "--bands", "7", "--dem", far,
                     "--dem", dem]) == 0
    assert "far.tif:ellipsoid contributed no height" in caplog.text
    with rasterio.open(out) as ds:
        assert (ds.read(1) == band7).all()
    with pytest.raises(SystemExit) as exc:  # an empty list is no "all bands"
        main(["map", str(prod), "-o", str(out), "--bands", ""])
    assert exc.value.code == 2


def test_a_geotiff_is_named_as_one(files, tmp_path, capsys):
    """``-o out.png`` is refused: the output is a GeoTIFF, named .tif or .tiff."""
    prod, _ = files
    for name in ("out.png", "out.nc", "out"):
        code, err = run_map(capsys, prod, "-o", tmp_path / name, "--bands", "7")
        assert code == 2 and "the output is a Cloud-Optimized GeoTIFF: name it .tif or .tiff" in err
    code, _ = run_map(capsys, prod, "-o", tmp_path / "OUT.TIF", "--bands", "7",
                      "--elevation", "tiepoints")
    assert code == 0 and sorted(p.name for p in tmp_path.iterdir()) == ["OUT.TIF"]

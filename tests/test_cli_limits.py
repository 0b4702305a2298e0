"""Output grid size guard and CRS checks at the command line (issue 15 reproducers): one clear
message, exit code 2, before any allocation, nothing left behind."""

from __future__ import annotations

import pytest

from napari_meris_ortho.cli import main
from ortho_samples import make_product


@pytest.fixture(scope="module")
def product(tmp_path_factory):
    d = tmp_path_factory.mktemp("limits")
    return make_product(d / "p.N1", height=130, width=321, lon0=15.0, nadir_col=-800.0)


def run(capsys, *argv) -> tuple[int, str]:
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    return code, err


@pytest.mark.parametrize(
    ("options", "fragments"),
    [
        (["--pixel-size", "1e-6"],
         ["output grid of", "exceeds the limit", "pixel size of at least"]),
        (["--ul", "-180", "90", "--lr", "180", "-90", "--pixel-size", "0.001"],
         ["output grid of 360000 x 180000 pixels (6.48e+10 pixels, about 1.9 TiB)"]),
        (["--pixel-size", "0.001", "--max-pixels", "1000"],
         ["limit of 1e+03 pixels (--max-pixels)"]),
    ],
)  # fmt: skip
def test_map_output_grid_size_guard(product, tmp_path, capsys, options, fragments):
    out = tmp_path / "out.tif"
    code, err = run(capsys, "map", product, "-o", out, "--bands", "1,2", *options)
    assert code == 2, err
    assert err.startswith("meris-ortho: error: ") and len(err.splitlines()) == 1
    for fragment in fragments:
        assert fragment in err, err
    assert list(tmp_path.iterdir()) == []


def test_max_pixels_raises_the_limit(product, tmp_path, capsys):
    out = tmp_path / "out.tif"
    code, err = run(capsys, "-q", "map", product, "-o", out, "--bands", "1", "--max-pixels",
                    "1e6", "--elevation", "none")  # fmt: skip
    assert code == 0 and out.exists(), err
    with pytest.raises(SystemExit) as info:  # argparse's own error: usage line, exit 2
        main(["map", str(product), "-o", str(out), "--max-pixels", "0"])
    assert info.value.code == 2
    assert "'0' is not a positive pixel count" in capsys.readouterr().err


def test_synthesis_over_the_world_is_refused_and_leaves_no_directory(product, tmp_path, capsys):
    out = tmp_path / "synthesis"
    code, err = run(capsys, "synthesize", product, "--out", out, "--ul", "-180", "90", "--lr",
                    "180", "-90", "--pixel-size", "1e-4")  # fmt: skip
    assert code == 2 and "output grid of 3600000 x 1800000 pixels" in err, err
    assert "free space in" in err
    assert list(tmp_path.iterdir()) == []  # refused before anything is created
    code, err = run(capsys, "synthesize", product, "--out", out, "--pixel-size", "1e-5")
    assert code == 2 and "exceeds the limit" in err, err
    assert not out.exists()  # (the store's lock file beside it may stay)


@pytest.mark.parametrize(
    ("crs", "fragment"),
    [
        ("EPSG:4978", "is geocentric"),
        ('LOCAL_CS["site",LOCAL_DATUM["d",0],UNIT["metre",1],AXIS["X",EAST],AXIS["Y",NORTH]]',
         "not a 2-D projected or geographic CRS"),
        ("IAU_2015:49900", "is not on the Earth"),
        ("+proj=longlat +a=1 +b=1", "is not on the Earth"),
    ],
)  # fmt: skip
def test_crs_that_cannot_hold_an_output_grid(product, tmp_path, capsys, crs, fragment):
    code, err = run(capsys, "map", product, "-o", tmp_path / "out.tif", f"--crs={crs}")
    assert code == 2 and fragment in err and "Traceback" not in err, err
    assert list(tmp_path.iterdir()) == []

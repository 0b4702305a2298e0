"""Output grid size guard and CRS checks at the command line: one clear
message, exit code 2, before any allocation, nothing left behind."""

from __future__ import annotations

import re

import numpy as np
import pytest

from napari_meris_ortho.cli import main
from napari_meris_ortho.errors import OptionsError
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
         # 2 bands streamed to the file: 2 bytes a pixel, refused before the segment's area
         # (16 + 2 x 2 more a pixel there) is known
         ["output grid of 360000 x 180000 pixels (6.48e+10 pixels, at least 120.7 GiB)"]),
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


def test_map_counts_the_bands_it_streams_and_orthorectify_those_it_holds(product, tmp_path,
                                                                        capsys):
    """``map`` writes the bands a few at a time (``write_map``), and the antecedents and the
    gathered bands cover the search area only (the rows and columns the segment reaches): its
    size guard counts 2 bytes a pixel of the grid (the writer's overviews) and 16 + 2 x 8 of
    the area for 15 bands, not every band as float32 over the grid (16 + 8 x 15), which refused
    grids it maps within the memory (a 15-band LAEA Europe extent: 24 GB estimated, 1.4 GB
    peak). The API's in-memory result counts them all, also when ``result()`` follows a
    streamed ``precompute``."""
    from napari_meris_ortho.geometry.grid import OutputGrid
    from napari_meris_ortho.options import OrthoOptions
    from napari_meris_ortho.ortho import bytes_per_output_pixel, orthorectify, precompute

    every = OrthoOptions.of(None)
    assert len(every.bands) == 15
    assert bytes_per_output_pixel(every, hold_bands=False) == 2 + 17 + 16
    assert bytes_per_output_pixel(every, hold_bands=False, area_share=0.25) == 2 + 33 / 4
    assert bytes_per_output_pixel(every) == 17 + 8 * 15 + 3
    three = OrthoOptions.of(None, bands=[7, 5, 2], diagnostics=True)
    assert bytes_per_output_pixel(three, hold_bands=False) == 2 + 48 + 17 + 6

    grid = OutputGrid("EPSG:4326", 11.0, 47.0, 0.001, 0.001, 2000, 1000)
    ante = precompute(product, grid, elevation="none", max_pixels=2_000_000)
    r0, r1, c0, c1 = ante.area
    area = (r1 - r0) * (c1 - c0)
    assert 0.2 < area / 2e6 < 0.6
    assert np.isnan(ante.line[:r0]).all() and np.isnan(ante.line[:, c1:]).all()

    def mib(n: float, what: str = "about") -> str:
        return f"(2e+06 pixels, {what} {n / 2**20:.1f} MiB)"

    out = tmp_path / "out.tif"
    code, err = run(capsys, "map", product, "-o", out, "--pixel-size", "0.001", "--elevation",
                    "none", "--ul", "11", "47", "--lr", "13", "46", "--max-pixels", "1000")
    # a pixel limit is checked before the spans: the whole grid's part of the estimate
    assert code == 2 and mib(2e6 * 2, "at least") in err, err
    with pytest.raises(OptionsError) as info:
        orthorectify(product, grid, elevation="none", max_pixels=1000)
    assert mib(2e6 * 123, "at least") in str(info.value)
    ante.max_pixels = 1000  # a streamed precompute: result() counts the bands it holds
    with pytest.raises(OptionsError) as info:
        ante.result()
    assert mib(2e6 * (8 * 15 + 3)) in str(info.value)
    held = precompute(product, grid, elevation="none", max_pixels=2_000_000, hold_bands=True)
    held.max_pixels = 1000  # counted by precompute: not refused after the search
    assert held.result().bands[7].shape == (1000, 2000)
    assert list(tmp_path.iterdir()) == []


def test_a_grid_of_too_many_rows_is_refused_before_its_spans(product, tmp_path, capsys):
    """The size guard first counts what the whole grid costs whatever the segment (the map's
    2 bytes a pixel), before the spans of the segment's rows are computed (one or more a row,
    5.9e5 rows here): the estimate in the message is that part alone."""
    from napari_meris_ortho.ortho import product_grid

    grid = product_grid(product, pixel_size=1e-6)
    code, err = run(capsys, "map", product, "-o", tmp_path / "out.tif", "--pixel-size", "1e-6",
                    "--bands", "1,2")
    pixels = grid.width * grid.height
    assert code == 2 and f"({pixels:.3g} pixels, at least {2 * pixels / 2**40:.1f} TiB)" in err


@pytest.mark.slow
def test_synthesis_over_the_world_is_refused_and_leaves_no_directory(product, tmp_path, capsys):
    out = tmp_path / "synthesis"
    code, err = run(capsys, "synthesize", product, "--out", out, "--ul", "-180", "90", "--lr",
                    "180", "-90", "--pixel-size", "1e-4")  # fmt: skip
    assert code == 2 and "output grid of 3600000 x 1800000 pixels" in err, err
    assert "65536 chunks of 512 x 512 pixels per layer" in err
    assert list(tmp_path.iterdir()) == []  # refused before anything is created
    code, err = run(capsys, "synthesize", product, "--out", out, "--pixel-size", "1e-6")
    assert code == 2 and "exceeds the limit" in err, err
    assert not out.exists()  # (the store's lock file beside it may stay)


def test_a_sparse_synthesis_grid_larger_than_the_disk_is_accepted(product, tmp_path, capsys):
    """A synthesis store holds the chunks its products write, not its extent: a grid of
    1.6e10 pixels (15 bands: 0.8 TB uncompressed, dense) takes one small product and stays
    small: the dense grid need not fit in the free disk space (it would not here)."""
    from napari_meris_ortho.synthesis import open_synthesis

    out = tmp_path / "continent"
    code, err = run(capsys, "-q", "synthesize", product, "--out", out, "--ul", "-40", "80",
                    "--lr", "86", "-46", "--pixel-size", "1e-3", "--elevation", "tiepoints",
                    "--workers", "0")  # fmt: skip
    assert code == 0, err
    synthesis = open_synthesis(out)
    assert (synthesis.grid.width, synthesis.grid.height) == (126000, 126000)
    assert len(synthesis.history()) == 1
    stored = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    assert stored < 100 * 2**20  # the product's tiles, not the grid


def test_a_run_that_does_not_fit_the_disk_is_refused_before_it_writes(product, tmp_path,
                                                                      monkeypatch):
    """What a run writes (its whole tiles, uncompressed, overviews included) is checked
    against the free space before anything is written; ``max_pixels`` lifts the check."""
    import shutil

    from napari_meris_ortho.synthesis import synthesize, tiling

    def tiny_disk(path):
        return shutil._ntuple_diskusage(10**12, 10**12 - 2**20, 2**20)

    monkeypatch.setattr(tiling.shutil, "disk_usage", tiny_disk)
    out = tmp_path / "store"
    with pytest.raises(OptionsError, match=r"to write, uncompressed, and 1\.0 MiB free in") as exc:
        synthesize([product], out, elevation="tiepoints", bands=(7,))
    assert "(max_pixels; the command line's --max-pixels) to run anyway" in str(exc.value)
    assert list(tmp_path.iterdir()) in ([], [tmp_path / ".store.meris-ortho-lock"])
    result = synthesize([product], out, elevation="tiepoints", bands=(7,), max_pixels=10**9)
    assert result.snapshot is not None


def test_the_write_estimate_counts_whole_tiles_bands_and_overviews(tmp_path):
    from napari_meris_ortho.synthesis.tiling import check_write_size, stored_bytes_per_pixel

    tiles = [(0, 1024, 0, 1024), (0, 1024, 1024, 1500)]
    pixels = 1024 * 1024 + 1024 * 476
    assert stored_bytes_per_pixel(15) == pytest.approx((30 + 8) * 4 / 3)
    need = pixels * stored_bytes_per_pixel(15)
    check_write_size(tiles, 15, tmp_path, None, free=int(need) + 1)
    with pytest.raises(OptionsError, match=re.escape(f"cover {pixels:.3g} pixels")):
        check_write_size(tiles, 15, tmp_path, None, free=int(need) - 1)
    with pytest.raises(OptionsError):  # float32 bands (stores of version 2): twice the bytes
        check_write_size(tiles, 15, tmp_path, None, band_bytes=4, free=int(need) + 1)
    check_write_size(tiles, 15, tmp_path, 10, free=0)  # max_pixels given: not checked


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

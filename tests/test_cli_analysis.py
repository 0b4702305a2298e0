"""``meris-ortho disparity`` and ``meris-ortho demcheck`` end to end on small files."""

from __future__ import annotations

import csv
import os
import time

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from analysis.test_demcheck import appendix_f2_scene
from analysis.test_disparity import fourier_shift, textured
from napari_meris_ortho.cli import main


def write_image(path, data, crs="EPSG:32632", x0=300000.0, y0=5100000.0, res=260.0):
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[-1], height=data.shape[-2],
                       count=data.shape[0] if data.ndim == 3 else 1, dtype="float32", crs=crs,
                       transform=from_origin(x0, y0, res, res), nodata=0.0) as ds:
        if data.ndim == 3:
            ds.write(data.astype(np.float32))
        else:
            ds.write(data.astype(np.float32), 1)
    return path


@pytest.fixture
def image_pair(tmp_path):
    a = textured(shape=(90, 120), seed=11)
    b = fourier_shift(a, dy=-2.6, dx=1.3)
    a[:, :10] = 0.0  # background (nodata) strip
    return write_image(tmp_path / "a.tif", a), write_image(tmp_path / "b.tif", b)


def test_disparity_cli(image_pair, tmp_path, capsys):
    a, b = image_pair
    vec, sta = tmp_path / "tie.csv", tmp_path / "out.sta"
    code = main(["-q", "disparity", str(a), str(b), "--vectors", str(vec), "--report", str(sta)])
    out = capsys.readouterr().out
    assert code == 0
    assert "STATISTICAL WINDOW SIZE = 5" in out and "EXPLORATION WINDOW WIDTH = 19" in out
    assert "TOTAL NUMBER OF PIXELS = 10800" in out and "IMAGE PIXELS = 9900" in out
    assert sta.read_text() == out
    with open(vec) as f:
        rows = list(csv.DictReader(f))
    assert len(rows) > 0.8 * 9900
    dx = np.array([float(r["dx_px"]) for r in rows])
    dy_m = np.array([float(r["dy_m"]) for r in rows])
    assert np.mean(dx) == pytest.approx(1.3, abs=0.05)
    assert np.mean(dy_m) == pytest.approx(-2.6 * 260.0, abs=0.05 * 260)
    first = rows[0]
    assert float(first["x"]) == pytest.approx(300000 + (int(first["column"]) + 0.5) * 260)
    assert "MODULUS = " in out


def test_disparity_cli_geographic_pixel_size_and_bands(tmp_path, capsys):
    a = textured(shape=(60, 80), seed=12)
    stack = np.stack([a, fourier_shift(a, dy=0.0, dx=2.0)])
    img = write_image(tmp_path / "ab.tif", stack, crs="EPSG:4326", x0=6.0, y0=46.0, res=0.01)
    code = main(["-q", "disparity", str(img), str(img), "--band", "1", "2"])
    out = capsys.readouterr().out
    assert code == 0
    # 0.01 deg on the 6 370 997 m sphere at 45.7 N: 776.6 m east, 1111.9 m north
    g = out.splitlines()[-1]
    dx_px = float(g.split("= (")[1].split(",")[0])
    dx_m = float(g.split("= (")[2].split(",")[0])
    assert dx_px == pytest.approx(2.0, abs=0.05)
    assert dx_m == pytest.approx(dx_px * 776.6, rel=2e-3)


def test_disparity_cli_errors(image_pair, tmp_path, capsys):
    a, _ = image_pair
    other = write_image(tmp_path / "c.tif", np.ones((40, 40)))
    assert main(["disparity", str(a), str(other)]) == 2
    assert "differs" in capsys.readouterr().err
    assert main(["disparity", str(a), str(tmp_path / "nope.tif")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not found" in err
    assert main(["disparity", str(a), str(a), "--explore", "8", "19"]) == 2
    assert "--explore" in capsys.readouterr().err
    assert main(["disparity", str(a), str(a), "--band", "3"]) == 2
    assert "no band 3" in capsys.readouterr().err
    # an exploration window of 99999 x 999999 is bounded: one message, at once (no hang)
    t0 = time.perf_counter()
    assert main(["disparity", str(a), str(a), "--explore", "99999", "999999"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "at most 129 lines and columns" in err
    assert main(["disparity", str(other), str(other), "--explore", "9", "101"]) == 2  # 40 x 40
    assert "101 columns explore shifts beyond the images' 40 columns (at most 79)" in (
        capsys.readouterr().err)
    assert time.perf_counter() - t0 < 5.0
    assert main(["disparity", str(a), str(a), "--band", "3"]) == 2
    assert "no band 3" in capsys.readouterr().err
    assert main(["disparity", str(a), str(a), "--vectors", str(tmp_path / "no" / "v.csv")]) == 2
    for size in (["0", "0"], ["-5", "nan"]):  # refused, not "(0.000, 0.000) m", "nan m"
        assert main(["disparity", str(a), str(a), "--pixel-size", *size]) == 2
        assert "--pixel-size must be two sizes > 0" in capsys.readouterr().err
    fifo = tmp_path / "fifo.tif"
    os.mkfifo(fifo)  # refused: reading it would block forever
    assert main(["disparity", str(fifo), str(a)]) == 2
    assert "the image is a FIFO, not a regular file" in capsys.readouterr().err


def test_demcheck_cli(tmp_path, capsys):
    pts, dem = appendix_f2_scene(tmp_path)
    png = tmp_path / "fig64.png"
    code = main(["-q", "demcheck", str(pts), "--dem", str(dem), "--plot", str(png)])
    out = capsys.readouterr().out
    assert code == 0
    lines = [" ".join(line.split()) for line in out.splitlines()]
    assert "DIFFERENCES BETWEEN GPS POINTS AND DEM - NEAREST NEIGHBOUR" in lines
    assert "DIFFERENCES BETWEEN GPS POINTS AND DEM - BI-CUBIC" in lines
    assert lines.count("NUMBER OF PROCESSED GCPs : 169 (77.9%)") == 1  # bilinear/bicubic: fewer
    assert "ARITHMETIC MEAN +10.828" in " ".join(lines)
    assert png.read_bytes()[:4] == b"\x89PNG"
    code = main(["-q", "demcheck", str(pts), "--dem", str(dem), "--method", "nearest",
                 "--no-listing"])
    out = capsys.readouterr().out
    assert code == 0 and "GCP #" not in out and ". STANDARD DEVIATION : 30.503" in out
    # --geoid (no file): the DEM heights are above EGM96; h = H + N moves the mean by -N
    code = main(["-q", "demcheck", str(pts), "--dem", str(dem), "--method", "nearest",
                 "--no-listing", "--geoid"])
    out = capsys.readouterr().out
    mean = float(out.split("ARITHMETIC MEAN")[1].split(":")[1].split()[0])
    assert code == 0 and "EGM96 (egm96_15.gtx)" in out and -45.0 < mean < -25.0
    assert main(["demcheck", str(pts), "--dem", f"{dem}:egm08"]) == 2
    assert "unknown vertical datum" in capsys.readouterr().err


def test_demcheck_cli_errors(tmp_path, capsys):
    pts, dem = appendix_f2_scene(tmp_path)
    assert main(["demcheck", str(tmp_path / "none.csv"), "--dem", str(dem)]) == 2
    assert "points file not found" in capsys.readouterr().err
    # a FIFO is refused (reading it would block forever); a missing geoid file is named as the
    # geoid, not "DEM not found"
    fifo = tmp_path / "fifo.csv"
    os.mkfifo(fifo)
    assert main(["demcheck", str(fifo), "--dem", str(dem)]) == 2
    assert "the points file is a FIFO, not a regular file" in capsys.readouterr().err
    assert main(["demcheck", str(pts), "--dem", str(dem), "--geoid",
                 str(tmp_path / "nofile.gtx")]) == 2
    assert "nofile.gtx: geoid undulation grid not found" in capsys.readouterr().err
    assert main(["demcheck", str(pts), "--dem", str(tmp_path / "none.tif")]) == 2
    assert "DEM not found" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["demcheck", str(pts), "--dem", str(dem), "--method", "spline"])
    assert exc.value.code == 2

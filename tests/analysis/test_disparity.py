"""Disparity analysis (ZNCC, handbook section 4.6): recovered shifts, signs, limits, statistics."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from napari_meris_ortho.analysis.disparity import disparity, format_report
from napari_meris_ortho.errors import OptionsError

FIXTURES = Path(__file__).parent / "fixtures"


def textured(shape=(120, 160), sigma=1.0, seed=1) -> np.ndarray:
    """Smoothed random texture, positive (no background), periodic for Fourier shifts."""
    rng = np.random.default_rng(seed)
    return ndimage.gaussian_filter(rng.normal(size=shape), sigma, mode="wrap") + 10.0


def fourier_shift(img: np.ndarray, dy: float, dx: float) -> np.ndarray:
    """The image content moved by (+dy lines, +dx columns): out(x) = img(x - d)."""
    ky = np.fft.fftfreq(img.shape[0])[:, None]
    kx = np.fft.fftfreq(img.shape[1])[None, :]
    return np.real(np.fft.ifft2(np.fft.fft2(img) * np.exp(-2j * np.pi * (ky * dy + kx * dx))))


@pytest.mark.slow
def test_synthetic_shift_recovered_to_a_tenth_of_a_pixel():
    a = textured()
    b = fourier_shift(a, dy=-2.6, dx=1.3)
    r = disparity(a, b, pixel_size_m=(300.0, 300.0))
    gx, gy = r.global_displacement
    assert abs(gx - 1.3) < 0.05 and abs(gy + 2.6) < 0.05
    assert r.stats["candidate_pixels"] > 0.8 * r.stats["image_pixels"]
    v = r.vectors()
    assert np.median(v[:, 2]) == pytest.approx(1.3, abs=1e-6)
    assert np.median(v[:, 3]) == pytest.approx(-2.6, abs=1e-6)
    # displacements are sampled on 0.1 px, as DISPAR's tie-points
    assert np.allclose(v[:, 2:4] * 10, np.round(v[:, 2:4] * 10), atol=1e-4)
    g = r.stats["global_displacement"]
    assert g["modulus_m"] == pytest.approx(math.hypot(gx * 300, gy * 300))


def test_sign_convention_feature_moved_east_and_south():
    """A bright blob moved by +3 columns and +2 lines in B gives dX = +3, dY = +2."""
    a = textured(sigma=1.5, seed=4)
    a[50:56, 70:76] += 8.0
    b = np.roll(a, (2, 3), axis=(0, 1))
    r = disparity(a, b, threshold=99.0)
    assert r.dx[53, 73] == pytest.approx(3.0) and r.dy[53, 73] == pytest.approx(2.0)
    assert r.confidence[53, 73] > 99.9
    assert r.global_displacement == pytest.approx((3.0, 2.0), abs=0.02)


def test_identical_images_zero_displacement_full_confidence():
    a = textured(seed=2)
    r = disparity(a, a.copy())
    inner = r.image & np.isfinite(r.confidence) & (r.confidence > 0)
    assert np.all(r.dx[inner] == 0) and np.all(r.dy[inner] == 0)
    assert np.nanmin(r.confidence[r.candidate]) > 99.99
    s = r.stats
    # every pixel with a full statistical window in both images is a candidate
    assert s["candidate_pixels"] == (120 - 4) * (160 - 4)
    assert s["x"]["candidates"]["rms"] == 0 and s["y"]["on_limit"] == 0


def test_shift_beyond_exploration_is_on_limit():
    """A 10-column shift of a smooth texture exceeds the 19-column window (|dX| <= 9): the
    correlation grows towards the true peak, so the best matches sit on the limit."""
    a = textured(sigma=3.0, seed=3)
    b = fourier_shift(a, dy=0.0, dx=10.0)
    r = disparity(a, b)
    assert r.stats["x"]["on_limit"] > 0.5 * r.stats["image_pixels"]
    assert r.stats["y"]["on_limit"] < 0.1 * r.stats["image_pixels"]
    assert not (r.on_limit_x | r.on_limit_y)[r.candidate].any()
    assert r.stats["candidate_pixels"] < 0.1 * r.stats["image_pixels"]
    assert np.nanmax(np.abs(r.dx)) == 9.0 and np.nanmax(np.abs(r.dy)) <= 4.0


def test_background_is_not_image_pixels():
    a = textured(seed=5)
    b = fourier_shift(a, dy=0.4, dx=-0.7)
    a[:, :40] = 0.0  # background of the first image
    b[100:, :] = 0.0  # background of the second image
    r = disparity(a, b)
    s = r.stats
    assert s["total_pixels"] == 120 * 160
    assert s["image_pixels"] == 100 * 120
    assert not r.candidate[:, :42].any() and not r.candidate[98:, :].any()
    assert r.global_displacement == pytest.approx((-0.7, 0.4), abs=0.05)
    mask = np.ones(a.shape, dtype=bool)
    mask[:60] = False
    masked = disparity(a, b, mask=mask)
    assert masked.stats["image_pixels"] == 40 * 120
    assert not masked.candidate[:62].any()


def test_step_and_statistics_consistency():
    a = textured(seed=6)
    b = fourier_shift(a, dy=1.0, dx=0.5)
    calls = []
    r = disparity(a, b, step=3, pixel_size_m=(260.0, 250.0),
                  progress=lambda done, total: calls.append((done, total)))
    assert calls[-1] == (40, 40) and all(d <= t for d, t in calls)
    s = r.stats
    assert s["total_pixels"] == 40 * 54
    assert not r.image[1::3].any() and not r.image[:, 2::3].any()
    for axis, size in (("x", 260.0), ("y", 250.0)):
        for sel in ("image", "candidates"):
            m = s[axis][sel]
            assert m["rms"] ** 2 == pytest.approx(m["mean"] ** 2 + m["std"] ** 2)
            assert s[axis][sel + "_m"]["mean"] == pytest.approx(m["mean"] * size, rel=1e-6)
            assert s[axis][sel + "_m"]["maximum"] == pytest.approx(m["maximum"] * size, rel=1e-6)
    assert s["confidence"]["candidates"]["minimum"] >= 95.0


def test_vectors_for_napari():
    a = textured(seed=7)
    b = fourier_shift(a, dy=0.0, dx=2.0)
    r = disparity(a, b, threshold=98.0)
    v = r.vectors()
    assert v.shape == (r.stats["candidate_pixels"], 5)
    assert np.all(v[:, 4] >= 98.0)
    nv = r.napari_vectors()
    assert nv.shape == (len(v), 2, 2)
    assert np.allclose(nv[:, 0], v[:, :2]) and np.allclose(nv[:, 1, 1], v[:, 2])


@pytest.mark.parametrize(
    ("kwargs", "word"),
    [({"stat_window": 4}, "stat-window"), ({"explore": (9, 18)}, "explore"),
     ({"threshold": 120.0}, "threshold"), ({"step": 0}, "step"), ({"subpixel": "fft"}, "subpixel")],
)
def test_bad_options(kwargs, word):
    a = textured(seed=8)
    with pytest.raises(OptionsError, match=word):
        disparity(a, a, **kwargs)


def test_bad_images():
    with pytest.raises(OptionsError, match="same grid"):
        disparity(np.ones((10, 10)), np.ones((10, 11)))
    with pytest.raises(OptionsError, match="no common"):
        disparity(np.zeros((10, 10)), np.ones((10, 10)))


def _handbook_stats(text: str) -> dict:
    """The numbers of a DISPAR log as a statistics dict (the inverse of format_report)."""

    def vs(label: str, block: str) -> tuple[float, float]:
        m = re.search(rf"^{label}\s*=\s*(\S+) vs\.\s*(\S+) \(\*\)", block, re.M)
        return float(m.group(1)), float(m.group(2))

    def moments(block: str, rms: bool = True) -> tuple[dict, dict]:
        out = ({}, {})
        for key, label in (("rms", "RMS"), ("minimum", "MINIMUM"), ("maximum", "MAXIMUM"),
                           ("mean", "MEAN"), ("std", "STANDARD DEVIATION")):
            if key == "rms" and not rms:
                continue
            for k, value in enumerate(vs(label, block)):
                out[k][key] = value
        return out

    num = {k: int(re.search(rf"{k} = (\d+)", text).group(1))
           for k in ("TOTAL NUMBER OF PIXELS", "IMAGE PIXELS", "TIE-POINTS")}
    conf_block = text.split("CONFIDENCE VALUES:")[1].split("X DISPLACEMENT:")[0]
    ci, cc = moments(conf_block, rms=False)
    for d, value in zip((ci, cc), vs("VARIANCE", conf_block), strict=True):
        d["variance"] = value * 100.0
    stats = {"stat_window": 5, "explore": (9, 19), "threshold": 95.0,
             "total_pixels": num["TOTAL NUMBER OF PIXELS"], "image_pixels": num["IMAGE PIXELS"],
             "candidate_pixels": num["TIE-POINTS"], "confidence": {"image": ci, "candidates": cc}}
    x_block, y_block = text.split("X DISPLACEMENT:")[1].split("Y DISPLACEMENT:")
    for axis, block in (("x", x_block), ("y", y_block)):
        pixels, metres = block.split("ORIGINAL VALUES:")
        image, cand = moments(pixels)
        image_m, cand_m = moments(metres)
        stats[axis] = {"on_limit": int(re.search(r"ON LIMIT\s*= (\d+)", pixels).group(1)),
                       "image": image, "candidates": cand, "image_m": image_m,
                       "candidates_m": cand_m}
    gx, gy = stats["x"]["candidates"]["mean"], stats["y"]["candidates"]["mean"]
    stats["global_displacement"] = {"dx": gx, "dy": gy}
    return stats


def _tokens(text: str) -> list[str]:
    return [" ".join(line.split()) for line in text.splitlines() if line.strip()]


def test_report_layout_reproduces_handbook_log():
    """format_report prints the handbook's log of section 4.6 (synthesis_no-ortho.sta.3) line by
    line, including its percentages and its VARIANCE convention (sigma^2 / 100)."""
    text = (FIXTURES / "synthesis_no-ortho.sta.3").read_text()
    stats = _handbook_stats(text)
    report = format_report(stats, title="synthesis_no-ortho.sta.3")
    ours = _tokens(report)
    assert ours[-1].startswith("GLOBAL DISPLACEMENT (dX, dY) = (-1.029730, 2.813514)")
    assert ours[:-1] == _tokens(text)


def test_moments_are_population_statistics_like_the_handbook():
    """The logs' STANDARD DEVIATION = sqrt(RMS^2 - MEAN^2) (population statistics), and so is
    ours; metres = pixels x 260 m; the SRTM synthesis' global displacement
    (-0.724138, 2.591379) px has a modulus of 699.569 m."""
    from napari_meris_ortho.analysis.disparity import _moments

    ours = _moments(np.random.default_rng(7).normal(0.4, 1.3, 50))
    assert math.sqrt(ours["rms"] ** 2 - ours["mean"] ** 2) == pytest.approx(ours["std"],
                                                                              rel=1e-12)
    assert ours["variance"] == pytest.approx(ours["std"] ** 2, rel=1e-12)
    stats = _handbook_stats((FIXTURES / "synthesis_no-ortho.sta.3").read_text())
    for axis in ("x", "y"):
        for sel in ("image", "candidates"):
            m = stats[axis][sel]
            assert math.sqrt(m["rms"] ** 2 - m["mean"] ** 2) == pytest.approx(m["std"], abs=6e-4)
            assert stats[axis][sel + "_m"]["rms"] == pytest.approx(m["rms"] * 260.0, rel=1e-6)
    c = stats["confidence"]["image"]
    assert c["variance"] == pytest.approx(c["std"] ** 2, rel=1e-6)
    assert math.hypot(-0.724138 * 260.0, 2.591379 * 260.0) == pytest.approx(699.569, abs=2e-3)

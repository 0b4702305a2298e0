"""Numbers as a user reads them: no negative zero in logs, reports, the status bar and help."""

from __future__ import annotations

import pytest

from analysis.test_disparity import textured
from napari_meris_ortho._napari.status import map_position
from napari_meris_ortho.analysis.disparity import disparity, format_report
from napari_meris_ortho.cli import build_parser
from napari_meris_ortho.display import fixed


@pytest.mark.parametrize(("value", "digits", "sign", "text"), [
    (-0.001, 2, False, "0.00"), (-0.004, 2, True, "+0.00"), (-0.006, 2, False, "-0.01"),
    (0.004, 2, True, "+0.00"), (-0.4, 0, False, "0"), (-0.6, 0, False, "-1"),
    (-0.0, 6, False, "0.000000"), (1.25, 1, True, "+1.2"), (float("nan"), 2, False, "nan"),
])
def test_a_value_that_rounds_to_zero_is_written_zero(value, digits, sign, text):
    assert fixed(value, digits, sign=sign) == text


def test_status_bar_near_the_origin_has_no_negative_zero():
    # world row 0.3 is northing -0.3 m: "N -0 m" without the fix
    assert map_position(0.3, -0.2, False, "EPSG:32632") == "E 0 m, N 0 m (EPSG:32632)"


def test_disparity_report_writes_a_vanishing_displacement_as_zero():
    a = textured(shape=(40, 50), seed=3)
    stats = disparity(a, a.copy(), pixel_size_m=(300.0, 300.0)).stats
    stats["global_displacement"].update(dx=-1e-9, dy=-2e-9, dx_m=-3e-7, dy_m=-6e-7,
                                        modulus_m=6.7e-7)
    text = format_report(stats)
    assert "GLOBAL DISPLACEMENT (dX, dY) = (0.000000, 0.000000) pixels = (0.000, 0.000) m" in text
    assert "-0.0" not in text


def test_tolerance_help_gives_our_default_beside_mersyns():
    sub = build_parser()._subparsers._group_actions[0].choices["map"]  # type: ignore[union-attr]
    action = next(a for a in sub._actions if a.dest == "tolerance")
    assert action.default == 0.01
    assert "default 0.01" in action.help and "MERSYN's 0.1" in action.help

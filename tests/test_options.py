"""Mode enums and OrthoOptions (options.py): plain strings accepted, one clear error otherwise,
kernel codes at the boundary."""

from __future__ import annotations

import pytest

from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.options import (
    PARALLAX_CHOICES,
    Elevation,
    Geolocation,
    MergeRule,
    OrthoOptions,
    Parallax,
    Sampling,
    SearchMethod,
    choices,
    parse,
)


def test_plain_strings_are_the_enum_values():
    assert parse(Elevation, "tiepoints") is Elevation.TIEPOINTS
    assert parse(Sampling, Sampling.BICUBIC) is Sampling.BICUBIC
    assert Elevation.DEM == "dem" and f"{MergeRule.MAX_NDVI}" == "max-ndvi"
    assert choices(Elevation) == ["none", "tiepoints", "dem"]
    assert choices(MergeRule) == ["min-radiance", "max-ndvi"]
    assert choices(SearchMethod) == ["primary", "handbook"]
    assert choices(PARALLAX_CHOICES) == ["handbook", "ellipsoid"]


@pytest.mark.parametrize(("enum", "value", "words"), [
    (Elevation, "srtm", "unknown elevation source 'srtm': choose none, tiepoints or dem"),
    (Sampling, "cubic", "unknown sampling method 'cubic': choose nearest, bilinear or bicubic"),
    (Parallax, 3, "unknown parallax model 3: choose handbook, ellipsoid or ellipsoid_h"),
    (MergeRule, None, "unknown algorithm None: choose min-radiance or max-ndvi"),
])
def test_bad_values_name_the_mode_and_the_choices(enum, value, words):
    with pytest.raises(OptionsError) as info:
        parse(enum, value)
    assert str(info.value) == words


def test_kernel_codes():
    assert [p.code for p in Parallax] == [0, 1, 2]
    assert [g.code for g in Geolocation] == [0, 1, 2]
    assert [s.taps for s in Sampling] == [1, 2, 4]
    assert Sampling.BICUBIC.margin == (1, 2) and Sampling.NEAREST.margin == (0, 1)
    assert Geolocation.default_for(Parallax.HANDBOOK) is Geolocation.BILINEAR
    assert Geolocation.default_for(Parallax.ELLIPSOID) is Geolocation.ECEF


def test_ortho_options_parse_checks_in_mersyn_order():
    o = OrthoOptions.parse(elevation="tiepoints", sampling="bilinear", parallax="ellipsoid",
                           method="handbook", tolerance=0.1, bands=[7, 5, 7, 2])
    assert o == OrthoOptions(Elevation.TIEPOINTS, Sampling.BILINEAR, Parallax.ELLIPSOID,
                             Geolocation.ECEF, SearchMethod.HANDBOOK, 0.1, (2, 5, 7), False)
    assert OrthoOptions.parse().bands == tuple(range(1, 16))
    with pytest.raises(OptionsError, match="DEMs are only used with elevation 'dem'"):
        OrthoOptions.parse(elevation="none", n_dems=1)
    for bad in (0, -1.0, float("nan"), "0.1"):
        with pytest.raises(OptionsError, match="tolerance"):
            OrthoOptions.parse(tolerance=bad)
    with pytest.raises(OptionsError, match="bands must be 1..15"):
        OrthoOptions.parse(bands=[0, 3])
    with pytest.raises(OptionsError, match="bands must be 1..15"):
        OrthoOptions.parse(bands=[])

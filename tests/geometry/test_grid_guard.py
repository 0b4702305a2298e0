"""Output grids: the size guard (pixel count against a limit from the available memory or
``max_pixels``, a suggested pixel size) and the CRSs an output grid accepts."""

from __future__ import annotations

import math

import pytest

from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.geometry.grid import (
    MEMORY_SHARE,
    OutputGrid,
    available_memory_bytes,
    check_grid_size,
    output_crs,
    pixel_limit,
)

LOCAL_CS = ('LOCAL_CS["site",LOCAL_DATUM["d",0],UNIT["metre",1],AXIS["X",EAST],'
            'AXIS["Y",NORTH]]')  # fmt: skip


def test_limit_from_available_memory():
    avail = available_memory_bytes()
    assert 1 << 24 < avail < 1 << 50
    assert pixel_limit(100) == pytest.approx(MEMORY_SHARE * avail / 100, rel=0.05)
    assert pixel_limit(100, max_pixels=123) == 123
    assert pixel_limit(8, budget_bytes=8000) == 1000


def test_world_at_a_thousandth_of_a_degree_is_refused_with_a_pixel_size_that_fits():
    with pytest.raises(OptionsError) as info:
        check_grid_size(360000, 180000, (0.001, 0.001), 136, max_pixels=10**8)
    message = str(info.value)
    assert "output grid of 360000 x 180000 pixels (6.48e+10 pixels, about 8.0 TiB)" in message
    assert "limit of 1e+08 pixels (--max-pixels)" in message
    suggested = float(message.split("pixel size of at least ")[1].split()[0])
    # the suggestion fits the limit, and is not needlessly coarse
    assert 360 / suggested * 180 / suggested <= 1e8
    assert suggested < 0.001 * math.sqrt(6.48e10 / 1e8) * 1.12


def test_grid_within_the_limit_passes():
    check_grid_size(1000, 1000, (1.0, 1.0), 136, max_pixels=10**6)
    with pytest.raises(OptionsError, match="free space in /x"):
        check_grid_size(1000, 1001, (1.0, 1.0), 4, budget_bytes=4 * 10**6,
                        budget_what="the free space in /x")  # fmt: skip


@pytest.mark.parametrize(
    ("crs", "fragment"),
    [
        ("EPSG:4978", "is geocentric"),
        ("EPSG:4979", "not a 2-D projected or geographic CRS"),
        ("EPSG:7415", "not a 2-D projected or geographic CRS"),  # compound: RD New + NAP
        (LOCAL_CS, "not a 2-D projected or geographic CRS"),
        ("IAU_2015:49900", "is not on the Earth (ellipsoid semi-major axis 3.39619e+06 m"),
        ("+proj=longlat +a=1 +b=1", "is not on the Earth (ellipsoid semi-major axis 1 m"),
        ("+proj=longlat +a=6378137 +rf=3", "inverse flattening 3"),
        ("not a crs", "unknown CRS"),
    ],
)
def test_crs_that_cannot_hold_an_output_grid(crs, fragment):
    with pytest.raises(OptionsError) as info:
        output_crs(crs)
    assert fragment in str(info.value)
    with pytest.raises(OptionsError):
        OutputGrid(crs, 0.0, 1.0, 1.0, 1.0, 10, 10)


@pytest.mark.parametrize(
    "crs", ["EPSG:4326", "OGC:CRS84", "EPSG:32633", "EPSG:3035", "EPSG:3857", "EPSG:27700",
            "+proj=longlat +R=6370997", "ESRI:54009"],
)  # fmt: skip
def test_earth_crs_are_accepted(crs):
    assert output_crs(crs).is_projected or output_crs(crs).is_geographic

"""Segment boundary (section 3.1, figs. 17-20) and scanline spans."""

from __future__ import annotations

import numpy as np
import pyproj
import pytest
from matplotlib.path import Path as MplPath
from scipy.ndimage import binary_dilation

from napari_meris_ortho.engine.boundary import Boundary, row_spans, segment_boundary
from napari_meris_ortho.geometry.grid import OutputGrid, default_grid


def shoelace(x, y):
    return 0.5 * abs(np.dot(x[:-1], y[1:]) - np.dot(x[1:], y[:-1]))


def tilted_footprint(lon0=12.0, lat0=47.5, n_lines=30, n_cols=36, azimuth=-167.0):
    geod = pyproj.Geod(ellps="WGS84")
    lat = np.empty((n_lines, n_cols))
    lon = np.empty((n_lines, n_cols))
    for i in range(n_lines):
        clon, clat, _ = geod.fwd(lon0, lat0, azimuth, i * 64 * 300.0)
        for k in range(n_cols):
            d = (k - (n_cols - 1) / 2) * 64 * 260.0
            lon[i, k], lat[i, k], _ = geod.fwd(clon, clat, azimuth + 90.0, d)
    return lat, lon


def test_boundary_follows_mersyn_vertex_order():
    """Appendix C: first column top->bottom, last line left->right, last column bottom->top,
    first line right->left; 2 (lines - 1 + columns - 1) + 1 vertices, closed."""
    lines, cols = 4, 5
    lat = np.arange(lines)[:, None] * -1.0 + np.zeros(cols) + 50.0
    lon = np.arange(cols)[None, :] * 1.0 + np.zeros((lines, 1))
    b = segment_boundary(lat, lon)
    assert b.lon.size == 2 * (lines - 1 + cols - 1) + 1
    assert (b.lon[0], b.lat[0]) == (b.lon[-1], b.lat[-1])
    expected = ([(0, 0), (0, 1), (0, 2), (0, 3), (1, 3), (2, 3), (3, 3), (4, 3), (4, 2),
                 (4, 1), (4, 0), (3, 0), (2, 0), (1, 0), (0, 0)])
    got = [(int(x), int(round(50 - y))) for x, y in zip(b.lon, b.lat, strict=True)]
    assert got == expected


def test_boundary_unwraps_longitude_across_antimeridian():
    lat = np.array([[10.0, 10.0, 10.0], [9.0, 9.0, 9.0]])
    lon = np.array([[179.0, -180.0, -179.0], [179.0, 180.0, -179.0]])
    b = segment_boundary(lat, lon)
    assert b.lon.min() == 179.0 and b.lon.max() == 181.0
    assert np.all(np.abs(np.diff(b.lon)) <= 1.0)
    assert b.crosses_antimeridian
    pieces = b.split_antimeridian()
    assert len(pieces) == 2
    for x, y in pieces:
        assert x.min() >= -180.0 and x.max() <= 180.0
        assert (x[0], y[0]) == (x[-1], y[-1])
    total = sum(shoelace(x, y) for x, y in pieces)
    assert total == pytest.approx(shoelace(b.lon, b.lat), rel=1e-12)
    assert sorted(round(shoelace(x, y), 9) for x, y in pieces) == [1.0, 1.0]


def test_spans_of_a_rectangle_are_the_pixel_centres_inside():
    b = Boundary(np.array([10.0, 12.0, 12.0, 10.0, 10.0]), np.array([46.0, 46.0, 45.0, 45.0, 46.0]))
    g = OutputGrid("EPSG:4326", 9.0, 47.0, 0.25, 0.25, 20, 12)
    s = row_spans(b, g)
    # rows with centres in (45, 46): y = 47 - (i + .5)/4 -> i = 4..7; columns x in [10, 12)
    # -> centres 9 + (j + .5)/4 >= 10 -> j >= 3.5 -> 4..11
    for i in range(12):
        assert s.spans(i) == ([(4, 12)] if 4 <= i <= 7 else [])
    assert s.count == 4 * 8
    assert s.mask().sum() == 32 and s.mask()[4:8, 4:12].all()
    sub = row_spans(b, g, 5, 7)
    assert sub.n_rows == 2 and sub.spans(5) == [(4, 12)]


@pytest.mark.parametrize("crs", ["EPSG:4326", "EPSG:32633", "EPSG:3035"])
def test_spans_match_point_in_polygon_in_output_crs(crs):
    lat, lon = tilted_footprint()
    b = segment_boundary(lat, lon)
    g = default_grid(b, 2600.0 if crs != "EPSG:4326" else 2600.0, crs)
    mask = row_spans(b, g).mask()
    (x, y), = b.polygons(g.crs)
    jj, ii = np.meshgrid(np.arange(g.width), np.arange(g.height))
    px, py = g.xy(ii, jj)
    inside = MplPath(np.c_[x, y]).contains_points(np.c_[px.ravel(), py.ravel()]).reshape(g.shape)
    assert 0.4 * mask.size < mask.sum()
    assert np.sum(mask != inside) <= 2  # only centres exactly on an edge may differ


def test_spans_across_antimeridian_geographic_both_extents():
    lat, lon = tilted_footprint(lon0=179.0, lat0=-30.0, n_lines=10)
    b = segment_boundary(lat, lon)
    assert b.crosses_antimeridian
    d = 0.02
    g_wrapped = default_grid(b, crs="EPSG:4326", pixel_size=d)
    assert g_wrapped.x0 < 180.0 < g_wrapped.x0 + g_wrapped.width * d
    n_wrapped = row_spans(b, g_wrapped).count
    # the same area on a grid in [-180, 180): both pieces
    g = OutputGrid.from_extent("EPSG:4326", (-180.0, g_wrapped.y0),
                               (180.0, g_wrapped.y0 - g_wrapped.height * d), d)
    s = row_spans(b, g)
    m = s.mask()
    assert m[:, : g.width // 2].any() and m[:, g.width // 2:].any()
    assert abs(s.count - n_wrapped) <= 0.002 * n_wrapped
    # the middle of the world is not inside
    assert not m[:, g.width // 4: 3 * g.width // 4].any()


def test_spans_across_antimeridian_plate_carree_split():
    """Section 3.1, fig. 20: a projection bounded at +-180 needs two polygons."""
    lat, lon = tilted_footprint(lon0=179.0, lat0=-30.0, n_lines=10)
    b = segment_boundary(lat, lon)
    polys = b.polygons("EPSG:32662")
    assert len(polys) == 2
    half = 20037508.342789244
    g = OutputGrid.from_extent("EPSG:32662", (-half, -2.0e6), (half, -5.0e6), 5000.0)
    s = row_spans(b, g)
    m = s.mask()
    assert m[:, :10].any() and m[:, -10:].any()
    area = sum(shoelace(x, y) for x, y in polys)
    assert s.count * 5000.0**2 == pytest.approx(area, rel=0.02)


def test_margin_dilates_by_whole_pixels():
    lat, lon = tilted_footprint(n_lines=12)
    b = segment_boundary(lat, lon)
    g = default_grid(b, 5000.0, "EPSG:32633")
    base = row_spans(b, g).mask()
    grown = row_spans(b, g, margin=2).mask()
    expected = binary_dilation(base, structure=np.ones((5, 5), bool))
    np.testing.assert_array_equal(grown, expected)
    part = row_spans(b, g, 10, 20, margin=2).mask()
    np.testing.assert_array_equal(part, expected[10:20])


def test_intersects():
    lat, lon = tilted_footprint(n_lines=12)
    b = segment_boundary(lat, lon)
    near = OutputGrid.from_extent("EPSG:4326", (10.0, 48.0), (14.0, 44.0), 0.05)
    far = OutputGrid.from_extent("EPSG:4326", (-80.0, 10.0), (-70.0, 0.0), 0.05)
    assert b.intersects(near)
    assert not b.intersects(far)


@pytest.mark.parametrize("margin", [1, 3, 6, 7, 11])
def test_margin_dilation_matches_a_square_structuring_element(margin):
    lat, lon = tilted_footprint(n_lines=12)
    b = segment_boundary(lat, lon)
    g = default_grid(b, 9000.0, "EPSG:32633")
    base = row_spans(b, g).mask()
    grown = row_spans(b, g, margin=margin).mask()
    side = 2 * margin + 1
    expected = binary_dilation(np.pad(base, margin), structure=np.ones((side, side), bool))
    np.testing.assert_array_equal(grown, expected[margin:-margin, margin:-margin])


def test_huge_margin_is_bounded():
    """A margin of 200 000 rows (a 0.1 m pixel) costs log2(margin) passes, not margin x rows:
    the dilated spans of 30 rows cover every column the boundary can reach."""
    lat, lon = tilted_footprint(n_lines=12)
    b = segment_boundary(lat, lon)
    g = default_grid(b, 5000.0, "EPSG:32633")
    spans = row_spans(b, g, 0, 30, margin=200_000)
    assert spans.n_rows == 30 and spans.count == 30 * g.width


@pytest.mark.parametrize(("crs", "size"), [("EPSG:32633", 260.0), ("EPSG:3035", 1040.0),
                                           ("EPSG:32633", 300.5)])
def test_projected_default_origin_is_a_multiple_of_the_pixel(crs, size):
    """A projected default grid starts on a multiple of its pixel size (the grids of
    different products line up) and still holds the whole segment boundary."""
    lat, lon = tilted_footprint(n_lines=12)
    b = segment_boundary(lat, lon)
    g = default_grid(b, size, crs)
    assert g.x0 % size == 0.0 and g.y0 % size == 0.0
    (x, y), = b.polygons(g.crs)
    assert g.x0 <= x.min() < g.x0 + size and g.y0 - size < y.max() <= g.y0
    assert x.max() <= g.x0 + g.width * size and y.min() >= g.y0 - g.height * size
    shifted = default_grid(segment_boundary(lat + 0.01, lon + 0.013), size, crs)
    assert (shifted.x0 - g.x0) % size == 0.0 and (shifted.y0 - g.y0) % size == 0.0


def test_geographic_default_origin_is_the_boundary_corner():
    """EPSG:4326 keeps MERSYN's origin: the corner of the boundary's bounding rectangle."""
    lat, lon = tilted_footprint(n_lines=12)
    b = segment_boundary(lat, lon)
    g = default_grid(b, 260.0, "EPSG:4326")
    (x, y), = b.polygons(g.crs)
    assert (g.x0, g.y0) == (float(x.min()), float(y.max()))

"""orthorectify(): the glue from a product and DEMs to mapped bands (sections 3.1-3.4)."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho import orthorectify
from napari_meris_ortho.engine.location import direct_location
from napari_meris_ortho.errors import DemError, N1FormatError, OptionsError
from napari_meris_ortho.geometry.grid import OutputGrid
from napari_meris_ortho.geometry.tiepoints import TiePointGrid
from napari_meris_ortho.products.n1 import read_product
from ortho_samples import COPERNICUS_SCENE, make_dem, make_product, terrain


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("ortho")
    # west part of a swath: view zenith 29..35 deg, so the parallax is several pixels
    prod = make_product(d / "west.N1", height=200, width=513, lon0=17.0, nadir_col=-1700.0)
    tp = read_product(prod).tie_points
    w, e = tp["longitude"].min() - 0.3, tp["longitude"].max() + 0.3
    s, n = tp["latitude"].min() - 0.3, tp["latitude"].max() + 0.3
    dem = make_dem(d / "dem.tif", w, s, e, n)
    part = make_dem(d / "part.tif", w, 0.5 * (s + n), e, n)  # the northern part only
    return d, prod, dem, part


@pytest.fixture(scope="module")
def dem_run(files):
    _, prod, dem, _ = files
    return orthorectify(prod, dems=[dem], diagnostics=True)


def _pixel_residual(tp, grid, diag, heights):
    ok = diag["iterations"] >= 0
    rows, cols = np.nonzero(ok)
    lon_t, lat_t = grid.lonlat()
    lon, lat = direct_location(tp, diag["line"][ok].astype(float), diag["col"][ok].astype(float),
                               heights)
    dx = ((lon - lon_t[rows, cols] + 180) % 360 - 180) * np.cos(np.radians(lat)) * 111320 / 260
    dy = (lat - lat_t[rows, cols]) * 111320 / 260
    return np.hypot(dx, dy)


def test_dem_mode_finds_consistent_antecedents(files, dem_run):
    _, prod, _, _ = files
    r = dem_run
    tp = TiePointGrid.from_product(read_product(prod))
    ok = r.valid
    d = r.diagnostics
    assert ok.sum() > 0.6 * 200 * 513 * (260 / 260) * 0.9
    # the band holding the product line/column shows the nearest antecedent (scaled radiance)
    f1 = read_product(prod).scaling.radiance[0]
    f2 = read_product(prod).scaling.radiance[1]
    assert np.array_equal(np.round(r.bands[1][ok] / f1), np.floor(d["line"][ok] + 0.5))
    assert np.array_equal(np.round(r.bands[2][ok] / f2), np.floor(d["col"][ok] + 0.5))
    assert np.array_equal(r.flags[ok], ((np.round(r.bands[1][ok] / f1) + np.round(
        r.bands[2][ok] / f2)) % 256).astype(np.uint8))
    assert np.all(r.bands[1][~ok] == 0) and np.all(r.flags[~ok] == 0)
    # the direct model at the antecedent with the DEM height gives the output point (0.01 px)
    res = _pixel_residual(tp, r.grid, d, d["elevation"][ok].astype(float))
    assert res.max() < 0.01
    lon, lat = r.grid.lonlat()
    assert np.max(np.abs(d["elevation"][ok] - terrain(lon[ok], lat[ok]))) < 5.0
    assert np.all(d["elevation_source"][ok] == 0)
    assert r.stats.elevation_sources["tiepoints"] == 0
    hist = r.stats.iterations_histogram
    assert len(hist) == 11 and sum(hist) == ok.sum() and sum(hist[4:]) == 0


def test_precompute_once_apply_to_any_band(files, dem_run):
    """Antecedents once, then counts (fused gather of all bands), radiances, flags."""
    from napari_meris_ortho import precompute

    _, prod, dem, _ = files
    product = read_product(prod)
    ante = precompute(prod, dems=[dem])
    np.testing.assert_array_equal(ante.line, dem_run.diagnostics["line"])
    counts = ante.counts([2, 1, 9])
    assert counts.dtype == np.uint16 and counts.shape == (3, *ante.grid.shape)
    ok = ante.valid
    line = np.floor(ante.line[ok] + 0.5).astype(int)
    col = np.floor(ante.col[ok] + 0.5).astype(int)
    for k, b in enumerate((2, 1, 9)):  # nearest: exactly the product's counts
        np.testing.assert_array_equal(counts[k][ok], product.counts(b)[line, col])
        assert not counts[k][~ok].any()
        np.testing.assert_array_equal(ante.radiance([b])[b], dem_run.bands[b])
    flags = ante.flags()
    assert flags.dtype == np.uint8
    np.testing.assert_array_equal(flags, dem_run.flags)
    np.testing.assert_array_equal(flags[ok], product.flags[line, col])
    # bilinear: counts are the interpolated radiances / sf_rad within half a count
    bil = precompute(prod, dems=[dem], sampling="bilinear")
    rad = bil.radiance([1])[1]
    c = bil.counts([1])[0]
    ok = bil.valid
    sf = product.scaling.radiance[0]
    assert np.max(np.abs(c[ok] * sf - rad[ok])) <= 0.5 * sf + 1e-6  # float32 radiances
    assert np.any(np.abs(rad[ok] / sf - np.round(rad[ok] / sf)) > 0.1)  # really interpolated
    assert bil.stats.seconds["resample"] > 0 and bil.window == tuple(
        bil.stats.product_lines_read) and bil.columns == tuple(bil.stats.product_columns_read)


def test_parallax_shift_matches_the_antecedent_move(files, dem_run):
    _, prod, _, _ = files
    none = orthorectify(prod, elevation="none", diagnostics=True)
    both = none.valid & dem_run.valid
    move_px = dem_run.diagnostics["col"][both] - none.diagnostics["col"][both]
    # terrain at 300..2700 m seen at ~30 deg moves the antecedent by several pixels
    assert 0.5 < np.abs(move_px).mean() < 15.0 and np.abs(move_px).max() > 3.0
    east = dem_run.diagnostics["shift_east_m"][both]
    assert np.all(east > 0)  # seen from the west, towards the satellite
    assert np.all(none.diagnostics["elevation"][none.valid] == 0)
    assert np.all(none.diagnostics["elevation_source"][none.valid] == -2)
    assert none.stats.orthorectification is False


def test_handbook_search_gives_the_same_antecedents(files):
    _, prod, dem, _ = files
    a = orthorectify(prod, dems=[dem], bands=[1], tolerance=1e-4, diagnostics=True)
    b = orthorectify(prod, dems=[dem], bands=[1], tolerance=1e-4, diagnostics=True,
                     method="handbook")
    both = a.valid & b.valid
    # MERSYN drops terrain points whose zero-height position is outside the swath (its first
    # inverse fails); the primary grid extends the edge facets and keeps them
    assert both.sum() >= 0.999 * b.valid.sum()
    assert b.valid.sum() < a.valid.sum() < 1.05 * b.valid.sum()
    assert np.max(np.abs(a.diagnostics["line"][both] - b.diagnostics["line"][both])) < 1e-3
    assert np.max(np.abs(a.diagnostics["col"][both] - b.diagnostics["col"][both])) < 1e-3
    fs = b.stats.facet_search
    assert fs["same"] > 0.8 * (fs["same"] + fs["4-connex"] + fs["8-connex"] + fs["all"])


def test_dem_list_falls_back_to_tie_points(files):
    _, prod, _, part = files
    r = orthorectify(prod, dems=[part], bands=[1], diagnostics=True)
    src = r.diagnostics["elevation_source"][r.valid]
    assert 0.1 < np.mean(src == 0) < 0.9
    assert set(np.unique(src)) == {-1, 0}
    n = r.stats.elevation_sources
    assert n["tiepoints"] == np.sum(src == -1) and n["0:part.tif"] == np.sum(src == 0)
    tp = TiePointGrid.from_product(read_product(prod))
    d = r.diagnostics
    ok = r.valid
    heights = np.where(d["elevation_source"][ok] == 0, d["elevation"][ok], np.nan)
    heights = np.where(np.isnan(heights), np.nan, heights)
    # tie-point points: the direct model with tie-point heights (None) must match as well
    res_t = _pixel_residual(tp, r.grid, {**d, "iterations": np.where(
        d["elevation_source"] == -1, d["iterations"], -1)}, None)
    assert res_t.max() < 0.01


def test_tie_point_mode_and_ellipsoid(files):
    _, prod, _, _ = files
    t = orthorectify(prod, elevation="tiepoints", bands=[2], diagnostics=True)
    assert np.all(t.diagnostics["elevation_source"][t.valid] == -1)
    h = orthorectify(prod, elevation="tiepoints", bands=[2], diagnostics=True,
                     parallax="handbook", tolerance=1e-4)
    e = orthorectify(prod, elevation="tiepoints", bands=[2], diagnostics=True,
                     parallax="ellipsoid", tolerance=1e-4)
    both = h.valid & e.valid
    diff = np.abs(h.diagnostics["col"][both] - e.diagnostics["col"][both])
    # the WGS84 radii move the parallax by a fraction of a percent: > 0, < 0.1 px
    assert 1e-4 < diff.max() < 0.1


def test_bilinear_sampling_interpolates_the_line_band(files, dem_run):
    _, prod, dem, _ = files
    r = orthorectify(prod, dems=[dem], bands=[1], sampling="bilinear", diagnostics=True)
    f1 = read_product(prod).scaling.radiance[0]
    line = r.diagnostics["line"]
    inner = r.valid & (line > 1) & (line < 198)
    assert np.max(np.abs(r.bands[1][inner] / f1 - line[inner])) < 2e-3


def test_explicit_grid_and_projected_crs(files):
    _, prod, dem, _ = files
    import pyproj

    tp = read_product(prod).tie_points
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32633", always_xy=True).transform(
        tp["longitude"][1, 4], tp["latitude"][1, 4])
    x, y = round(x, -3), round(y, -3)
    grid = OutputGrid.from_extent("EPSG:32633", (x - 20000, y + 15000), (x + 20000, y - 15000),
                                  300.0)
    r = orthorectify(prod, grid=grid, dems=[dem], bands=[1, 2])
    assert r.bands[1].shape == (100, 134) and r.grid is grid
    assert r.valid.mean() > 0.3
    assert sorted(r.bands) == [1, 2]


def test_antimeridian_product_has_no_holes(tmp_path):
    prod = make_product(tmp_path / "am.N1", height=150, width=321, lon0=-179.6, nadir_col=160.0)
    r = orthorectify(prod, elevation="tiepoints", bands=[1, 2], diagnostics=True)
    lon, _ = r.grid.lonlat()
    assert np.nanmin(lon) < -179.5 and np.nanmax(lon) > 179.5
    # every product pixel is reached by some output pixel (no seam at 180 deg)
    f1 = read_product(prod).scaling.radiance[0]
    f2 = read_product(prod).scaling.radiance[1]
    hit = np.zeros((150, 321), bool)
    hit[np.round(r.bands[1][r.valid] / f1).astype(int),
        np.round(r.bands[2][r.valid] / f2).astype(int)] = True
    assert hit[1:-1, 1:-1].mean() > 0.95
    # and the output columns on both sides of 180 deg are mapped
    near = np.abs(np.abs(lon) - 180.0) < 0.01
    assert r.valid[near].mean() > 0.3


@pytest.fixture(scope="module")
def wide_run(files, dem_run):
    """dem_run's grid widened by 30 pixels on each side: terrain points beyond the boundary."""
    _, prod, dem, _ = files
    g = dem_run.grid
    wide = OutputGrid(g.crs, g.x0 - 30 * g.dx, g.y0 + 30 * g.dy, g.dx, g.dy, g.width + 60,
                      g.height + 60)
    return orthorectify(prod, grid=wide, dems=[dem], bands=[1, 2], diagnostics=True)


@pytest.mark.parametrize("sampling", ["nearest", "bicubic"])
def test_tile_reads_only_the_antecedent_lines(files, wide_run, sampling):
    """A tile reads min..max antecedent line and column plus the kernel margin, and samples
    it right."""
    _, prod, dem, _ = files
    tile = wide_run.grid.window(150, 190, 200, 600)
    r = orthorectify(prod, grid=tile, dems=[dem], bands=[1, 2], sampling=sampling,
                     diagnostics=True)
    f1, f2 = read_product(prod).scaling.radiance[:2]
    ok = r.valid
    line, col = r.diagnostics["line"][ok], r.diagnostics["col"][ok]
    pad = 1 if sampling == "bicubic" else 0
    first, stop = r.stats.product_lines_read
    assert first == max(int(np.floor(line.min())) - pad, 0) > 0
    assert stop == int(np.floor(line.max())) + 2 + pad < 200
    assert stop - first <= 100  # at most half of the 200 product lines
    c_first, c_stop = r.stats.product_columns_read
    assert c_first == max(int(np.floor(col.min())) - pad, 0) > 0
    assert c_stop == int(np.floor(col.max())) + 2 + pad < 513
    assert c_stop - c_first <= 450  # fewer than the 513 columns
    if sampling == "nearest":  # band 1 counts the product line, band 2 the column
        np.testing.assert_array_equal(np.round(r.bands[1][ok] / f1), np.floor(line + 0.5))
        np.testing.assert_array_equal(np.round(r.bands[2][ok] / f2), np.floor(col + 0.5))
        np.testing.assert_array_equal(r.flags, wide_run.flags[150:190, 200:600])
    else:  # Keys cubic reproduces the linear line/column ramps
        inner = (col > 1) & (col < 511)
        assert np.max(np.abs(r.bands[1][ok] / f1 - line)) < 2e-3
        assert np.max(np.abs(r.bands[2][ok][inner] / f2 - col[inner])) < 2e-3


def test_allow_empty_keeps_terrain_points_beyond_the_boundary(files, wide_run):
    """East of the zero-height boundary (no pixel centre inside it) terrain points shifted
    towards the satellite are still mapped with allow_empty; a far tile is all background."""
    _, prod, dem, _ = files
    wide = wide_run.grid
    east = wide.window(0, wide.height, 885, wide.width)  # the boundary ends at column 884
    with pytest.raises(OptionsError, match="misses"):
        orthorectify(prod, grid=east, dems=[dem], bands=[1])
    r = orthorectify(prod, grid=east, dems=[dem], bands=[1, 2], allow_empty=True,
                     diagnostics=True)
    assert r.stats.points_in_boundary == 0
    assert r.valid.sum() == wide_run.valid[:, 885:].sum() > 100
    np.testing.assert_array_equal(r.valid, wide_run.valid[:, 885:])
    np.testing.assert_array_equal(r.bands[1], wide_run.bands[1][:, 885:])
    assert np.nanmin(r.diagnostics["elevation"]) > 500.0  # mountains seen obliquely
    far = wide.window(0, 20, 0, 20)
    e = orthorectify(prod, grid=far, dems=[dem], bands=[1, 2], allow_empty=True,
                     diagnostics=True)
    assert e.valid.sum() == 0 and e.bands[1].max() == 0.0 and e.bands[2].shape == (20, 20)
    assert e.stats.processed_points == 0 and e.stats.product_lines_read == [0, 0]
    assert e.stats.product_columns_read == [0, 0]
    assert e.stats.elevation_sources == {"tiepoints": 0, "0:dem.tif": 0}
    assert (e.diagnostics["iterations"] == -1).all()


def test_bad_inputs(files, tmp_path):
    d, prod, dem, _ = files
    with pytest.raises(N1FormatError):
        orthorectify(tmp_path / "missing.N1")
    foreign = tmp_path / "foreign.N1"
    foreign.write_bytes(b"hello, I am not an ENVISAT product" * 100)
    with pytest.raises(N1FormatError):
        orthorectify(foreign)
    with pytest.raises(DemError):
        orthorectify(prod, dems=[tmp_path / "nodem.tif"])
    bad_dem = tmp_path / "bad.tif"
    bad_dem.write_bytes(b"garbage" * 10)
    with pytest.raises(DemError):
        orthorectify(prod, dems=[bad_dem])
    with pytest.raises(OptionsError, match="DEMs"):
        orthorectify(prod, dems=[dem], elevation="none")
    far = OutputGrid.from_extent("EPSG:4326", (100.0, 10.0), (101.0, 9.0), 0.01)
    with pytest.raises(OptionsError, match="misses"):
        orthorectify(prod, grid=far)
    with pytest.raises(OptionsError, match="tolerance"):
        orthorectify(prod, tolerance=0.0)
    with pytest.raises(OptionsError, match="CRS"):
        orthorectify(prod, crs="EPSG:999999")
    with pytest.raises(OptionsError, match="pixel size"):
        orthorectify(prod, pixel_size=-1.0)
    with pytest.raises(OptionsError, match="bands"):
        orthorectify(prod, bands=[16])
    with pytest.raises(OptionsError, match="elevation"):
        orthorectify(prod, elevation="srtm")


def _truth_error(scene, r, stride=7):
    ok = r.valid.copy()
    ok.ravel()[np.arange(ok.size) % stride != 0] = False  # every 7th point: the truth is slow
    lon, lat = r.grid.lonlat()
    h = scene.dem_height(lon[ok], lat[ok])
    tl, tc = scene.true_antecedent(lon[ok], lat[ok], h)
    return np.hypot(r.diagnostics["line"][ok] - tl, r.diagnostics["col"][ok] - tc)


@pytest.fixture(scope="module")
def fr_small():
    from napari_meris_ortho.simulate.scene import generate_scene

    return generate_scene("fr-small")


@pytest.mark.slow
def test_accuracy_against_the_simulator_truth(fr_small):
    """fr-small (20-30 deg view zenith over a 4.5 km range): DEM mode within 0.05 px RMS."""
    s = fr_small
    dem = s.dem_paths["geotiff"]
    e = _truth_error(s, orthorectify(s.product_path, dems=[dem], parallax="ellipsoid",
                                     bands=[7], diagnostics=True))
    assert np.sqrt(np.mean(e ** 2)) <= 0.05 and e.max() <= 0.25
    e_hb = _truth_error(s, orthorectify(s.product_path, dems=[dem], bands=[7],
                                        diagnostics=True))
    assert np.sqrt(np.mean(e_hb ** 2)) <= 0.05 and e_hb.max() <= 0.25
    # the ellipsoid model (WGS84 radii + ecef interpolation) gains over the handbook's
    assert np.sqrt(np.mean(e ** 2)) < 0.5 * np.sqrt(np.mean(e_hb ** 2))
    e_none = _truth_error(s, orthorectify(s.product_path, elevation="none", bands=[7],
                                          diagnostics=True))
    assert np.sqrt(np.mean(e_none ** 2)) > 1.0 and e_none.max() > 5.0


@pytest.mark.slow
def test_a_grid_far_larger_than_the_segment_searches_only_the_segment(fr_small):
    """A fixed extent 5 x 5 times the segment's own UTM grid (a regional grid for time series):
    the same antecedents inside (within the truth tolerance), nothing searched in the rows and
    columns the segment does not reach (the primary-grid nodes searched in vain stay within a
    few times those of the own grid, not every node of the whole rows: 60 x)."""
    s = fr_small
    dem = s.dem_paths["geotiff"]
    own = orthorectify(s.product_path, dems=[dem], crs="EPSG:32633", bands=[7],
                       diagnostics=True)
    g = own.grid
    big = OutputGrid.from_extent(
        "EPSG:32633", (g.x0 - 2 * g.width * g.dx, g.y0 + 2 * g.height * g.dy),
        (g.x0 + 3 * g.width * g.dx, g.y0 - 3 * g.height * g.dy), g.dx)
    r = orthorectify(s.product_path, dems=[dem], grid=big, bands=[7], diagnostics=True)
    window = (slice(2 * g.height, 3 * g.height), slice(2 * g.width, 3 * g.width))
    assert np.mean(r.valid[window] == own.valid) > 0.9999
    assert r.valid.sum() - r.valid[window].sum() < 100  # terrain points past the own grid
    e = _truth_error(s, r)
    assert np.sqrt(np.mean(e ** 2)) <= 0.05 and e.max() <= 0.25
    assert r.stats.facet_search["not found"] <= 3 * own.stats.facet_search["not found"]


@pytest.mark.parametrize("sampling", ["nearest", "bicubic"])
def test_a_grid_far_larger_than_the_segment_samples_only_the_segment(fr_small, sampling):
    """On a grid 5 x 5 times the segment's, the search keeps the antecedents of its area only,
    and the bands, flags and saturation are sampled over the extent of the antecedents only
    (its points, not the grid's, in the nearest index), equal, bit for bit, to the resampling
    of every point of the grid, 0 around."""
    from napari_meris_ortho.engine.resample import resample_bands
    from napari_meris_ortho.ortho import precompute

    s = fr_small
    g = OutputGrid.from_extent("EPSG:32633", (440_000.0, 5_200_000.0),
                               (560_000.0, 5_080_000.0), 300.0)
    big = OutputGrid.from_extent(
        "EPSG:32633", (g.x0 - 2 * g.width * g.dx, g.y0 + 2 * g.height * g.dy),
        (g.x0 + 3 * g.width * g.dx, g.y0 - 3 * g.height * g.dy), g.dx)
    bands = [2, 7, 13]
    ante = precompute(s.product_path, big, elevation="tiepoints", sampling=sampling,
                      bands=bands)
    r0, r1, c0, c1 = ante._extent()
    rows, cols = np.nonzero(np.isfinite(ante.line))
    a0, a1, b0, b1 = ante.area
    # the rows of the finite antecedents; their columns, or the area's when over half of them
    assert (r0, r1) == (rows.min(), rows.max() + 1)
    finite = (cols.min(), cols.max() + 1)
    assert (c0, c1) == (finite if 2 * (finite[1] - finite[0]) <= b1 - b0 else (b0, b1))
    assert (r1 - r0) * (c1 - c0) < big.width * big.height / 10
    # the search kept only its area (rows, columns the segment reaches), inside: NaN around
    assert ante.area_line.shape == (a1 - a0, b1 - b0) and a0 <= r0 < r1 <= a1
    assert ante.area_line.size < big.width * big.height / 5 and b0 <= c0 < c1 <= b1
    assert np.array_equal(ante.line[a0:a1, b0:b1], ante.area_line, equal_nan=True)
    prod = read_product(s.product_path)
    every = resample_bands([prod.counts(b) for b in bands], ante.line, ante.col, sampling)
    counts = ante.counts()
    radiance = ante.radiance()
    for k, b in enumerate(bands):
        expected = np.clip(np.floor(every[k] + np.float32(0.5)), 0, 65535).astype(np.uint16)
        assert np.array_equal(counts[k], expected) and expected.any()
        sf = np.float32(prod.scaling.radiance[b - 1])
        assert np.array_equal(radiance[b], every[k] * sf)
    flags = resample_bands([prod.flags], ante.line, ante.col, "nearest")[0]
    assert np.array_equal(ante.flags(), flags.astype(np.uint8))
    outside = counts.copy()
    outside[:, r0:r1, c0:c1] = 0
    assert not outside.any()
    if sampling == "nearest":
        assert ante._nearest_index().size == (r1 - r0) * (c1 - c0)


@pytest.mark.slow
def test_accuracy_across_the_antimeridian():
    """rr-antimeridian, a box across 180 deg: no seam, DEM mode within 0.05 px RMS."""
    from napari_meris_ortho.simulate.scene import generate_scene

    s = generate_scene("rr-antimeridian")
    d = np.degrees(1040.0 / 6370997.0)
    grid = OutputGrid.from_extent("EPSG:4326", (178.5, 63.4), (181.5, 62.0), (2 * d, d))
    r = orthorectify(s.product_path, grid=grid, dems=[s.dem_paths["geotiff"]], bands=[7],
                     parallax="ellipsoid", diagnostics=True)
    assert r.valid.mean() > 0.99  # the box lies inside the swath: no hole, no seam at 180
    e = _truth_error(s, r)
    assert np.sqrt(np.mean(e ** 2)) <= 0.05 and e.max() <= 0.25


def _write_dem(path, data, transform, crs="EPSG:4326", nodata=None):
    import rasterio

    with rasterio.open(path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0],
                       count=1, dtype=data.dtype.name, crs=crs, transform=transform,
                       nodata=nodata, tiled=True, blockxsize=64, blockysize=64) as ds:
        ds.write(data, 1)
    return str(path)


def _old_heights(stack, lon, lat, mask, method):
    """The heights as before the compiled lookup: ``DemStack.sample`` at the masked points."""
    h = np.full(lon.shape, np.nan, np.float32)
    src = np.full(lon.shape, -1, np.int8)
    hv, iv = stack.sample(lon[mask], lat[mask], method)
    h[mask], src[mask] = hv, iv
    return h, src


@pytest.mark.parametrize("method", ["bilinear", "nearest", "bicubic"])
def test_dem_heights_by_the_window_kernel_equal_the_dem_stack(tmp_path, method):
    """``_heights`` (compiled lookup in the prepared windows) gives the heights and DEM indices
    of ``DemStack.sample``: nodata holes and implausible posts sending points to the next DEM,
    points beyond the prepared window, a UTM DEM, EGM96 heights, a 0..360 deg global DEM."""
    from rasterio.transform import from_origin

    from napari_meris_ortho.dem.stack import DemStack
    from napari_meris_ortho.ortho.heights import dem_heights as _heights

    rng = np.random.default_rng(12)
    geo = rng.uniform(0.0, 3000.0, (200, 300)).astype(np.float32)
    geo[rng.integers(0, 200, 300), rng.integers(0, 300, 300)] = -32768.0  # holes
    geo[rng.integers(0, 200, 50), rng.integers(0, 300, 50)] = 9999.0  # implausible
    tif = _write_dem(tmp_path / "geo.tif", geo, from_origin(10.0, 47.0, 0.01, 0.01),
                     nodata=-32768.0)
    x0, y0 = 560000.0, 5230000.0  # UTM 32N around (9.8, 47.2)
    utm = (1500.0 + 0.01 * np.arange(260)[None, :] - 0.02 * np.arange(300)[:, None]
           + rng.normal(0.0, 5.0, (300, 260))).astype(np.float32)
    utm_tif = _write_dem(tmp_path / "utm.tif", utm, from_origin(x0, y0, 1000.0, 1000.0),
                         "EPSG:32632")
    world = rng.uniform(-100.0, 2000.0, (90, 180)).astype(np.int16)  # 2 deg posts, 0..360 E
    world_tif = _write_dem(tmp_path / "world.tif", world, from_origin(0.0, 90.0, 2.0, 2.0))
    egm = _write_dem(tmp_path / "egm.tif", geo[::-1].copy(), from_origin(10.0, 47.0, 0.01, 0.01),
                     nodata=-32768.0)
    dems = [tif, f"{egm}:egm96", f"{utm_tif}:ellipsoid", f"{world_tif}:ellipsoid"]
    lon, lat = np.meshgrid(np.linspace(9.5, 13.5, 400), np.linspace(48.0, 44.5, 300))
    lon = np.where(lon > 12.0, lon - 360.0, lon)  # a turn away: the same points
    mask = rng.random(lon.shape) < 0.9
    new_stack, old_stack = DemStack(dems), DemStack(dems)
    for stack in (new_stack, old_stack):  # windows smaller than the points' extent
        stack.prepare(10.3, 45.3, 12.6, 46.9)
    assert all(s.lattice_window() is not None for s in new_stack.sources)
    h, src = _heights(new_stack, lon, lat, mask, method)
    h_old, src_old = _old_heights(old_stack, lon, lat, mask, method)
    np.testing.assert_array_equal(src, src_old)
    assert set(np.unique(src).tolist()) == {-1, 0, 1, 2, 3}
    assert np.all(np.isnan(h[src < 0])) and np.all(np.isfinite(h[src >= 0]))
    ok = src >= 0
    if method == "bicubic":  # other float64 summation order than numpy's einsum
        np.testing.assert_array_max_ulp(h[ok], h_old[ok], maxulp=1)
    else:
        np.testing.assert_array_equal(h, h_old)
    assert np.mean(h[ok] == h_old[ok]) > 0.95


@pytest.mark.parametrize("method", ["bilinear", "bicubic"])
def test_tile_directory_heights_by_the_window_kernel_equal_the_dem_stack(method):
    """GETASSE30 (both variants), SRTM30 and Copernicus tile directories get prepared windows
    of posts (per Copernicus zone, per SRTM tile; a tile the bounds miss: an empty window) and
    ``_heights`` gives ``DemStack.sample``'s heights and sources, also for points beyond the
    windows and where no tile is."""
    from napari_meris_ortho.dem.stack import DemStack, open_dem
    from napari_meris_ortho.ortho.heights import dem_heights as _heights
    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene({"base": "fr-small", "lines": 128, "columns": 193,
                            "first_column": 1150})
    cop = generate_scene(COPERNICUS_SCENE)
    for sc, keys in ((scene, ["getasse30", "srtm30"]), (scene, ["getasse30_beam"]),
                     (cop, ["copernicus"])):
        dems = [sc.dem_paths[k] for k in keys]
        b = open_dem(sc.dem_paths["geotiff"]).bounds
        new_stack, old_stack = DemStack(dems), DemStack(dems)
        for stack in (new_stack, old_stack):  # windows smaller than the points' extent
            stack.prepare(b[0] + 0.2, b[1] + 0.2, b[2] - 0.2, b[3] - 0.2)
        windows = [part.lattice_window() for dem in new_stack.sources for part, _ in dem.parts()]
        assert windows and all(w is not None for w in windows), keys
        assert any(w.data.size > 1000 for w in windows), keys
        rng = np.random.default_rng(5)
        lon = rng.uniform(b[0] - 0.1, b[2] + 0.1, (60, 70))
        lat = rng.uniform(b[1] - 0.1, b[3] + 0.1, (60, 70))
        mask = rng.random(lon.shape) < 0.9
        h, src = _heights(new_stack, lon, lat, mask, method)
        h_old, src_old = _old_heights(old_stack, lon, lat, mask, method)
        np.testing.assert_array_equal(src, src_old)
        ok = src >= 0
        assert ok.mean() > 0.5 and np.all(np.isnan(h[~ok])), keys
        np.testing.assert_allclose(h[ok], h_old[ok], rtol=0, atol=1e-3)  # float32 heights

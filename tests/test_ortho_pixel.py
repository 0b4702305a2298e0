"""``orthorectify(..., geolocation="pixel")`` of per-pixel geolocated products (FRG N1, SEN3)
against the simulator's truth, and beside the tie-point orthorectification of the same scene."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.ortho import orthorectify


@pytest.fixture(scope="module")
def tiepoint_result(fr_small):
    return orthorectify(fr_small.product_path, dems=[fr_small.dem_paths["geotiff"]], bands=[7],
                        parallax="ellipsoid", diagnostics=True)


def _truth_error(fr_small, r, stride=5):
    """Antecedent error (product pixels) against the simulator's line of sight, every
    ``stride``-th valid point."""
    ok = r.valid.copy()
    ok.ravel()[np.arange(ok.size) % stride != 0] = False
    lon, lat = r.grid.lonlat()
    tl, tc = fr_small.true_antecedent(lon[ok], lat[ok], fr_small.dem_height(lon[ok], lat[ok]))
    return np.hypot(r.diagnostics["line"][ok] - tl, r.diagnostics["col"][ok] - tc)


@pytest.mark.parametrize("kind", ["fsg", "sen3"])
def test_pixel_geolocation_accuracy_against_the_truth(fr_small, geolocated, tiepoint_result, kind):
    """The per-pixel truth geolocation inverted on the tie-point run's grid: <= 0.05 px RMS
    (bilinear between terrain points of pixel centres; the error is where relief folds)."""
    r = orthorectify(geolocated[kind], grid=tiepoint_result.grid, geolocation="pixel", bands=[7],
                     diagnostics=True)
    e = _truth_error(fr_small, r)
    rms = float(np.sqrt(np.mean(e ** 2)))
    assert rms <= 0.05, rms
    assert np.percentile(e, 99) < 0.25 and e.max() < 2.0
    # the same points are mapped as by the tie-point model with the DEM (no hole, no parallax)
    assert abs(int(r.valid.sum()) - int(tiepoint_result.valid.sum())) < 0.01 * r.valid.sum()
    both = r.valid & tiepoint_result.valid
    dl = r.diagnostics["line"][both] - tiepoint_result.diagnostics["line"][both]
    dc = r.diagnostics["col"][both] - tiepoint_result.diagnostics["col"][both]
    assert np.sqrt(np.mean(dl ** 2 + dc ** 2)) < 0.06
    # the product altitude at the antecedent is the diagnostics' elevation
    h = fr_small.dem_height(*[a[both] for a in r.grid.lonlat()])
    assert np.median(np.abs(r.diagnostics["elevation"][both] - h)) < 5.0
    assert r.stats.geolocation == "pixel"
    # nearest neighbour: the same product pixel almost everywhere (flicker: nothing moves)
    assert np.mean(r.bands[7][both] == tiepoint_result.bands[7][both]) > 0.95


def test_pixel_geolocation_without_terrain_correction_would_be_wrong(fr_small, geolocated,
                                                                     tiepoint_result):
    """Re-applying the parallax to terrain points (tie-point model on the same radiances with
    elevation none) is pixels off: the pixel model is what removes it."""
    r = orthorectify(geolocated["sen3"], grid=tiepoint_result.grid, elevation="none", bands=[7],
                     diagnostics=True)
    e = _truth_error(fr_small, r)
    assert np.sqrt(np.mean(e ** 2)) > 1.0


def test_pixel_geolocation_needs_a_geolocated_product(fr_small, geolocated):
    with pytest.raises(OptionsError, match="per-pixel geolocation"):
        orthorectify(fr_small.product_path, geolocation="pixel", bands=[7])
    # DEMs go with elevation "dem" (the pixel geolocation's heights then come from them)
    with pytest.raises(OptionsError, match="DEMs are only used with elevation 'dem'"):
        orthorectify(geolocated["fsg"], geolocation="pixel", elevation="tiepoints",
                     dems=[fr_small.dem_paths["geotiff"]])


@pytest.mark.parametrize("pattern", ["scatter", "block"])
def test_masked_geolocation_costs_only_the_cells_touching_it(geolocated, tmp_path, pattern):
    """No-data pixels of the geolocation (fill values of ``geo_coordinates.nc``) leave no data
    only at the output points whose bilinear cell has such a pixel as a corner: 100 scattered
    pixels cost 661 points of fr-small (6.6 each), a 10 x 10 block 204 (+1 beside it); every
    other point keeps its antecedent to the bit. A bisection along a product line that stepped
    on a no-data pixel would lose the points of the whole line beyond it (412 points more, up
    to 42 px from a masked pixel)."""
    import shutil

    import netCDF4

    from napari_meris_ortho.products.open import read_product

    ref = orthorectify(geolocated["sen3"], geolocation="pixel", bands=[7], diagnostics=True)
    bad = tmp_path / geolocated["sen3"].name
    shutil.copytree(geolocated["sen3"], bad)
    with netCDF4.Dataset(bad / "geo_coordinates.nc", "r+") as ds:
        nl, nc = ds["latitude"].shape
        mask = np.zeros((nl, nc), bool)
        if pattern == "scatter":
            rng = np.random.default_rng(1)
            mask[rng.integers(20, nl - 20, 100), rng.integers(20, nc - 20, 100)] = True
        else:
            mask[nl // 2:nl // 2 + 10, nc // 3:nc // 3 + 10] = True
        for name in ("latitude", "longitude"):
            var = ds[name]
            var.set_auto_maskandscale(False)
            raw = var[:]
            raw[mask] = var._FillValue
            var[:] = raw
    masked = np.isnan(read_product(bad).pixel_longitude())  # (the product's column order)
    assert masked.sum() == 100
    r = orthorectify(bad, grid=ref.grid, geolocation="pixel", bands=[7], diagnostics=True)
    line, col, ok = ref.diagnostics["line"], ref.diagnostics["col"], ref.valid
    i = np.clip(np.floor(np.where(ok, line, 0)).astype(int), 0, nl - 2)
    j = np.clip(np.floor(np.where(ok, col, 0)).astype(int), 0, nc - 2)
    touch = ok & (masked[i, j] | masked[i + 1, j] | masked[i, j + 1] | masked[i + 1, j + 1])
    lost = ok & ~r.valid
    assert np.all(lost[touch]) and touch.sum() > (400 if pattern == "scatter" else 150)
    assert np.count_nonzero(lost & ~touch) <= 1
    kept = ok & r.valid
    assert np.array_equal(r.diagnostics["line"][kept], line[kept])
    assert np.array_equal(r.diagnostics["col"][kept], col[kept])
    assert np.array_equal(r.bands[7][kept], ref.bands[7][kept])


@pytest.fixture(scope="module")
def steep(tmp_path_factory):
    """Scene fr-steep (9 km relief at up to 41 deg view zenith), its SEN3, the tie-point + DEM
    run's grid and, per output point, the true antecedent (tl, tc), its distance to the product
    edge (px) and whether its ground lies in the product (``inside``) and is seen (``seen``)."""
    from types import SimpleNamespace

    from napari_meris_ortho.simulate.geocorrected import write_geocorrected
    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene("fr-steep")
    sen3 = write_geocorrected(scene, fsg=False, out_dir=tmp_path_factory.mktemp("steep"))["sen3"]
    ref = orthorectify(scene.product_path, dems=[scene.dem_paths["geotiff"]], bands=[7],
                       parallax="ellipsoid", diagnostics=True)
    g = scene.geometry
    lon, lat = ref.grid.lonlat()
    h = scene.dem_height(lon, lat)
    tl, tc = scene.true_antecedent(lon, lat, h)
    inside = ((tl >= -0.5) & (tl < g.lines - 0.5) & (tc >= -0.5) & (tc < g.columns - 0.5)
              & np.isfinite(h))
    seen = np.zeros(inside.shape, bool)
    seen[inside] = scene.seen_from_sensor(lon[inside], lat[inside], h[inside], tl[inside],
                                          tc[inside])
    edge = np.minimum.reduce([tl + 0.5, g.lines - 0.5 - tl, tc + 0.5, g.columns - 0.5 - tc])
    pixel = orthorectify(sen3, grid=ref.grid, geolocation="pixel", bands=[7], diagnostics=True)
    return SimpleNamespace(scene=scene, sen3=sen3, grid=ref.grid, lon=lon, lat=lat, h=h, tl=tl,
                           tc=tc, inside=inside, seen=seen, edge=edge, pixel=pixel)


@pytest.mark.slow
def test_pixel_geolocation_in_steep_terrain(steep):
    """9 km relief at up to 41 deg view zenith (scene fr-steep): every output point whose
    ground the sensor sees is mapped (the cell holding it is searched along its product line,
    where the parallax moves it), within 0.08 px RMS of the truth (the floor of a bilinear model
    between terrain points of pixel centres, 260 m apart, on this relief); ground hidden by the
    relief is reported (iterations -2, counted in the statistics), not a silent hole."""
    from napari_meris_ortho.engine.pixelgeo import OCCLUDED

    r, tl, tc, inside, seen, edge = (steep.pixel, steep.tl, steep.tc, steep.inside, steep.seen,
                                     steep.edge)
    hidden = inside & ~seen
    assert 0.02 < hidden.sum() / inside.sum() < 0.05  # a steep scene indeed (2.8 %)
    it = r.diagnostics["iterations"]
    # the seen ground is mapped: 0.014 % left, all within 0.5 px of the product edge or taken
    # for hidden ground at a crest
    lost = seen & ~r.valid
    assert lost.sum() < 2e-4 * seen.sum()
    assert np.all((edge[lost] < 0.5) | (it[lost] == OCCLUDED))
    e = np.hypot(r.diagnostics["line"] - tl, r.diagnostics["col"] - tc)[seen & r.valid]
    assert np.sqrt(np.mean(e ** 2)) < 0.08 and np.percentile(e, 99) < 0.35 and e.max() < 2.5
    # hidden ground is reported: counted, 95 % of the reported points truly hidden; the hidden
    # ground not reported is mapped (a crest sampled between pixel centres hides it) or at the
    # product edge, never dropped unexplained
    reported = it == OCCLUDED
    assert r.stats.facet_search["occluded"] == reported.sum() > 0.03 * hidden.sum()
    assert (reported & hidden).sum() > 0.9 * reported.sum()
    assert np.count_nonzero(hidden & (it == -1) & (edge > 0.5)) < 2e-3 * hidden.sum()
    assert not np.any(r.valid & reported)
    assert any("points hidden by the relief (no antecedent) = " in line
               for line in r.stats.log_lines())


@pytest.mark.slow
def test_pixel_geolocation_with_a_dem_in_steep_terrain(steep):
    """With the scene's DEM the per-pixel terrain points are moved back to the ellipsoid and
    every output point gets the parallax of its own DEM height (``engine.pixeldem``): on
    fr-steep's seen ground 0.0014 px RMS with the handbook sphere (0.0008 with the WGS84 radii;
    the pixel model alone: 0.077 px, its heights between pixel centres missing), every seen
    point mapped but one 0.006 px inside the product edge (lost by the tie points + DEM too);
    the DEM's height is the diagnostics' elevation; ground hidden by the relief (the line of
    sight marched over the DEM, ``ortho.occlusion``) reported, not mapped."""
    from napari_meris_ortho.engine.pixelgeo import OCCLUDED

    dem = steep.scene.dem_paths["geotiff"]
    r = orthorectify(steep.sen3, grid=steep.grid, dems=[dem], geolocation="pixel", bands=[7],
                     diagnostics=True)
    tl, tc, seen = steep.tl, steep.tc, steep.seen
    e = np.hypot(r.diagnostics["line"] - tl, r.diagnostics["col"] - tc)[seen & r.valid]
    rms = float(np.sqrt(np.mean(e ** 2)))
    assert rms < 0.005 and np.percentile(e, 99) < 0.01 and e.max() < 0.1, rms
    lost = seen & ~r.valid & (r.diagnostics["iterations"] != OCCLUDED)
    assert lost.sum() <= 1 and np.all(steep.edge[lost] < 0.05)
    # hidden ground is reported as the pixel model alone reports it (iterations OCCLUDED,
    # counted, no data): 6331 of the 6351 reported points hidden by the truth's 5 m march, all
    # of its 6331 hidden reported (not mapped to the pixel whose line of sight passes through
    # it, which shows the ridge in front: a double image). The other 20
    # are hidden too, by crests 1.0-2.2 m above the ray between the truth's samples (0.1 m
    # steps): the exact march per DEM cell finds them
    hidden = steep.inside & ~seen
    reported = r.diagnostics["iterations"] == OCCLUDED
    assert r.stats.facet_search["occluded"] == reported.sum()
    assert (reported & hidden).sum() >= 0.99 * reported.sum()
    assert (reported & hidden).sum() >= 0.99 * hidden.sum()
    assert not np.any(r.valid & reported) and np.all(r.bands[7][reported] == 0)
    assert any("points hidden by the relief (no antecedent) = " in line
               for line in r.stats.log_lines())
    ok = r.valid
    dh = r.diagnostics["elevation"][ok] - steep.h[ok]
    assert np.max(np.abs(dh)) < 1.0
    assert r.stats.elevation_sources == {"tiepoints": 0, f"0:{dem.name}": int(ok.sum())}
    assert r.stats.geolocation == "pixel" and r.stats.dems == [str(dem)]
    # nearest neighbour: the product pixel of the truth (the pixel model alone misses more)
    tn = (np.floor(tl + 0.5) == np.floor(r.diagnostics["line"] + 0.5)) & (
        np.floor(tc + 0.5) == np.floor(r.diagnostics["col"] + 0.5))
    assert np.mean(tn[seen & ok]) > 0.999


@pytest.mark.slow
def test_pixel_geolocation_falls_back_where_the_dem_ends(steep, tmp_path):
    """A DEM covering the west of the scene only: east of it the points fall back to the
    product's own geolocation (the pixel model alone: same antecedents, hidden ground reported),
    west of it they keep the DEM's accuracy."""
    import rasterio
    from rasterio.windows import Window

    from napari_meris_ortho.engine.pixelgeo import OCCLUDED

    cut = 12.3  # deg E: the scene runs 10.6 .. 14.2
    west = tmp_path / "west.tif"
    with rasterio.open(steep.scene.dem_paths["geotiff"]) as src:
        n = int(round((cut - src.transform.c) / src.transform.a))
        window = Window(0, 0, n, src.height)
        profile = {**src.profile, "width": n, "transform": src.window_transform(window),
                   "tiled": False}
        profile.pop("blockxsize")
        profile.pop("blockysize")
        with rasterio.open(west, "w", **profile) as dst:
            dst.write(src.read(1, window=window), 1)
            dst.update_tags(**src.tags())
    r = orthorectify(steep.sen3, grid=steep.grid, dems=[west], geolocation="pixel", bands=[7],
                     diagnostics=True)
    p = steep.pixel
    covered = steep.lon < cut - 0.01
    bare = steep.lon > cut + 0.01
    assert 0.2 < covered[steep.inside].mean() < 0.8
    src = r.diagnostics["elevation_source"]
    assert np.all(src[covered & r.valid] == 0) and np.all(src[bare & r.valid] == -1)
    same = (r.diagnostics["iterations"] == p.diagnostics["iterations"]) & bare & steep.inside
    assert same.sum() > 0.999 * (bare & steep.inside).sum()
    both = bare & r.valid & p.valid
    assert np.array_equal(r.diagnostics["line"][both], p.diagnostics["line"][both])
    assert np.array_equal(r.diagnostics["col"][both], p.diagnostics["col"][both])
    reported = np.count_nonzero(bare & (r.diagnostics["iterations"] == OCCLUDED))
    assert reported == np.count_nonzero(bare & (p.diagnostics["iterations"] == OCCLUDED)) > 40
    seen_west = steep.seen & covered & r.valid
    e = np.hypot(r.diagnostics["line"] - steep.tl, r.diagnostics["col"] - steep.tc)[seen_west]
    assert np.sqrt(np.mean(e ** 2)) < 0.005


@pytest.mark.slow
def test_hidden_ground_with_a_stack_of_dems(steep):
    """Two DEMs (the scene's DEM given twice): the lines of sight are marched over the first
    DEM's window in memory as with one DEM (a cell without data there would hand the ray to the
    stack's march): the same points reported hidden as with the DEM alone (the stack's march by
    samples finds 97.8 % of the hidden ground, and takes 80 s on fr-alps instead of 1 s), the
    seen ground mapped as with one DEM."""
    from napari_meris_ortho.engine.pixelgeo import OCCLUDED

    dem = steep.scene.dem_paths["geotiff"]
    one = orthorectify(steep.sen3, grid=steep.grid, dems=[dem], geolocation="pixel",
                       bands=[7], diagnostics=True)
    r = orthorectify(steep.sen3, grid=steep.grid, dems=[dem, dem], geolocation="pixel",
                     bands=[7], diagnostics=True)
    hidden = steep.inside & ~steep.seen
    reported = r.diagnostics["iterations"] == OCCLUDED
    assert np.array_equal(reported, one.diagnostics["iterations"] == OCCLUDED)
    assert r.stats.facet_search["occluded"] == reported.sum()
    assert (reported & hidden).sum() >= 0.99 * hidden.sum()
    lost = steep.seen & ~r.valid & ~reported
    assert lost.sum() <= 1 and np.all(steep.edge[lost] < 0.05)


@pytest.mark.slow
def test_hidden_ground_with_a_dem_above_the_geoid(steep, tmp_path):
    """The scene's DEM written as heights above the EGM96 geoid (posts - N, read as
    ``PATH:egm96``): the window is made ellipsoidal once (posts + N) and marched cell by cell
    like an ellipsoidal DEM: the same points reported hidden as with the ellipsoidal DEM but
    where the two sources' heights differ by their float32 rounding (not sampled by the
    stack's march: 10 s on fr-alps instead of 1 s)."""
    import rasterio

    from napari_meris_ortho.dem.geoid import geoid_undulation
    from napari_meris_ortho.engine.pixelgeo import OCCLUDED

    dem = steep.scene.dem_paths["geotiff"]
    geoidal = tmp_path / "egm96.tif"
    with rasterio.open(dem) as src:
        h = src.read(1)
        rows, cols = np.mgrid[0:src.height, 0:src.width]
        lon, lat = rasterio.transform.xy(src.transform, rows.ravel(), cols.ravel())
        n = geoid_undulation(np.asarray(lon), np.asarray(lat)).reshape(h.shape)
        with rasterio.open(geoidal, "w", **src.profile) as dst:
            dst.write((h - n).astype(np.float32), 1)
    assert 40.0 < float(np.mean(n)) < 55.0  # the Alps: N of about 47 m
    one = orthorectify(steep.sen3, grid=steep.grid, dems=[dem], geolocation="pixel",
                       bands=[7], diagnostics=True)
    r = orthorectify(steep.sen3, grid=steep.grid, dems=[f"{geoidal}:egm96"],
                     geolocation="pixel", bands=[7], diagnostics=True)
    assert np.nanmax(np.abs(r.diagnostics["elevation"] - one.diagnostics["elevation"])) < 0.01
    reported = r.diagnostics["iterations"] == OCCLUDED
    expected = one.diagnostics["iterations"] == OCCLUDED
    assert reported.sum() > 5000
    assert np.count_nonzero(reported != expected) <= 3


@pytest.mark.slow
def test_hidden_ground_with_a_projected_dem(steep, tmp_path):
    """A projected DEM in memory (the scene's DEM reprojected to UTM 32N, 100 m posts) is
    marched cell by cell along each point's track on its lattice (its projected look vector):
    on fr-steep the same hidden ground as the stack's sampled march (every 1/32 post, about 80
    times slower on fr-alps's 250 m UTM DEM), and the crests grazing a ray between the
    samples."""
    import time

    import rasterio
    from rasterio.warp import Resampling, calculate_default_transform, reproject

    from napari_meris_ortho.dem.stack import DemStack
    from napari_meris_ortho.engine.pixeldem import look_vectors
    from napari_meris_ortho.geometry.tiepoints import TiePointGrid
    from napari_meris_ortho.ortho import occlusion
    from napari_meris_ortho.products.open import read_product

    utm = tmp_path / "utm.tif"
    with rasterio.open(steep.scene.dem_paths["geotiff"]) as src:
        transform, width, height = calculate_default_transform(
            src.crs, "EPSG:32632", src.width, src.height, *src.bounds, resolution=100.0)
        profile = {**src.profile, "crs": "EPSG:32632", "transform": transform, "width": width,
                   "height": height, "nodata": -9999.0, "tiled": False}
        profile.pop("blockxsize", None)
        profile.pop("blockysize", None)
        with rasterio.open(utm, "w", **profile) as dst:
            reproject(rasterio.band(src, 1), rasterio.band(dst, 1), dst_nodata=-9999.0,
                      resampling=Resampling.bilinear)
            dst.update_tags(VERTICAL_DATUM="ellipsoid")
    ok = steep.pixel.valid & steep.inside
    ok.ravel()[np.arange(ok.size) % 4 != 0] = False
    lon, lat = steep.lon[ok], steep.lat[ok]
    line = steep.pixel.diagnostics["line"][ok].astype(np.float64)
    col = steep.pixel.diagnostics["col"][ok].astype(np.float64)
    stack = DemStack([utm])
    stack.prepare(float(steep.lon.min()), float(steep.lat.min()), float(steep.lon.max()),
                  float(steep.lat.max()))
    h, _ = stack.sample(lon, lat)
    sight = occlusion.Sightlines.of(stack, float(np.mean(lat)))
    assert sight.window is not None and sight.window.transform is not None
    _, _, coef, df, dj = TiePointGrid.from_product(read_product(steep.sen3)).kernel_args()
    t = time.perf_counter()
    fast = sight.hidden(lon, lat, h, line, col, coef, df, dj)
    took = time.perf_counter() - t
    e, n = look_vectors(line, col, coef, df, dj)
    ray = (lon, lat, h, e, n)
    maybe = np.flatnonzero(occlusion._march(stack, ray, sight.ceiling, sight.step,
                                            occlusion.TOLERANCE_M - occlusion.MARGIN_M))
    sampled = np.zeros(lon.shape, bool)
    sampled[maybe] = occlusion._march(stack, tuple(a[maybe] for a in ray), sight.ceiling,
                                      sight.step / occlusion.FINE, occlusion.TOLERANCE_M)
    assert sampled.sum() > 1000
    # 1436 hidden by the samples, all found; 3 more (crests between the samples)
    assert np.count_nonzero(sampled & ~fast) <= 0.002 * sampled.sum()
    assert np.count_nonzero(fast & ~sampled) <= 0.01 * sampled.sum()
    assert took < 2.0, took

"""Mapping of the simulated OLCI scenes against the simulator's truth: olci-efr-alps (EFR, the
Alps under the 45-57 deg view zenith part of the tilted swath) and olci-err-andes (ERR, the
Andes there): tie points on every row (facets one row tall), 77 tie columns, per-pixel
geolocation."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from napari_meris_ortho.ortho import orthorectify

#: every STRIDE-th output point is compared with the truth (the truth is slow)
STRIDE = 7


def _truth(scene, result, near: int = 0):
    """The true antecedent of every STRIDE-th output point at its DEM height, whether it lies
    in the product (not within half a pixel of its edge), and the points picked; ``near``: only
    points within that many output pixels of a mapped one (a thin strip's box is mostly
    empty)."""
    pick = np.zeros(result.valid.shape, bool)
    pick.ravel()[::STRIDE] = True
    if near:
        from scipy.ndimage import binary_dilation

        pick &= binary_dilation(result.valid, iterations=near)
    lon, lat = result.grid.lonlat()
    h = scene.dem_height(lon[pick], lat[pick])
    tl, tc = scene.true_antecedent(lon[pick], lat[pick], h)
    g = scene.geometry
    inside = ((tl >= 0.0) & (tl <= g.lines - 1.0) & (tc >= 0.0) & (tc <= g.columns - 1.0)
              & np.isfinite(h))
    seen = np.zeros_like(inside)
    seen[inside] = scene.seen_from_sensor(lon[pick][inside], lat[pick][inside], h[inside],
                                          tl[inside], tc[inside])
    return SimpleNamespace(pick=pick, tl=tl, tc=tc, inside=inside & seen,
                           hidden=inside & ~seen)


def _error(result, truth):
    ok = result.valid[truth.pick]
    d = result.diagnostics
    return np.hypot(d["line"][truth.pick][ok] - truth.tl[ok],
                    d["col"][truth.pick][ok] - truth.tc[ok])


@pytest.fixture(scope="module", params=["olci-efr-alps", "olci-err-andes"])
def olci_runs(request):
    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene(request.param)
    dem = scene.dem_paths["geotiff"]
    runs = {par: orthorectify(scene.product_path, dems=[dem], bands=[8], parallax=par,
                              diagnostics=True) for par in ("handbook", "ellipsoid")}
    truth = _truth(scene, runs["handbook"])
    runs["pixel"] = orthorectify(scene.product_path, grid=runs["handbook"].grid,
                                 geolocation="pixel", bands=[8], diagnostics=True)
    return SimpleNamespace(scene=scene, runs=runs, truth=truth)


@pytest.mark.slow
@pytest.mark.parametrize("parallax", ["handbook", "ellipsoid"])
def test_dem_mode_matches_the_truth_without_holes(olci_runs, parallax):
    """Tie-point geolocation + the scene's DEM: within 0.05 px RMS and 0.25 px of the truth
    everywhere, up to 57 deg view zenith over 5-7 km relief; every output point whose true
    antecedent lies in the product is mapped or found hidden from the sensor (left unmapped,
    ``hidden="mask"``, the default), and no more than 0.2 % of the seen ground is found
    hidden."""
    r, truth = olci_runs.runs[parallax], olci_runs.truth
    e = _error(r, truth)
    assert e.size > 50_000
    assert np.sqrt(np.mean(e ** 2)) <= 0.05 and e.max() <= 0.25, (
        float(np.sqrt(np.mean(e ** 2))), float(e.max()))
    hidden = r.hidden[truth.pick]
    holes = truth.inside & ~r.valid[truth.pick] & ~hidden
    assert holes.sum() == 0, np.flatnonzero(holes)[:5]
    # the hidden ground is left unmapped; seen ground flagged hidden (crests that the truth's
    # 5 m samples step over) stays within the bound of the hidden-ground accuracy
    assert not r.valid[truth.pick][truth.hidden].any()
    assert np.count_nonzero(truth.inside & hidden) <= 0.002 * np.count_nonzero(truth.inside)
    # the relief and the tilt are real: the DEM heights and their parallax shifts
    ok = r.valid
    assert r.diagnostics["elevation"][ok].max() > 4000.0
    assert np.abs(r.diagnostics["shift_east_m"][ok]).max() > 6000.0


@pytest.mark.slow
def test_pixel_geolocation_matches_the_truth(olci_runs):
    """ESA's per-pixel "DEM corrected" geolocation (no parallax left): within 0.08 px RMS and
    0.3 px at the 99th percentile of the truth (a bilinear model between the terrain points of
    pixel centres, which relief seen at up to 57 deg folds: pixels at crests hiding ground);
    the ground of the DEM mode's map is mapped but for the hidden ground, which is reported."""
    r, truth = olci_runs.runs["pixel"], olci_runs.truth
    e = _error(r, truth)
    assert np.sqrt(np.mean(e ** 2)) <= 0.08 and np.percentile(e, 99) <= 0.3, (
        float(np.sqrt(np.mean(e ** 2))), float(np.percentile(e, 99)))
    assert e.max() < 6.0
    n_dem = int(olci_runs.runs["handbook"].valid.sum())
    assert abs(int(r.valid.sum()) - n_dem) < 0.02 * n_dem
    assert r.stats.facet_search["occluded"] > 0


#: a 24-row piece of olci-efr-alps crossing the Alps, its DEM on 0.008 deg posts
EFR_PIECE = {"base": "olci-efr-alps", "lines": 24, "orbit": {"nadir_lat": 45.9, "nadir_lon": 19.2},
             "dem": {"spacing_deg": 0.008},
             "exports": {"getasse30": False, "srtm30": False, "reference": False}}


def test_one_row_facets_and_77_tie_columns_of_an_efr_piece(tmp_path):
    """The whole EFR width (4865 columns, 77 tie columns 64 apart, tie points on every row:
    facets one row tall) up to 57 deg view zenith over the Alps: DEM mode within the targets,
    no hole."""
    from napari_meris_ortho.products.open import read_product
    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene(EFR_PIECE, out_dir=tmp_path)
    p = read_product(scene.product_path)
    assert p.tie_points["latitude"].shape == (24, 77) and p.lines_per_tie_point == 1
    r = orthorectify(p, dems=[scene.dem_paths["geotiff"]], bands=[8], diagnostics=True)
    truth = _truth(scene, r, near=8)
    e = _error(r, truth)
    assert np.sqrt(np.mean(e ** 2)) <= 0.05 and e.max() <= 0.25
    assert truth.inside.sum() > 20_000 and not (truth.inside & ~r.valid[truth.pick]).any()
    vz = p.tie_points["view_zenith"]
    assert vz[:, -1].min() > 56.0 and r.diagnostics["elevation"][r.valid].max() > 3000.0

"""Every elevation x parallax x search combination of ``orthorectify`` against the simulator's
truth on fr-small.

The truth of an output point (lon, lat) is the product position whose line of sight passes
through (lon, lat, h): h = 0 for ``elevation="none"``, the scene's DEM for "dem" and the
tie-point height at the antecedent for "tiepoints". Each combination must be within 0.05 px RMS
and 0.25 px max of it, and leave no output point unmapped whose true antecedent lies inside the
product. The handbook search is MERSYN's: it starts from the zero-height inverse in the tie-point
facets (section 3.4), so its holes must all lie outside the tie-point grid at zero height.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from napari_meris_ortho import orthorectify
from napari_meris_ortho.products.n1 import read_product

pytestmark = pytest.mark.slow

ELEVATIONS = ("none", "tiepoints", "dem")
PARALLAXES = ("handbook", "ellipsoid")
SEARCHES = ("primary", "handbook")
#: an antecedent this close to the product edge may fall either side within the accuracy
EDGE_PX = 0.05


@pytest.fixture(scope="module")
def scene():
    from napari_meris_ortho.simulate.scene import generate_scene

    return generate_scene("fr-small")


@pytest.fixture(scope="module")
def runs(scene):
    out = {}
    for elev, par, search in itertools.product(ELEVATIONS, PARALLAXES, SEARCHES):
        dems = [scene.dem_paths["geotiff"]] if elev == "dem" else []
        out[elev, par, search] = orthorectify(scene.product_path, dems=dems, elevation=elev,
                                              parallax=par, method=search, bands=[7],
                                              diagnostics=True)
    grids = {(r.grid.x0, r.grid.y0, r.grid.shape) for r in out.values()}
    assert len(grids) == 1  # one default grid for all: the truth is computed once
    return out


def _tiepoint_height(prod, line, col):
    """dem_alt interpolated bilinearly at product positions (eq. 1)."""
    tp = prod.tie_points["dem_alt"]
    coords = np.stack([line / prod.lines_per_tie_point, col / prod.samples_per_tie_point])
    return map_coordinates(tp, coords, order=1, mode="nearest")


def _truth(scene, prod, elevation, lon, lat):
    """True antecedents of output points for an elevation source (module docstring)."""
    if elevation == "none":
        return scene.true_antecedent(lon, lat, np.zeros_like(lon))
    if elevation == "dem":
        return scene.true_antecedent(lon, lat, scene.dem_height(lon, lat))
    line, col = scene.true_antecedent(lon, lat, np.zeros_like(lon))
    for _ in range(4):  # the tie-point height depends on the antecedent: fixed point
        line, col = scene.true_antecedent(lon, lat, _tiepoint_height(prod, line, col))
    return line, col


@pytest.fixture(scope="module")
def truth(scene, runs):
    """True antecedents of every output point near the footprint, per elevation source."""
    prod = read_product(scene.product_path)
    grid = next(iter(runs.values())).grid
    lon, lat = grid.lonlat()
    near = np.zeros(grid.shape, bool)
    for r in runs.values():
        near |= r.valid
    near = _dilate(near, 4)
    out = {}
    for elev in ELEVATIONS:
        line = np.full(grid.shape, np.nan)
        col = np.full(grid.shape, np.nan)
        line[near], col[near] = _truth(scene, prod, elev, lon[near], lat[near])
        out[elev] = line, col
    return prod, near, out


def _dilate(mask, n):
    out = mask.copy()
    for _ in range(n):
        grown = out.copy()
        grown[1:] |= out[:-1]
        grown[:-1] |= out[1:]
        grown[:, 1:] |= out[:, :-1]
        grown[:, :-1] |= out[:, 1:]
        out = grown
    return out


def _handbook_processes(prod, zero, antecedent):
    """Output points MERSYN's loop (Appendix C) can map: the zero-height inverse x0 and the
    first correction's inverse f^-1(f(x0, h)) ~ 2 x0 - x must both lie in the tie-point
    facets. Elsewhere (the outer half pixel of the product, terrain within one parallax shift
    of the near-nadir edge) MERSYN's facet search fails and the point stays background."""
    last_line = (prod.tie_points["latitude"].shape[0] - 1) * prod.lines_per_tie_point
    last_col = prod.width - 1

    def in_facets(line, col):
        return ((line >= EDGE_PX) & (line <= last_line - EDGE_PX)
                & (col >= EDGE_PX) & (col <= last_col - EDGE_PX))

    (l0, p0), (lt, pt) = zero, antecedent
    return in_facets(l0, p0) & in_facets(2 * l0 - lt, 2 * p0 - pt)


@pytest.mark.parametrize("elev,par,search",
                         list(itertools.product(ELEVATIONS, PARALLAXES, SEARCHES)))
def test_combination_matches_the_truth(scene, runs, truth, elev, par, search):
    r = runs[elev, par, search]
    prod, near, true = truth
    tl, tc = true[elev]
    d = r.diagnostics
    ok = r.valid
    assert not (ok & ~near).any()
    err = np.hypot(d["line"][ok] - tl[ok], d["col"][ok] - tc[ok])
    rms = float(np.sqrt(np.mean(err ** 2)))
    assert rms <= 0.05 and err.max() <= 0.25, (rms, float(err.max()))
    # elevation diagnostics on every path: the height used and its parallax shift
    h = d["elevation"][ok]
    assert np.isfinite(h).all() and np.isfinite(d["shift_east_m"][ok]).all()
    if elev == "none":
        assert np.all(h == 0)
    else:
        assert h.max() > 1000.0 and np.abs(d["shift_east_m"][ok]).max() > 300.0
    if elev == "dem":
        lon, lat = r.grid.lonlat()
        assert np.max(np.abs(h - scene.dem_height(lon[ok], lat[ok]))) < 1.0
    # no hole: every output point whose true antecedent lies inside the product is mapped
    n_lines, n_cols = prod.height, prod.width
    inside = ((tl >= -0.5 + EDGE_PX) & (tl < n_lines - 0.5 - EDGE_PX)
              & (tc >= -0.5 + EDGE_PX) & (tc < n_cols - 0.5 - EDGE_PX))
    holes = inside & ~ok
    if r.hidden is not None:  # ground hidden by the relief is no data (hidden="mask")
        holes &= ~r.hidden
    if search == "handbook":
        holes &= _handbook_processes(prod, true["none"], (tl, tc))
    assert holes.sum() == 0, np.argwhere(holes)[:5]
    assert ok.sum() > 0.97 * inside.sum()


def test_handbook_search_in_dem_mode_loses_terrain_beyond_the_boundary(runs, truth):
    """The handbook search loses terrain as MERSYN does: high terrain near the near-nadir edge
    of the product is seen from pixels whose zero-height position lies outside the swath; the
    handbook search misses those output points, the primary-grid search maps them with the same
    accuracy."""
    prod, _, true = truth
    tl, tc = true["dem"]
    hb = runs["dem", "ellipsoid", "handbook"]
    pg = runs["dem", "ellipsoid", "primary"]
    lost = pg.valid & ~hb.valid
    depth = np.minimum(np.minimum(tl[lost] + 0.5, prod.height - 0.5 - tl[lost]),
                       np.minimum(tc[lost] + 0.5, prod.width - 0.5 - tc[lost]))
    assert lost.sum() > 100 and depth.max() > 3.0  # several pixels deep on fr-small
    assert not (hb.valid & ~pg.valid).any()

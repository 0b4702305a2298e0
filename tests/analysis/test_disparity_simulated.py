"""Disparity (section 4.6) of simulated products against the simulator's truth reference.

The ``fr-small`` scene (320 x 513 FR pixels over a high range, 20-30 deg view zenith) is mapped on
the grid of its truth reference image (band 5, 0.0025 deg posts) with and without terrain
correction; DISPAR-like statistics must show no displacement for the orthorectified image and the
parallax predicted by the simulator's exact line-of-sight geometry for the uncorrected one.
"""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from scipy.spatial import cKDTree

from napari_meris_ortho.analysis.disparity import disparity
from napari_meris_ortho.geometry.grid import OutputGrid
from napari_meris_ortho.ortho import orthorectify

BAND = 5  # the reference image holds bands 5, 7, 13
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def mapped(fr_small_scene):
    scene = fr_small_scene
    with rasterio.open(scene.reference_path) as ds:
        band_index = ds.descriptions.index(f"band {BAND} radiance") + 1
        reference = ds.read(band_index)
        t = ds.transform
        grid = OutputGrid("EPSG:4326", t.c, t.f, t.a, -t.e, ds.width, ds.height)
    ortho = orthorectify(scene.product_path, grid=grid, dems=[scene.dem_paths["geotiff"]],
                         elevation="dem", sampling="bilinear", bands=[BAND]).bands[BAND]
    flat = orthorectify(scene.product_path, grid=grid, elevation="none", sampling="bilinear",
                        bands=[BAND]).bands[BAND]
    return scene, grid, reference, ortho, flat


def expected_parallax(scene, grid, rows, cols):
    """Displacement (dX, dY) in grid pixels that the uncorrected mapping shows at the ground
    points of grid pixels (rows, cols): ellipsoid location E minus terrain point T of the
    product pixel that sees them (simulator truth, nearest of every 2nd line and column)."""
    g = scene.pixel_geometry(np.arange(0, scene.geometry.lines, 2),
                             np.arange(0, scene.geometry.columns, 2))
    ex = ((g["e_lon"] - g["t_lon"]) / grid.dx).ravel()
    ey = (-(g["e_lat"] - g["t_lat"]) / grid.dy).ravel()  # lines grow southwards
    tree = cKDTree(np.column_stack([g["t_lon"].ravel(), g["t_lat"].ravel()]))
    lon = grid.x0 + (cols + 0.5) * grid.dx
    lat = grid.y0 - (rows + 0.5) * grid.dy
    _, idx = tree.query(np.column_stack([lon, lat]))
    return ex[idx], ey[idx], scene.dem_height(lon, lat)


def test_orthorectified_image_has_no_global_displacement(mapped):
    scene, grid, reference, ortho, _ = mapped
    r = disparity(reference, ortho)
    gx, gy = r.global_displacement
    assert r.stats["candidate_pixels"] > 0.1 * r.stats["image_pixels"]
    assert abs(gx) < 0.1 and abs(gy) < 0.1
    # also where the parallax is largest: above 2000 m
    v = r.vectors()
    high = scene.dem_height(grid.x0 + (v[:, 1] + 0.5) * grid.dx,
                            grid.y0 - (v[:, 0] + 0.5) * grid.dy) > 2000.0
    assert high.sum() > 500
    assert abs(v[high, 2].mean()) < 0.1 and abs(v[high, 3].mean()) < 0.1


def test_uncorrected_image_shows_the_parallax_of_the_mountains(mapped):
    scene, grid, reference, _, flat = mapped
    r = disparity(reference, flat)
    v = r.vectors()
    ex, ey, h = expected_parallax(scene, grid, v[:, 0], v[:, 1])
    high = h > 2000.0
    assert high.sum() > 500
    mx, my = v[high, 2].mean(), v[high, 3].mean()
    # away from the satellite (east of the scene): several pixels westwards, a little north
    assert mx < -5.0 and my < -0.5
    assert mx == pytest.approx(ex[high].mean(), abs=0.2)
    assert my == pytest.approx(ey[high].mean(), abs=0.2)
    assert abs(np.median(v[high, 2] - ex[high])) < 0.1
    assert abs(np.median(v[high, 3] - ey[high])) < 0.1
    # the displacement grows with the height
    low = h < 500.0
    assert abs(v[low, 2].mean()) < 0.5 * abs(mx)

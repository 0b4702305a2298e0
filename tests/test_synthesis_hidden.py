"""A synthesis of two steep products that see the relief from opposite sides: ground one of
them cannot see comes from the other, never from the product whose pixel shows the ridge in
front; where neither sees it the count is 0; the bytes do not depend on the product order."""

from __future__ import annotations

import numpy as np
import pytest

from napari_meris_ortho.ortho import orthorectify
from napari_meris_ortho.synthesis import open_synthesis, synthesize

#: fr-steep seen from an orbit west of its range (the range east of the track, to the left of
#: the descending flight): the slopes fr-steep's sensor, east of the range, cannot see
WEST = {"base": "fr-steep", "name": "fr-steep-west", "orbit": {"nadir_lon": 7.0,
                                                               "nadir_lat": 48.0},
        "first_column": -2240}


@pytest.fixture(scope="module")
def pair():
    from types import SimpleNamespace

    from napari_meris_ortho.simulate.scene import generate_scene

    east, west = generate_scene("fr-steep"), generate_scene(WEST)
    dems = [east.dem_paths["geotiff"], west.dem_paths["geotiff"]]
    a = orthorectify(east.product_path, dems=dems, bands=[7])
    b = orthorectify(west.product_path, grid=a.grid, dems=dems, bands=[7])
    return SimpleNamespace(east=east, west=west, dems=dems, grid=a.grid, a=a, b=b)


def _layers(path) -> dict[str, np.ndarray]:
    store = open_synthesis(path)
    return {name: np.asarray(store.read(name)) for name in store.layers()}


@pytest.mark.slow
def test_ground_one_product_cannot_see_comes_from_the_other(pair, tmp_path) -> None:
    a, b = pair.a, pair.b
    one_sees = a.hidden & b.valid & ~b.hidden  # hidden from fr-steep, seen from the west
    other_sees = b.hidden & a.valid & ~a.hidden
    assert one_sees.sum() > 3000 and other_sees.sum() > 5000
    assert not np.any(a.hidden & b.hidden)  # seen from opposite sides
    paths = [pair.east.product_path, pair.west.product_path]
    out = tmp_path / "s"
    result = synthesize(paths, out, grid=pair.grid, dems=pair.dems, bands=[7],
                        algorithm="min-radiance")
    index = {r.path: r.index for r in result.reports}
    ia, ib = index[str(paths[0])], index[str(paths[1])]
    got = _layers(out)
    product, count, band = got["product"], got["count"], got["band_07"]
    # the composite there comes from the product that sees the ground, with its radiance
    assert np.all(product[one_sees] == ib) and np.all(product[other_sees] == ia)
    assert np.allclose(band[one_sees], b.bands[7][one_sees], rtol=1e-3, atol=0.05)
    assert np.allclose(band[other_sees], a.bands[7][other_sees], rtol=1e-3, atol=0.05)
    assert np.all(count[one_sees] == 1) and np.all(count[other_sees] == 1)
    # never a hidden point: each winner sees its ground
    assert not np.any((product == ia) & a.hidden) and not np.any((product == ib) & b.hidden)
    # the run records the hidden points of each product
    hidden = {r.path: r.hidden for r in result.reports}
    assert hidden[str(paths[0])] == a.stats.hidden_points
    assert hidden[str(paths[1])] == b.stats.hidden_points
    assert any("NUMBER OF POINTS HIDDEN BY THE RELIEF = " in line
               for r in result.reports for line in r.lines(pair.grid.width * pair.grid.height))
    commit = open_synthesis(out).history()[0]
    assert sorted(p["hidden"] for p in commit.products) == sorted(hidden.values())
    assert commit.run["options"]["hidden"] == "mask"
    # the same bytes whatever the order of the products
    out2 = tmp_path / "s2"
    synthesize(paths[::-1], out2, grid=pair.grid, dems=pair.dems, bands=[7],
               algorithm="min-radiance", hidden="keep")
    for key, value in _layers(out2).items():
        assert value.tobytes() == got[key].tobytes(), key
    # hidden from every product (one here): nothing merged, count 0
    alone = tmp_path / "alone"
    synthesize(paths[:1], alone, grid=pair.grid, dems=pair.dems, bands=[7])
    got = _layers(alone)
    assert np.all(got["count"][a.hidden] == 0) and np.all(got["product"][a.hidden] == 0)
    assert np.all(got["band_07"][a.hidden] == 0)
    assert np.mean(got["count"][a.valid] == 1) > 0.99  # (L1b flags leave a few out)

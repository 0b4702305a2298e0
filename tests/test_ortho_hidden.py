"""Ground hidden from the sensor by the relief, in every mode with DEMs: found against the
simulator's truth (``SimulatedScene.seen_from_sensor``, a 5 m march), left no data (``mask``)
or mapped (``keep``), counted in the statistics and the log, in the diagnostics, the COG's
mask, the tags and ``to_xarray``."""

from __future__ import annotations

import json
import logging
from types import SimpleNamespace

import numpy as np
import pytest
import rasterio

from napari_meris_ortho.cli import main
from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.options import Hidden, OrthoOptions
from napari_meris_ortho.ortho import orthorectify


def test_the_hidden_option_is_checked() -> None:
    assert OrthoOptions.of(None).hidden is Hidden.MASK
    assert OrthoOptions.of(None, hidden="keep").hidden is Hidden.KEEP
    assert OrthoOptions.of(None, hidden="keep").values()["hidden"] is Hidden.KEEP
    with pytest.raises(OptionsError, match="unknown hidden-ground choice 'hide': choose mask "
                                           "or keep"):
        OrthoOptions.of(None, hidden="hide")


def test_the_cli_refuses_an_unknown_hidden_choice(capsys, tmp_path) -> None:
    with pytest.raises(SystemExit) as info:
        main(["map", str(tmp_path / "p.N1"), "-o", str(tmp_path / "o.tif"), "--hidden", "x"])
    assert info.value.code == 2
    assert "--hidden: invalid choice: 'x'" in capsys.readouterr().err


def _truth(scene, grid, window=None):
    """Per output point of ``grid`` (rows, columns ``window``): true antecedent, in the
    product, seen from the sensor."""
    r0, r1, c0, c1 = window or (0, grid.height, 0, grid.width)
    lon, lat = grid.lonlat(r0, r1, col_start=c0, col_stop=c1)
    h = scene.dem_height(lon, lat)
    tl, tc = scene.true_antecedent(lon, lat, h)
    g = scene.geometry
    inside = ((tl >= -0.5) & (tl < g.lines - 0.5) & (tc >= -0.5) & (tc < g.columns - 0.5)
              & np.isfinite(h))
    seen = np.zeros(inside.shape, bool)
    seen[inside] = scene.seen_from_sensor(lon[inside], lat[inside], h[inside], tl[inside],
                                          tc[inside], step=5.0)
    return SimpleNamespace(tl=tl, tc=tc, inside=inside, seen=seen, hidden=inside & ~seen)


def _rms(r, truth, where) -> float:
    e = np.hypot(r.diagnostics["line"] - truth.tl, r.diagnostics["col"] - truth.tc)[where]
    return float(np.sqrt(np.mean(e ** 2)))


@pytest.fixture(scope="module")
def steep():
    """fr-steep (9 km relief at 23-41 deg view zenith, 2.8 % of its ground hidden), its DEM,
    the default run's grid and the truth there."""
    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene("fr-steep")
    dem = scene.dem_paths["geotiff"]
    first = orthorectify(scene.product_path, dems=[dem], bands=[7], diagnostics=True)
    return SimpleNamespace(scene=scene, dem=dem, grid=first.grid, first=first,
                           truth=_truth(scene, first.grid))


#: fr-steep seen from an orbit west of its range: lines of sight going west
STEEP_WEST = {"base": "fr-steep", "name": "fr-steep-west",
              "orbit": {"nadir_lon": 7.0, "nadir_lat": 48.0}, "first_column": -2240}


@pytest.mark.parametrize(("scene_name", "utm"), [("fr-steep", False), ("fr-steep", True),
                                                 ("fr-steep-west", False),
                                                 ("rr-segment", False)])
def test_the_horizon_bound_marches_every_point_that_can_be_hidden(scene_name, utm, monkeypatch
                                                                    ) -> None:
    """Points the horizon bound clears are seen: the hidden-ground mask is the same as when
    every line of sight is marched (east- and west-looking scenes, one across nadir; a
    geographic grid, whose cells are found a row and a column at a time, and a UTM one); on
    moderate relief the bound clears most points."""
    from napari_meris_ortho import read_product
    from napari_meris_ortho.engine import sightline
    from napari_meris_ortho.geometry.grid import footprint_utm
    from napari_meris_ortho.ortho import occlusion
    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene(STEEP_WEST if scene_name == "fr-steep-west" else scene_name)
    kw = {"dems": [scene.dem_paths["geotiff"]], "bands": [7]}
    if utm:
        tp = read_product(scene.product_path).tie_points
        kw["crs"] = footprint_utm(tp.latitude, tp.longitude).to_string()
    marched: dict[str, int] = {}

    def counting(name: str):
        chooser = getattr(sightline, name)

        def counted(*a, **k):
            r = chooser(*a, **k)
            marched[name] = marched.get(name, 0) + r.size
            return r
        return counted

    for name in ("to_march", "to_march_grid"):
        monkeypatch.setattr(sightline, name, counting(name))
    bounded = orthorectify(scene.product_path, **kw)
    monkeypatch.undo()
    assert list(marched) == (["to_march"] if utm else ["to_march_grid"])
    monkeypatch.setattr(occlusion, "_horizon", lambda *a, **k: None)
    every = orthorectify(scene.product_path, **kw)
    assert np.array_equal(bounded.hidden, every.hidden)
    assert np.array_equal(bounded.valid, every.valid)
    assert bounded.hidden.sum() == every.hidden.sum() > (1000 if "steep" in scene_name else 10)
    if scene_name == "rr-segment":  # moderate relief: beyond the columns near nadir (a
        # ninth of the swath, always marched) few points are within reach of a slope
        assert sum(marched.values()) < 0.2 * bounded.valid.sum()


@pytest.mark.slow
@pytest.mark.parametrize(("parallax", "method"), [("handbook", "primary"),
                                                  ("ellipsoid", "primary"),
                                                  ("handbook", "handbook"),
                                                  ("ellipsoid", "handbook")])
def test_hidden_ground_of_the_tie_points_with_a_dem(steep, parallax, method) -> None:
    """Both parallax models, both searches: 100 % of fr-steep's hidden ground flagged (the
    truth's 6331 points), 0.01 % of the seen ground flagged (crests grazed by less than the
    truth's 5 m samples see), none of the hidden ground mapped with ``mask``; ``keep`` maps
    what the tie points map without the mask (the same antecedents: the seen ground's RMS
    distance to the truth unchanged to 0.001 px, 0.0458 px with the handbook sphere)."""
    t = steep.truth
    kw = dict(grid=steep.grid, dems=[steep.dem], bands=[7], diagnostics=True,
              parallax=parallax, method=method)
    mask = steep.first if (parallax, method) == ("handbook", "primary") else orthorectify(
        steep.scene.product_path, **kw)
    keep = orthorectify(steep.scene.product_path, hidden="keep", **kw)
    assert t.hidden.sum() == 6331
    for r in (mask, keep):
        assert r.hidden is not None
        assert (r.hidden & t.hidden).sum() >= 0.97 * t.hidden.sum()
        assert (r.hidden & t.seen).sum() <= 0.002 * t.seen.sum()
        assert r.stats.hidden_points == int(r.hidden.sum())
        assert np.array_equal(r.diagnostics["hidden"], r.hidden.astype(np.uint8))
    assert np.array_equal(mask.hidden, keep.hidden)
    # mask: hidden ground no data, counted; keep: mapped, counted
    assert (mask.valid & t.hidden).sum() <= 0.03 * t.hidden.sum()
    assert not np.any(mask.valid & mask.hidden) and np.all(mask.bands[7][mask.hidden] == 0)
    assert np.all(mask.diagnostics["iterations"][mask.hidden & keep.valid] == -2)
    assert np.array_equal(mask.valid, keep.valid & ~keep.hidden)
    assert (keep.valid & t.hidden).sum() >= 0.97 * t.hidden.sum()
    assert np.array_equal(keep.bands[7][~keep.hidden], mask.bands[7][~keep.hidden])
    assert mask.stats.hidden == "mask" and keep.stats.hidden == "keep"
    n = mask.stats.hidden_points
    assert n > 6000
    assert f"points hidden by the relief (no antecedent) = {n}" in mask.stats.log_lines()
    assert f"points hidden by the relief (mapped, hidden keep) = {n}" in keep.stats.log_lines()
    # the seen ground: the same antecedents with or without the mask
    seen = t.seen & mask.valid
    assert seen.sum() >= 0.999 * (t.seen & keep.valid).sum()
    assert abs(_rms(mask, t, seen) - _rms(keep, t, t.seen & keep.valid)) < 0.001
    ok = keep.valid & ~keep.hidden
    assert np.array_equal(mask.diagnostics["line"][ok], keep.diagnostics["line"][ok])
    if (parallax, method) == ("handbook", "primary"):
        assert abs(_rms(mask, t, seen) - 0.0458) < 0.001


@pytest.mark.slow
def test_hidden_ground_in_the_alps() -> None:
    """fr-alps (4.5 km ranges at 0-40 deg view zenith, its 9" DEM), over the high range: the
    hidden ground found (recall >= 97 %, false alarms <= 0.2 % of the seen ground), none of
    it mapped with ``mask``."""
    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene("fr-alps")
    dem = scene.dem_paths["geotiff"]
    r = orthorectify(scene.product_path, dems=[dem], bands=[7], diagnostics=True)
    lon, lat = r.grid.lonlat(0, 1, col_start=0, col_stop=r.grid.width)
    cols = np.flatnonzero((lon[0] > 9.5) & (lon[0] < 12.5))
    lon, lat = r.grid.lonlat(0, r.grid.height, col_start=0, col_stop=1)
    rows = np.flatnonzero((lat[:, 0] > 46.0) & (lat[:, 0] < 47.0))
    window = (int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1)
    t = _truth(scene, r.grid, window)
    r0, r1, c0, c1 = window
    flagged, valid = r.hidden[r0:r1, c0:c1], r.valid[r0:r1, c0:c1]
    assert t.hidden.sum() > 1000
    assert (flagged & t.hidden).sum() >= 0.97 * t.hidden.sum()
    assert (flagged & t.seen).sum() <= 0.002 * t.seen.sum()
    assert (valid & t.hidden).sum() <= 0.03 * t.hidden.sum()


@pytest.mark.slow
@pytest.mark.parametrize("hidden", ["mask", "keep"])
def test_the_map_carries_the_hidden_ground(steep, tmp_path, caplog, hidden) -> None:
    """``meris-ortho map --hidden``: the log, ``--stats-json`` and the tags count the hidden
    ground; the diagnostics' band ``hidden`` flags it; with ``mask`` it is nodata, so GDAL's
    mask of the file (``dataset_mask``) leaves it out; ``to_xarray`` carries ``hidden``."""
    caplog.set_level(logging.INFO, logger="napari_meris_ortho")
    out, stats = tmp_path / "out.tif", tmp_path / "stats.json"
    assert main(["map", str(steep.scene.product_path), "--dem", str(steep.dem), "-o", str(out),
                 "--bands", "7", "--diagnostics", "--stats-json", str(stats),
                 "--hidden", hidden]) == 0
    flagged = steep.first.hidden
    n = int(flagged.sum())
    what = "no antecedent" if hidden == "mask" else "mapped, hidden keep"
    assert f"points hidden by the relief ({what}) = {n}" in caplog.text
    doc = json.loads(stats.read_text())
    assert doc["hidden_points"] == n and doc["hidden"] == hidden
    assert doc["output"]["hidden"] == hidden and doc["output"]["hidden_points"] == n
    with rasterio.open(out) as ds:
        tags = ds.tags()
        assert tags["hidden"] == hidden and tags["hidden_points"] == str(n)
        mask = ds.dataset_mask()
        band = ds.read(1)
    with rasterio.open(tmp_path / "out_diagnostics.tif") as ds:
        names = list(ds.descriptions)
        diag = ds.read(names.index("hidden") + 1)
    assert np.array_equal(diag == 1, flagged)
    if hidden == "mask":
        assert np.all(mask[flagged] == 0) and np.all(band[flagged] == 0)
    else:
        assert np.count_nonzero(mask[flagged]) > 0.97 * n
    assert np.array_equal(mask == 255, band != 0)  # GDAL's mask: the file's nodata (0)
    assert np.mean(mask[steep.first.valid] == 255) > 0.999
    ds = steep.first.to_xarray()
    assert ds["hidden"].dtype == bool and int(ds["hidden"].sum()) == n
    assert ds.attrs["hidden"] == "mask" and ds.attrs["hidden_points"] == n

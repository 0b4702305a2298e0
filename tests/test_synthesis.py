"""On-disk synthesis (synthesis.py): layers, manifest, option checks of Appendix C."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio

from napari_meris_ortho.engine.grid import OutputGrid
from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.synthesis import (
    _commit,
    _create_layers,
    _Layers,
    grid_window,
    open_synthesis,
    synthesize,
    tiles,
)


def _grid() -> OutputGrid:
    return OutputGrid("EPSG:4326", 10.0, 46.0, 0.01, 0.01, 300, 200)


def test_tiles_cover_window_once_aligned() -> None:
    window = (100, 700, 30, 530)
    seen = np.zeros((800, 600), np.int32)
    for r0, r1, c0, c1 in tiles(window, 256):
        assert (r0 // 256) == ((r1 - 1) // 256) and (c0 // 256) == ((c1 - 1) // 256)
        seen[r0:r1, c0:c1] += 1
    assert seen[100:700, 30:530].min() == 1 and seen.sum() == 600 * 500


def test_grid_window_geolocation() -> None:
    grid = _grid()
    sub = grid_window(grid, 50, 120, 30, 90)
    assert (sub.height, sub.width) == (70, 60)
    x, y = grid.xy(np.array([55.0]), np.array([33.0]))
    xs, ys = sub.xy(np.array([5.0]), np.array([3.0]))
    assert abs(x[0] - xs[0]) < 1e-12 and abs(y[0] - ys[0]) < 1e-12


def test_layers_round_trip_and_manifest(tmp_path) -> None:
    grid = _grid()
    work = tmp_path / "out" / ".gen-000001.x.tmp"
    work.mkdir(parents=True)
    _create_layers(work, grid, (7, 13), "max-ndvi")
    layers = _Layers(work, (7, 13), "max-ndvi")
    win = (10, 60, 20, 300)
    state = layers.read(win)
    assert state["synthesis"].shape == (2, 50, 280) and not state["synthesis"].any()
    state["synthesis"][1] = 42.5
    state["ndvi"][:] = 49152
    state["count"][:] = 3
    layers.write(win, state)
    layers.close()
    _commit(work, tmp_path / "out", "gen-000001", None, "max-ndvi", (7, 13), grid, [])
    store = open_synthesis(tmp_path / "out")
    assert store.bands == (7, 13) and store.algorithm == "max-ndvi"
    assert store.grid == grid
    band = store.read("band_13")
    assert band.dtype == np.float32 and band.shape == (200, 300)
    assert band[10:60, 20:].min() == 42.5 and band.sum() == 42.5 * 50 * 280
    assert store.read("ndvi", (10, 12, 20, 22)).tolist() == [[49152] * 2] * 2
    with rasterio.open(store.files()["ndvi"]) as ds:
        assert ds.dtypes[0] == "uint16" and ds.nodata == 0
        assert ds.transform.c == 10.0 and ds.transform.f == 46.0
    assert not any(p.name.endswith(".tmp") for p in (tmp_path / "out").iterdir())


def test_options_refused_like_mersyn(tmp_path) -> None:
    grid = _grid()
    work = tmp_path / "syn" / ".gen-000001.x.tmp"
    work.mkdir(parents=True)
    _create_layers(work, grid, (3,), "min-radiance")
    _commit(work, tmp_path / "syn", "gen-000001", None, "min-radiance", (3,), grid, [])
    product = tmp_path / "p.N1"
    with pytest.raises(OptionsError, match="shall not be given"):
        synthesize([product], tmp_path / "syn", input=tmp_path / "syn", grid=grid)
    with pytest.raises(OptionsError, match="shall not be given"):
        synthesize([product], tmp_path / "syn", input=tmp_path / "syn", pixel_size=0.1)
    with pytest.raises(OptionsError, match="shall not be given"):
        synthesize([product], tmp_path / "syn", input=tmp_path / "syn", bands=[3])
    with pytest.raises(OptionsError, match="min-radiance synthesis"):
        synthesize([product], tmp_path / "syn", input=tmp_path / "syn", algorithm="max-ndvi")
    with pytest.raises(OptionsError, match="already holds a synthesis"):
        synthesize([product], tmp_path / "syn")
    with pytest.raises(OptionsError, match="algorithm"):
        synthesize([product], tmp_path / "new", algorithm="mean")
    with pytest.raises(OptionsError, match="bands"):
        synthesize([product], tmp_path / "new", bands=[0, 16])
    with pytest.raises(OptionsError, match="not a synthesis"):
        synthesize([product], tmp_path / "new", input=tmp_path)
    (tmp_path / "syn" / "synthesis.json").write_text(json.dumps({"format": "other"}))
    with pytest.raises(OptionsError, match="damaged"):
        open_synthesis(tmp_path / "syn")

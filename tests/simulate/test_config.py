"""Scene configs, overrides, cache and determinism."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import napari_meris_ortho
from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.products.n1 import read_product
from napari_meris_ortho.simulate import (
    config_hash,
    default_out_dir,
    generate_scene,
    resolve_config,
    scene_names,
)
from napari_meris_ortho.simulate.scene import scene_dirs

OFF = {"getasse30": False, "getasse30_beam": False, "srtm30": False, "geotiff_utm": False,
       "reference": False}
TINY = {"base": "fr-small", "lines": 40, "columns": 65, "exports": OFF}


def test_named_scenes_are_package_data(tmp_path, monkeypatch):
    names = {"fr-alps", "fr-small", "rr-segment", "rr-antimeridian", "fr-south-ascending",
             "fr-steep", "olci-efr-alps", "olci-err-andes"}
    assert names <= set(scene_names())
    package = scene_dirs()[-1]
    assert package == Path(napari_meris_ortho.__file__).parent / "scenes"
    assert {p.stem for p in package.glob("*.json")} == names
    # $MERIS_ORTHO_SCENES comes first and adds names
    (tmp_path / "mine.json").write_text(json.dumps({"base": "fr-small", "lines": 64}))
    monkeypatch.setenv("MERIS_ORTHO_SCENES", str(tmp_path))
    assert scene_dirs()[0] == tmp_path and "mine" in scene_names()
    assert resolve_config("mine")["lines"] == 64


def test_overrides_merge_recursively():
    cfg = resolve_config({"base": "fr-small", "clouds": {"seed": 2, "fraction": 0.3},
                          "terrain": {"plain_height": 50}})
    alps = resolve_config("fr-alps")
    assert cfg["name"] == "fr-small" and cfg["lines"] == 320
    assert cfg["terrain"]["plain_height"] == 50
    assert cfg["terrain"]["ranges"] == alps["terrain"]["ranges"]
    assert cfg["clouds"] == {"seed": 2, "fraction": 0.3}
    assert cfg["exports"]["utm_spacing_m"] == 500.0 and cfg["exports"]["getasse30"] is True
    assert config_hash(cfg) == config_hash(json.loads(json.dumps(cfg)))
    assert config_hash(cfg) != config_hash(resolve_config("fr-small"))


def test_bad_configs_raise_one_clear_error():
    with pytest.raises(OptionsError, match="unknown scene 'nope'.*fr-alps"):
        resolve_config("nope")
    with pytest.raises(OptionsError, match="64 k \\+ 1"):
        resolve_config({"base": "fr-small", "columns": 100})
    with pytest.raises(OptionsError, match="FR or RR"):
        resolve_config({"base": "fr-small", "resolution": "XR"})
    with pytest.raises(OptionsError, match="ISO date"):
        resolve_config({"base": "fr-small", "date": "yesterday"})


def test_default_cache_directory(monkeypatch, tmp_path):
    monkeypatch.setenv("MERIS_ORTHO_CACHE", str(tmp_path))
    cfg = resolve_config(TINY)
    assert default_out_dir(cfg) == tmp_path / f"fr-small-{config_hash(cfg)}"


@pytest.mark.slow
def test_cache_reuse_regeneration_and_determinism(tmp_path):
    a = generate_scene(TINY, out_dir=tmp_path / "a")
    stamp = a.product_path.stat().st_mtime_ns
    again = generate_scene(TINY, out_dir=tmp_path / "a")
    assert again.product_path.stat().st_mtime_ns == stamp  # reused
    g = a.pixel_geometry([20.0], [32.0])
    lon, lat = g["e_lon"][0, 0], g["e_lat"][0, 0]
    assert np.isfinite(a.dem_height(lon, lat))
    assert again.dem_height(lon, lat) == a.dem_height(lon, lat)
    assert np.array_equal(again.pixel_geometry([20.0], [32.0])["t_lon"], g["t_lon"])
    a.product_path.unlink()
    regen = generate_scene(TINY, out_dir=tmp_path / "a")
    assert regen.product_path.exists()
    b = generate_scene(TINY, out_dir=tmp_path / "b")
    pa, pb = read_product(regen.product_path), read_product(b.product_path)
    for band in (1, 7, 15):
        assert np.array_equal(pa.counts(band), pb.counts(band))
    for key in pa.tie_points:
        assert np.array_equal(pa.tie_points[key], pb.tie_points[key])
    assert np.array_equal(pa.flags, pb.flags)


def test_clouds_only_change_the_cloudy_pixels(tmp_path):
    clear = read_product(generate_scene(TINY, out_dir=tmp_path / "c0").product_path)
    c1 = read_product(generate_scene({**TINY, "clouds": {"seed": 1, "fraction": 0.4}},
                                     out_dir=tmp_path / "c1").product_path)
    c2 = read_product(generate_scene({**TINY, "clouds": {"seed": 2, "fraction": 0.4}},
                                     out_dir=tmp_path / "c2").product_path)
    for k in ("latitude", "dem_alt", "view_zenith"):
        assert np.array_equal(clear.tie_points[k], c1.tie_points[k])
    r0, r1, r2 = (p.radiance(3) for p in (clear, c1, c2))
    changed1 = r1 != r0
    assert 0.2 < changed1.mean() < 0.7
    assert np.all(r1[changed1] > r0[changed1])  # clouds are brighter than the ground
    assert not np.array_equal(changed1, r2 != r0)


def test_progress_is_reported_up_to_the_total(tmp_path):
    calls = []
    generate_scene({**TINY, "seed": 5}, out_dir=tmp_path / "p",
                   progress=lambda done, total: calls.append((done, total)))
    done = [d for d, _ in calls]
    assert len(calls) > 3 and all(t == 100 for _, t in calls)
    assert done == sorted(done) and done[-1] == 100

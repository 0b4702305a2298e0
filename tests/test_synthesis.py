"""Synthesis of many products (synthesis.py; section 3.1 use cases 1-2, Appendix B-C) on
simulated products: clouds, maximum NDVI, mosaic of adjacent orbits, incremental = batch, the
Icechunk store (layers, product table, history, snapshots), idempotent updates and the option
checks. Runs in this process (workers=0); dask workers: test_synthesis_distributed.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio

from napari_meris_ortho.engine.synthesis import ndvi_encode, validated_pixels
from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.geometry.grid import OutputGrid
from napari_meris_ortho.options import StoreCodec
from napari_meris_ortho.ortho import orthorectify
from napari_meris_ortho.simulate.radiometry import CLOUD_SPECTRUM
from napari_meris_ortho.synthesis import store as st
from napari_meris_ortho.synthesis.api import synthesize
from napari_meris_ortho.synthesis.export import export_cog
from napari_meris_ortho.synthesis.reading import open_synthesis
from napari_meris_ortho.synthesis.tiling import tiles

NO_EXPORTS = {"getasse30": False, "getasse30_beam": False, "srtm30": False,
              "geotiff_utm": False, "reference": False}
BANDS = (7, 13)
#: test grid over the fr-small piece (0.0015 deg pixels: 2 x 2 tiles of 256)
GRID = OutputGrid("EPSG:4326", 13.45, 46.70, 0.0015, 0.0015, 540, 340)


def scene_product(clouds: dict | None = None, orbit_shift_deg: float = 0.0,
                  **options: object) -> str:
    """A small simulated FR product (128 x 193) of the fr-small area, cached by the simulator.
    Cloudy variants of one acquisition get the file counter ``seed // 10`` in their product
    name (otherwise they would be one product: same name, same sensing time)."""
    from napari_meris_ortho.simulate.scene import generate_scene

    cfg = {"base": "fr-small", "lines": 128, "columns": 193, "first_column": 1150,
           "exports": NO_EXPORTS, "clouds": clouds, **options}
    if clouds and "file_counter" not in options:
        cfg["file_counter"] = int(clouds.get("seed", 0)) // 10 + 1
    if orbit_shift_deg:
        cfg["orbit"] = {"nadir_lon": 18.014693 + orbit_shift_deg}
    return str(generate_scene(cfg).product_path)


def layers(path, at: str | None = None) -> dict[str, np.ndarray]:
    """Every layer of a synthesis store as arrays."""
    store = open_synthesis(path, at=at)
    return {name: store.read(name) for name in store.layers()}


def stack(path) -> np.ndarray:
    store = open_synthesis(path)
    return np.stack([store.band(b) for b in store.bands])


@pytest.fixture(scope="module")
def products() -> dict[str, str]:
    out = {"clear": scene_product()}
    for k in (1, 2, 3):
        out[f"cloudy{k}"] = scene_product({"fraction": 0.4, "scale_km": 12.0, "seed": 10 * k})
    out["east"] = out["clear"]
    out["west"] = scene_product(orbit_shift_deg=-0.6, file_counter=9)
    return out


@pytest.fixture(scope="module")
def singles(products, tmp_path_factory) -> dict[str, np.ndarray]:
    """Each product alone on GRID (same tiles): its orthorectified bands (background 0)."""
    root = tmp_path_factory.mktemp("singles")
    out = {}
    for name in ("clear", "cloudy1", "cloudy2", "cloudy3"):
        synthesize([products[name]], root / name, grid=GRID, bands=BANDS, tile=256,
                   elevation="tiepoints")
        out[name] = stack(root / name)
    return out


def _grid() -> OutputGrid:
    return OutputGrid("EPSG:4326", 10.0, 46.0, 0.01, 0.01, 300, 200)


def test_tiles_cover_window_once_aligned() -> None:
    window = (100, 700, 30, 530)
    seen = np.zeros((800, 600), np.int32)
    for r0, r1, c0, c1 in tiles(window, 256):
        assert (r0 // 256) == ((r1 - 1) // 256) and (c0 // 256) == ((c1 - 1) // 256)
        seen[r0:r1, c0:c1] += 1
    assert seen[100:700, 30:530].min() == 1 and seen.sum() == 600 * 500


def test_store_layout_history_and_snapshots(products, tmp_path) -> None:
    """One commit per run; arrays chunked by the tile with decimated overviews; the product
    table names the winner of every pixel; --at reads an older state."""
    import zarr

    out = tmp_path / "s"
    first = synthesize([products["cloudy1"]], out, grid=GRID, bands=BANDS, tile=256,
                       algorithm="max-ndvi", elevation="tiepoints")
    state1 = layers(out)
    second = synthesize([products["cloudy2"]], out, input=out, tile=256, elevation="tiepoints")
    store = open_synthesis(out)
    assert store.snapshot == second.snapshot != first.snapshot
    assert store.layers() == ["band_07", "band_13", "ndvi", "count", "product"]
    assert store.overviews == [2] == st.overview_factors(540, 340, 256)
    root = zarr.open_group(store.session.store, mode="r")
    # compact band layers: uint16 counts with the band's Appendix A factor as CF scale_factor
    assert root["band_07"].attrs["scale_factor"] == st.BAND_SCALES[7] == 0.006815
    assert store.read("band_07").dtype == np.float32
    for name, dtype in (("band_07", "uint16"), ("ndvi", "uint16"), ("count", "uint16"),
                        ("product", "int32")):
        assert root[name].dtype == dtype and root[name].chunks == (256, 256)
        assert root[name].shape == (340, 540)
        assert root[f"overview_2/{name}"].chunks == (128, 128)
        np.testing.assert_array_equal(store.read(name, level=2), store.read(name)[::2, ::2])
    # history: one commit per run, newest first, listing its products
    history = store.history()
    assert [c.snapshot for c in history] == [second.snapshot, first.snapshot]
    assert [p["product_name"] for p in history[1].products] == [first.reports[0].product_name]
    assert history[0].products[0]["status"] == "merged" and "1 product(s)" in history[0].message
    # the winner layer: index into the product table, present exactly where count > 0
    names = store.product_names()
    assert sorted(names) == [1, 2]
    winner, count = store.read("product"), store.read("count")
    np.testing.assert_array_equal(winner > 0, count > 0)
    assert set(np.unique(winner)) == {0, 1, 2}
    assert [(r.added) for r in second.reports] == [int((winner == 2).sum())]
    # the first snapshot is still there, byte for byte
    older = layers(out, at=first.snapshot)
    for key, value in state1.items():
        assert value.tobytes() == older[key].tobytes(), key
    with pytest.raises(OptionsError, match="no snapshot"):
        open_synthesis(out, at="0" * 20)


def test_product_already_merged_is_skipped(products, tmp_path) -> None:
    """Same product name and sensing time: reported and skipped, the count does not grow
    (also within one run, and without a commit when nothing is new)."""
    out = tmp_path / "s"
    synthesize([products["cloudy1"], products["cloudy1"]], out, grid=GRID, bands=(13,),
               tile=256, elevation="tiepoints")
    before = layers(out)
    assert open_synthesis(out).read("count").max() == 1
    result = synthesize([products["cloudy1"], products["cloudy2"]], out, input=out, tile=256,
                        elevation="tiepoints")
    assert [r.status for r in result.reports] == ["already in the synthesis", "merged"]
    assert result.skipped[0].product_name == result.reports[0].product_name
    assert open_synthesis(out).read("count").max() == 2
    again = synthesize([products["cloudy2"]], out, input=out, tile=256, elevation="tiepoints")
    assert again.snapshot is None and len(again.skipped) == 1
    assert len(open_synthesis(out).history()) == 2
    assert before["count"].sum() < open_synthesis(out).read("count").sum()


def test_options_refused_like_mersyn(products, tmp_path) -> None:
    grid = _grid()
    product = products["cloudy1"]
    synthesize([product], tmp_path / "syn", grid=GRID, bands=(13,), tile=256,
               elevation="tiepoints")
    with pytest.raises(OptionsError, match="shall not be given"):
        synthesize([product], tmp_path / "syn", input=tmp_path / "syn", grid=grid)
    with pytest.raises(OptionsError, match="shall not be given"):
        synthesize([product], tmp_path / "syn", input=tmp_path / "syn", pixel_size=0.1)
    with pytest.raises(OptionsError, match="shall not be given"):
        synthesize([product], tmp_path / "syn", input=tmp_path / "syn", bands=[3])
    with pytest.raises(OptionsError, match="keep their codec"):
        synthesize([product], tmp_path / "syn", input=tmp_path / "syn", codec="delta-zstd")
    with pytest.raises(OptionsError, match="min-radiance synthesis"):
        synthesize([product], tmp_path / "syn", input=tmp_path / "syn", algorithm="max-ndvi")
    with pytest.raises(OptionsError, match="already holds a synthesis"):
        synthesize([product], tmp_path / "syn")
    with pytest.raises(OptionsError, match="algorithm"):
        synthesize([product], tmp_path / "new", algorithm="mean")
    with pytest.raises(OptionsError, match="bands"):
        synthesize([product], tmp_path / "new", bands=[0, 16])
    with pytest.raises(OptionsError, match="sampling"):
        synthesize([product], tmp_path / "new", sampling="sinc")
    with pytest.raises(OptionsError, match="elevation"):
        synthesize([product], tmp_path / "new", elevation="sea")
    with pytest.raises(OptionsError, match="unknown store codec 'lzma': choose zstd or delta"):
        synthesize([product], tmp_path / "new", codec="lzma")
    with pytest.raises(OptionsError, match="DEMs are only used with elevation"):
        synthesize([product], tmp_path / "new", elevation="none", dems=["x.tif"])
    with pytest.raises(OptionsError, match="CRS"):
        synthesize([product], tmp_path / "new", crs="EPSG:99999999")
    with pytest.raises(OptionsError, match="workers"):
        synthesize([product], tmp_path / "new", workers=-1)
    with pytest.raises(OptionsError, match="absolute path"):
        synthesize([product], "relative/store", scheduler="tcp://127.0.0.1:8786")
    with pytest.raises(OptionsError, match="not a synthesis store"):
        synthesize([product], tmp_path / "new", input=tmp_path)
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("x")
    with pytest.raises(OptionsError, match="not empty and not a synthesis store"):
        synthesize([product], tmp_path / "busy")
    assert not (tmp_path / "new").exists()
    # a synthesis of the old generation-directory format is refused with a clear message
    old = tmp_path / "old"
    old.mkdir()
    (old / "synthesis.json").write_text('{"format": "napari-meris-ortho synthesis"}')
    with pytest.raises(OptionsError, match="old generation-directory format"):
        open_synthesis(old)


# --------------------------------------------------------------------------- merge on products


def test_minimum_radiance_is_cloud_free_where_one_product_is_clear(products, singles,
                                                                    tmp_path) -> None:
    cloudy = ["cloudy1", "cloudy2", "cloudy3"]
    result = synthesize([products[k] for k in cloudy], tmp_path / "s", grid=GRID, bands=BANDS,
                        tile=256, elevation="tiepoints")
    assert not result.failed and result.snapshot is not None
    synthesis = stack(tmp_path / "s")
    clear = singles["clear"]
    inside = clear[0] > 0
    clear_in = [np.all(singles[k] == clear, axis=0) & inside for k in cloudy]
    one_clear = np.logical_or.reduce(clear_in)
    for c in clear_in:  # each date alone is clear on 38-43 % of the scene
        assert 0.3 < c.sum() / inside.sum() < 0.5
    assert one_clear.sum() / inside.sum() > 0.8  # 82 % on this scene
    # wherever one product is clear, the synthesis is the clear radiance, where the ground
    # is darker than the clouds (all but snow, 0.6 % here; 99.85 % exact, the rest
    # are pixels next to snow posts, where a cloud mixture is darker still)
    darker = np.all(clear < CLOUD_SPECTRUM[np.array(BANDS) - 1, None, None], axis=0)
    sel = one_clear & darker
    assert sel.sum() > 0.98 * one_clear.sum()
    exact = np.all(synthesis[:, sel] == clear[:, sel], axis=0)
    assert exact.mean() > 0.995
    assert np.all(synthesis[:, sel][:, ~exact] <= clear[:, sel][:, ~exact])
    # and band by band it is the minimum of the dates
    dates = np.stack([np.where(singles[k] > 0, singles[k], np.inf) for k in cloudy])
    expected = dates.min(axis=0)
    expected[np.isinf(expected)] = 0
    np.testing.assert_array_equal(synthesis, expected)
    count = open_synthesis(tmp_path / "s").read("count")
    np.testing.assert_array_equal(count, sum((singles[k][0] > 0).astype(int) for k in cloudy))


def test_maximum_ndvi_keeps_the_greenest_date(products, singles, tmp_path) -> None:
    cloudy = ["cloudy1", "cloudy2", "cloudy3"]
    result = synthesize([products[k] for k in cloudy], tmp_path / "s", grid=GRID, bands=BANDS,
                        algorithm="max-ndvi", tile=256, elevation="tiepoints")
    assert not result.failed
    synthesis = stack(tmp_path / "s")
    code = open_synthesis(tmp_path / "s").read("ndvi")
    dates = np.stack([singles[k] for k in cloudy])  # (date, band, row, col)
    red, nir = dates[:, 0].astype(np.float32), dates[:, 1].astype(np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):
        ndvi = np.where(red + nir > 0, (nir - red) / (red + nir), -np.inf)
    best = ndvi.max(axis=0)
    covered = np.isfinite(best)
    assert (code > 0).sum() == covered.sum() > 0.5 * code.size
    # the stored NDVI is the greenest date's, coded on 16 bits (within one quantum)
    diff = code[covered].astype(int) - ndvi_encode(best[covered]).astype(int)
    assert np.abs(diff).max() <= 1 and (diff == 0).mean() > 0.99
    decoded = open_synthesis(tmp_path / "s").ndvi()
    assert np.isnan(decoded[~covered]).all()
    assert np.abs(decoded[covered] - best[covered]).max() <= 1.5 / 32767
    # every band comes from one date whose NDVI is the maximum (within one quantum)
    quantum = 2.0 / 65534
    from_date = np.all(dates == synthesis[None], axis=1) & (ndvi >= best - quantum)
    assert from_date.any(axis=0)[covered].all()
    # clouds lower the NDVI of vegetation (NDVI > 0; a mixture's NDVI lies between its
    # parts'): there the greenest date is cloud free wherever one date is clear
    clear = singles["clear"]
    with np.errstate(invalid="ignore", divide="ignore"):
        green = (clear[1] - clear[0]) / (clear[1] + clear[0]) > 0
    one_clear = np.logical_or.reduce([np.all(singles[k] == clear, axis=0)
                                      for k in cloudy]) & covered & green
    assert one_clear.sum() > 0.3 * covered.sum()
    exact = np.all(synthesis[:, one_clear] == clear[:, one_clear], axis=0)
    assert exact.mean() > 0.999  # 99.99 % on this scene: pixels mixing a snow post


@pytest.mark.parametrize("algorithm", ["min-radiance", "max-ndvi"])
@pytest.mark.slow
def test_incremental_equals_batch(products, tmp_path, algorithm) -> None:
    names = [products[k] for k in ("cloudy1", "cloudy2", "cloudy3")]
    synthesize(names, tmp_path / "batch", grid=GRID, bands=BANDS, algorithm=algorithm,
               tile=256, elevation="tiepoints")
    inc = tmp_path / "inc"
    synthesize(names[:1], inc, grid=GRID, bands=BANDS, algorithm=algorithm, tile=256,
               elevation="tiepoints")
    for name in names[1:]:
        result = synthesize([name], inc, input=inc, tile=256, elevation="tiepoints")
        assert not result.failed
    batch, incremental = layers(tmp_path / "batch"), layers(inc)
    assert batch.keys() == incremental.keys()
    for key in batch:  # the winner indices too: products were added in canonical order
        assert batch[key].tobytes() == incremental[key].tobytes(), key
    store = open_synthesis(inc)
    assert len(store.history()) == 3
    assert [p["product"] for p in store.products] == [Path(n).name for n in names]


def test_adjacent_orbits_mosaic_without_seam(products, tmp_path) -> None:
    grid = OutputGrid("EPSG:4326", 12.80, 46.70, 0.0025, 0.0025, 600, 204)
    east, west = products["east"], products["west"]
    synthesize([east, west], tmp_path / "m", grid=grid, bands=BANDS, tile=256,
               elevation="tiepoints")
    synthesize([east], tmp_path / "e", grid=grid, bands=BANDS, tile=256, elevation="tiepoints")
    synthesize([west], tmp_path / "w", grid=grid, bands=BANDS, tile=256, elevation="tiepoints")
    count = open_synthesis(tmp_path / "m").read("count")
    cover_e = open_synthesis(tmp_path / "e").read("count") > 0
    cover_w = open_synthesis(tmp_path / "w").read("count") > 0
    np.testing.assert_array_equal(count, cover_e.astype(int) + cover_w)
    overlap = cover_e & cover_w
    assert overlap.sum() > 2000 and (cover_e & ~cover_w).sum() > 2000
    # every line where the swaths meet is one run of covered pixels: no gap between orbits
    # (but the product pixels flagged INVALID, which both orthorectified images show too)
    flagged = np.zeros(count.shape, bool)
    for product in (east, west):
        direct = orthorectify(product, grid=grid, elevation="tiepoints", bands=[7])
        flagged |= direct.valid & (direct.flags & 128 > 0)
    assert flagged.sum() < 10
    rows = np.flatnonzero(overlap.any(axis=1))
    assert rows.size > 100
    for i in rows:
        cols = np.flatnonzero((count[i] > 0) | flagged[i])
        assert cols[-1] - cols[0] + 1 == cols.size, f"gap in line {i}"
    # the west product fills the mosaic beyond the east one with its own radiances
    mosaic, only_w = stack(tmp_path / "m"), stack(tmp_path / "w")
    west_only = cover_w & ~cover_e
    np.testing.assert_array_equal(mosaic[:, west_only], only_w[:, west_only])


def test_failed_product_is_skipped_and_reported(products, tmp_path, caplog) -> None:
    bad = tmp_path / "broken.N1"
    bad.write_bytes(b"PRODUCT=" + b"x" * 3000)
    good = [products["cloudy1"], products["cloudy2"]]
    with caplog.at_level("INFO", logger="napari_meris_ortho.synthesis"):
        result = synthesize([good[0], str(bad), good[1]], tmp_path / "s", grid=GRID,
                            bands=BANDS, tile=256, elevation="tiepoints")
    assert [r.path for r in result.failed] == [str(bad)]
    assert "broken.N1" in caplog.text and "SKIPPED" in caplog.text
    synthesize(good, tmp_path / "ref", grid=GRID, bands=BANDS, tile=256, elevation="tiepoints")
    np.testing.assert_array_equal(stack(tmp_path / "s"), stack(tmp_path / "ref"))
    # Appendix B log: processed/validated points and share of the synthesis
    report = result.reports[0]
    count = open_synthesis(tmp_path / "ref").read("count")
    assert report.processed >= report.validated > 0.3 * GRID.width * GRID.height
    share = 100.0 * report.processed / (GRID.width * GRID.height)
    assert f"NUMBER OF PROCESSED POINTS IN SEGMENT = {report.processed} ({share:.1f}% of " \
        "synthesis)" in caplog.text
    assert "NUMBER OF VALIDATED POINTS IN SEGMENT" in caplog.text
    assert count.max() == 2


def test_new_synthesis_takes_the_first_footprint(products, tmp_path) -> None:
    from napari_meris_ortho.engine.boundary import segment_boundary
    from napari_meris_ortho.geometry.grid import default_grid
    from napari_meris_ortho.products.n1 import read_product

    result = synthesize([products["clear"]], tmp_path / "s", bands=(7,), elevation="tiepoints")
    p = read_product(products["clear"])
    expected = default_grid(segment_boundary(p.tie_points["latitude"],
                                             p.tie_points["longitude"]), 260.0, "EPSG:4326")
    assert result.grid == expected == open_synthesis(tmp_path / "s").grid
    count = open_synthesis(tmp_path / "s").read("count")
    assert count.sum() == result.reports[0].validated > 0.5 * count.size


def test_update_into_another_store_and_lock(products, tmp_path) -> None:
    first, second = products["cloudy1"], products["cloudy2"]
    a, b = tmp_path / "a", tmp_path / "b"
    synthesize([first], a, grid=GRID, bands=(13,), tile=256, elevation="tiepoints")
    before = layers(a)
    result = synthesize([second], b, input=a, tile=256, elevation="tiepoints")
    assert open_synthesis(b).grid == GRID and open_synthesis(b).read("count").max() == 2
    assert len(open_synthesis(b).history()) == 2  # the copy keeps the history
    assert result.snapshot == open_synthesis(b).snapshot != open_synthesis(a).snapshot
    for key, value in layers(a).items():
        assert value.tobytes() == before[key].tobytes()
    with st.locked(a), pytest.raises(OptionsError, match="another synthesis run"):
        synthesize([second], a, input=a, tile=256, elevation="tiepoints")
    assert len(open_synthesis(a).history()) == 1


def test_bright_pixels_kept_out_on_request(products, tmp_path) -> None:
    cloudy = products["cloudy1"]
    kept = synthesize([cloudy], tmp_path / "k", grid=GRID, bands=(13,), tile=256,
                      elevation="tiepoints").reports[0]
    out = synthesize([cloudy], tmp_path / "o", grid=GRID, bands=(13,), tile=256,
                     elevation="tiepoints", reject_bright=True).reports[0]
    assert kept.processed == out.processed
    direct = orthorectify(cloudy, grid=GRID, elevation="tiepoints", bands=[13])
    bright = direct.valid & (direct.flags & 32 > 0)
    assert 0.1 * direct.valid.sum() < bright.sum()  # the clouds of this date
    assert kept.validated - out.validated == pytest.approx(bright.sum(), rel=1e-3)
    count = open_synthesis(tmp_path / "o").read("count")
    expected = direct.valid & (direct.flags & (4 | 32 | 128) == 0)
    assert (count.astype(bool) == expected).mean() > 0.999


def test_tile_beyond_the_zero_height_boundary_keeps_terrain_pixels(tmp_path) -> None:
    """Mountains seen from the west (view azimuth ~102 deg) are mapped up to 3 pixels east of
    the zero-height segment boundary (22 pixels here); with the tile edge right after the
    boundary, the east tiles hold no boundary pixel, yet the synthesis keeps those pixels
    (ortho allow_empty)."""
    from napari_meris_ortho.simulate.scene import generate_scene
    from napari_meris_ortho.synthesis.tiling import terrain_margin_px

    scene = generate_scene({"base": "fr-small", "lines": 128, "columns": 193,
                            "first_column": 1150, "exports": NO_EXPORTS, "clouds": None})
    dem = scene.dem_paths["geotiff"]
    # GRID's boundary ends at its column 531: make that the last column of the west tiles
    grid = OutputGrid("EPSG:4326", GRID.x0 + 276 * GRID.dx, GRID.y0, GRID.dx, GRID.dy, 512,
                      GRID.height)
    with pytest.raises(OptionsError, match="misses"):
        orthorectify(scene.product_path, grid=grid.window(0, 256, 256, 512), dems=[dem])
    synthesize([scene.product_path], tmp_path / "s", grid=grid, bands=(7,), tile=256,
               dems=[dem])
    count = open_synthesis(tmp_path / "s").read("count")
    direct = orthorectify(scene.product_path, grid=grid, dems=[dem], bands=[7])
    valid = validated_pixels(direct.valid, direct.flags, False)
    np.testing.assert_array_equal(count > 0, valid)
    assert 20 <= count[:, 256:].sum() == valid[:, 256:].sum()
    # the cheap tile skip leaves a margin for 9000 m seen at 45 deg: 9 km over pixels of
    # 0.0015 deg x cos(46.6 deg) = 115 m (the narrower pixel side), 79 pixels, plus 2
    from napari_meris_ortho.products.n1 import read_product

    product = read_product(scene.product_path)
    lat = float(np.max(np.abs(product.tie_points["latitude"])))
    assert 46.5 < lat < 46.8
    pixel_m = 0.0015 * np.cos(np.radians(lat)) * 111320.0
    assert terrain_margin_px(product, grid) == int(np.ceil(9000.0 / pixel_m)) + 2 == 81


def test_product_table_and_cog_export_carry_band_and_scaling_metadata(products,
                                                                      tmp_path) -> None:
    """Band description (number, wavelength) and radiance factors sf_rad in the product table
    and the COG export."""
    from napari_meris_ortho.products.n1 import read_product

    clear, cloudy = read_product(products["clear"]), read_product(products["cloudy1"])
    synthesize([products["clear"]], tmp_path / "s", grid=GRID, bands=BANDS, tile=256,
               elevation="tiepoints")
    synthesize([products["cloudy1"]], tmp_path / "s", input=tmp_path / "s", tile=256,
               elevation="tiepoints")
    store = open_synthesis(tmp_path / "s")
    table = store.products
    assert [p["product_name"] for p in table] == [clear.product_name, cloudy.product_name]
    assert table[1]["sf_rad"] == {str(b): cloudy.scaling.radiance[b - 1] for b in BANDS}
    assert table[0]["sensing_start"] == str(clear.first_line_time)
    out = export_cog(store, tmp_path / "s.tif", bands=[13])
    with rasterio.open(out) as ds:
        assert ds.count == 1 and ds.descriptions[0] == "MERIS band 13 (864.8 nm)"
        assert ds.tags()["products"].split() == [clear.product_name, cloudy.product_name]
        assert ds.overviews(1) and ds.profile["blockxsize"] == 512  # the COG block of write_map
        assert (ds.width, ds.height) == (GRID.width, GRID.height)
        assert ds.transform.c == GRID.x0 and ds.transform.f == GRID.y0
        assert ds.dtypes[0] == "uint16" and ds.scales[0] == st.BAND_SCALES[13]
        radiance = ds.read(1).astype(np.float32) * np.float32(ds.scales[0])
        assert radiance.tobytes() == store.band(13).tobytes()
    out = export_cog(store, tmp_path / "f.tif", bands=[13], dtype="float32")
    with rasterio.open(out) as ds:
        assert ds.read(1).tobytes() == store.band(13).tobytes()
    winner = export_cog(store, tmp_path / "w.tif", layer="product")
    with rasterio.open(winner) as ds:
        assert ds.dtypes[0] == "int32" and ds.read(1).max() == 2
    with pytest.raises(OptionsError, match="not in the synthesis"):
        export_cog(store, tmp_path / "x.tif", bands=[3])
    assert not (tmp_path / "x.tif").exists()


def test_progress_per_task_and_cancel_leave_the_store_untouched(products, tmp_path) -> None:
    """``progress(done, total)`` once before the first task (the total shown from the start),
    then after each product's piece of a tile and each merged tile (in process); an exception
    raised by it (napari's Cancel) stops the run: no commit, a new store is not left behind."""
    calls: list[tuple[int, int]] = []
    out = tmp_path / "s"
    synthesize([products["cloudy1"]], out, grid=GRID, bands=(13,), tile=256,
               elevation="tiepoints", progress=lambda d, t: calls.append((d, t)))
    total = calls[-1][1]
    assert [d for d, _ in calls] == list(range(0, total + 1))
    # a piece and a merge for each tile the product touches (of 3 x 2)
    assert total % 2 == 0 and 2 <= total <= 12
    before = layers(out)

    class Cancelled(Exception):
        pass

    def cancel(done: int, total: int) -> None:
        if done == 3:
            raise Cancelled

    with pytest.raises(Cancelled):
        synthesize([products["cloudy2"]], out, input=out, tile=256, elevation="tiepoints",
                   progress=cancel)
    assert len(open_synthesis(out).history()) == 1
    for key, value in layers(out).items():
        assert value.tobytes() == before[key].tobytes()
    with pytest.raises(Cancelled):
        synthesize([products["cloudy2"]], tmp_path / "new", grid=GRID, bands=(13,), tile=256,
                   elevation="tiepoints", progress=cancel)
    assert not (tmp_path / "new").exists()


def test_tie_points_and_boundary_built_once_per_product(tmp_path, monkeypatch) -> None:
    """The (product, tile) tasks share one tie-point grid, segment boundary and DEM
    window per product and process; every tile still equals the product orthorectified alone
    on that tile (DEM heights from the product-wide window = the tile's own)."""
    from collections import Counter, OrderedDict

    from napari_meris_ortho.ortho import core as ortho
    from napari_meris_ortho.simulate.scene import generate_scene
    from napari_meris_ortho.synthesis import run as _synthesis_run

    scene = generate_scene({"base": "fr-small", "lines": 128, "columns": 193,
                            "first_column": 1150, "exports": NO_EXPORTS, "clouds": None})
    dem = scene.dem_paths["geotiff"]
    builds: Counter[str] = Counter()
    tasks: Counter[str] = Counter()
    real_boundary, real_tp = ortho.segment_boundary, ortho.TiePointGrid.from_product.__func__
    real_task = _synthesis_run.segment_task

    def boundary(*args, **kwargs):
        builds["boundary"] += 1
        return real_boundary(*args, **kwargs)

    def tie_points(cls, prod):
        builds["tie_points"] += 1
        return real_tp(cls, prod)

    def task(spec, index, path, *args):
        tasks[path] += 1
        return real_task(spec, index, path, *args)

    monkeypatch.setattr(_synthesis_run, "_SEGMENTS", OrderedDict())  # this run's builds only
    monkeypatch.setattr(ortho, "segment_boundary", boundary)
    monkeypatch.setattr(ortho.TiePointGrid, "from_product", classmethod(tie_points))
    monkeypatch.setattr(_synthesis_run, "segment_task", task)
    synthesize([scene.product_path], tmp_path / "s", grid=GRID, bands=(7,), tile=256,
               dems=[dem])
    assert tasks[str(scene.product_path)] >= 4  # the tiles of 256 x 256 holding its pixels
    assert builds == {"boundary": 1, "tie_points": 1}
    monkeypatch.undo()
    band, compared = open_synthesis(tmp_path / "s").band(7), 0
    for r0 in range(0, GRID.height, 256):
        for c0 in range(0, GRID.width, 256):
            window = (r0, min(r0 + 256, GRID.height), c0, min(c0 + 256, GRID.width))
            try:
                alone = orthorectify(scene.product_path, grid=GRID.window(*window), dems=[dem],
                                     bands=[7])
            except OptionsError:  # no pixel of the product there
                continue
            valid = validated_pixels(alone.valid, alone.flags, False)
            tile = band[window[0]:window[1], window[2]:window[3]]
            np.testing.assert_array_equal(tile[valid], alone.bands[7][valid])
            assert not tile[~valid].any()
            compared += 1
    assert compared >= 4


@pytest.mark.parametrize("sampling", ["nearest", "bilinear"])
def test_compact_layers_round_trip_within_half_a_count(products, tmp_path, sampling) -> None:
    """Band layers are uint16 counts of the band's Appendix A factor: a standard product's
    nearest-neighbour radiances come back exactly, interpolated ones within half a count; the
    layers read back as float32 radiances, and smaller than float32 would be."""
    from napari_meris_ortho.products.open import read_product

    out = tmp_path / "s"
    synthesize([products["clear"]], out, grid=GRID, bands=BANDS, tile=256,
               elevation="tiepoints", sampling=sampling)
    store = open_synthesis(out)
    mapped = orthorectify(read_product(products["clear"]), GRID, bands=BANDS,
                          elevation="tiepoints", sampling=sampling)
    for b in BANDS:
        stored, want = store.band(b), mapped.bands[b]
        inside = store.read("count") > 0
        assert stored.dtype == np.float32 and inside.sum() > 50_000
        error = np.abs(stored[inside].astype(np.float64) - want[inside])
        if sampling == "nearest":
            assert error.max() == 0.0
        else:
            # half a count, plus the float32 rounding of the radiances themselves
            ulp = float(np.spacing(np.float32(want.max())))
            assert error.max() <= st.BAND_SCALES[b] / 2 + 2 * ulp and error.max() > 0
        assert (stored[~inside] == 0).all()


@pytest.mark.parametrize("sampling", ["nearest", "bilinear"])
def test_a_products_own_counts_are_merged_as_they_are(products, sampling) -> None:
    """At the nearest pixel, a standard product's counts already are the compact store's (its
    scales are Appendix A's): the tile task takes them as they are (``counts_as_stored``), and
    its state is, array for array, the one made through float32 radiances and back. Bilinear
    values and a product of other scales go through the radiances."""
    from dataclasses import replace

    from napari_meris_ortho.engine.synthesis import segment_counts_state
    from napari_meris_ortho.ortho import precompute
    from napari_meris_ortho.products.open import read_product
    from napari_meris_ortho.synthesis.run import _Sampled, counts_as_stored

    product = read_product(products["cloudy1"])
    antecedents = precompute(product, GRID, bands=[5, 7, 13], elevation="tiepoints",
                             sampling=sampling, hold_bands=True)
    radiances = antecedents.result().bands
    scales = {b: float(product.scaling.radiance[b - 1]) for b in (5, 7, 13)}
    spec = _spec(sampling)
    plan = spec.plan(product.sensor)
    assert counts_as_stored(spec, plan, scales) == (sampling == "nearest")
    assert not counts_as_stored(spec, plan, {**scales, 5: scales[5] * 1.5})
    assert not counts_as_stored(replace(spec, compact=False), plan, scales)
    sampled = _Sampled.of(antecedents, spec, plan)
    assert sampled.counts == (sampling == "nearest")
    valid = sampled.validated(spec, plan)
    assert valid.sum() > 50_000
    red, nir = (sampled.radiance(b, (0, GRID.height, 0, GRID.width)) for b in (7, 13))
    np.testing.assert_array_equal(red, radiances[7])
    np.testing.assert_array_equal(nir, radiances[13])
    if sampling != "nearest":
        return
    counts = antecedents.counts([5, 7])
    fast = segment_counts_state([counts[0], counts[1]], (0, 0), None, valid, 3, red, nir)
    slow = segment_counts_state([radiances[5], radiances[7]], (0, 0),
                                [st.count_divisor(st.BAND_SCALES[b]) for b in (5, 7)],
                                valid, 3, radiances[7], radiances[13])
    for name in ("bands", "count", "winner", "ndvi"):
        assert np.array_equal(getattr(fast, name), getattr(slow, name)), name
    assert fast.bands.dtype == np.uint16 and fast.bands[0][valid].min() > 0
    assert (fast.bands[:, ~valid] == 0).all() and (fast.winner[valid] == 3).all()


def _spec(sampling: str):
    """The task description of a maximum-NDVI synthesis of band 5 on GRID."""
    from napari_meris_ortho.options import OrthoOptions
    from napari_meris_ortho.synthesis.run import Spec

    options = OrthoOptions.of(None, n_dems=0, bands=[5, 7, 13], elevation="tiepoints",
                              sampling=sampling)
    return Spec(grid=(), bands=(5,), algorithm="max-ndvi", dems=(), options=options,
                reject_bright=False, tile=256, names=("band_05", "ndvi", "count", "product"),
                overviews=(2,))


def test_stored_tile_is_read_while_its_first_piece_is_computed(products, tmp_path,
                                                               monkeypatch) -> None:
    """A tile task starts reading its stored tile before its first piece is orthorectified
    (``run._read_ahead``): each read begins before the end of the first piece of its tile,
    and the update's layers equal those of one run of both products."""
    import threading
    import time

    from napari_meris_ortho.synthesis import run

    out = tmp_path / "s"
    synthesize([products["cloudy1"]], out, grid=GRID, bands=BANDS, tile=256,
               algorithm="max-ndvi", elevation="tiepoints")
    reads: dict[tuple[int, ...], float] = {}
    firsts: dict[tuple[int, ...], float] = {}
    lock = threading.Lock()
    real_read, real_segment = st.read_tile, run.segment_task

    def read_tile(store, names, window, layout=""):
        with lock:
            reads.setdefault(tuple(window), time.perf_counter())
        return real_read(store, names, window, layout)

    def segment_task(spec, index, path, piece, extent):
        result = real_segment(spec, index, path, piece, extent)
        tiles = [w for w in tiles_of if w[0] <= piece[0] < w[1] and w[2] <= piece[2] < w[3]]
        with lock:
            for w in tiles:
                firsts.setdefault(w, time.perf_counter())
        return result

    tiles_of = [tuple(w) for w in tiles((0, GRID.height, 0, GRID.width), 256)]
    monkeypatch.setattr(st, "read_tile", read_tile)
    monkeypatch.setattr(run, "segment_task", segment_task)
    synthesize([products["cloudy2"]], out, input=out, elevation="tiepoints")
    monkeypatch.undo()
    assert reads and set(reads) <= set(firsts)
    assert all(reads[w] < firsts[w] for w in reads), (reads, firsts)
    both = tmp_path / "both"
    synthesize([products["cloudy1"], products["cloudy2"]], both, grid=GRID, bands=BANDS,
               tile=256, algorithm="max-ndvi", elevation="tiepoints")
    want = layers(both)
    assert all(value.tobytes() == want[key].tobytes() for key, value in layers(out).items())


def test_update_writes_only_the_chunks_it_changes(products, tmp_path, monkeypatch) -> None:
    """An update rewrites exactly the chunks whose values change, counted in Icechunk's diff
    of the two commits: for ``count``, the chunks holding a validated pixel of the new product
    (at every overview level, its decimated pixels); for every layer, the chunks that differ
    between the snapshots, none else. Chunks (64 here) are smaller than the tile (256)."""
    from napari_meris_ortho.products.open import read_product

    monkeypatch.setattr(st, "CHUNK", 64)
    grid = OutputGrid("EPSG:4326", 12.80, 46.70, 0.0025, 0.0025, 600, 204)
    out = tmp_path / "s"
    first = synthesize([products["west"]], out, grid=grid, bands=BANDS, tile=256,
                       elevation="tiepoints")
    second = synthesize([products["east"]], out, input=out, elevation="tiepoints")
    store = open_synthesis(out)
    assert store.overviews == [2]
    diff = store.repo.diff(from_snapshot_id=first.snapshot, to_snapshot_id=second.snapshot)
    written = {path.strip("/"): {tuple(c) for c in coords}
               for path, coords in diff.updated_chunks.items()}

    def chunks(mask: np.ndarray) -> set[tuple[int, int]]:
        rows, cols = np.nonzero(mask)
        return set(zip((rows // 64).tolist(), (cols // 64).tolist(), strict=True))

    direct = orthorectify(read_product(products["east"]), grid=grid, elevation="tiepoints",
                          bands=[7])
    touched = validated_pixels(direct.valid, direct.flags, False)
    assert chunks(touched) == written["count"]
    assert chunks(touched[::2, ::2]) == written["overview_2/count"]
    assert 10 <= len(written["count"]) < 4 * 10  # 4 x 10 chunks of 64 in the grid
    before = layers(out, at=first.snapshot)
    for name, after in layers(out).items():
        for level in (1, 2):
            old, new = before[name][::level, ::level], after[::level, ::level]
            path = name if level == 1 else f"overview_2/{name}"
            assert written.get(path, set()) == chunks(old != new), path
    # a tile (4 x 4 chunks) the product only partly covers is only partly rewritten
    partial = [(ti, tj) for ti in range(1) for tj in range(3)
               if 0 < len({c for c in written["count"] if (c[0] // 4, c[1] // 4) == (ti, tj)})
               < len({(i, j) for i in range(4) for j in range(4 * tj, min(4 * tj + 4, 10))})]
    assert partial


def test_an_update_reads_only_zarr_v3_keys(products, tmp_path, monkeypatch) -> None:
    """Icechunk stores are Zarr v3: opening an array asks for its ``zarr.json`` only. Left to
    guess the format, zarr also asked for ``.zarray``, ``.zattrs``, ``.zgroup`` and
    ``.zmetadata`` at every open (2 169 of an fr-alps update's 4 116 reads; 0.3-0.5 s)."""
    import icechunk.store as ics

    grid = OutputGrid("EPSG:4326", 12.80, 46.70, 0.0025, 0.0025, 600, 204)
    out = tmp_path / "s"
    synthesize([products["west"]], out, grid=grid, bands=BANDS, tile=256, elevation="tiepoints")
    keys: list[str] = []
    get = ics.IcechunkStore.get

    async def counted(self, key, *args, **kwargs):
        keys.append(str(key))
        return await get(self, key, *args, **kwargs)

    monkeypatch.setattr(ics.IcechunkStore, "get", counted)
    synthesize([products["east"]], out, input=out, elevation="tiepoints")
    v2 = [k for k in keys if k.rsplit("/", 1)[-1] in (".zarray", ".zattrs", ".zgroup",
                                                      ".zmetadata")]
    # bands 7 and 13, count, product at levels 1 and 2: each array's zarr.json read
    arrays = {f"{level}{name}/zarr.json" for name in open_synthesis(out).layers()
              for level in ("", "overview_2/")}
    assert v2 == [] and len(arrays) == 8 and arrays <= set(keys)
    assert layers(out)["count"].max() >= 1


def test_tile_tasks_read_each_array_metadata_once(products, tmp_path, monkeypatch) -> None:
    """The tile tasks of a run read and write the same arrays of one snapshot: each array's
    ``zarr.json`` is read once in the process, not once per tile (3 tiles here; a tile task
    opening every layer it reads and every level it writes would read each full-resolution
    array 5 times and each overview twice in this update)."""
    import collections

    import icechunk.store as ics

    grid = OutputGrid("EPSG:4326", 12.80, 46.70, 0.0025, 0.0025, 600, 204)
    out = tmp_path / "s"
    synthesize([products["west"]], out, grid=grid, bands=BANDS, tile=256, elevation="tiepoints")
    reads: collections.Counter[str] = collections.Counter()
    get = ics.IcechunkStore.get

    async def counted(self, key, *args, **kwargs):
        if str(key).endswith("/zarr.json"):  # an array's, not the root group's
            reads[str(key)] += 1
        return await get(self, key, *args, **kwargs)

    monkeypatch.setattr(ics.IcechunkStore, "get", counted)
    result = synthesize([products["east"]], out, input=out, elevation="tiepoints",
                        workers=0)
    assert len(result.merged) == 1
    names = open_synthesis(out).layers()
    assert len(names) == 4  # bands 7 and 13, count, product
    assert reads == {f"{level}{name}/zarr.json": 1 for name in names
                     for level in ("", "overview_2/")}


def test_a_store_directory_made_meanwhile_by_another_run_is_no_error(tmp_path, monkeypatch
                                                                     ) -> None:
    """Two runs start the same new store: the one that looked before the other made the
    directory must still go on to the lock (which decides), not fail on "output exists and is a
    directory" (seen once in ``test_two_concurrent_runs_on_one_store``). Modelled here by a
    look that says "missing" while the directory is there; the messages of a file in the way
    and of a missing parent stay."""
    from pathlib import Path

    from napari_meris_ortho.errors import OutputError
    from napari_meris_ortho.synthesis.api import _make_dir

    out = tmp_path / "syn"
    assert _make_dir(out) is True and out.is_dir()
    real_exists = Path.exists
    monkeypatch.setattr(Path, "exists",
                        lambda self, *a, **k: False if self == out else real_exists(self, *a, **k))
    assert _make_dir(out) is False
    monkeypatch.undo()
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputError, match="exists and is not a directory"):
        _make_dir(tmp_path / "file")
    with pytest.raises(OutputError, match="does not exist"):
        _make_dir(tmp_path / "missing" / "syn")


def test_version_3_store_is_updated_in_its_own_layout(products, tmp_path, monkeypatch) -> None:
    """A store of version 3 (one chunk per tile, overviews by the tile / factor) keeps its
    layout and version when updated, and holds the layers a version-4 store gets."""
    import zarr

    names = [products["cloudy1"], products["cloudy2"]]
    old = tmp_path / "v3"
    with monkeypatch.context() as m:
        m.setattr(st, "VERSION", 3)
        m.setattr(st, "CHUNK", 1024)  # level_chunk(1024, 256, f) = 256 / f: the v3 layout
        synthesize(names[:1], old, grid=GRID, bands=BANDS, tile=256, algorithm="max-ndvi",
                   elevation="tiepoints")
    synthesize(names[1:], old, input=old, elevation="tiepoints")
    monkeypatch.setattr(st, "CHUNK", 64)
    synthesize(names, tmp_path / "v4", grid=GRID, bands=BANDS, tile=256, algorithm="max-ndvi",
               elevation="tiepoints")
    store = open_synthesis(old)
    root = zarr.open_group(store.session.store, mode="r")
    assert store.attrs["version"] == 3 and open_synthesis(tmp_path / "v4").attrs["version"] == 4
    assert root["band_07"].chunks == (256, 256) and root["overview_2/count"].chunks == (128, 128)
    new = layers(tmp_path / "v4")
    for key, value in layers(old).items():
        assert value.tobytes() == new[key].tobytes(), key


def _codecs(root, path: str) -> list[str]:
    return [c["name"] for c in root[path].metadata.to_dict()["codecs"]]


def _chunk_bytes(store, prefix: str) -> int:
    from zarr.core.buffer import default_buffer_prototype
    from zarr.core.sync import sync

    async def size() -> int:
        keys = [k async for k in store.list_prefix(prefix) if k.startswith(f"{prefix}/c/")]
        return sum([len((await store.get(k, default_buffer_prototype())).to_bytes())
                    for k in keys])

    return sync(size())


@pytest.mark.parametrize("workers", [0, 1])
@pytest.mark.slow
def test_store_codecs_kept_by_updates(products, tmp_path, workers) -> None:
    """A store of codec delta-zstd encodes the full-resolution bands and NDVI by delta then
    zstd (smaller chunks), the overviews, count and product by zstd alone; a default (zstd)
    store has zstd everywhere; updates keep each store's codecs, in process and on a
    LocalCluster, and both hold the same layers."""
    import zarr

    names = [products["cloudy1"], products["cloudy2"]]
    old, new = tmp_path / "zstd", tmp_path / "delta"
    for path, codec in ((old, None), (new, "delta-zstd")):
        synthesize(names[:1], path, grid=GRID, bands=BANDS, tile=256, algorithm="max-ndvi",
                   elevation="tiepoints", codec=codec)
        synthesize(names[1:], path, input=path, elevation="tiepoints", workers=workers)
    roots = {k: zarr.open_group(open_synthesis(p).session.store, mode="r")
             for k, p in (("old", old), ("new", new))}
    zstd, delta = ["bytes", "zstd"], ["numcodecs.delta", "bytes", "zstd"]
    for layer in ("band_07", "band_13", "ndvi", "count", "product"):
        assert _codecs(roots["old"], layer) == zstd, layer
        assert _codecs(roots["new"], layer) == (delta if layer[0] in "bn" else zstd), layer
        assert _codecs(roots["new"], f"overview_2/{layer}") == zstd, layer
    assert (open_synthesis(old).codec, open_synthesis(new).codec) == ("zstd", "delta-zstd")
    want = layers(new)
    assert sorted(want) == sorted(layers(old))
    for key, value in layers(old).items():
        assert value.tobytes() == want[key].tobytes(), key
    sizes = {k: _chunk_bytes(open_synthesis(p).session.store, "band_07")
             for k, p in (("old", old), ("new", new))}
    assert sizes["new"] < 0.95 * sizes["old"], sizes


@pytest.mark.parametrize("codec", list(StoreCodec))
def test_tile_chunks_are_the_bytes_zarr_writes(tmp_path, codec) -> None:
    """write_tile encodes chunks itself (padding past the edge, [delta,] zstd, no chunk for
    fill values only): every key of the store holds the bytes zarr's own setitem gives, on an
    edge tile whose array ends inside its chunks, at full resolution and on an overview, for
    both store codecs."""
    import zarr

    shape, tile, names = (1300, 1100), 1024, ["band_07", "ndvi", "count", "product"]
    rng = np.random.default_rng(7)
    window = (1024, 1300, 1024, 1100)
    arrays = {n: rng.integers(1, 4000, (276, 76)).astype(st.layer_dtype(n) if n != "band_07"
                                                           else np.uint16) for n in names}
    arrays["count"][:] = 0  # a layer of fill values only: its old chunk goes away
    stored = {n: np.ones_like(a) for n, a in arrays.items()}
    stores = {}
    for how in ("ours", "zarr"):
        repo = st.create_repository(tmp_path / how)
        session = repo.writable_session(st.BRANCH)
        st.create_layout(session.store, {}, shape, tile, names, [2], st.CHUNK, codec)
        for n in names:  # the old values, written by zarr
            for f in (1, 2):
                a = zarr.open_array(session.store, path=st._level_path(n, f), mode="r+")
                a[window[0] // f:, window[2] // f:] = stored[n][::f, ::f]
        if how == "ours":
            written = st.write_tile(session.store, window, arrays, stored, [2])
            assert written == 8
        else:
            for n in names:
                for f in (1, 2):
                    a = zarr.open_array(session.store, path=st._level_path(n, f), mode="r+")
                    a[window[0] // f:, window[2] // f:] = arrays[n][::f, ::f]
        stores[how] = session.store

    def content(store) -> dict[str, bytes]:
        from zarr.core.buffer import default_buffer_prototype
        from zarr.core.sync import sync

        async def read() -> dict[str, bytes]:
            keys = [k async for k in store.list() if "/c/" in k]
            values = [await store.get(k, default_buffer_prototype()) for k in keys]
            return {k: v.to_bytes() for k, v in zip(keys, values, strict=True)}

        return sync(read())

    ours, theirs = content(stores["ours"]), content(stores["zarr"])
    root = zarr.open_group(stores["ours"], mode="r")
    first = "numcodecs.delta" if codec is StoreCodec.DELTA_ZSTD else "bytes"
    assert [_codecs(root, n)[0] for n in names] == [first] * 2 + ["bytes"] * 2
    assert sorted(ours) == sorted(theirs)
    assert len(ours) == 6 and not any(k.startswith("count/") for k in ours)
    assert all(ours[k] == theirs[k] for k in ours)
    read = st.read_tile(stores["ours"], names, window)  # edge chunks, one layer deleted
    assert all(np.array_equal(read[n], arrays[n]) and read[n].dtype == arrays[n].dtype
               for n in names)
    corner = st.read_tile(stores["zarr"], names, (0, 1024, 0, 1024))  # never written: 0
    assert all(corner[n].shape == (1024, 1024) and not corner[n].any() for n in names)
    assert np.array_equal(st.read_tile(stores["zarr"], ["overview_2/ndvi"], (512, 650, 512, 550))
                          ["overview_2/ndvi"], arrays["ndvi"][::2, ::2])


def test_winner_counts_equal_the_sorted_count() -> None:
    """A tile's winners are counted in one pass (``count_winners``), as ``np.unique`` counts
    them: the new products that hold pixels, with their pixel counts, none for the others."""
    from napari_meris_ortho.synthesis.run import winner_counts

    rng = np.random.default_rng(25)
    winner = rng.integers(0, 7, (1024, 1024)).astype(np.int32)
    winner[:, 512:] = 0  # background
    winner[winner == 4] = 2  # index 4 holds nothing
    ids, counts = np.unique(winner, return_counts=True)
    want = {int(i): int(n) for i, n in zip(ids, counts, strict=True) if int(i) in {2, 4, 5, 9}}
    got = winner_counts(winner, {2, 4, 5, 9})
    assert got == want
    assert set(got) == {2, 5} and sum(got.values()) == int(np.isin(winner, [2, 5]).sum())
    assert got[2] > 2 * got[5] > 0  # index 2 also holds the old index 4's pixels
    assert winner_counts(winner[:, 512:], {1, 3}) == {}


def test_tiles_are_submitted_with_the_most_work_first() -> None:
    """Longest processing time first: a tile's work is its products' pixels inside it plus a
    piece's fixed cost, so a tile covered by one product goes before a tile touched by three
    slivers; an excluded product's pixels do not count; equal work keeps the grid order."""
    from napari_meris_ortho.synthesis.run import PIECE_WORK_PX, submission_order, tile_work

    a, b, c, d = (0, 1024, 0, 1024), (0, 1024, 1024, 2048), (1024, 2048, 0, 1024), \
        (1024, 2048, 1024, 2048)
    jobs = {t: [] for t in (a, b, c, d)}
    work = {a: {1: 1_000_000}, b: {1: 1000, 2: 1000, 3: 1000}, c: {2: 500_000, 3: 500_000},
            d: {1: 1_000_000}}
    assert tile_work(work[c]) == 1_000_000 + 2 * PIECE_WORK_PX
    assert submission_order(jobs, work) == [c, a, d, b]  # by pieces it was b, c, a, d
    assert tile_work(work[c], frozenset({2})) == 500_000 + PIECE_WORK_PX
    assert submission_order(jobs, work, frozenset({2})) == [a, d, c, b]


def test_a_run_computes_its_tiles_in_submission_order(products, tmp_path, monkeypatch) -> None:
    """In process the tiles are computed in the order they are submitted, the plan's
    ``submission_order`` (on workers it is their priority): here not the grid order, nor the
    order by number of products."""
    from napari_meris_ortho.synthesis import run as _run

    planned: list = []
    ran: list = []
    real_jobs, real_tile_job = _run.Synthesis._jobs, _run.tile_job

    def jobs(self, todo):
        out = real_jobs(self, todo)
        planned.append(out)
        return out

    def tile_job(fork, spec, window, *args, **kwargs):
        ran.append(window)
        return real_tile_job(fork, spec, window, *args, **kwargs)

    monkeypatch.setattr(_run.Synthesis, "_jobs", jobs)
    monkeypatch.setattr(_run, "tile_job", tile_job)
    synthesize([products["east"], products["west"]], tmp_path / "s", grid=GRID, bands=BANDS,
               tile=256, elevation="tiepoints")
    (plan, work), = planned
    assert ran == _run.submission_order(plan, work)
    assert ran != sorted(plan) and ran != sorted(plan, key=lambda w: -len(plan[w]))
    works = [_run.tile_work(work[w]) for w in ran]
    assert works == sorted(works, reverse=True) and works[0] > works[-1]


@pytest.mark.parametrize("bands", [(2, 9), (2, 7, 9, 13)])
@pytest.mark.slow
def test_bands_read_where_a_product_wins_give_the_layers_of_whole_pieces(
        products, tmp_path, monkeypatch, bands) -> None:
    """Maximum NDVI on standard products: a piece reads its bands at its merge, where it wins
    only (``run.gathers_winners``); the layers, a new synthesis and an update into it, are the
    bytes of pieces gathered whole (with and without the NDVI bands among the stored ones)."""
    from napari_meris_ortho.synthesis import run

    seen: list[bool] = []
    real = run.gathers_winners

    def observed(spec, plan, product):
        seen.append(real(spec, plan, product))
        return seen[-1]

    def merge(out) -> dict[str, np.ndarray]:
        options = dict(grid=GRID, bands=bands, tile=256, algorithm="max-ndvi",
                       elevation="tiepoints")
        synthesize([products["cloudy1"], products["west"]], out, **options)
        synthesize([products["cloudy2"], products["cloudy3"]], out, input=out,
                   elevation="tiepoints")
        return layers(out)

    monkeypatch.setattr(run, "gathers_winners", observed)
    lazy = merge(tmp_path / "lazy")
    assert seen and all(seen)
    monkeypatch.setattr(run, "gathers_winners", lambda spec, plan, product: False)
    whole = merge(tmp_path / "whole")
    assert sorted(lazy) == sorted(whole)
    assert all(lazy[k].tobytes() == whole[k].tobytes() for k in lazy)
    assert len(np.unique(whole["product"])) == 5  # background and four products hold pixels


@pytest.mark.slow
def test_in_process_the_sen3_bands_of_a_tiles_products_decode_ahead_once(tmp_path,
                                                                        monkeypatch):
    """A synthesis in this process starts decoding the bands of every product of a tile in the
    background (``run._decode_ahead``, on ``sen3-bands`` threads) while the first products are
    orthorectified: each band of each product is decoded once in the run, and the layers are
    those of a run that decodes each product's bands when it comes to them."""
    import shutil
    import threading

    from napari_meris_ortho.products.sen3 import kept
    from napari_meris_ortho.products.sen3.reader import MerisSen3Product
    from napari_meris_ortho.simulate.geocorrected import write_geocorrected
    from napari_meris_ortho.simulate.scene import generate_scene
    from napari_meris_ortho.synthesis import run

    first = write_geocorrected(generate_scene("fr-small"), fsg=False, out_dir=tmp_path)["sen3"]
    second = first.with_name(first.name.replace("_000_000______MOR", "_002_000______MOR"))
    assert second != first
    shutil.copytree(first, second)  # another cycle's product, the same values
    seen: list[tuple[str, int, str]] = []
    decode = MerisSen3Product._counts

    def decoding(self, band: int) -> np.ndarray:
        seen.append((self.product_name, band, threading.current_thread().name))
        return decode(self, band)

    events: list[tuple[str, str]] = []
    ahead, segment = run._decode_ahead, run.segment_task

    def asked(path: str, spec) -> None:
        events.append(("ahead", Path(path).name))
        ahead(path, spec)

    def piece(spec, index, path, *args):
        events.append(("piece", Path(path).name))
        return segment(spec, index, path, *args)

    monkeypatch.setattr(kept, "usable_threads", lambda: 2)  # as on this 2-core machine
    monkeypatch.setattr(MerisSen3Product, "_counts", decoding)
    monkeypatch.setattr(run, "_decode_ahead", asked)
    monkeypatch.setattr(run, "segment_task", piece)
    options = dict(bands=(2, 7, 13), tile=256, elevation="tiepoints")
    result = synthesize([str(first), str(second)], tmp_path / "ahead", **options)
    assert len(result.merged) == 2
    assert sorted(events[:2]) == [("ahead", first.name), ("ahead", second.name)]
    assert events[2][0] == "piece"  # both asked for before the first piece
    names = sorted({name for name, _, _ in seen})
    assert len(names) == 2
    assert sorted((n, b) for n, b, _ in seen) == [(n, b) for n in names for b in (2, 7, 13)]
    assert all(thread.startswith("sen3-") for _, _, thread in seen)  # never this thread
    seen.clear()
    monkeypatch.setattr(run, "_decode_ahead", lambda path, spec: None)
    synthesize([str(first), str(second)], tmp_path / "plain", **options)
    assert len(seen) == 6
    left, right = layers(tmp_path / "ahead"), layers(tmp_path / "plain")
    assert left.keys() == right.keys()
    for key in left:
        assert left[key].tobytes() == right[key].tobytes(), key

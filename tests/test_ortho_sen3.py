"""A ``.SEN3`` as ESA writes it, mapped: the SEN3 and the N1 of one simulated
acquisition orthorectify to the same map; a fill pixel never yields a radiance in any sampling
(a sample touching it is no data); a zipped SEN3 maps end to end; saturated pixels of a band are
no data for that band in a synthesis."""

from __future__ import annotations

import shutil
import zipfile

import netCDF4
import numpy as np
import pytest
import rasterio

from napari_meris_ortho.cli import main
from napari_meris_ortho.engine.resample import touches
from napari_meris_ortho.ortho import orthorectify, precompute
from napari_meris_ortho.products.open import read_product
from napari_meris_ortho.products.sen3 import mirror_columns


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    from napari_meris_ortho.simulate.geocorrected import write_geocorrected
    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene("fr-small")
    out = tmp_path_factory.mktemp("sen3map")
    paths = write_geocorrected(scene, fsg=False, out_dir=out)
    return scene.product_path, paths["sen3"]


@pytest.fixture
def sen3_copy(pair, tmp_path):
    dst = tmp_path / pair[1].name
    shutil.copytree(pair[1], dst)
    return dst


def test_sen3_and_n1_of_one_acquisition_give_the_same_map(pair):
    n1, s3 = read_product(pair[0]), read_product(pair[1])
    for sampling in ("nearest", "bicubic"):
        a = orthorectify(n1, bands=(2, 7, 13), elevation="tiepoints", sampling=sampling)
        b = orthorectify(s3, bands=(2, 7, 13), elevation="tiepoints", sampling=sampling,
                         grid=a.grid)
        for band in (2, 7, 13):
            np.testing.assert_array_equal(a.bands[band], b.bands[band])
        np.testing.assert_array_equal(a.flags, b.flags)
        assert a.valid.sum() > 100_000


def _set_fill(directory, band: int, cells: list[tuple[int, int]]) -> None:
    """Fill value 65535 at N1-order (line, column) cells of a band of a .SEN3 directory."""
    with netCDF4.Dataset(directory / f"M{band:02d}_radiance.nc", "a") as ds:
        v = ds.variables[f"M{band:02d}_radiance"]
        v.set_auto_maskandscale(False)
        stored = mirror_columns(v[...])
        for line, col in cells:
            stored[line, col] = 65535
        v[...] = mirror_columns(stored)


@pytest.mark.parametrize("sampling", ["nearest", "bilinear", "bicubic"])
def test_a_fill_pixel_never_yields_a_radiance(pair, sen3_copy, sampling):
    cells = [(100 + 7 * k, 60 + 31 * k) for k in range(12)]
    _set_fill(sen3_copy, 7, cells)
    clean = precompute(read_product(pair[1]), bands=(6, 7), elevation="tiepoints",
                       sampling=sampling)
    filled = precompute(read_product(sen3_copy), clean.grid, bands=(6, 7),
                        elevation="tiepoints", sampling=sampling)
    a, b = clean.radiance(), filled.radiance()
    np.testing.assert_array_equal(a[6], b[6])  # other bands untouched
    mask = np.zeros((320, 513), bool)
    for cell in mask_cells(cells):
        mask[cell] = True
    hit = touches(mask, filled.line.astype(np.float64), filled.col, sampling)
    assert hit.sum() >= len(cells)
    assert (b[7][hit] == 0).all()  # no data, never a fill x scale (~450) nor a mixed value
    np.testing.assert_array_equal(a[7][~hit], b[7][~hit])
    assert b[7].max() <= a[7].max()
    counts = filled.counts([7])[0]
    assert (counts[hit] == 0).all() and counts.max() < 65535


def mask_cells(cells):
    return [(int(r), int(c)) for r, c in cells]


def test_a_zipped_sen3_maps_end_to_end(pair, tmp_path, capsys):
    archive = tmp_path / (pair[1].name + ".zip")
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(pair[1].iterdir()):
            z.write(f, f"{pair[1].name}/{f.name}")
    outs = []
    for src, name in ((archive, "zip.tif"), (pair[1], "dir.tif")):
        out = tmp_path / name
        assert main(["-q", "map", str(src), "-o", str(out), "--bands", "7,13",
                     "--geolocation", "pixel"]) == 0, capsys.readouterr().err
        with rasterio.open(out) as ds:
            outs.append((ds.read(), ds.transform, ds.crs))
    np.testing.assert_array_equal(outs[0][0], outs[1][0])
    assert outs[0][1:] == outs[1][1:] and (outs[0][0] > 0).sum() > 100_000


def test_a_renamed_zip_is_still_its_product_in_a_synthesis(pair, tmp_path, caplog):
    """A download saved as "product (1).zip" holds ESA's ``<name>.SEN3/``: its product name is
    that folder's, so a synthesis that merged the directory skips the archive (same sensing
    time and name) instead of merging the same acquisition twice."""
    from napari_meris_ortho.synthesis.reading import open_synthesis

    archive = tmp_path / "product (1).zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_STORED) as z:
        for f in sorted(pair[1].iterdir()):
            z.write(f, f"{pair[1].name}/{f.name}")
    assert read_product(archive).product_name == pair[1].name.removesuffix(".SEN3")
    out = tmp_path / "syn"
    common = ["--elevation", "tiepoints", "--tile", "256", "--workers", "0"]
    assert main(["-q", "synthesize", str(pair[1]), "--out", str(out), "--bands", "7",
                 *common]) == 0
    caplog.clear()
    assert main(["synthesize", str(archive), "--input", str(out), "--out", str(out),
                 *common]) == 0
    assert "already in the synthesis" in caplog.text
    store = open_synthesis(out)
    assert len(store.history()) == 1 and int(store.read("count").max()) == 1


@pytest.mark.slow
def test_a_synthesis_decodes_each_band_of_a_sen3_once(pair, tmp_path, monkeypatch):
    """Every tile task reads every band of its products; a .SEN3 band (zlib netCDF-4) is
    decoded once per process for the run, not once per tile, then freed; the layers are those
    of a run that decodes at every tile (nothing kept: budget 0)."""
    from napari_meris_ortho.products.sen3 import kept
    from napari_meris_ortho.products.sen3.reader import MerisSen3Product
    from napari_meris_ortho.synthesis.api import synthesize
    from test_synthesis import layers

    decoded: list[int] = []
    real = MerisSen3Product._counts

    def counted(self, band):  # the real decoding, observed
        decoded.append(band)
        return real(self, band)

    monkeypatch.setattr(MerisSen3Product, "_counts", counted)
    options = dict(bands=(7, 13), algorithm="max-ndvi", elevation="tiepoints", tile=256)
    result = synthesize([pair[1]], tmp_path / "kept", **options)
    assert len(result.merged) == 1 and sorted(decoded) == [7, 13]
    assert kept.kept_bytes() == 0  # freed at the end of the run
    product = read_product(pair[1])  # outside a run: nothing kept
    assert not product.counts(7).flags.writeable and kept.kept_bytes() == 0
    decoded.clear()
    monkeypatch.setattr(kept, "BUDGET_BYTES", 0)
    synthesize([pair[1]], tmp_path / "each", **options)
    assert len(decoded) == 2 * 8 and decoded.count(7) == 8  # once a tile: 8 tiles of 256
    a, b = layers(tmp_path / "kept"), layers(tmp_path / "each")
    assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def test_saturated_pixels_are_no_data_for_their_band_in_a_synthesis(pair, sen3_copy, tmp_path):
    from napari_meris_ortho.synthesis.api import synthesize
    from napari_meris_ortho.synthesis.reading import open_synthesis

    with netCDF4.Dataset(sen3_copy / "qualityFlags.nc", "a") as ds:
        v = ds.variables["quality_flags"]
        v.set_auto_maskandscale(False)
        q = v[...]
        q[:, 200:260] |= np.uint32(1 << (21 - 7))  # saturated_M07, stored columns 200-259
        v[...] = q
    out = tmp_path / "syn"
    synthesize([sen3_copy], out, bands=(6, 7), elevation="tiepoints", sampling="nearest",
               tile=256)
    store = open_synthesis(out)
    b6, b7 = store.read("band_06"), store.read("band_07")
    ref = tmp_path / "ref"
    synthesize([pair[1]], ref, bands=(6, 7), elevation="tiepoints", sampling="nearest",
               tile=256)
    r7 = open_synthesis(ref).read("band_07")
    lost = (r7 > 0) & (b7 == 0)
    assert lost.sum() > 5000  # the saturated strip
    assert (b6[lost] > 0).all()  # band 6 of the same pixels is kept
    np.testing.assert_array_equal(b7[~lost], r7[~lost])


def test_napari_shows_the_sen3_and_its_n1_the_same_way_round(pair):
    """The plugin's product layers (radiance stack, RGB quick-look, flags) of the SEN3 equal the
    N1's, pixel for pixel: a real SEN3's mirrored columns are not shown mirrored."""
    from napari_meris_ortho._napari.reader import n1_layers

    n1, s3 = n1_layers(pair[0]), n1_layers(pair[1])
    np.testing.assert_array_equal(np.asarray(n1[0][0][6]), np.asarray(s3[0][0][6]))
    np.testing.assert_array_equal(n1[1][0], s3[1][0])
    np.testing.assert_array_equal(n1[2][0], s3[2][0])


def test_info_describes_a_zipped_sen3(pair, tmp_path, capsys):
    archive = tmp_path / (pair[1].name + ".zip")
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(pair[1].iterdir()):
            z.write(f, f"{pair[1].name}/{f.name}")
    assert main(["info", str(archive)]) == 0
    out = capsys.readouterr().out
    assert "SAFE .SEN3 zip archive, 23 files" in out and "ME_1_FRG___" in out
    size = (pair[1] / "M07_radiance.nc").stat().st_size
    line = next(x for x in out.splitlines() if "M07_radiance.nc" in x)
    assert line.split()[-2:] == [str(size), "bytes"]


def test_a_mapping_reads_the_sen3_bands_ahead(pair):
    """``precompute`` starts reading the product's bands (whole, on a background thread) while
    it computes the antecedents, and the sampling takes them: the same radiances as bands read
    when sampled. An N1 has nothing to read ahead (its bands are memory-mapped)."""
    import threading

    product = read_product(pair[1])
    readers: list[str] = []
    counts = product._counts

    def reading(band: int) -> np.ndarray:
        readers.append(threading.current_thread().name)
        return counts(band)

    product._counts = reading  # type: ignore[method-assign]
    ante = precompute(product, bands=[7, 2], elevation="tiepoints")
    assert sorted(product._ahead) == [2, 7]
    ahead = ante.radiance()
    assert product._ahead == {} and len(readers) == 2
    assert all(name.startswith("sen3-bands") for name in readers)
    again = ante.radiance()  # read when sampled, on this thread
    assert readers[2:] == [threading.current_thread().name] * 2
    for b in (7, 2):
        np.testing.assert_array_equal(ahead[b], again[b])
    assert not hasattr(read_product(pair[0]), "read_ahead")

"""Synthesis across sensors (synthesis/bandsets, run, reading, export): MERIS and OLCI products
in one store. OLCI products feed a MERIS store with their matching bands (M11 ~ Oa13 said to be
approximate), an OLCI-only store holds Oa01..Oa21, a MERIS product is refused by an OLCI store;
the NDVI comes from 665/865 nm of each sensor, each winning pixel says its sensor, OLCI's
uint32 saturation bits reach bands 17..21, and a mixed synthesis is the same bytes in any
product order (in process here; dask workers: test_synthesis_distributed.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio

from napari_meris_ortho.bands import OLCI, Sensor
from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.products.olci import quality_flags_of, write_olci
from napari_meris_ortho.products.olci.layout import EFR
from napari_meris_ortho.products.open import read_product
from napari_meris_ortho.synthesis import store as st
from napari_meris_ortho.synthesis.api import synthesize
from napari_meris_ortho.synthesis.export import export_cog
from napari_meris_ortho.synthesis.reading import SENSOR_CODES, open_synthesis
from test_synthesis import GRID, layers, scene_product

#: metres per degree of latitude (sphere of the handbook's radius)
M_PER_DEG = 6_370_997.0 * np.pi / 180.0
#: an EFR piece over GRID: 200 rows, 257 columns (5 tie columns), column 0 in the east
ROWS, WIDTH = 200, 257
LAT0, LON0 = 46.72, 14.30
#: the OLCI piece's radiances (mW m-2 sr-1 nm-1): dark and bright blocks at 665 nm, green and
#: bare ones by NDVI (Oa08, Oa17): where it is dark or green it wins over the MERIS dates
DARK, BRIGHT = 8.0, 120.0
COMMON = dict(grid=GRID, bands=(7, 13), tile=256, elevation="tiepoints")


def olci_geometry() -> dict[str, np.ndarray]:
    """Per-pixel latitude/longitude of the EFR piece (N1 column order: column 0 in the east on
    a descending pass), 294 m between rows, 270 m between columns, altitude 0."""
    i = np.arange(ROWS, dtype=np.float64)[:, None]
    j = np.arange(WIDTH, dtype=np.float64)[None, :]
    lat = LAT0 - i * 294.0 / M_PER_DEG - j * 0.00005
    lon = LON0 - j * 270.0 / (M_PER_DEG * np.cos(np.radians(LAT0))) - i * 0.0004
    return {"latitude": lat, "longitude": lon, "altitude": np.zeros((ROWS, WIDTH))}


def blocks(seed: int) -> np.ndarray:
    """A (ROWS, WIDTH) bool pattern of 12 x 12-pixel blocks: True where the piece is dark and
    green (it wins), False where it is bright and bare; each seed its own pattern."""
    rng = np.random.default_rng(seed)
    coarse = rng.random(((ROWS + 11) // 12, (WIDTH + 11) // 12)) < 0.5
    return np.kron(coarse, np.ones((12, 12), bool))[:ROWS, :WIDTH]


def write_olci_over_grid(out: Path, seed: int, day: int, saturate_nir: bool = True,
                         scale_factors: tuple[float, ...] | None = None) -> Path:
    """An OL_1_EFR___ product over GRID sensed on 2021-08-``day`` (written into the directory
    ``out`` under its default name): where ``blocks(seed)`` is
    True, 665 nm is dark (``DARK``) and 865 nm bright (NDVI 0.88), elsewhere 665 nm is bright
    (``BRIGHT``) and 865 nm dark (NDVI -0.5); every band varies by a few counts with the pixel.
    ``saturate_nir``: Oa17 (bit 16 of the uint32 saturation bits) saturated on row 100."""
    geo = olci_geometry()
    tie_cols = np.arange(0, WIDTH, EFR.samples_per_tie_point)
    tie = {"latitude": geo["latitude"][:, tie_cols], "longitude": geo["longitude"][:, tie_cols],
           "sun_zenith": np.full((ROWS, tie_cols.size), 40.0),
           "sun_azimuth": np.full((ROWS, tie_cols.size), 160.0),
           "view_zenith": np.repeat(np.linspace(5.0, 20.0, tie_cols.size)[None], ROWS, 0),
           "view_azimuth": np.full((ROWS, tie_cols.size), 100.0)}
    scales = scale_factors or tuple(st.OLCI_BAND_SCALES[b] for b in range(1, 22))
    wins = blocks(seed)
    i, j = np.mgrid[0:ROWS, 0:WIDTH]
    ripple = (i % 5) + 3 * (j % 7)  # a few counts, so that every pixel's place shows
    counts = []
    for b in range(1, 22):
        level = np.where(wins, DARK, BRIGHT)
        if b in (17, 18, 19, 20, 21):  # near infrared: green where 665 nm is dark
            level = np.where(wins, 140.0, 40.0)
        value = np.round(level / scales[b - 1]) + ripple
        counts.append(np.clip(value, 1, 65534).astype(np.uint16))
    saturated = np.zeros((ROWS, WIDTH), np.uint32)
    if saturate_nir:
        saturated[100, :] = np.uint32(1 << 16)  # Oa17
    flags = np.zeros((ROWS, WIDTH), np.uint8)
    return write_olci(
        out, product_type="EFR", counts=counts, scale_factors=list(scales),
        quality_flags=quality_flags_of(flags, saturated), pixel_geolocation=geo,
        tie_points=tie, detector_index=np.tile(np.arange(WIDTH, dtype=np.int16), (ROWS, 1)),
        lambda0=np.tile(np.asarray(OLCI.centres, np.float32)[:, None], (1, 3700)),
        fwhm=np.tile(np.asarray(OLCI.widths, np.float32)[:, None], (1, 3700)),
        solar_flux=np.full((21, 3700), 1500.0, np.float32),
        start_time=np.datetime64(f"2021-08-{day:02d}T09:10:11"), platform="S3A")


@pytest.fixture(scope="module")
def olci(tmp_path_factory) -> list[str]:
    """Two OLCI dates over GRID (distinct patterns)."""
    root = tmp_path_factory.mktemp("olci")
    return [str(write_olci_over_grid(root, seed=k, day=10 + k)) for k in (1, 2)]


@pytest.fixture(scope="module")
def meris() -> list[str]:
    """Two cloudy MERIS dates of the fr-small piece (GRID)."""
    return [scene_product({"fraction": 0.4, "scale_km": 12.0, "seed": 10 * k}) for k in (1, 2)]


def _digest(path: Path) -> dict[str, str]:
    """sha256 of every layer's bytes."""
    import hashlib

    return {k: hashlib.sha256(v.tobytes()).hexdigest()[:16] for k, v in layers(path).items()}


def test_olci_products_read_as_olci(olci) -> None:
    product = read_product(olci[0])
    assert product.sensor is Sensor.OLCI and product.n_bands == 21
    assert product.saturated.dtype == np.uint32
    assert (product.saturated[100] == 1 << 16).all()


@pytest.mark.parametrize("algorithm", ["min-radiance", "max-ndvi"])
def test_mixed_synthesis_is_the_same_bytes_in_any_order(meris, olci, tmp_path,
                                                        algorithm) -> None:
    """Two MERIS and two OLCI dates in one store of MERIS bands: the layers are the same bytes
    whatever the order of the products; both sensors win pixels, and the product table and
    the per-pixel sensor say which."""
    products = [meris[0], olci[0], meris[1], olci[1]]
    orders = [products, products[::-1], [products[k] for k in (1, 3, 0, 2)]]
    digests = []
    for k, order in enumerate(orders):
        result = synthesize(order, tmp_path / f"o{k}", algorithm=algorithm, **COMMON)
        assert len(result.merged) == 4 and not result.failed
        digests.append(_digest(tmp_path / f"o{k}"))
    assert digests[0] == digests[1] == digests[2]
    store = open_synthesis(tmp_path / "o0")
    assert store.sensor is Sensor.MERIS and store.band_names == ["M07", "M13"]
    sensors = store.product_sensors()
    assert sorted(sensors.values()) == ["MERIS", "MERIS", "OLCI", "OLCI"]
    winners = store.read("product")
    pixel_sensor = store.sensor_of_pixels()
    for index, sensor in sensors.items():
        held = winners == index
        assert held.sum() > 1000, (index, sensor)  # every product wins somewhere
        assert (pixel_sensor[held] == SENSOR_CODES[Sensor(sensor)]).all()
    assert (pixel_sensor[winners == 0] == 0).all()
    # the store says which Oa band feeds each of its bands
    assert store.attrs["olci_bands"] == {"M07": "Oa08", "M13": "Oa17"}
    assert store.attrs["approximate_bands"] == []
    assert "sensor" not in store.attrs  # MERIS bands


def test_olci_radiances_reach_the_matching_meris_band(olci, tmp_path) -> None:
    """Alone in a store of MERIS bands, an OLCI product's Oa08 is band 7 (M07) and its Oa13
    band 11 (M11, the approximate match), quantized to the store's counts (Appendix A scales):
    within half a count of the product's own radiance at the pixel holding its centre."""
    out = tmp_path / "s"
    result = synthesize([olci[0]], out, band_set="MERIS", grid=GRID, bands=(1, 7, 11, 13),
                        tile=256, elevation="tiepoints")
    assert len(result.merged) == 1
    store = open_synthesis(out)
    assert store.sensor is Sensor.MERIS
    assert store.attrs["approximate_bands"] == ["M11"]
    assert "M11 ~ Oa13" in store.attrs["band_matching"]
    product = read_product(olci[0])
    geo = olci_geometry()
    rows, cols = np.meshgrid(np.arange(20, ROWS - 20, 9), np.arange(20, WIDTH - 20, 11),
                             indexing="ij")
    r, c = GRID.xy_of_lonlat(geo["longitude"][rows, cols], geo["latitude"][rows, cols])
    r, c = np.rint(r).astype(int), np.rint(c).astype(int)
    inside = (r >= 0) & (r < GRID.height) & (c >= 0) & (c < GRID.width)
    assert inside.sum() > 200
    for band, oa in ((1, 2), (7, 8), (11, 13), (13, 17)):
        got = store.band(band)[r[inside], c[inside]]
        want = product.radiance(oa)[rows[inside], cols[inside]]
        assert np.abs(got - want).max() <= st.BAND_SCALES[band] / 2 + 1e-4, band


def test_olci_only_store_holds_all_21_bands_and_refuses_meris(meris, olci, tmp_path) -> None:
    """OLCI products alone make a store of Oa01..Oa21, counts of ESA's scale factors (the
    product's own counts, as they are); a MERIS product given to it is refused with one
    message and the store is left as it was."""
    out = tmp_path / "olci"
    result = synthesize(olci, out, algorithm="max-ndvi", grid=GRID, tile=256,
                        elevation="tiepoints")
    assert len(result.merged) == 2
    store = open_synthesis(out)
    assert store.sensor is Sensor.OLCI and store.bands == tuple(range(1, 22))
    assert store.band_names[0] == "Oa01" and store.band_names[-1] == "Oa21"
    assert store.attrs["sensor"] == "OLCI"
    before = _digest(out)
    with pytest.raises(OptionsError, match="MERIS product cannot join a synthesis of OLCI "
                                           "bands .*Oa01, Oa09, Oa14, Oa15, Oa20, Oa21"):
        synthesize([meris[0]], out, input=out, elevation="tiepoints")
    assert _digest(out) == before and open_synthesis(out).snapshot == store.snapshot
    # the NDVI of Oa08 and Oa17: a pixel whose Oa17 is saturated (row 100 of both dates; bit
    # 16 of the uint32 bits, beyond a uint16) has none: no date holds it
    geo = olci_geometry()
    cols = np.arange(30, WIDTH - 30, 7)
    winners = {}
    for row in (60, 100):
        r, c = GRID.xy_of_lonlat(geo["longitude"][row, cols], geo["latitude"][row, cols])
        winners[row] = store.read("product")[np.rint(r).astype(int), np.rint(c).astype(int)]
    assert set(np.unique(winners[60])) == {1, 2} and (winners[100] == 0).all()


def test_saturated_olci_bands_beyond_16_are_no_data(olci, tmp_path) -> None:
    """One OLCI date in a store of its own bands (minimum radiance): its counts as they are
    (ESA's scale factors are the store's) at the pixel holding each product pixel's centre;
    on row 100, saturated Oa17 (bit 16 of the uint32 saturation bits) is no data (0) while
    Oa16 and Oa18 keep their values."""
    out = tmp_path / "one"
    synthesize([olci[0]], out, grid=GRID, bands=(16, 17, 18, 20), tile=256,
               elevation="tiepoints")
    store = open_synthesis(out)
    product = read_product(olci[0])
    geo = olci_geometry()
    cols = np.arange(30, WIDTH - 30, 7)
    for row in (60, 100):
        r, c = GRID.xy_of_lonlat(geo["longitude"][row, cols], geo["latitude"][row, cols])
        r, c = np.rint(r).astype(int), np.rint(c).astype(int)
        for band in (16, 17, 18, 20):
            got = store.band(band)[r, c]
            want = product.radiance(band)[row, cols]
            if row == 100 and band == 17:
                assert (got == 0).all()
            else:
                np.testing.assert_array_equal(got, want)


def test_max_ndvi_takes_each_sensors_own_red_and_near_infrared(olci, tmp_path) -> None:
    """The NDVI of an OLCI product comes from Oa08 and Oa17 (665, 865 nm) in a store of
    MERIS bands and in an OLCI store alike: the green blocks' 0.88, the bare ones' -0.5."""
    from napari_meris_ortho.engine.synthesis import ndvi_decode

    want = {True: (140.0 - DARK) / (140.0 + DARK), False: (40.0 - BRIGHT) / (40.0 + BRIGHT)}
    for band_set, bands in (("MERIS", (7, 13)), ("OLCI", (8, 17))):
        out = tmp_path / band_set
        synthesize([olci[0]], out, algorithm="max-ndvi", band_set=band_set, grid=GRID,
                   bands=bands, tile=256, elevation="tiepoints")
        ndvi = ndvi_decode(open_synthesis(out).read("ndvi"))
        held = np.isfinite(ndvi)
        assert held.sum() > 10_000
        for green, value in want.items():
            near = np.abs(ndvi[held] - value) < 0.02
            assert near.sum() > 2_000, (band_set, green)
        nearest = np.min([np.abs(ndvi[held] - v) for v in want.values()], axis=0)
        assert nearest.max() < 0.02, band_set  # not MERIS's bands 7/13 of an OLCI product


def test_band_set_and_bands_checked(meris, olci, tmp_path) -> None:
    with pytest.raises(OptionsError, match="band set 'landsat'"):
        synthesize(olci, tmp_path / "a", band_set="landsat", **COMMON)
    with pytest.raises(OptionsError, match=r"bands \[7, 17\]: the synthesis holds MERIS bands"):
        synthesize([meris[0], olci[0]], tmp_path / "b", grid=GRID, bands=(7, 17), tile=256,
                   elevation="tiepoints")
    assert not (tmp_path / "b").exists()
    with pytest.raises(OptionsError, match="bands must be 1..15"):
        synthesize(olci, tmp_path / "c", band_set="MERIS", grid=GRID, bands=(17,), tile=256)
    result = synthesize(olci, tmp_path / "d", grid=GRID, bands=(17, 21), tile=256,
                        elevation="tiepoints")
    assert open_synthesis(tmp_path / "d").band_names == ["Oa17", "Oa21"]
    assert len(result.merged) == 2


def test_xarray_and_export_name_the_sensors_and_oa_bands(meris, olci, tmp_path) -> None:
    """``to_xarray`` gives the band names and a per-pixel ``sensor`` (flag values and
    meanings), the product sensors as an attribute; ``export`` of an OLCI store names the
    bands Oa.. and tags the products' sensors; of a mixed store, the Oa band of each band."""
    pytest.importorskip("xarray")
    mixed = tmp_path / "mixed"
    synthesize([meris[0], olci[0]], mixed, **COMMON)
    ds = open_synthesis(mixed).to_xarray()
    assert list(ds["band_name"].values) == ["M07", "M13"]
    assert ds.attrs["product_sensors"] == ["MERIS", "OLCI"]  # sensing time: MERIS first
    sensor = ds["sensor"].values
    np.testing.assert_array_equal(sensor, open_synthesis(mixed).sensor_of_pixels())
    assert set(np.unique(sensor)) == {0, 1, 2}
    assert ds["sensor"].attrs["flag_meanings"] == "background MERIS OLCI"
    assert ds.attrs["olci_bands"] == "M07=Oa08 M13=Oa17"
    tif = export_cog(open_synthesis(mixed), tmp_path / "mixed.tif")
    with rasterio.open(tif) as src:
        tags = src.tags()
        assert tags["olci_bands"] == "M07=Oa08 M13=Oa17"
        assert sorted(tags["product_sensors"].split()) == ["MERIS", "OLCI"]
        assert src.descriptions[0].startswith("MERIS band 7")
    only = tmp_path / "olci"
    synthesize(olci, only, grid=GRID, bands=(8, 17, 21), tile=256, elevation="tiepoints")
    tif = export_cog(open_synthesis(only), tmp_path / "olci.tif")
    with rasterio.open(tif) as src:
        assert src.descriptions == ("Oa08 (665.0 nm)", "Oa17 (865.0 nm)", "Oa21 (1020.0 nm)")
        assert src.tags(1)["band_name"] == "Oa08"
        assert src.tags()["band_set"] == "OLCI"
        assert src.tags()["product_sensors"] == "OLCI OLCI"
        assert abs(src.scales[0] - st.OLCI_BAND_SCALES[8]) < 1e-9
    xr_only = open_synthesis(only).to_xarray()
    assert list(xr_only["band_name"].values) == ["Oa08", "Oa17", "Oa21"]
    np.testing.assert_allclose(xr_only["wavelength"].values, [665.0, 865.0, 1020.0])


def test_cli_synthesize_and_export_olci_products(meris, olci, tmp_path, capsys) -> None:
    """``meris-ortho synthesize`` takes OLCI products (an OLCI store, ``--bands`` of its band
    set), ``export`` names its bands Oa..; bands beyond the band set and a MERIS product for
    an OLCI store: one error line, exit 2, nothing written."""
    from napari_meris_ortho.cli import main

    grid = ["--crs", "EPSG:4326", "--ul", "13.45", "46.70", "--lr", "14.26", "46.19",
            "--pixel-size", "0.0015", "--elevation", "tiepoints", "--tile", "256",
            "--workers", "0"]
    out = tmp_path / "olci"
    assert main(["-q", "synthesize", *olci, "--out", str(out), "--bands", "8,17,21",
                 *grid]) == 0
    assert open_synthesis(out).band_names == ["Oa08", "Oa17", "Oa21"]
    tif = tmp_path / "olci.tif"
    assert main(["-q", "export", str(out), "-o", str(tif), "--bands", "21,8"]) == 0
    with rasterio.open(tif) as src:
        assert src.descriptions == ("Oa21 (1020.0 nm)", "Oa08 (665.0 nm)")
    capsys.readouterr()
    assert main(["synthesis-log", str(out)]) == 0
    log = capsys.readouterr().out
    assert "OLCI bands [8, 17, 21] (Oa08, Oa17, Oa21)" in log.splitlines()[0]
    assert log.count(" OLCI index ") == 2
    cases = [
        ([meris[0], olci[0], "--out", str(tmp_path / "a"), "--bands", "7,16", *grid],
         "the synthesis holds MERIS bands (MERIS bands are 1..15"),
        ([*olci, "--out", str(tmp_path / "b"), "--bands", "17", "--band-set", "meris", *grid],
         "MERIS bands are 1..15"),
        ([meris[0], "--input", str(out), "--out", str(out), "--workers", "0",
          "--elevation", "tiepoints"], "a MERIS product cannot join a synthesis of OLCI bands"),
        ([olci[0], "--input", str(out), "--out", str(out), "--band-set", "OLCI"],
         "shall not be given"),
    ]
    snapshot = open_synthesis(out).snapshot
    for args, message in cases:
        assert main(["-q", "synthesize", *args]) == 2, message
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("meris-ortho: error:") and message in err[0]
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    assert open_synthesis(out).snapshot == snapshot


def test_meris_store_records_nothing_new_until_olci_joins(meris, olci, tmp_path) -> None:
    """A store of MERIS products, made and updated, has the attributes of every store before
    OLCI products were read (no ``sensor``, no band matching; readers take it as MERIS);
    an OLCI product merged into it adds its own ``sensor`` entry and the band matching."""
    import zarr

    out = tmp_path / "s"
    synthesize([meris[0]], out, **COMMON)
    synthesize([meris[1]], out, input=out, elevation="tiepoints")

    def raw(path: Path) -> dict:
        store = open_synthesis(path)
        return dict(zarr.open_group(store.session.store, mode="r", zarr_format=3).attrs)

    attrs = raw(out)
    assert not {"sensor", "olci_bands", "approximate_bands", "band_matching"} & set(attrs)
    assert all("sensor" not in p for p in attrs["products"])
    assert open_synthesis(out).product_sensors() == {1: "MERIS", 2: "MERIS"}
    synthesize([olci[0]], out, input=out, elevation="tiepoints")
    attrs = raw(out)
    assert "sensor" not in attrs and attrs["olci_bands"] == {"M07": "Oa08", "M13": "Oa17"}
    assert [p.get("sensor") for p in attrs["products"]] == [None, None, "OLCI"]
    assert open_synthesis(out).product_sensors() == {1: "MERIS", 2: "MERIS", 3: "OLCI"}

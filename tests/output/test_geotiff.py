"""GeoTIFF output: georeferencing, nodata, descriptions, metadata, tiling, atomic writes."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import rasterio

from napari_meris_ortho.engine.resample import overview_level
from napari_meris_ortho.errors import OutputError
from napari_meris_ortho.geometry.grid import OutputGrid
from napari_meris_ortho.output.geotiff import (
    meris_band_description,
    overview_levels,
    radiance_to_counts,
    read_geotiff,
    write_cog,
    write_geotiff,
)


def bands_for(grid, n=2):
    base = np.arange(grid.width * grid.height, dtype=np.float32).reshape(grid.shape)
    return [base * (i + 1) for i in range(n)]


def test_gdal_reopens_crs_transform_nodata_descriptions(tmp_path):
    g = OutputGrid.from_extent("EPSG:32631", (500000, 5000000), (600100, 4920000), 260.0)
    bands = bands_for(g)
    calls = []
    out = write_geotiff(
        tmp_path / "ortho.tif", bands, g,
        descriptions=[meris_band_description(7, 664.73), meris_band_description(13)],
        metadata={"sf_rad_7": 0.0123, "product": "MER_FR__1P"},
        band_metadata=[{"band": 7, "wavelength_nm": 664.73}, {"band": 13}],
        progress=lambda d, t: calls.append((d, t)))
    assert out == tmp_path / "ortho.tif" and calls == [(1, 2), (2, 2)]
    with rasterio.open(out) as ds:
        assert ds.crs.to_epsg() == 32631
        assert tuple(ds.transform)[:6] == (260.0, 0.0, 500000.0, 0.0, -260.0, 5000000.0)
        assert (ds.width, ds.height, ds.count) == (g.width, g.height, 2)
        assert ds.nodata == 0
        assert ds.descriptions == ("MERIS band 7 (664.7 nm)", "MERIS band 13")
        assert ds.tags()["sf_rad_7"] == "0.0123"
        assert ds.tags(1)["wavelength_nm"] == "664.73"
        assert ds.profile["tiled"] and ds.block_shapes[0] == (256, 256)
        assert ds.compression.name.lower() == "deflate"
        np.testing.assert_array_equal(ds.read(2), bands[1])
    assert [p.name for p in tmp_path.iterdir()] == ["ortho.tif"]


def test_read_geotiff_round_trip_geographic_past_180(tmp_path):
    g = OutputGrid("EPSG:4326", 175.0, -20.0, 0.01, 0.01, 900, 300)
    bands = [b.astype(np.uint16) for b in bands_for(g, 1)]
    write_geotiff(tmp_path / "geo.tif", bands, g, descriptions=["b1"], dtype=np.uint16)
    arrays, g2, meta = read_geotiff(tmp_path / "geo.tif")
    assert g2 == g and g2.is_lonlat
    assert g2.x0 + g2.width * g2.dx == pytest.approx(184.0)
    assert arrays[0].dtype == np.uint16
    np.testing.assert_array_equal(arrays[0], bands[0])
    assert meta["descriptions"] == ["b1"] and meta["nodata"] == 0
    assert meta["dtype"] == "uint16"


def test_unwritable_directory_raises_and_leaves_no_file(tmp_path):
    g = OutputGrid("EPSG:4326", 0.0, 1.0, 0.1, 0.1, 10, 10)
    with pytest.raises(OutputError, match="does not exist"):
        write_geotiff(tmp_path / "missing" / "x.tif", bands_for(g), g)
    ro = tmp_path / "ro"
    ro.mkdir()
    os.chmod(ro, 0o555)
    try:
        # root ignores permission bits: /proc refuses new files to everyone
        target = ro if not os.access(ro, os.W_OK) else Path("/proc")
        with pytest.raises(OutputError, match="not writable|cannot write"):
            write_geotiff(target / "x.tif", bands_for(g), g)
        assert not (target / "x.tif").exists()
        assert list(ro.iterdir()) == []
    finally:
        os.chmod(ro, 0o755)


def test_failed_write_keeps_previous_file(tmp_path):
    g = OutputGrid("EPSG:4326", 0.0, 1.0, 0.1, 0.1, 10, 10)
    path = write_geotiff(tmp_path / "x.tif", bands_for(g, 1), g)
    before = path.read_bytes()
    with pytest.raises(OutputError, match="shape"):
        write_geotiff(path, [np.zeros((3, 3), np.float32)], g)
    with pytest.raises(OutputError, match="descriptions"):
        write_geotiff(path, bands_for(g, 2), g, descriptions=["only one"])
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["x.tif"]


def test_read_geotiff_errors(tmp_path):
    (tmp_path / "bad.tif").write_bytes(b"garbage")
    with pytest.raises(OutputError, match="cannot read"):
        read_geotiff(tmp_path / "bad.tif")


# ---------------------------------------------------------------------- Cloud-Optimized GeoTIFF
def radiances_for(grid, scales):
    """Float32 radiances = integer counts x scale, with a background 0 border."""
    rng = np.random.default_rng(3)
    counts = rng.integers(1, 40000, size=(len(scales), *grid.shape)).astype(np.uint16)
    counts[:, :5] = 0
    return counts, [c.astype(np.float32) * np.float32(s) for c, s in zip(counts, scales,
                                                                           strict=True)]


def test_cog_of_counts_validates_with_overviews_and_scale(tmp_path):
    from rio_cogeo.cogeo import cog_validate

    g = OutputGrid("EPSG:4326", 10.0, 47.0, 0.002, 0.002, 1300, 1100)
    scales = [0.0123, 0.00871]
    counts, radiance = radiances_for(g, scales)
    consumed = []

    def stream():  # one band at a time, as map streams them
        for s, r in zip(scales, radiance, strict=True):
            consumed.append(s)
            yield radiance_to_counts(r, s)

    calls = []
    out = write_cog(tmp_path / "c.tif", stream(), g, count=2, scales=scales, offsets=[0.0, 0.0],
                    units=["W m-2 sr-1 um-1"] * 2, descriptions=["b7", "b13"],
                    band_metadata=[{"sf_rad": s} for s in scales], metadata={"product": "p"},
                    halve=overview_level, progress=lambda d, t: calls.append((d, t)))
    assert calls == [(1, 3), (2, 3), (3, 3)] and consumed == scales
    valid, errors, warnings = cog_validate(out, quiet=True)
    assert valid and not errors, errors
    with rasterio.open(out) as ds:
        assert ds.dtypes == ("uint16", "uint16") and ds.nodata == 0
        assert ds.overviews(1) == [2, 4] and ds.block_shapes[0] == (512, 512)
        assert ds.compression.name.lower() == "zstd"
        assert ds.scales == tuple(scales) and ds.offsets == (0.0, 0.0)
        assert ds.units == ("W m-2 sr-1 um-1",) * 2 and ds.descriptions == ("b7", "b13")
        assert ds.tags()["product"] == "p" and float(ds.tags(2)["sf_rad"]) == scales[1]
        np.testing.assert_array_equal(ds.read(1), counts[0])  # counts given back exactly
        phys = ds.read(2, masked=True).astype(np.float64) * ds.scales[1] + ds.offsets[1]
        ov = ds.read(1, out_shape=(g.height // 2, g.width // 2))
    # scale/offset give back the radiances within half a count; background is masked
    ok = counts[1] > 0
    assert np.all(phys.mask == ~ok)
    assert np.max(np.abs(phys[ok] - radiance[1][ok])) <= 0.5 * scales[1]
    # the first overview is the 2x2 average of the counts
    assert abs(int(ov[100, 100]) - counts[0][200:202, 200:202].mean()) <= 1
    assert [p.name for p in tmp_path.iterdir()] == ["c.tif"]
    arrays, g2, meta = read_geotiff(out, scaled=True)
    assert g2 == g and meta["scales"] == scales and arrays[0].dtype == np.float32
    np.testing.assert_allclose(arrays[1], radiance[1], atol=0.5 * scales[1])


def test_radiance_to_counts_rounds_half_up_and_keeps_background():
    c = radiance_to_counts(np.array([0.0, 0.5, 1.49, 1.5, 2.0, -3.0, 1e9], np.float32), 1.0)
    assert c.tolist() == [0, 1, 1, 2, 2, 0, 65535]


def test_cog_float32_deflate_and_errors_leave_no_file(tmp_path):
    from rio_cogeo.cogeo import cog_validate

    g = OutputGrid("EPSG:32631", 500000.0, 5000000.0, 260.0, 260.0, 600, 520)
    bands = bands_for(g)
    out = write_cog(tmp_path / "f.tif", iter(bands), g, count=2, dtype="float32",
                    nodata=None, compress="deflate", overview_resampling="nearest",
                    halve=overview_level)
    assert cog_validate(out, quiet=True)[0]
    with rasterio.open(out) as ds:
        assert ds.compression.name.lower() == "deflate" and ds.nodata is None
        assert ds.overviews(1) == [2] and ds.crs.to_epsg() == 32631
        np.testing.assert_array_equal(ds.read(2), bands[1])
    before = out.read_bytes()
    for kwargs, match in ((dict(count=3), "2 bands given, 3 expected"),
                          (dict(count=1), "more than 1"),
                          (dict(count=2, descriptions=["x"]), "descriptions"),
                          (dict(count=2, compress="lzw"), "compression")):
        with pytest.raises(OutputError, match=match):
            write_cog(out, iter(bands), g, dtype="float32", halve=overview_level, **kwargs)
    with pytest.raises(OutputError, match="shape"):
        write_cog(out, [np.zeros((3, 3))], g, count=1, halve=overview_level)
    assert out.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["f.tif"]


def test_overview_levels():
    assert overview_levels(3758, 2944) == [2, 4, 8] and overview_levels(512, 300) == []

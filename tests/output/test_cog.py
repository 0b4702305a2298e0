"""The COG container: predictors, layout (GDAL reads and validates it), spill and BigTIFF."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from rasterio.io import MemoryFile
from rasterio.transform import from_origin

from napari_meris_ortho.engine.resample import overview_level
from napari_meris_ortho.output.cog import (
    EVERY_IFD_TAGS,
    GEO_TAGS,
    CogWriter,
    predicted_tile,
    template_tags,
)


def test_predictor_2_is_horizontal_differencing_per_tile_row():
    a = np.arange(12, dtype=np.uint16).reshape(3, 4) * 7 + 65530  # wraps past 65535
    t = predicted_tile(a, 0, 0, 4)
    assert t.shape == (4, 4) and t.dtype == np.uint16
    np.testing.assert_array_equal(np.cumsum(t, axis=1, dtype=np.uint16)[:3], a)
    assert not t[3].any()  # padding past the band's edge


def test_predictor_3_splits_bytes_most_significant_first_then_differences():
    a = np.array([[1.5, -2.25], [3.0, 1e-3]], np.float32)
    t = predicted_tile(a, 0, 0, 2)
    assert t.dtype == np.uint8 and t.shape == (2, 8)
    rows = np.cumsum(t, axis=1, dtype=np.uint8)  # undo the differencing
    planes = rows.reshape(2, 4, 2).transpose(0, 2, 1)[:, :, ::-1]  # back to little-endian
    np.testing.assert_array_equal(np.ascontiguousarray(planes).view(np.float32)[..., 0], a)


def _template(count, dtype, nodata, transform):
    with MemoryFile() as mem:
        with mem.open(driver="GTiff", width=1, height=1, count=count, dtype=dtype,
                      crs="EPSG:32632", transform=transform, nodata=nodata) as ds:
            ds.update_tags(product="p")
            ds.scales = [0.5] * count
        tags = template_tags(bytes(mem.getbuffer()))
    return ({k: v for k, v in tags.items() if k in GEO_TAGS},
            {k: v for k, v in tags.items() if k in EVERY_IFD_TAGS})


@pytest.mark.parametrize(("dtype", "compress", "bigtiff", "budget"),
                         [("uint16", "zstd", True, 0), ("float32", "deflate", False, 2 ** 20),
                          ("int16", "zstd", None, 10 ** 9)])
def test_layout_reads_back_in_gdal_and_validates(tmp_path, dtype, compress, bigtiff, budget):
    from rio_cogeo.cogeo import cog_validate

    rng = np.random.default_rng(1)
    h, w, count, block = 700, 1100, 3, 256
    bands = [(rng.normal(100, 40, (h, w)) * (rng.random((h, w)) > 0.1)).astype(dtype)
             for _ in range(count)]
    transform = from_origin(400_000.0, 5_100_000.0, 300.0, 300.0)
    main, every = _template(count, dtype, 0, transform)
    writer = CogWriter((h, w), 2, dtype, tmp_path / "spill", compress=compress, block=block,
                       memory_budget=budget)
    levels = []
    try:
        for b in bands:
            lv = [b]
            for _ in range(2):
                lv.append(overview_level(lv[-1], 0))
            levels.append(lv)
            writer.add_band(b, lambda a: overview_level(a, 0))
        with open(tmp_path / "c.tif", "wb") as f:
            writer.finish(f, main, every, bigtiff=bigtiff)
    finally:
        writer.close()
    assert ((tmp_path / "spill").stat().st_size > 0) == (budget < 10 ** 9)  # 2 ** 20: mixed
    valid, errors, warnings = cog_validate(tmp_path / "c.tif", quiet=True, strict=True)
    assert valid and not errors and not warnings, (errors, warnings)
    with rasterio.open(tmp_path / "c.tif") as ds:
        assert ds.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG"
        assert ds.tags(ns="IMAGE_STRUCTURE")["INTERLEAVE"] == "BAND"
        assert ds.crs.to_epsg() == 32632 and ds.transform == transform and ds.nodata == 0
        assert ds.scales == (0.5,) * count and ds.tags()["product"] == "p"
        assert ds.overviews(1) == [2, 4] and ds.block_shapes[0] == (block, block)
        assert ds.compression.name.lower() == compress
        # the file ends with the last band's last tile and its 4-byte trailer: the blocks
        # preallocated beyond it are gone
        last = {n: int(ds.get_tag_item(f"BLOCK_{n}_{(w - 1) // block}_{(h - 1) // block}",
                                       "TIFF", bidx=count)) for n in ("OFFSET", "SIZE")}
        assert (tmp_path / "c.tif").stat().st_size == last["OFFSET"] + last["SIZE"] + 4
        for k in range(count):
            np.testing.assert_array_equal(ds.read(k + 1), bands[k])
            for lv in levels[k][1:]:
                np.testing.assert_array_equal(ds.read(k + 1, out_shape=lv.shape), lv)
    with open(tmp_path / "c.tif", "rb") as f:
        assert f.read(4) == (b"II+\x00" if bigtiff else b"II*\x00")


def test_template_must_be_a_little_endian_tiff():
    with pytest.raises(ValueError, match="little-endian"):
        template_tags(b"MM\x00*" + bytes(8))

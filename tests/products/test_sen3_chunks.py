"""Bands inflated from their HDF5 chunks (``products.sen3.chunks``): the values netCDF4 reads for
every storage a netCDF-4 writer gives a 2-D variable, None for the others (netCDF4 then reads
them), one error for a damaged chunk, and several bands decoded at once."""

from __future__ import annotations

import shutil
import threading
import time
from pathlib import Path

import netCDF4
import numpy as np
import pytest
import sen3_real as real

from napari_meris_ortho.errors import Sen3FormatError
from napari_meris_ortho.products.open import read_product
from napari_meris_ortho.products.sen3 import kept
from napari_meris_ortho.products.sen3.chunks import DamagedChunk, chunk_index, decode
from napari_meris_ortho.products.sen3.layout import radiance_file, radiance_variable

SHAPE = (301, 257)  # no chunk size below divides it: edge chunks are cut

#: storage name -> (dtype, createVariable keywords)
STORAGES = {
    "one chunk, shuffle and deflate (ours)": ("u2", dict(zlib=True, complevel=1)),
    "cut chunks, shuffle and deflate": ("u2", dict(zlib=True, complevel=4, chunksizes=(64, 100))),
    "deflate without shuffle": ("u2", dict(zlib=True, shuffle=False, chunksizes=(50, 50))),
    "chunked, no filter": ("u2", dict(chunksizes=(128, 64))),
    "contiguous": ("u2", dict(contiguous=True)),
    "big-endian": (">u2", dict(zlib=True, endian="big", chunksizes=(64, 64))),
    "signed 16 bits": ("i2", dict(zlib=True, chunksizes=(100, 100))),
    "32 bits": ("u4", dict(zlib=True, chunksizes=(100, 100))),
}


def _values(dtype: str) -> np.ndarray:
    info = np.iinfo(dtype)
    rng = np.random.default_rng(5)
    return rng.integers(info.min, info.max, SHAPE, endpoint=True).astype(dtype)


def _write(path: Path, dtype: str, fill: int | None = None, part: bool = False,
           **options) -> np.ndarray:
    """A file of one variable "v"; ``part``: its top-left 64 x 64 written only. Returns the
    values netCDF4 reads back."""
    with netCDF4.Dataset(path, "w") as ds:
        ds.createDimension("rows", SHAPE[0])
        ds.createDimension("columns", SHAPE[1])
        v = ds.createVariable("v", dtype, ("rows", "columns"), fill_value=fill, **options)
        v.set_auto_maskandscale(False)
        if part:
            v[:64, :64] = _values(dtype)[:64, :64]
        else:
            v[...] = _values(dtype)
    with netCDF4.Dataset(path) as ds:
        ds.variables["v"].set_auto_maskandscale(False)
        return np.asarray(ds.variables["v"][...])


@pytest.mark.parametrize("storage", list(STORAGES))
def test_every_storage_of_a_netcdf4_writer_reads_as_netcdf4_reads_it(storage, tmp_path):
    dtype, options = STORAGES[storage]
    path = tmp_path / "v.nc"
    expected = _write(path, dtype, **options)
    for source in (path, path.read_bytes()):  # a file, an archived member's bytes
        index = chunk_index(source, "v")
        assert index is not None and index.shape == SHAPE and index.complete
        got = decode(index, source)  # in the native byte order
        assert got.dtype == expected.dtype.newbyteorder("=") and np.array_equal(got, expected)
        assert np.array_equal(decode(index, source, mirrored=True), expected[:, ::-1])


@pytest.mark.parametrize("fill", [7, None], ids=["_FillValue 7", "netCDF's default"])
def test_chunks_never_written_hold_the_fill_value(fill, tmp_path):
    path = tmp_path / "v.nc"
    expected = _write(path, "u2", fill=fill, part=True, zlib=True, chunksizes=(64, 64))
    index = chunk_index(path, "v")
    assert index is not None and not index.complete and len(index.chunks) == 1
    assert index.fill == (65535 if fill is None else fill)
    assert np.count_nonzero(expected == index.fill) > 0.9 * expected.size
    assert np.array_equal(decode(index, path), expected)


@pytest.mark.parametrize("options", [dict(zlib=True, fletcher32=True), dict(zlib=True, dims=3)],
                         ids=["fletcher32", "3-D"])
def test_other_storages_are_left_to_netcdf4(options, tmp_path):
    path = tmp_path / "v.nc"
    with netCDF4.Dataset(path, "w") as ds:
        ds.createDimension("rows", 30)
        ds.createDimension("columns", 20)
        dims = ("rows", "columns")
        if options.pop("dims", 2) == 3:
            ds.createDimension("bands", 2)
            dims = ("bands", *dims)
        ds.createVariable("v", "u2", dims, **options)[...] = 1
    assert chunk_index(path, "v") is None
    assert chunk_index(path, "w") is None  # no such variable
    assert chunk_index(tmp_path / "missing.nc", "v") is None
    (tmp_path / "foreign.nc").write_bytes(b"CDF\x01" + bytes(100))  # netCDF-3: not HDF5
    assert chunk_index(tmp_path / "foreign.nc", "v") is None


@pytest.fixture(scope="module")
def product_dir(tmp_path_factory):
    return real.write_real_like(tmp_path_factory.mktemp("real"))


@pytest.mark.slow
def test_the_bands_of_a_product_are_netcdf4s_values_in_the_n1_column_order(product_dir):
    product = read_product(product_dir)
    assert product.mirrored  # ESA's column order, the mirror of the N1's
    for band in range(1, 16):
        got = product._band_values(band)
        expected = product._raw(radiance_file(band), radiance_variable(band))
        assert got.dtype == expected.dtype and np.array_equal(got, expected), band


def test_a_damaged_band_chunk_is_one_error_naming_the_member(product_dir, tmp_path):
    copy = tmp_path / product_dir.name
    shutil.copytree(product_dir, copy)
    member = copy / radiance_file(7)
    index = chunk_index(member, radiance_variable(7))
    assert index is not None and index.deflate
    data = bytearray(member.read_bytes())
    _, _, offset, size = index.chunks[0]
    middle = offset + size // 2
    data[middle:middle + 16] = bytes(b ^ 0x5A for b in data[middle:middle + 16])
    member.write_bytes(bytes(data))
    product = read_product(copy)
    with pytest.raises(Sen3FormatError, match=rf"{radiance_file(7)}: cannot read "
                                              rf"{radiance_variable(7)}: chunk at byte {offset}"):
        product.counts(7)
    assert product.counts(8).shape == (product.height, product.width)  # the others read


def test_a_member_ending_inside_a_chunk_is_damaged_from_a_file_and_from_bytes(product_dir,
                                                                               tmp_path):
    """The index read, the member then ends inside its first chunk (a file cut while read, an
    archive member cut short): DamagedChunk names the chunk, from a path and from bytes."""
    member = product_dir / radiance_file(7)
    index = chunk_index(member, radiance_variable(7))
    assert index is not None
    _, _, offset, size = index.chunks[0]
    cut = member.read_bytes()[:offset + size // 2]
    short = tmp_path / "cut.nc"
    short.write_bytes(cut)
    for source in (short, cut):
        with pytest.raises(DamagedChunk, match=rf"chunk at byte {offset} cut short "
                                               rf"\({size // 2} of {size} bytes\)"):
            decode(index, source)


def test_a_product_decodes_its_bands_several_at_a_time(product_dir, monkeypatch):
    """``prepare_bands`` (a synthesis in one process) decodes the bands on as many threads as
    there are usable cores, each band once, and keeps them."""
    monkeypatch.setattr(kept, "usable_threads", lambda: 2)
    product = read_product(product_dir)
    counts = product._counts
    threads: dict[int, str] = {}
    running, most = [0], [0]
    lock = threading.Lock()

    def decoding(band: int) -> np.ndarray:
        with lock:
            running[0] += 1
            most[0] = max(most[0], running[0])
        threads[band] = threading.current_thread().name
        time.sleep(0.05)  # long enough for the other thread to begin one
        try:
            return counts(band)
        finally:
            with lock:
                running[0] -= 1

    product._counts = decoding  # type: ignore[method-assign]
    kept.keep_decoded_bands()
    try:
        product.prepare_bands(list(range(1, 16)))
        assert sorted(threads) == list(range(1, 16)) and most[0] == 2
        assert len(set(threads.values())) == 2
        for band in (1, 7, 15):
            held = product.kept.get(band)
            assert held is not None and np.array_equal(held, counts(band))
    finally:
        kept.release_decoded_bands()

"""A netCDF-4 image variable read from its HDF5 chunks, inflated here instead of by netCDF-C.

netCDF-C is not thread-safe: every read of a ``.SEN3`` member holds one lock (``members.LOCK``),
so through it the 15 bands of a product inflate one after the other on one core (fr-alps: 40 ms
a band, 2.5 s of the 9.6 s a synthesis of 4 ``.SEN3`` products takes in process). h5py gives the
chunk index (``H5Dget_chunk_info``: where each stored chunk lies in the file and which filters
it went through), which netCDF4-python does not expose. The chunk bytes are then read with
``os.pread`` and inflated with ``zlib`` (both outside the GIL), and the HDF5 byte shuffle is
undone with numpy, so that several bands decode at once on several cores.

Only the storage netCDF-4 writers give image variables is read so: chunked (or contiguous),
through nothing, deflate, shuffle, or shuffle then deflate (HDF5 filters 2 and 1), every chunk
through all of them. Anything else (Fletcher32, szip, a skipped filter, a compact dataset)
gives None, and the caller reads the variable through netCDF4 instead.
"""

from __future__ import annotations

import io
import os
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: HDF5 filter identifiers (H5Zpublic.h)
FILTER_DEFLATE = 1
FILTER_SHUFFLE = 2
#: the filter pipelines read here, as stored (first applied first on writing)
PIPELINES = ((), (FILTER_DEFLATE,), (FILTER_SHUFFLE,), (FILTER_SHUFFLE, FILTER_DEFLATE))


class DamagedChunk(ValueError):
    """A chunk that does not inflate to its size (a damaged file)."""


@dataclass(frozen=True)
class ChunkIndex:
    """Where the stored chunks of one variable lie in its file: ``shape`` and ``dtype`` (as
    stored, byte order included) of the variable, ``chunk`` the chunk shape, ``fill`` the
    value of the chunks never written, the filters (``shuffle``, ``deflate``) and, per stored
    chunk, its first element (rows, columns), byte offset and size in the file."""

    shape: tuple[int, int]
    dtype: np.dtype
    chunk: tuple[int, int]
    fill: float | int
    shuffle: bool
    deflate: bool
    chunks: tuple[tuple[int, int, int, int], ...]  # (row, column, byte offset, size)

    @property
    def complete(self) -> bool:
        """Whether the stored chunks cover the variable (no fill value to lay first)."""
        per_row = -(-self.shape[1] // self.chunk[1])
        return len(self.chunks) == per_row * -(-self.shape[0] // self.chunk[0])


def chunk_index(source: Path | bytes, variable: str) -> ChunkIndex | None:
    """The chunk index of 2-D ``variable`` of the netCDF-4 file ``source`` (a path, or the
    bytes of an archived member); None when its storage is not one read here, or when h5py
    cannot open it (netCDF4 then reads it, and says what is wrong)."""
    try:
        import h5py
        from h5py import h5d
    except ImportError:  # pragma: no cover - a dependency
        return None
    try:
        with h5py.File(io.BytesIO(source) if isinstance(source, bytes) else source, "r") as f:
            dataset = f.get(variable)
            if not isinstance(dataset, h5py.Dataset) or dataset.ndim != 2:
                return None
            plist = dataset.id.get_create_plist()
            pipeline = tuple(int(plist.get_filter(i)[0]) for i in range(plist.get_nfilters()))
            layout = plist.get_layout()
            if pipeline not in PIPELINES or layout not in (h5d.CHUNKED, h5d.CONTIGUOUS):
                return None
            shape = (int(dataset.shape[0]), int(dataset.shape[1]))
            fill = dataset.fillvalue
            stored: tuple[tuple[int, int, int, int], ...]
            if layout == h5d.CONTIGUOUS:
                offset = dataset.id.get_offset()
                stored = () if offset is None else (
                    (0, 0, int(offset), int(dataset.id.get_storage_size())),)
                chunk = shape
            else:
                chunk = (int(dataset.chunks[0]), int(dataset.chunks[1]))
                infos = [dataset.id.get_chunk_info(i)
                         for i in range(dataset.id.get_num_chunks())]
                if any(info.filter_mask != 0 for info in infos):  # a filter skipped
                    return None
                stored = tuple((int(info.chunk_offset[0]), int(info.chunk_offset[1]),
                                int(info.byte_offset), int(info.size))
                               for info in infos if info.byte_offset is not None)
            return ChunkIndex(shape, np.dtype(dataset.dtype), chunk,
                              fill.item() if hasattr(fill, "item") else fill,
                              FILTER_SHUFFLE in pipeline, FILTER_DEFLATE in pipeline, stored)
    except (OSError, ValueError, KeyError, RuntimeError, TypeError):
        return None


def _chunk_bytes(index: ChunkIndex, source: Path | bytes) -> Iterator[tuple[int, bytes]]:
    """(byte offset, stored bytes) of every chunk of ``index``, in its order, each read when
    asked (``os.pread``: one chunk's bytes held at a time)."""
    if isinstance(source, bytes):
        view = memoryview(source)
        yield from _read_each(index, lambda offset, size: bytes(view[offset:offset + size]))
        return
    fd = os.open(source, os.O_RDONLY)
    try:
        yield from _read_each(index, lambda offset, size: os.pread(fd, size, offset))
    finally:
        os.close(fd)


def _read_each(index: ChunkIndex, read: Callable[[int, int], bytes]
               ) -> Iterator[tuple[int, bytes]]:
    """(byte offset, ``read(offset, size)``) of every chunk of ``index``; DamagedChunk when the
    source ends before a chunk does."""
    for _, _, offset, size in index.chunks:
        data = read(offset, size)
        if len(data) != size:
            raise DamagedChunk(f"chunk at byte {offset} cut short ({len(data)} of "
                               f"{size} bytes)")
        yield offset, data


def decode(index: ChunkIndex, source: Path | bytes, mirrored: bool = False) -> np.ndarray:
    """The whole variable of ``index`` in the native byte order, its columns in the other
    order when ``mirrored`` (``layout.mirror_columns``). A chunk's bytes are inflated, then
    each byte plane of the HDF5 shuffle is written straight into its place in the result (one
    copy; the peak is a chunk's stored and inflated bytes besides the result). DamagedChunk
    when a chunk does not inflate to its size."""
    rows, cols = index.shape
    out = np.empty(index.shape, index.dtype.newbyteorder("="))
    if not index.complete:
        out[...] = index.fill
    size = index.dtype.itemsize
    planes_of = out.view(np.uint8).reshape(rows, cols, size)
    swapped = not index.dtype.isnative and size > 1
    nbytes = index.chunk[0] * index.chunk[1] * size
    for k, (offset, data) in enumerate(_chunk_bytes(index, source)):
        r0, c0 = index.chunks[k][:2]
        if index.deflate:
            try:
                data = zlib.decompress(data, bufsize=nbytes)  # one block: no joining copy
            except zlib.error as exc:
                raise DamagedChunk(f"chunk at byte {offset}: {exc}") from None
        if len(data) != nbytes:
            raise DamagedChunk(f"chunk at byte {offset} holds {len(data)} bytes, not {nbytes}")
        h, w = min(index.chunk[0], rows - r0), min(index.chunk[1], cols - c0)
        columns = slice(cols - c0 - 1, None if c0 + w == cols else cols - c0 - w - 1, -1) \
            if mirrored else slice(c0, c0 + w)
        if index.shuffle and size > 1:  # plane j: byte j of every value, as stored
            planes = np.frombuffer(data, np.uint8).reshape(size, *index.chunk)
            for j in range(size):
                planes_of[r0:r0 + h, columns, size - 1 - j if swapped else j] = \
                    planes[j, :h, :w]
        else:
            out[r0:r0 + h, columns] = np.frombuffer(data, index.dtype).reshape(index.chunk)[:h, :w]
        del data
    return out

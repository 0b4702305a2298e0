"""Cloud-Optimized GeoTIFF container: compressed tiles streamed band by band.

GDAL's COG driver only copies a finished dataset (``CreateCopy``): staging every band, reading
it back and compressing it after the engine has finished would cost a third of a ``map``. Here
each band and its overview levels are cut into square tiles, predicted (TIFF predictor 2,
horizontal differencing, for integers; 3, floating point, for floats) and compressed (ZSTD through
zstandard, DEFLATE through zlib; both release the GIL) on worker threads while the caller
computes the next band. ``CogWriter.finish`` then lays the file out as GDAL's COG driver does:

- TIFF (BigTIFF when the file would pass 4 GiB) header, then the ghost area
  ``GDAL_STRUCTURAL_METADATA`` (LAYOUT=IFDS_BEFORE_DATA, BLOCK_ORDER=ROW_MAJOR,
  BLOCK_LEADER=SIZE_AS_UINT4, BLOCK_TRAILER=LAST_4_BYTES_REPEATED);
- the IFD of the full resolution, then those of the overviews (NewSubfileType 1), each followed
  by its out-of-line values, all before any pixel;
- the tiles of the smallest overview first and of the full resolution last; bands are separate
  planes (PlanarConfiguration 2), tiles in row-major order, each with a 4-byte size before it
  and its last 4 bytes repeated after it.

Georeferencing and metadata tags (GeoKeys, ModelPixelScale/Tiepoint, GDAL_METADATA,
GDAL_NODATA) are not encoded here: ``template_tags`` reads them from a 1 x 1 GeoTIFF that GDAL
wrote with the same CRS, transform and metadata (``geotiff.write_cog``), and they are copied
as they are. Nothing here imports GDAL.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import struct
import threading
import zlib
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from ..cores import usable_threads

#: TIFF field types: size in bytes
_TYPE_SIZE = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8,
              16: 8, 17: 8, 18: 8}
SHORT, LONG, LONG8 = 3, 4, 16
#: TIFF compression codes
COMPRESSION_CODE = {"zstd": 50000, "deflate": 8}
#: tags copied from GDAL's template: to the full-resolution IFD / to every IFD
GEO_TAGS = (33550, 33922, 34264, 34735, 34736, 34737, 42112)
EVERY_IFD_TAGS = (42113,)
_GHOST = (b"LAYOUT=IFDS_BEFORE_DATA\nBLOCK_ORDER=ROW_MAJOR\nBLOCK_LEADER=SIZE_AS_UINT4\n"
          b"BLOCK_TRAILER=LAST_4_BYTES_REPEATED\nKNOWN_INCOMPATIBLE_EDITION=NO\n ")
_CLASSIC_LIMIT = 2 ** 32 - 2 ** 20


@dataclass(frozen=True)
class Tag:
    """One TIFF field: type code, value count and the packed little-endian values."""

    type: int
    count: int
    data: bytes


def template_tags(tiff: bytes) -> dict[int, Tag]:
    """Fields of the first IFD of a little-endian classic TIFF (GDAL's 1 x 1 template)."""
    if tiff[:4] != b"II*\x00":
        raise ValueError("the template is not a little-endian classic TIFF")
    (off,) = struct.unpack_from("<I", tiff, 4)
    (n,) = struct.unpack_from("<H", tiff, off)
    tags = {}
    for k in range(n):
        pos = off + 2 + 12 * k
        code, typ, count, value = struct.unpack_from("<HHII", tiff, pos)
        size = _TYPE_SIZE.get(typ, 1) * count
        start = pos + 8 if size <= 4 else value
        tags[code] = Tag(typ, count, bytes(tiff[start:start + size]))
    return tags


def predictor_for(dtype: np.dtype) -> int:
    """TIFF predictor: 2 (horizontal differencing) for integers, 3 (floating point) for floats."""
    return 3 if np.dtype(dtype).kind == "f" else 2


def predicted_tile(a: np.ndarray, i0: int, j0: int, block: int) -> np.ndarray:
    """The ``block`` x ``block`` tile at (i0, j0) of a 2-D band (zero padded past its edge)
    with its TIFF predictor applied, as contiguous bytes (TIFF 6.0 section 14; Adobe's
    floating-point predictor: bytes split into planes, most significant first, then differenced).
    """
    part = a[i0:i0 + block, j0:j0 + block]
    h, w = part.shape
    if a.dtype.kind == "f":
        t = np.zeros((block, block), a.dtype)
        t[:h, :w] = part
        size = a.dtype.itemsize
        planes = t.view(np.uint8).reshape(block, block, size)[:, :, ::-1]
        rows = np.ascontiguousarray(planes.transpose(0, 2, 1)).reshape(block, block * size)
        rows[:, 1:] = rows[:, 1:] - rows[:, :-1]
        return rows
    # differences straight from the band (one pass); the padding past its edge stays 0
    t = np.empty((block, block), a.dtype) if (h, w) == (block, block) else np.zeros(
        (block, block), a.dtype)
    t[:h, 0] = part[:, 0]
    np.subtract(part[:, 1:], part[:, :-1], out=t[:h, 1:w])  # unsigned/two's complement wrap
    return t


@dataclass(frozen=True)
class _Level:
    """One resolution level: its size and tiles."""

    width: int
    height: int
    block: int

    @property
    def tiles_across(self) -> int:
        return -(-self.width // self.block)

    @property
    def tiles_down(self) -> int:
        return -(-self.height // self.block)

    def corners(self) -> list[tuple[int, int]]:
        """(row, column) of each tile's first pixel, in row-major (file) order."""
        b = self.block
        return [(i * b, j * b) for i in range(self.tiles_down) for j in range(self.tiles_across)]


class CogWriter:
    """Streams bands into a COG file (module docstring): ``add_band(band, halve)`` per band,
    ``finish(out, ...)`` once, ``close()`` always.

    Compressed tiles stay in memory up to ``memory_budget`` bytes (writing a file costs about
    2-3 ms per MB here: a detour through a scratch file costs as much as the final write, and
    a map at half the default pixel size, 620 MB, takes 8 s held and 8.3-10.8 s spilled beyond
    256 MiB); beyond it, full-resolution tiles go to ``spill`` (a scratch file) as they are
    done. Memory holds at most three bands in flight besides.
    """

    def __init__(self, shape: tuple[int, int], n_levels: int, dtype: Any, spill: Path, *,
                 compress: str = "zstd", level: int = 1, block: int = 512,
                 threads: int | None = None, memory_budget: int = 2 ** 30) -> None:
        if compress not in COMPRESSION_CODE:
            raise ValueError(f"unknown compression {compress!r}")
        self.dtype = np.dtype(dtype)
        self.compress, self.level, self.block = compress, int(level), int(block)
        h, w = shape
        self.levels = []
        for k in range(n_levels + 1):
            f = 2 ** k
            self.levels.append(_Level(-(-w // f), -(-h // f), self.block))
        n = threads or usable_threads()
        self._pool = ThreadPoolExecutor(max_workers=max(n, 1), thread_name_prefix="cog")
        self._spill: BinaryIO = open(spill, "w+b")  # closed by close()
        self._full: list[list[Future[bytes]]] = []  # per band, its full-resolution tiles
        self._sizes: list[int] = []  # full-resolution tiles done, in file order
        self._held: list[bytes] = []  # the first of them, held in memory
        self._held_bytes = 0
        self._budget = int(memory_budget)
        self._drained = 0
        self._overview_jobs: list[Future[list[list[bytes]]]] = []
        self._encoder = self._make_encoder()

    def _make_encoder(self) -> Any:
        """bytes -> compressed bytes, callable from any worker thread: ZSTD by a compressor
        kept per thread (python-zstandard's are not shared between threads), or DEFLATE."""
        lvl = self.level
        if self.compress != "zstd":
            return lambda buf: zlib.compress(buf, lvl)
        import zstandard

        local = threading.local()

        def encode(buf: bytes) -> bytes:
            if not hasattr(local, "compressor"):
                local.compressor = zstandard.ZstdCompressor(level=lvl)
            return local.compressor.compress(buf)

        return encode

    def _encode(self, a: np.ndarray, i0: int, j0: int) -> bytes:
        return self._encoder(predicted_tile(a, i0, j0, self.block))

    def add_band(self, band: np.ndarray, halve: Callable[[np.ndarray], np.ndarray]) -> None:
        """Queue one band: a worker job for its overview levels (``halve`` of the level above,
        one after the other) and their compressed tiles, queued first (``finish`` can lay out
        the file once every band's overviews are done), then the tiles of its full
        resolution; the caller computes the next band meanwhile. The band must not change
        after."""
        full = self.levels[0]
        if band.shape != (full.height, full.width):
            raise ValueError(f"band of shape {band.shape}, expected {(full.height, full.width)}")
        a = np.ascontiguousarray(band, dtype=self.dtype)
        self._overview_jobs.append(self._pool.submit(self._overviews, a, halve))
        self._full.append([self._pool.submit(self._encode, a, i, j) for i, j in full.corners()])
        self._drain(keep=2)

    def _overviews(self, a: np.ndarray, halve: Callable[[np.ndarray], np.ndarray]
                   ) -> list[list[bytes]]:
        """The compressed tiles of each overview level of a band (from its full resolution
        ``a``), in one worker job: small next to the full resolution, and known early."""
        out = []
        for lev in self.levels[1:]:
            a = np.ascontiguousarray(halve(a), dtype=self.dtype)
            if a.shape != (lev.height, lev.width):
                raise ValueError(f"overview of shape {a.shape}, expected "
                                 f"{(lev.height, lev.width)}")
            out.append([self._encode(a, i, j) for i, j in lev.corners()])
        return out

    def _drain(self, keep: int) -> None:
        """Collect the finished full-resolution bands (all but the last ``keep``): held in
        memory while within the budget, then (and once spilling has begun, always: the file
        order) written to the spill."""
        full = self._full
        while self._drained < len(full) - keep:
            for fut in full[self._drained]:
                data = fut.result()
                self._sizes.append(len(data))
                if self._held_bytes + len(data) <= self._budget and self._spill.tell() == 0:
                    self._held.append(data)
                    self._held_bytes += len(data)
                else:
                    _write_tile(self._spill, data)
            full[self._drained] = []
            self._drained += 1

    def finish(self, out: BinaryIO, tags: Mapping[int, Tag], nodata_tags: Mapping[int, Tag],
               bigtiff: bool | None = None) -> None:
        """Lay the file out (module docstring) into ``out``: header, ghost, IFDs, overview
        tiles (smallest first), then the full-resolution tiles (memory, the spill, then the
        ones still being compressed, each written as it is done: the write overlaps the last
        compressions; the IFDs, which list every tile, are written last, into their place).
        ``tags`` go to the full-resolution IFD, ``nodata_tags`` to every IFD; ``bigtiff``: None
        = when the file could pass 4 GiB."""
        over_by_band = [job.result() for job in self._overview_jobs]  # (or a job's error)
        over = [[t for band in over_by_band for t in band[k]] for k in range(len(self.levels) - 1)]
        count = len(self._full)
        layout = _Layout(self._could_pass_4gib(count) if bigtiff is None else bigtiff)
        ifds = [self._ifd_fields(k, count, layout, tags if k == 0 else {}, nodata_tags)
                for k in range(len(self.levels))]
        ifd_start = layout.header_size + len(_ghost_area())
        ifd_start += ifd_start % 2
        positions, pos = [], ifd_start
        for fields in ifds:
            positions.append(pos)
            pos += layout.ifd_size(fields)
        _preallocate(out, self._size_bound(pos, over))
        out.write(layout.header(ifd_start))
        out.write(_ghost_area())
        out.write(b"\x00" * (pos - out.tell()))  # the IFDs' place
        sizes: list[list[int]] = [[] for _ in self.levels]
        offsets: list[list[int]] = [[] for _ in self.levels]
        for k in range(len(self.levels) - 1, 0, -1):  # smallest overview first
            for t in over[k - 1]:
                offsets[k].append(pos + 4)
                sizes[k].append(len(t))
                pos += len(t) + 8
                _write_tile(out, t)
        for t in self._held:
            _write_tile(out, t)
        self._held = []
        self._spill.flush()
        out.flush()
        _append(self._spill, out)
        for band in self._full[self._drained:]:  # the last bands: written as they are done
            for fut in band:
                data = fut.result()
                self._sizes.append(len(data))
                _write_tile(out, data)
        for s in self._sizes:
            offsets[0].append(pos + 4)
            pos += s + 8
        sizes[0] = self._sizes
        for k, fields in enumerate(ifds):
            fields[324] = layout.offsets_tag(offsets[k])
            fields[325] = layout.offsets_tag(sizes[k])
        out.truncate(pos)  # (the preallocation's excess)
        out.seek(positions[0])
        for k, fields in enumerate(ifds):
            nxt = positions[k + 1] if k + 1 < len(ifds) else 0
            out.write(layout.ifd_bytes(fields, positions[k], nxt))
        out.seek(0, os.SEEK_END)

    def _size_bound(self, prefix: int, over: list[list[bytes]]) -> int:
        """At least the file's size: the prefix (header, IFDs), the overview tiles, the
        full-resolution tiles held and spilled, and the raw size of those still compressing
        (ZSTD and DEFLATE add under 1 %)."""
        pending = sum(len(band) for band in self._full[self._drained:])
        return (prefix + sum(len(t) + 8 for lev in over for t in lev)
                + sum(self._sizes) + 8 * len(self._sizes) + pending * self._tile_bound)

    @property
    def _tile_bound(self) -> int:
        """Bytes a tile takes at most in the file: its raw samples (ZSTD and DEFLATE add under
        1 % to incompressible data) and its leader and trailer."""
        return int(self.block ** 2 * self.dtype.itemsize * 1.01) + 8

    def _could_pass_4gib(self, count: int) -> bool:
        """Whether the file could pass 4 GiB: every tile at its ``_tile_bound``."""
        raw = sum(lev.tiles_across * lev.tiles_down * count * self._tile_bound
                  for lev in self.levels)
        return raw + 16 + len(_GHOST) + 2 ** 20 >= _CLASSIC_LIMIT

    def _ifd_fields(self, k: int, count: int, layout: _Layout, tags: Mapping[int, Tag],
                    nodata_tags: Mapping[int, Tag]) -> dict[int, Tag]:
        lev = self.levels[k]
        fmt = {"u": 1, "i": 2, "f": 3}[self.dtype.kind]
        n_tiles = lev.tiles_across * lev.tiles_down * count
        f: dict[int, Tag] = {}
        if k > 0:
            f[254] = _long([1])
        f[256] = _long([lev.width])
        f[257] = _long([lev.height])
        f[258] = _short([8 * self.dtype.itemsize] * count)
        f[259] = _short([COMPRESSION_CODE[self.compress]])
        f[262] = _short([1])  # BlackIsZero
        f[277] = _short([count])
        f[284] = _short([2])  # separate planes: one band per plane
        f[317] = _short([predictor_for(self.dtype)])
        f[322] = _short([self.block])
        f[323] = _short([self.block])
        f[324] = layout.offsets_tag([0] * n_tiles)  # placeholders of the final size
        f[325] = layout.offsets_tag([0] * n_tiles)
        if count > 1:
            f[338] = _short([0] * (count - 1))  # unspecified extra samples
        f[339] = _short([fmt] * count)
        f.update(tags)
        f.update(nodata_tags)
        return f

    def close(self) -> None:
        """Stop the workers and close the spill (safe to call twice)."""
        self._pool.shutdown(wait=True, cancel_futures=True)
        self._spill.close()


def _append(src: BinaryIO, dst: BinaryIO) -> None:
    """Copy all of ``src`` to the end of ``dst`` inside the kernel (``copy_file_range``: no
    pass through user memory; a reflink on file systems that share extents), else by buffers."""
    size = os.fstat(src.fileno()).st_size
    done = 0
    try:
        while done < size:
            n = os.copy_file_range(src.fileno(), dst.fileno(), size - done, done)
            if n == 0:
                break
            done += n
    except OSError:  # not supported between these files: copy through a buffer
        pass
    if done < size:
        src.seek(done)
        dst.seek(0, os.SEEK_END)
        shutil.copyfileobj(src, dst, 16 * 2 ** 20)


def _preallocate(f: BinaryIO, size: int) -> None:
    """Allocate the file's blocks up to ``size`` before writing (Linux ``fallocate``; the
    caller truncates the excess): ext4 otherwise delays the allocation, then writes the whole
    file back when it is closed after a truncation or renamed over an existing file
    (``auto_da_alloc``: 0.08-0.1 s of a 231 MB map here). Nothing where the file system or
    platform cannot (no emulation by writing zeros)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fallocate = libc.fallocate
    except (OSError, AttributeError):  # pragma: no cover - not glibc/Linux
        return
    fallocate.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int64, ctypes.c_int64]
    f.flush()
    fallocate(f.fileno(), 0, 0, max(int(size), 1))  # failure: delayed allocation, as without it


def _write_tile(f: BinaryIO, data: bytes) -> None:
    """A tile as GDAL's COG stores it: its size (uint32), the bytes, its last 4 bytes again
    (written in pieces: no copy of the tile)."""
    f.write(struct.pack("<I", len(data)))
    f.write(data)
    f.write(data[-4:])


def _ghost_area() -> bytes:
    return b"GDAL_STRUCTURAL_METADATA_SIZE=%06d bytes\n" % len(_GHOST) + _GHOST


def _short(values: Sequence[int]) -> Tag:
    return Tag(SHORT, len(values), struct.pack(f"<{len(values)}H", *values))


def _long(values: Sequence[int]) -> Tag:
    return Tag(LONG, len(values), struct.pack(f"<{len(values)}I", *values))


@dataclass(frozen=True)
class _Layout:
    """Classic TIFF or BigTIFF: header, IFD entry sizes and offset field types."""

    big: bool

    @property
    def header_size(self) -> int:
        return 16 if self.big else 8

    def header(self, first_ifd: int) -> bytes:
        if self.big:
            return b"II+\x00" + struct.pack("<HHQ", 8, 0, first_ifd)
        return b"II*\x00" + struct.pack("<I", first_ifd)

    @property
    def _inline(self) -> int:
        return 8 if self.big else 4

    def offsets_tag(self, values: Sequence[int]) -> Tag:
        if self.big:
            return Tag(LONG8, len(values), np.asarray(values, "<u8").tobytes())
        return Tag(LONG, len(values), np.asarray(values, "<u4").tobytes())

    def ifd_size(self, fields: Mapping[int, Tag]) -> int:
        entry, head = (20, 16) if self.big else (12, 6)
        extra = sum(_even(len(t.data)) for t in fields.values() if len(t.data) > self._inline)
        return head + entry * len(fields) + extra

    def ifd_bytes(self, fields: Mapping[int, Tag], at: int, next_ifd: int) -> bytes:
        """The IFD at file offset ``at``: entries sorted by tag, then out-of-line values."""
        codes = sorted(fields)
        entry = 20 if self.big else 12
        data_at = at + (8 if self.big else 2) + entry * len(codes) + (8 if self.big else 4)
        head = struct.pack("<Q" if self.big else "<H", len(codes))
        entries, extra = [], []
        for code in codes:
            t = fields[code]
            if len(t.data) <= self._inline:
                value = t.data.ljust(self._inline, b"\x00")
            else:
                value = struct.pack("<Q" if self.big else "<I", data_at)
                extra.append(t.data.ljust(_even(len(t.data)), b"\x00"))
                data_at += _even(len(t.data))
            count = struct.pack("<Q" if self.big else "<I", t.count)
            entries.append(struct.pack("<HH", code, t.type) + count + value)
        tail = struct.pack("<Q" if self.big else "<I", next_ifd)
        return head + b"".join(entries) + tail + b"".join(extra)


def _even(n: int) -> int:
    return n + (n % 2)

"""The member files of a ``.SEN3`` product, where they are: a directory, or a ``.zip`` archive as
archives deliver it (``...SEN3.zip``: one ``<name>.SEN3/`` folder inside), read member by member
into memory (netCDF-4 opens a file image in memory), never unpacked to disk.

Errors name the product and the member (:class:`Sen3FormatError`).
"""

from __future__ import annotations

import os
import threading
import xml.etree.ElementTree as ET
import zipfile
import zlib
from collections.abc import Generator, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from ...errors import Sen3FormatError
from .layout import MANIFEST

#: netCDF/HDF5 is not thread-safe: one read at a time (napari reads in worker threads)
LOCK = threading.RLock()
#: archived members read ahead by this many threads (``Members.read_ahead``)
READ_AHEAD = 2


def _zip_prefix(path: Path) -> str | None:
    """The folder holding ``xfdumanifest.xml`` inside a zip archive ("" at its root), or None
    when ``path`` is not a zip archive of a SAFE product."""
    try:
        if not path.is_file() or not zipfile.is_zipfile(path):
            return None
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
    except (OSError, zipfile.BadZipFile):
        return None
    # at any depth (a delivery package may wrap the .SEN3 folder in folders of its own); the
    # shallowest when there are several
    found = sorted((n for n in names if n.rsplit("/", 1)[-1] == MANIFEST), key=len)
    return found[0][: -len(MANIFEST)] if found else None


def is_sen3(path: str | os.PathLike[str]) -> bool:
    """True for a SAFE ``.SEN3`` product: a directory (or its manifest) or a zip archive of one."""
    p = Path(path)
    if p.name == MANIFEST:
        p = p.parent
    if p.is_dir():
        return p.suffix.upper() == ".SEN3" or (p / MANIFEST).is_file()
    return p.suffix.lower() == ".zip" and _zip_prefix(p) is not None


def product_name_of(path: Path, prefix: str | None = None) -> str:
    """The product name of a ``.SEN3`` directory or ``.SEN3.zip``/``.zip`` archive: an
    archive's folder holding the manifest (``prefix``; a download renamed "product (1).zip"
    still holds ESA's ``<name>.SEN3/``), else the file's own name."""
    name = Path(prefix.rstrip("/")).name if prefix else path.name
    for suffix in (".zip", ".ZIP", ".SEN3", ".sen3"):
        name = name.removesuffix(suffix)
    return name


class Members:
    """Read access to the member files of one product (directory or zip archive)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        p = Path(path)
        if p.name == MANIFEST:
            p = p.parent
        self.path = p
        self.prefix: str | None = None
        if p.is_dir():
            return
        if p.suffix.lower() == ".zip":
            if p.is_file() and not zipfile.is_zipfile(p):
                raise Sen3FormatError(p, "not a zip archive, or a truncated or damaged zip "
                                      "archive (its central directory cannot be read)")
            self.prefix = _zip_prefix(p)
            if self.prefix is None:
                raise Sen3FormatError(p, "not a zip archive of a .SEN3 product (no "
                                      f"{MANIFEST} in it)")
            with zipfile.ZipFile(p) as z:
                self._names = {n[len(self.prefix):] for n in z.namelist()
                               if n.startswith(self.prefix)}
            return
        raise Sen3FormatError(p, "not a directory (a .SEN3 product is a directory or its .zip "
                              "archive)")

    @property
    def archived(self) -> bool:
        return self.prefix is not None

    def sizes(self) -> dict[str, int]:
        """Member file -> its size in bytes (uncompressed in an archive), by name."""
        if self.prefix is None:
            return {p.name: p.stat().st_size for p in sorted(self.path.iterdir())
                    if p.is_file()}
        with zipfile.ZipFile(self.path) as z:
            return {i.filename[len(self.prefix):]: i.file_size
                    for i in sorted(z.infolist(), key=lambda i: i.filename)
                    if i.filename.startswith(self.prefix) and not i.is_dir()}

    def where(self, name: str) -> str:
        """The member as messages name it."""
        return str(self.path / name) if self.prefix is None else f"{self.path}!{name}"

    def exists(self, name: str) -> bool:
        if self.prefix is None:
            return (self.path / name).is_file()
        return name in self._names

    def read_bytes(self, name: str) -> bytes:
        try:
            if self.prefix is None:
                return (self.path / name).read_bytes()
            with zipfile.ZipFile(self.path) as z:
                return z.read(self.prefix + name)
        except (OSError, KeyError, zipfile.BadZipFile, EOFError, zlib.error,
                NotImplementedError, RuntimeError) as exc:
            # zlib.error: a damaged compressed member; NotImplementedError: a compression
            # method zipfile lacks (Deflate64); RuntimeError: an encrypted member
            raise Sen3FormatError(self.where(name), f"cannot read (damaged or unsupported "
                                  f"archive member): {exc}") from None

    def read_ahead(self, names: list[str], ahead: int = READ_AHEAD
                   ) -> Generator[bytes | None, None, None]:
        """The bytes of archived members ``names``, in order, each read (inflated) by one of
        ``ahead`` threads while the caller uses the ones before: inflating releases the GIL
        (fr-alps, 15 band members of 8 MB: 0.37 s one by one, 0.23-0.25 s with 2 threads). At
        most ``ahead`` + 1 are held at once. None for each name of a directory product (its
        files are opened where they are)."""
        if self.prefix is None:
            yield from (None for _ in names)
            return
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(ahead, thread_name_prefix="sen3-read") as pool:
            pending = [pool.submit(self.read_bytes, n) for n in names[:ahead]]
            for k in range(len(names)):
                if k + ahead < len(names):
                    pending.append(pool.submit(self.read_bytes, names[k + ahead]))
                yield pending.pop(0).result()

    @contextmanager
    def dataset(self, name: str, data: bytes | None = None) -> Iterator[Any]:
        """``netCDF4.Dataset`` of a member (under the module lock), from ``data`` when given
        (its bytes, ``read_ahead``); Sen3FormatError when it is not a netCDF file."""
        import netCDF4

        with LOCK:
            try:
                if self.prefix is None:
                    ds = netCDF4.Dataset(self.path / name)
                else:
                    ds = netCDF4.Dataset(name, memory=self.read_bytes(name) if data is None
                                         else data)
            except OSError as exc:
                raise Sen3FormatError(self.where(name), f"not a netCDF file ({exc})") from None
            try:
                yield ds
            finally:
                ds.close()

    def manifest(self) -> ET.Element:
        """The parsed ``xfdumanifest.xml``; Sen3FormatError when it cannot be parsed."""
        try:
            return ET.fromstring(self.read_bytes(MANIFEST))
        except ET.ParseError as exc:
            raise Sen3FormatError(self.where(MANIFEST), f"manifest cannot be parsed: {exc}"
                                  ) from None

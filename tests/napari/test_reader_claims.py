"""The reader claims only files it can read: a plain TIFF falls back to
napari's own reader instead of "Choose reader" and "GeoTIFF has no CRS"."""

from __future__ import annotations

import warnings

import numpy as np
import rasterio
from rasterio.errors import NotGeoreferencedWarning
from rasterio.transform import Affine

from napari_meris_ortho._napari.reader import get_reader


def _plain_tiff(path):
    with warnings.catch_warnings():  # written without georeferencing, as meant
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path, "w", driver="GTiff", width=6, height=5, count=1,
                           dtype="uint16") as ds:
            ds.write(np.arange(30, dtype=np.uint16).reshape(1, 5, 6))
    return path


def _geotiff(path):
    with rasterio.open(path, "w", driver="GTiff", width=6, height=5, count=1, dtype="float32",
                       crs="EPSG:32632", transform=Affine(260, 0, 4e5, 0, -260, 5.1e6)) as ds:
        ds.write(np.ones((1, 5, 6), np.float32))
    return path


def test_reader_declines_what_it_cannot_read(tmp_path, tiny_n1):
    assert get_reader(str(_plain_tiff(tmp_path / "plain.tif"))) is None
    assert get_reader(str(tmp_path / "missing.tif")) is None
    fake = tmp_path / "notes.N1"
    fake.write_text("not a MERIS product\n")
    assert get_reader(str(fake)) is None
    assert get_reader(str(tmp_path / "missing.N1")) is None
    assert get_reader([str(_geotiff(tmp_path / "geo.tif")), str(tmp_path / "plain.tif")]) is None
    # what it reads, it claims
    assert get_reader(str(tmp_path / "geo.tif")) is not None
    assert get_reader(str(tiny_n1)) is not None
    truncated = tmp_path / "truncated.N1"
    truncated.write_bytes(tiny_n1.read_bytes()[:5000])  # an N1 header: ours to report
    assert get_reader(str(truncated)) is not None


def test_plain_tiff_opens_with_napari_builtins(make_napari_viewer, tmp_path):
    viewer = make_napari_viewer()
    path = _plain_tiff(tmp_path / "plain.tif")
    (layer,) = viewer.open(str(path))  # one compatible reader: no "Choose reader"
    np.testing.assert_array_equal(np.asarray(layer.data), np.arange(30).reshape(5, 6))
    assert layer.source.reader_plugin != "napari-meris-ortho"


def test_reader_declines_special_files_at_once(tmp_path):
    """A FIFO named x.tif or x.N1 (reading it blocks until a writer comes) returns None within
    1 s, never hanging on it."""
    import os
    import threading
    import time

    for name in ("x.tif", "x.N1", "x.zip"):
        fifo = tmp_path / name
        os.mkfifo(fifo)
        answer: list[object] = []
        thread = threading.Thread(target=lambda f=fifo, out=answer: out.append(get_reader(str(f))),
                                  daemon=True)
        t0 = time.perf_counter()
        thread.start()
        thread.join(1.0)
        elapsed = time.perf_counter() - t0
        if thread.is_alive():  # unblock the reader stuck in open() before failing
            fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
            os.close(fd)
            thread.join(5.0)
        assert answer == [None] and elapsed < 1.0, (name, answer, elapsed)
    assert get_reader([str(tmp_path / "x.tif"), str(tmp_path / "x.N1")]) is None
    assert get_reader(str(tmp_path)) is None  # a plain directory: not a product nor a store

"""``export_cog``: layers of a synthesis store as a Cloud-Optimized GeoTIFF.

The bands go through ``ortho.writing.write_map``, the writer of every mapped product (float32
radiances, band descriptions, units, averaged overviews); the other layers (``ndvi``, ``count``,
``product``) through the same COG writer with their own type and nearest overviews. Both stream
one layer at a time from the store.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import OptionsError
from ..geometry.grid import OutputGrid
from ..progress import ProgressCallback
from . import store as st
from .reading import SynthesisStore

#: compression of the exported COGs (DEFLATE: read by every GDAL build)
COMPRESS = "deflate"


class _StoreBands:
    """The bands of a synthesis as ``write_map`` reads a mapped product (radiances only: the
    store holds no product counts), one band read from the store at a time."""

    stats = None
    diagnostics: dict[str, np.ndarray] = {}

    def __init__(self, store: SynthesisStore, bands: list[int],
                 progress: ProgressCallback | None) -> None:
        self.store, self.bands, self.progress = store, bands, progress

    @property
    def grid(self) -> OutputGrid:
        return self.store.grid

    def radiance(self, bands: Sequence[int] | None = None) -> dict[int, np.ndarray]:
        out = {}
        for b in self.bands if bands is None else bands:
            out[int(b)] = np.asarray(self.store.band(int(b)), np.float32)
            if self.progress is not None:
                self.progress(self.bands.index(int(b)) + 1, len(self.bands) + 1)
        return out


def export_cog(store: SynthesisStore, out: str | os.PathLike[str], *,
               bands: Sequence[int] | None = None, layer: str | None = None,
               progress: ProgressCallback | None = None) -> Path:
    """Write bands (default all of the synthesis) or one other ``layer`` (``ndvi``, ``count``,
    ``product``) of ``store`` as a Cloud-Optimized GeoTIFF (module docstring); atomic."""
    from .._atomic import check_distinct
    from ..ortho.writing import check_geotiff_name, write_map

    check_distinct({"output": out}, {"synthesis store": [store.path]})
    check_geotiff_name("output", out)
    if layer is not None and bands is not None:
        raise OptionsError("choose bands or one other layer, not both")
    tags = {"algorithm": store.algorithm, "snapshot": store.snapshot,
            "products": " ".join(store.product_names().values())}
    if layer is not None:
        others = [n for n in store.layers() if not n.startswith("band_")]
        if layer not in others:
            raise OptionsError(f"{store.path}: no layer {layer!r} to export (the synthesis has "
                               f"{', '.join(others)})")
        path = _write_layer(store, out, layer, tags)
    else:
        chosen = list(store.bands) if bands is None else list(dict.fromkeys(int(b)
                                                                             for b in bands))
        missing = [b for b in chosen if b not in store.bands]
        if missing:
            raise OptionsError(f"{store.path}: bands {missing} are not in the synthesis "
                               f"(it has {list(store.bands)})")
        path = write_map(out, _StoreBands(store, chosen, progress), dtype="float32",
                         compress=COMPRESS, metadata=tags,
                         software="napari-meris-ortho export", order=chosen)
    if progress is not None:
        progress(1, 1)
    return path


def _write_layer(store: SynthesisStore, out: str | os.PathLike[str], layer: str,
                 tags: dict[str, Any]) -> Path:
    """One bookkeeping layer (its own type, 0 = background, nearest overviews)."""
    from ..engine.resample import overview_level
    from ..output.geotiff import write_cog

    def one() -> Iterator[np.ndarray]:
        yield np.asarray(store.read(layer))

    return write_cog(Path(out), one(), store.grid, count=1, halve=overview_level,
                     dtype=st.layer_dtype(layer), descriptions=[layer], metadata=tags,
                     compress=COMPRESS, overview_resampling="nearest")

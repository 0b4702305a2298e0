"""``export_cog``: layers of a synthesis store as a Cloud-Optimized GeoTIFF."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import OptionsError, OutputError
from ..progress import ProgressCallback
from . import store as st

if TYPE_CHECKING:
    pass
from .reading import SynthesisStore
from .tiling import BLOCK, tiles

# --------------------------------------------------------------------------- export


def export_cog(store: SynthesisStore, out: str | os.PathLike[str], *,
               bands: Sequence[int] | None = None, layer: str | None = None,
               progress: ProgressCallback | None = None) -> Path:
    """Write bands (default all of the synthesis) or one other ``layer`` (``ndvi``, ``count``,
    ``product``) of ``store`` as a Cloud-Optimized GeoTIFF (deflate, overviews). The store is
    read tile by tile into a tiled temporary GeoTIFF, then copied with GDAL's COG driver."""
    import tempfile

    import rasterio
    import rasterio.shutil
    from rasterio.errors import RasterioError
    from rasterio.windows import Window

    from .._atomic import atomic_path
    from ..output.geotiff import meris_band_description

    if layer is not None and bands is not None:
        raise OptionsError("choose bands or one other layer, not both")
    if layer is not None:
        others = [n for n in store.layers() if not n.startswith("band_")]
        if layer not in others:
            raise OptionsError(f"{store.path}: no layer {layer!r} to export (the synthesis has "
                               f"{', '.join(others)})")
        names, descriptions = [layer], [layer]
    else:
        chosen = list(store.bands) if bands is None else [int(b) for b in bands]
        missing = [b for b in chosen if b not in store.bands]
        if missing:
            raise OptionsError(f"{store.path}: bands {missing} are not in the synthesis "
                               f"(it has {list(store.bands)})")
        names = [st.band_layer(b) for b in chosen]
        descriptions = [meris_band_description(b) for b in chosen]
    grid = store.grid
    dtype = st.layer_dtype(names[0])
    profile = dict(driver="GTiff", width=grid.width, height=grid.height, count=len(names),
                   dtype=dtype, crs=rasterio.crs.CRS.from_wkt(grid.crs.to_wkt()),
                   transform=grid.transform, nodata=0, tiled=True, blockxsize=BLOCK,
                   blockysize=BLOCK, BIGTIFF="IF_SAFER")
    windows = list(tiles((0, grid.height, 0, grid.width), store.tile))
    session_store = store.session.store
    try:
        with tempfile.TemporaryDirectory(dir=Path(out).parent if Path(out).parent.is_dir()
                                         else None) as tmp_dir, \
                atomic_path(out, suffix=".tif") as tmp:
            work = Path(tmp_dir) / "tiles.tif"
            with rasterio.open(work, "w", **profile) as ds:
                ds.update_tags(algorithm=store.algorithm, snapshot=store.snapshot,
                               products=" ".join(store.product_names().values()))
                for i, d in enumerate(descriptions, start=1):
                    ds.set_band_description(i, d)
                for k, w in enumerate(windows):
                    arrays = st.read_window(session_store, names, w)
                    win = Window(w[2], w[0], w[3] - w[2], w[1] - w[0])
                    for i, name in enumerate(names, start=1):
                        ds.write(arrays[name], i, window=win)
                    if progress is not None:
                        progress(k + 1, len(windows) + 1)
            rasterio.shutil.copy(work, tmp, driver="COG", compress="DEFLATE",
                                 blocksize=BLOCK, overview_resampling="nearest",
                                 BIGTIFF="IF_SAFER")
    except (RasterioError, OSError) as exc:
        raise OutputError(f"{out}: cannot write the Cloud-Optimized GeoTIFF ({exc})") from exc
    if progress is not None:
        progress(len(windows) + 1, len(windows) + 1)
    return Path(out)

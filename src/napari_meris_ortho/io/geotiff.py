"""GeoTIFF output of orthorectified bands and syntheses (GDAL through rasterio).

``write_geotiff(path, bands, grid, ...)`` writes one GeoTIFF band per array: CRS and transform
of the ``OutputGrid``, nodata 0 (the MERSYN background), band descriptions (e.g.
``meris_band_description(7, 665.0)`` -> "MERIS band 7 (665.0 nm)"), dataset and per-band
metadata tags (radiance scale factors...), 256 x 256 tiles, deflate compression, written to a
temporary file renamed at the end (``_atomic.atomic_path``).
``read_geotiff(path)`` -> ``(arrays, grid, metadata)`` with metadata = {"tags": dataset tags,
"descriptions": per band, "band_tags": per band, "nodata": value, "dtype": name}.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from .._atomic import atomic_path
from ..errors import OutputError
from ..geometry.grid import OutputGrid
from ..progress import ProgressCallback

TILE = 256


def meris_band_description(band: int, wavelength_nm: float | None = None) -> str:
    """Band description naming the MERIS band number and its central wavelength."""
    if wavelength_nm is None:
        return f"MERIS band {int(band)}"
    return f"MERIS band {int(band)} ({float(wavelength_nm):.1f} nm)"


def _tag_values(tags: Mapping[str, Any] | None) -> dict[str, str]:
    return {str(k): str(v) for k, v in (tags or {}).items()}


def write_geotiff(
    path: str | Path, bands: Sequence[np.ndarray], grid: OutputGrid, *, nodata: float | None = 0,
    descriptions: Sequence[str] | None = None, metadata: Mapping[str, Any] | None = None,
    band_metadata: Sequence[Mapping[str, Any]] | None = None, dtype: Any = None,
    progress: ProgressCallback | None = None,
) -> Path:
    """Write ``bands`` (each (grid.height, grid.width)) as a tiled, deflate-compressed GeoTIFF.

    Raises OutputError for a missing or read-only directory (no file is left behind) or bands
    that do not match the grid.
    """
    import rasterio
    from rasterio.errors import RasterioError

    out = Path(path)
    bands = [np.asarray(b) for b in bands]
    if not bands:
        raise OutputError(f"{out}: no band to write")
    for i, b in enumerate(bands):
        if np.shape(b) != grid.shape:
            raise OutputError(f"{out}: band {i + 1} has shape {np.shape(b)}, grid is {grid.shape}")
    for name, seq in (("descriptions", descriptions), ("band_metadata", band_metadata)):
        if seq is not None and len(seq) != len(bands):
            raise OutputError(f"{out}: {len(seq)} {name} for {len(bands)} bands")
    dt = np.dtype(dtype) if dtype is not None else np.result_type(*[b.dtype for b in bands])
    profile = dict(
        driver="GTiff", width=grid.width, height=grid.height, count=len(bands), dtype=dt.name,
        crs=rasterio.crs.CRS.from_wkt(grid.crs.to_wkt()), transform=grid.transform,
        nodata=nodata, tiled=True, blockxsize=TILE, blockysize=TILE, compress="deflate",
        interleave="band", BIGTIFF="IF_SAFER",
    )
    try:
        with atomic_path(out, suffix=".tif") as tmp, rasterio.open(tmp, "w", **profile) as ds:
            ds.update_tags(**_tag_values(metadata))
            for i, b in enumerate(bands, start=1):
                ds.write(b.astype(dt, copy=False), i)
                if descriptions is not None:
                    ds.set_band_description(i, str(descriptions[i - 1]))
                if band_metadata is not None:
                    ds.update_tags(i, **_tag_values(band_metadata[i - 1]))
                if progress is not None:
                    progress(i, len(bands))
    except (RasterioError, OSError) as exc:
        raise OutputError(f"{out}: cannot write GeoTIFF ({exc})") from exc
    return out


def read_geotiff(path: str | Path, bands: Sequence[int] | None = None
                 ) -> tuple[list[np.ndarray], OutputGrid, dict[str, Any]]:
    """Read a north-up GeoTIFF: (arrays, OutputGrid, metadata) (module docstring).

    ``bands``: 1-based band numbers to read (default all). Raises OutputError when the file
    cannot be read or is not north-up.
    """
    import rasterio
    from rasterio.errors import RasterioError

    try:
        with rasterio.open(path) as ds:
            t = ds.transform
            if t.b != 0 or t.d != 0 or t.a <= 0 or t.e >= 0:
                raise OutputError(f"{path}: only north-up rasters are supported")
            if ds.crs is None:
                raise OutputError(f"{path}: the raster has no coordinate reference system")
            crs = pyproj.CRS.from_user_input(ds.crs.to_wkt())
            grid = OutputGrid(crs, t.c, t.f, t.a, -t.e, ds.width, ds.height)
            idx = list(bands) if bands is not None else list(range(1, ds.count + 1))
            arrays = [ds.read(i) for i in idx]
            meta = {
                "tags": ds.tags(),
                "descriptions": [ds.descriptions[i - 1] for i in idx],
                "band_tags": [ds.tags(i) for i in idx],
                "nodata": ds.nodata,
                "dtype": ds.dtypes[0],
            }
    except (RasterioError, OSError, IndexError) as exc:
        raise OutputError(f"{path}: cannot read GeoTIFF ({exc})") from exc
    return arrays, grid, meta

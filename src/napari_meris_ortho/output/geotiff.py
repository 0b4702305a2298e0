"""GeoTIFF output of orthorectified bands and syntheses (GDAL through rasterio).

``write_geotiff(path, bands, grid, ...)`` writes one GeoTIFF band per array: CRS and transform
of the ``OutputGrid``, nodata 0 (the MERSYN background), band descriptions (e.g.
``meris_band_description(7, 665.0)`` -> "MERIS band 7 (665.0 nm)"), dataset and per-band
metadata tags (radiance scale factors...), 256 x 256 tiles, deflate compression, written to a
temporary file renamed at the end (``_atomic.atomic_path``).
``write_cog(path, bands, grid, count=..., halve=...)`` writes a Cloud-Optimized GeoTIFF from an
iterable of bands (a generator: one band in memory at a time): each band and its overview levels
(2 x 2 average, nodata ignored: the caller's ``halve`` kernel) cut into 512 x 512 tiles,
predicted and compressed (ZSTD or DEFLATE) on all cores while the next band is computed, laid
out as GDAL's COG driver does (``output.cog``), with GDAL's own georeferencing and metadata tags.
Integer bands carry GDAL scale/offset (``counts_to_radiance``: radiance = counts x scale +
offset), so GDAL, QGIS and rasterio (``masked=True`` and the scales) read physical values.
``read_geotiff(path)`` -> ``(arrays, grid, metadata)`` with metadata = {"tags": dataset tags,
"descriptions": per band, "band_tags": per band, "nodata": value, "dtype": name, "scales",
"offsets"}; ``scaled=True`` applies scale/offset (float32, background stays 0).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from .._atomic import atomic_path, scratch_dir
from ..errors import OutputError
from ..geometry.grid import OutputGrid
from ..progress import ProgressCallback
from .cog import EVERY_IFD_TAGS, GEO_TAGS, CogWriter, Tag, template_tags

TILE = 256
#: block size of the Cloud-Optimized GeoTIFFs (COG driver default)
COG_BLOCK = 512
COMPRESSIONS = ("zstd", "deflate")
#: compression levels: fast, most of the size gain (ZSTD 1 ~ DEFLATE 6 in size here)
_LEVEL = {"zstd": 1, "deflate": 6}
COUNT_MAX = 65535
#: one overview level from the previous: (array, nodata, "average" | "nearest") -> array
Halve = Callable[[np.ndarray, float | None, str], np.ndarray]


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


def radiance_to_counts(radiance: np.ndarray, scale: float, offset: float = 0.0) -> np.ndarray:
    """uint16 counts of float radiances (round half up, clipped to 0..65535); background 0
    (radiance 0) stays 0. Inverse of ``counts x scale + offset``."""
    r = np.asarray(radiance, np.float32)
    c = np.floor((r - np.float32(offset)) / np.float32(scale) + np.float32(0.5))
    c = np.clip(np.nan_to_num(c, nan=0.0), 0, COUNT_MAX).astype(np.uint16)
    c[r == 0] = 0
    return c


def overview_levels(width: int, height: int, block: int = COG_BLOCK) -> list[int]:
    """Decimation factors 2, 4, ... until the overview fits one block (GDAL COG ``AUTO``)."""
    levels, f = [], 1
    while max(-(-width // f), -(-height // f)) > block:
        f *= 2
        levels.append(f)
    return levels


def _optional(seq: Sequence[Any] | None, count: int, name: str, out: Path) -> None:
    if seq is not None and len(seq) != count:
        raise OutputError(f"{out}: {len(seq)} {name} for {count} bands")


def write_cog(
    path: str | Path, bands: Iterable[np.ndarray], grid: OutputGrid, *, count: int,
    halve: Halve, dtype: Any = np.uint16, nodata: float | None = 0,
    scales: Sequence[float] | None = None, offsets: Sequence[float] | None = None,
    units: Sequence[str] | None = None, descriptions: Sequence[str] | None = None,
    metadata: Mapping[str, Any] | None = None,
    band_metadata: Sequence[Mapping[str, Any]] | None = None, compress: str = "zstd",
    level: int | None = None, overview_resampling: str = "average",
    progress: ProgressCallback | None = None,
) -> Path:
    """Write ``count`` bands (an iterable, consumed one band at a time) as a Cloud-Optimized
    GeoTIFF with internal overviews (module docstring); atomic (tmp file + rename).

    ``halve(level, nodata, overview_resampling)`` gives the next overview level of a band
    (``engine.resample.overview_level``). Each band's tiles are compressed on worker threads
    while the next band is computed (``output.cog``); GDAL writes the georeferencing and metadata
    tags into a 1 x 1 template that is copied. Raises OutputError for an unwritable directory,
    bands not matching the grid or ``count``.
    """
    out = Path(path)
    dt = np.dtype(dtype)
    for name, seq in (("descriptions", descriptions), ("band_metadata", band_metadata),
                      ("scales", scales), ("offsets", offsets), ("units", units)):
        _optional(seq, count, name, out)
    if compress not in COMPRESSIONS:
        raise OutputError(f"unknown compression {compress!r}: choose {', '.join(COMPRESSIONS)}")
    if overview_resampling not in ("average", "nearest"):
        raise OutputError(f"unknown overview resampling {overview_resampling!r}")
    n_levels = len(overview_levels(grid.width, grid.height))
    tags = _template(out, grid, count, dt, nodata, scales, offsets, units, descriptions,
                     metadata, band_metadata)
    main = {k: v for k, v in tags.items() if k in GEO_TAGS}
    every = {k: v for k, v in tags.items() if k in EVERY_IFD_TAGS}
    try:
        with atomic_path(out, suffix=".tif") as tmp, _stage_dir(out) as stage:
            writer = CogWriter(grid.shape, n_levels, dt, stage / "full.tiles",
                               compress=compress, level=level or _LEVEL[compress],
                               block=COG_BLOCK)
            try:
                n = 0
                for n, b in enumerate(bands, start=1):
                    writer.add_band(_checked(b, n, grid, dt, out, count),
                                    lambda a: halve(a, nodata, overview_resampling))
                    if progress is not None:
                        progress(n, count + 1)
                if n != count:
                    raise OutputError(f"{out}: {n} bands given, {count} expected")
                # the empty file atomic_path made, not truncated again ("wb"): ext4 writes back
                # a truncated file's data when it is closed (auto_da_alloc; the writer also
                # preallocates, against the same on a rename over an existing output)
                with open(tmp, "r+b") as f:
                    writer.finish(f, main, every)
            finally:
                writer.close()
    except OSError as exc:
        raise OutputError(f"{out}: cannot write GeoTIFF ({exc})") from exc
    if progress is not None:
        progress(count + 1, count + 1)
    return out


def _checked(b: np.ndarray, n: int, grid: OutputGrid, dt: np.dtype, out: Path,
             count: int) -> np.ndarray:
    """Band ``n`` as ``dt``, checked against the grid and ``count``."""
    if n > count:
        raise OutputError(f"{out}: more than {count} bands given")
    if np.shape(b) != grid.shape:
        raise OutputError(f"{out}: band {n} has shape {np.shape(b)}, grid is {grid.shape}")
    return np.asarray(b).astype(dt, copy=False)


def _template(out: Path, grid: OutputGrid, count: int, dt: np.dtype, nodata: float | None,
              scales: Sequence[float] | None, offsets: Sequence[float] | None,
              units: Sequence[str] | None, descriptions: Sequence[str] | None,
              metadata: Mapping[str, Any] | None,
              band_metadata: Sequence[Mapping[str, Any]] | None) -> dict[int, Tag]:
    """The TIFF fields GDAL writes for this grid and metadata, from a 1 x 1 GeoTIFF in memory
    (CRS GeoKeys, transform, GDAL_METADATA with scales/offsets/units/descriptions, nodata)."""
    import rasterio
    from rasterio.errors import RasterioError
    from rasterio.io import MemoryFile

    try:
        with MemoryFile() as mem:
            with mem.open(driver="GTiff", width=1, height=1, count=count, dtype=dt.name,
                          crs=rasterio.crs.CRS.from_wkt(grid.crs.to_wkt()),
                          transform=grid.transform, nodata=nodata) as ds:
                ds.update_tags(**_tag_values(metadata))
                _band_info(ds, descriptions, band_metadata, units)
                if scales is not None:
                    ds.scales = [float(v) for v in scales]
                if offsets is not None:
                    ds.offsets = [float(v) for v in offsets]
            return template_tags(bytes(mem.getbuffer()))
    except (RasterioError, ValueError) as exc:
        raise OutputError(f"{out}: cannot write GeoTIFF ({exc})") from exc


def _stage_dir(out: Path) -> Any:
    """A hidden scratch directory next to the output (the full-resolution tiles spill there),
    removed in any case (also on a signal; after a SIGKILL by the next write there)."""
    return scratch_dir(out, suffix=".stage")


def _band_info(ds: Any, descriptions: Sequence[str] | None,
               band_metadata: Sequence[Mapping[str, Any]] | None,
               units: Sequence[str] | None) -> None:
    for i in range(1, ds.count + 1):
        if descriptions is not None:
            ds.set_band_description(i, str(descriptions[i - 1]))
        if band_metadata is not None:
            ds.update_tags(i, **_tag_values(band_metadata[i - 1]))
        if units is not None:
            ds.set_band_unit(i, str(units[i - 1]))


def raster_grid(path: str | Path) -> OutputGrid:
    """The grid of a raster (GeoTIFF or any GDAL raster): its CRS, transform and size, no pixel
    read (``--like``, as ``rio warp --like``). OptionsError when it cannot be read, has no CRS or
    is not north-up."""
    import rasterio
    from rasterio.errors import RasterioError

    from .._atomic import check_input_file
    from ..errors import OptionsError

    check_input_file(path, "grid reference raster")
    try:
        with rasterio.open(path) as ds:
            t, crs, width, height = ds.transform, ds.crs, ds.width, ds.height
    except (RasterioError, OSError) as exc:
        raise OptionsError(f"{path}: cannot read the grid reference raster ({exc})") from exc
    if crs is None:
        raise OptionsError(f"{path}: the grid reference raster has no coordinate reference "
                           "system")
    if t.b != 0 or t.d != 0 or t.a <= 0 or t.e >= 0:
        raise OptionsError(f"{path}: the grid reference raster is not north-up (rotated or "
                           "flipped): only north-up grids are written")
    return OutputGrid(pyproj.CRS.from_user_input(crs.to_wkt()), t.c, t.f, t.a, -t.e, width,
                      height)


def read_geotiff(path: str | Path, bands: Sequence[int] | None = None, *, scaled: bool = False
                 ) -> tuple[list[np.ndarray], OutputGrid, dict[str, Any]]:
    """Read a north-up GeoTIFF: (arrays, OutputGrid, metadata) (module docstring).

    ``bands``: 1-based band numbers to read (default all); ``scaled``: apply the bands' GDAL
    scale/offset (float32; nodata points give 0). Raises OutputError when the file cannot be
    read or is not north-up.
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
            arrays = [_scaled(ds, i) if scaled else ds.read(i) for i in idx]
            meta = {
                "scales": [ds.scales[i - 1] for i in idx],
                "offsets": [ds.offsets[i - 1] for i in idx],
                "tags": ds.tags(),
                "descriptions": [ds.descriptions[i - 1] for i in idx],
                "band_tags": [ds.tags(i) for i in idx],
                "nodata": ds.nodata,
                "dtype": ds.dtypes[0],
            }
    except (RasterioError, OSError, IndexError) as exc:
        raise OutputError(f"{path}: cannot read GeoTIFF ({exc})") from exc
    return arrays, grid, meta


def _scaled(ds: Any, band: int) -> np.ndarray:
    """Physical values of a band (counts x scale + offset), nodata -> 0, float32."""
    data = ds.read(band, masked=True)
    values = data.astype(np.float32) * np.float32(ds.scales[band - 1]) + np.float32(
        ds.offsets[band - 1])
    return np.ma.filled(values, np.float32(0))

"""A mapped product as a file: ``write_map``, the one writer of mapped bands.

``meris-ortho map``, the napari widget and the synthesis export all write through
``write_map``: a Cloud-Optimized GeoTIFF (``output.geotiff.write_cog``) with one band per MERIS
band, streamed one band at a time; uint16 counts with GDAL scale = sf_rad (GDAL, QGIS and
rasterio read radiances) or float32 radiances; overviews averaged with nodata 0 ignored
(``engine.resample.overview_level``); optionally the diagnostics as ``OUT_diagnostics.tif``
(its band ``hidden``: 1 on ground hidden from the sensor by the relief). Hidden ground left
no data (hidden ``mask``) is 0, the nodata of every band: GDAL's and QGIS's mask of the file
leaves it out.
What the file says of its bands and of the run (band order, wavelengths, units, scale/offset,
nodata, options, DEMs with their vertical datums, software version) is a ``MapDescription``
(``ortho.description``): the GeoTIFF tags, the ``--stats-json`` file and the xarray attributes
are all written from it.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ..engine.resample import overview_level
from ..errors import OptionsError
from ..geometry.grid import OutputGrid
from ..output.geotiff import COMPRESSIONS, write_cog
from ..progress import ProgressCallback
from .antecedents import GATHER_GROUP
from .description import MapDescription, check_dtype, describe_map
from .stats import RunStats

#: the diagnostics layers of ``OUT_diagnostics.tif``, in band order
DIAGNOSTICS = ("line", "col", "elevation", "elevation_source", "iterations", "shift_east_m",
               "shift_north_m", "hidden")


class Mapped(Protocol):
    """What ``write_map`` writes: bands on a grid (``Antecedents``: sampled while writing;
    ``OrthoResult``; a synthesis's bands). ``stats``: the run's, or None (then ``metadata``
    describes the bands)."""

    @property
    def grid(self) -> OutputGrid: ...
    @property
    def bands(self) -> Any: ...
    @property
    def stats(self) -> RunStats | None: ...
    @property
    def diagnostics(self) -> dict[str, np.ndarray]: ...
    def radiance(self, bands: Sequence[int] | None = None) -> dict[int, np.ndarray]: ...


def diagnostics_path(out: str | os.PathLike[str]) -> Path:
    """``OUT_diagnostics.tif`` beside ``OUT.tif``."""
    p = Path(out)
    return p.with_name(p.stem + "_diagnostics" + (p.suffix or ".tif"))


def check_outputs(outputs: Mapping[str, str | os.PathLike[str] | None],
                  products: Sequence[str | os.PathLike[str]],
                  dems: Sequence[str | os.PathLike[str]] = (), *,
                  references: Sequence[str | os.PathLike[str]] = ()) -> None:
    """Before any work: every output (name -> path, None: not requested) distinct from the
    others, never an input product, a DEM of the list (``PATH[:DATUM]``) or a grid reference
    raster (``--like``), never a special file, in a writable directory; OutputError naming the
    output otherwise. The one output check of the CLI and the widget."""
    from .._atomic import check_distinct, check_writable_dir
    from ..dem.geoid import split_datum

    check_distinct(dict(outputs), {"input product": list(products),
                                   "DEM": [split_datum(d)[0] for d in dems],
                                   "grid reference": list(references)})
    for out in outputs.values():
        if out is not None:
            check_writable_dir(out)


#: what a GeoTIFF output may be named
GEOTIFF_SUFFIXES = (".tif", ".tiff")


def check_geotiff_name(name: str, path: str | os.PathLike[str]) -> None:
    """A GeoTIFF output named as one: ``out.png`` would hold a TIFF under another format's
    name (OptionsError)."""
    if Path(path).suffix.lower() not in GEOTIFF_SUFFIXES:
        raise OptionsError(f"{name} {path}: the output is a Cloud-Optimized GeoTIFF: name it "
                           f"{' or '.join(GEOTIFF_SUFFIXES)}")


def write_map(path: str | os.PathLike[str], mapped: Mapped, *, dtype: str = "uint16",
              compress: str = "zstd", diagnostics: bool = False,
              metadata: Mapping[str, Any] | None = None, software: str = "napari-meris-ortho",
              progress: ProgressCallback | None = None,
              order: Sequence[int] | None = None) -> Path:
    """Write the bands of ``mapped`` as a Cloud-Optimized GeoTIFF (module docstring); with
    ``diagnostics`` also its diagnostics layers. ``dtype``: "uint16" (counts + GDAL scale;
    needs ``mapped.counts``, which ``Antecedents`` have) or "float32" (radiances);
    ``metadata``: more dataset tags; ``order``: the bands' order in the file (the user's
    ``--bands 7,5,2``: an RGB composite in any viewer; default ascending; repeats dropped).
    Atomic (tmp file + rename); OutputError/OptionsError."""
    check_dtype(dtype)
    if compress not in COMPRESSIONS:
        raise OptionsError(f"unknown compression {compress!r}: choose "
                           f"{', '.join(COMPRESSIONS)}")
    counts = dtype == "uint16"
    if counts and not hasattr(mapped, "counts"):
        raise OptionsError("uint16 output needs the product counts: write float32 radiances")
    described = describe_mapped(mapped, dtype, order=order, software=software)
    if counts and any(b.scale is None for b in described.bands):
        raise OptionsError("uint16 output needs the radiance scale of every band: write "
                           "float32 radiances")
    bands = described.band_numbers
    write_cog(
        Path(path), _streamed(mapped, bands, counts, progress), mapped.grid, count=len(bands),
        dtype=dtype, nodata=described.nodata,
        scales=[b.scale for b in described.bands] if counts else None,  # type: ignore[misc]
        offsets=[b.offset for b in described.bands] if counts else None,  # type: ignore[misc]
        units=[b.units for b in described.bands],
        descriptions=[b.description for b in described.bands],
        band_metadata=[b.tags() for b in described.bands],
        compress=compress, halve=overview_level,
        metadata={**described.tags(), **(metadata or {})})
    if diagnostics:
        layers = mapped.diagnostics
        shape = mapped.grid.shape
        arrays = (np.nan_to_num(layers[n].astype(np.float32), nan=0.0) if n in layers
                  else np.zeros(shape, np.float32) for n in DIAGNOSTICS)
        write_cog(diagnostics_path(path), arrays, mapped.grid, count=len(DIAGNOSTICS),
                  nodata=None, descriptions=list(DIAGNOSTICS), dtype="float32",
                  compress=compress, overview_resampling="nearest", halve=overview_level,
                  metadata={"elevation_source": "k >= 0: DEM k; -1: tie points; -2: none",
                            "hidden": "1: ground hidden from the sensor by the relief",
                            "iterations": "-1: no antecedent; -2: hidden by the relief"})
    return Path(path)


def describe_mapped(mapped: Mapped, dtype: str = "uint16", *,
                    order: Sequence[int] | None = None,
                    software: str = "napari-meris-ortho") -> MapDescription:
    """The ``MapDescription`` of ``write_map(path, mapped, dtype=..., order=...)``: the bands
    in file order (``band_order``), their facts from ``mapped.stats`` or, without a run, from
    ``mapped.scale_factors`` (a synthesis's), ``mapped.run`` and ``mapped.dems``."""
    bands = band_order(mapped.bands, order)
    return describe_map(mapped.stats, bands, dtype,
                        scales=getattr(mapped, "scale_factors", None),
                        run=getattr(mapped, "run", None), dems=getattr(mapped, "dems", None),
                        software=software, table=getattr(mapped, "band_table", None))


def band_order(available: Iterable[int], order: Sequence[int] | None) -> list[int]:
    """``order`` without repeats (every band of it must be ``available``), or the available
    bands ascending."""
    have = sorted(int(b) for b in available)
    if order is None:
        return have
    wanted = list(dict.fromkeys(int(b) for b in order))
    missing = [b for b in wanted if b not in have]
    if missing or not wanted:
        raise OptionsError(f"bands {wanted} to write, the result has {have}")
    return wanted


def _streamed(mapped: Mapped, bands: list[int], counts: bool,
              progress: ProgressCallback | None) -> Iterator[np.ndarray]:
    """One band at a time (uint16 counts or float32 radiances), sampled ``GATHER_GROUP`` at a
    time; progress after the antecedent rows (``orthorectify``'s own steps) and each band."""
    nr = mapped.grid.height
    for g in range(0, len(bands), GATHER_GROUP):
        group = bands[g:g + GATHER_GROUP]
        if counts:
            values = list(mapped.counts(group))  # type: ignore[attr-defined]
        else:
            radiance = mapped.radiance(group)
            values = [radiance[b] for b in group]
        for k, v in enumerate(values):
            yield v
            if progress is not None:
                progress(nr + g + k + 1, nr + len(bands))

"""A mapped product as a file: ``describe_map``, the one description of a mapped product's
bands, and ``write_map``, the one writer of mapped bands.

``meris-ortho map``, the napari widget and the synthesis export all write through
``write_map``: a Cloud-Optimized GeoTIFF (``output.geotiff.write_cog``) with one band per MERIS
band, streamed one band at a time; uint16 counts with GDAL scale = sf_rad (GDAL, QGIS and
rasterio read radiances) or float32 radiances; overviews averaged with nodata 0 ignored
(``engine.resample.overview_level``); optionally the diagnostics as ``OUT_diagnostics.tif``.
What the file says of its bands and of the run (band order, wavelengths, units, scale/offset,
nodata, options, DEMs with their vertical datums, software version) is a ``MapDescription``:
the GeoTIFF tags, the ``--stats-json`` file and the xarray attributes are all written from it.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ..engine.resample import overview_level
from ..errors import OptionsError
from ..geometry.grid import OutputGrid
from ..output.geotiff import COMPRESSIONS, meris_band_description, write_cog
from ..progress import ProgressCallback
from .antecedents import GATHER_GROUP, RADIANCE_UNITS
from .stats import RunStats

#: dataset tag explaining the band values and the per-band ``sf_rad`` tags
RADIANCE_NOTE = {
    "uint16": "TOA radiance = counts x scale (GDAL scale = sf_rad of the source product, "
              "Scaling Factor GADS); counts 0 = background (nodata)",
    "float32": "TOA radiance (float32, 0 = background) = counts x sf_rad of the source "
               "product (Scaling Factor GADS); no further scaling applies",
}
DTYPES = tuple(RADIANCE_NOTE)
#: the diagnostics layers of ``OUT_diagnostics.tif``, in band order
DIAGNOSTICS = ("line", "col", "elevation", "elevation_source", "iterations", "shift_east_m",
               "shift_north_m")


#: the background of radiance bands, in both types
NODATA = 0


def software_version() -> str:
    """The version of this software (``napari_meris_ortho.__version__``)."""
    from .. import __version__

    return __version__


@dataclass(frozen=True)
class BandFacts:
    """One band of a mapped product as written: MERIS band number, description, central
    wavelength and bandwidth (nm), unit, GDAL scale/offset (uint16 counts; None for float32
    radiances) and the source's counts-to-radiance factor ``sf_rad`` (Scaling Factor GADS)."""

    band: int
    wavelength_nm: float | None
    bandwidth_nm: float | None
    units: str
    scale: float | None
    offset: float | None
    sf_rad: float | None

    @property
    def description(self) -> str:
        return meris_band_description(self.band, self.wavelength_nm)

    def tags(self) -> dict[str, Any]:
        """The band's GDAL metadata tags."""
        out: dict[str, Any] = {"meris_band": self.band, "units": self.units}
        for key in ("wavelength_nm", "bandwidth_nm", "sf_rad"):
            value = getattr(self, key)
            if value is not None:
                out[key] = value
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"band": self.band, "description": self.description,
                "wavelength_nm": self.wavelength_nm, "bandwidth_nm": self.bandwidth_nm,
                "units": self.units, "scale": self.scale, "offset": self.offset,
                "sf_rad": self.sf_rad}


@dataclass(frozen=True)
class MapDescription:
    """What a mapped product's file says: its bands in file order (``BandFacts``), the band
    type, nodata and how values become radiances, the run (product, options), the DEMs used
    (path, name, vertical datum) and the software that wrote it with its version."""

    dtype: str
    bands: tuple[BandFacts, ...]
    run: Mapping[str, Any] = field(default_factory=dict)
    dems: tuple[Mapping[str, str], ...] = ()
    software: str = "napari-meris-ortho"
    version: str = field(default_factory=software_version)
    nodata: float = NODATA

    @property
    def band_numbers(self) -> list[int]:
        return [b.band for b in self.bands]

    @property
    def values(self) -> str:
        return RADIANCE_NOTE[self.dtype]

    def tags(self) -> dict[str, str]:
        """The dataset tags of the GeoTIFF (also the xarray attributes)."""
        out = {"radiance": self.values, **{k: str(v) for k, v in self.run.items()},
               "bands": ",".join(str(b) for b in self.band_numbers),
               "dems": dems_text(self.dems), "software": self.software,
               "software_version": self.version}
        return out

    def to_dict(self) -> dict[str, Any]:
        """The description as plain values (``--stats-json``'s ``output``)."""
        return {"bands": self.band_numbers, "band_facts": [b.to_dict() for b in self.bands],
                "dtype": self.dtype, "nodata": self.nodata, "radiance": self.values,
                **dict(self.run), "dems": [dict(d) for d in self.dems],
                "software": self.software, "software_version": self.version}


def dems_text(dems: Sequence[Mapping[str, str]]) -> str:
    """The DEMs of a run in one tag: "dem.tif (egm96); getasse30 (ellipsoid)", or "none"."""
    if not dems:
        return "none"
    return "; ".join(f"{d['name']} ({d.get('datum') or 'unknown datum'})" for d in dems)


def dem_facts(stats: RunStats) -> tuple[dict[str, str], ...]:
    """The DEMs of a mapping run (``dem_list``); none unless its elevation source is DEMs."""
    if stats.elevation != "dem":
        return ()
    return dem_list(stats.dems, stats.dem_datums)


def dem_list(entries: Sequence[str], datums: Sequence[str | None]
             ) -> tuple[dict[str, str], ...]:
    """DEM entries (``PATH[:DATUM]``) in the order tried: path, file name and vertical datum
    of the heights as read ("ellipsoid", "egm96", "egm2008"; "mixed" for tiles of several)."""
    from ..dem.geoid import split_datum

    out = []
    for k, entry in enumerate(entries):
        path = split_datum(entry)[0]
        datum = datums[k] if k < len(datums) else None
        out.append({"path": path, "name": Path(path.rstrip("/\\")).name or path,
                    "datum": datum or "mixed"})
    return tuple(out)


def options_tags(opts: Any) -> dict[str, Any]:
    """The options of a run (``OrthoOptions``) as the file's tags name them."""
    return {"elevation": opts.elevation.value, "parallax": opts.parallax.value,
            "geolocation": opts.geolocation.value, "tolerance_px": opts.tolerance,
            "sampling": opts.sampling.value, "search": opts.method.value}


def describe_map(stats: RunStats | None, bands: Sequence[int], dtype: str = "uint16", *,
                 scales: Mapping[int, float] | None = None,
                 run: Mapping[str, Any] | None = None,
                 dems: Sequence[Mapping[str, str]] | None = None,
                 software: str = "napari-meris-ortho") -> MapDescription:
    """The ``MapDescription`` of ``bands`` (file order) written as ``dtype``: wavelengths,
    bandwidths and ``sf_rad`` from the run's ``stats`` (the product's own), else the
    *MERIS Product Handbook*'s nominal Appendix A values and ``scales``; the run's options and
    DEMs from ``stats`` unless ``run``/``dems`` are given (a synthesis's)."""
    from ..products.n1.format import APPENDIX_A_BANDWIDTHS, APPENDIX_A_WAVELENGTHS

    if dtype not in DTYPES:
        raise OptionsError(f"unknown output type {dtype!r}: choose {', '.join(DTYPES)}")
    if stats is not None:
        wl, bw, sf = stats.wavelengths, stats.bandwidths, stats.scale_factors
    else:
        wl = {b: APPENDIX_A_WAVELENGTHS[b - 1] for b in bands}
        bw = {b: APPENDIX_A_BANDWIDTHS[b - 1] for b in bands}
        sf = dict(scales or {})
    counts = dtype == "uint16"
    facts = tuple(BandFacts(int(b), wl.get(b), bw.get(b), RADIANCE_UNITS,
                            sf.get(b) if counts else None, 0.0 if counts else None, sf.get(b))
                  for b in bands)
    if run is None:
        run = {} if stats is None else run_options(stats)
    if dems is None:
        dems = () if stats is None else dem_facts(stats)
    return MapDescription(dtype, facts, dict(run), tuple(dict(d) for d in dems), software)


def run_options(stats: RunStats) -> dict[str, Any]:
    """The product and the options of a mapping run, as the file's tags name them."""
    return {"product": stats.product, "product_name": stats.product_name,
            "elevation": stats.elevation, "parallax": stats.parallax,
            "geolocation": stats.geolocation, "tolerance_px": stats.tolerance,
            "sampling": stats.sampling, "search": stats.method}


def stats_document(stats: RunStats, description: MapDescription) -> dict[str, Any]:
    """The ``--stats-json`` file: the run's statistics with the bands and the per-band values
    in file order, and the file's description under ``output``."""
    out = stats.to_dict()
    order = description.band_numbers
    out["bands"] = order
    for key in ("wavelengths", "bandwidths", "scale_factors"):
        values = getattr(stats, key)
        out[key] = {b: values[b] for b in order if b in values}
    out["output"] = description.to_dict()
    return out


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
                  dems: Sequence[str | os.PathLike[str]] = ()) -> None:
    """Before any work: every output (name -> path, None: not requested) distinct from the
    others, never an input product or a DEM of the list (``PATH[:DATUM]``), never a special
    file, in a writable directory; OutputError naming the output otherwise. The one output
    check of the CLI and the widget."""
    from .._atomic import check_distinct, check_writable_dir
    from ..dem.geoid import split_datum

    check_distinct(dict(outputs), {"input product": list(products),
                                   "DEM": [split_datum(d)[0] for d in dems]})
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
    if dtype not in DTYPES:
        raise OptionsError(f"unknown output type {dtype!r}: choose {', '.join(DTYPES)}")
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
        arrays = (np.nan_to_num(mapped.diagnostics[n].astype(np.float32), nan=0.0)
                  for n in DIAGNOSTICS)
        write_cog(diagnostics_path(path), arrays, mapped.grid, count=len(DIAGNOSTICS),
                  nodata=None, descriptions=list(DIAGNOSTICS), dtype="float32",
                  compress=compress, overview_resampling="nearest", halve=overview_level,
                  metadata={"elevation_source": "k >= 0: DEM k; -1: tie points; -2: none"})
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
                        software=software)


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

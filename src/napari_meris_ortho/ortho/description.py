"""The one description of a mapped product's bands: ``describe_map`` -> ``MapDescription``.

Band order as in the file, central wavelengths and bandwidths, units, GDAL scale/offset,
nodata, how values become radiances, the run's product and options, the DEMs used with the
vertical datum of their heights, and the software with its version. ``ortho.writing.write_map``
writes it as GeoTIFF tags, ``meris-ortho map --stats-json`` under ``output``, ``to_xarray`` as
attributes; ``synthesis.export`` describes a store's bands with it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..bands import BandTable
from ..errors import OptionsError
from ..output.geotiff import meris_band_description
from .stats import RunStats

#: unit of the radiances of the output bands (counts x sf_rad, Scaling Factor GADS)
RADIANCE_UNITS = "W m-2 sr-1 um-1"
#: dataset tag explaining the band values and the per-band ``sf_rad`` tags
RADIANCE_NOTE = {
    "uint16": "TOA radiance = counts x scale (GDAL scale = sf_rad of the source product, "
              "Scaling Factor GADS); counts 0 = background (nodata)",
    "float32": "TOA radiance (float32, 0 = background) = counts x sf_rad of the source "
               "product (Scaling Factor GADS); no further scaling applies",
}
DTYPES = tuple(RADIANCE_NOTE)
#: the background of radiance bands, in both types
NODATA = 0


def check_dtype(dtype: str) -> None:
    """OptionsError unless ``dtype`` is an output type of mapped bands (``DTYPES``)."""
    if dtype not in DTYPES:
        raise OptionsError(f"unknown output type {dtype!r}: choose {', '.join(DTYPES)}")


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
    #: the band's name when it is no MERIS band (``Oa08``: an OLCI store's export)
    name: str | None = None

    @property
    def description(self) -> str:
        if self.name is not None:
            where = "" if self.wavelength_nm is None else f" ({self.wavelength_nm:.1f} nm)"
            return f"{self.name}{where}"
        return meris_band_description(self.band, self.wavelength_nm)

    def tags(self) -> dict[str, Any]:
        """The band's GDAL metadata tags (``meris_band``, or ``band_name`` and ``band`` for
        bands of another sensor)."""
        out: dict[str, Any] = ({"meris_band": self.band} if self.name is None
                               else {"band_name": self.name, "band": self.band})
        out["units"] = self.units
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
        return {"radiance": self.values, **{k: str(v) for k, v in self.run.items()},
               "bands": ",".join(str(b) for b in self.band_numbers),
               "dems": dems_text(self.dems), "software": self.software,
               "software_version": self.version}

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


#: the options of a run as the file's tags name them: (tag, attribute of ``OrthoOptions`` and
#: of ``RunStats``)
OPTION_TAGS = (("elevation", "elevation"), ("parallax", "parallax"),
               ("geolocation", "geolocation"), ("tolerance_px", "tolerance"),
               ("sampling", "sampling"), ("search", "method"), ("hidden", "hidden"))


def options_tags(source: Any) -> dict[str, Any]:
    """The options of a run (``OrthoOptions``, its enums as their values, or ``RunStats``) as
    the file's tags name them."""
    values = {tag: getattr(source, attr) for tag, attr in OPTION_TAGS}
    return {tag: getattr(v, "value", v) for tag, v in values.items()}


def describe_map(stats: RunStats | None, bands: Sequence[int], dtype: str = "uint16", *,
                 scales: Mapping[int, float] | None = None,
                 run: Mapping[str, Any] | None = None,
                 dems: Sequence[Mapping[str, str]] | None = None,
                 software: str = "napari-meris-ortho",
                 table: BandTable | None = None) -> MapDescription:
    """The ``MapDescription`` of ``bands`` (file order) written as ``dtype``: wavelengths,
    bandwidths and ``sf_rad`` from the run's ``stats`` (the product's own), else the
    nominal values of ``table`` (default MERIS: Appendix A's) and ``scales``; bands of a
    ``table`` other than MERIS's named (``Oa08``); the run's options and DEMs from ``stats``
    unless ``run``/``dems`` are given (a synthesis's)."""
    from ..bands import MERIS, Sensor

    check_dtype(dtype)
    table = table or MERIS
    if stats is not None:
        wl, bw, sf = stats.wavelengths, stats.bandwidths, stats.scale_factors
    else:
        wl = {b: table.centres[b - 1] for b in bands}
        bw = {b: table.widths[b - 1] for b in bands}
        sf = dict(scales or {})
    counts = dtype == "uint16"
    named = table.sensor is not Sensor.MERIS
    facts = tuple(BandFacts(int(b), wl.get(b), bw.get(b), RADIANCE_UNITS,
                            sf.get(b) if counts else None, 0.0 if counts else None, sf.get(b),
                            table.name(int(b)) if named else None)
                  for b in bands)
    if run is None:
        run = {} if stats is None else run_options(stats)
    if dems is None:
        dems = () if stats is None else dem_facts(stats)
    return MapDescription(dtype, facts, dict(run), tuple(dict(d) for d in dems), software)


def run_options(stats: RunStats) -> dict[str, Any]:
    """The product and the options of a mapping run, as the file's tags name them."""
    out = {"product": stats.product, "product_name": stats.product_name, **options_tags(stats)}
    if stats.hidden_points is not None:  # DEMs marched: points hidden by the relief
        out["hidden_points"] = stats.hidden_points
    return out


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

"""The band set of a synthesis store, and how each product's bands feed it.

A store holds the bands of one sensor, its *band set*: MERIS bands ``M01``..``M15`` or OLCI
bands ``Oa01``..``Oa21``. A new store takes OLCI bands when every product merged is OLCI,
MERIS bands otherwise (or the band set asked for). MERIS products feed a MERIS store band for
band; OLCI products feed a MERIS store through ``bands.MERIS_TO_OLCI`` (their band of the same
centre and width; M11 takes Oa13, the nearest band: ``bands.APPROXIMATE_MATCHES``), and an
OLCI store band for band. A MERIS product cannot feed an OLCI store: Oa01, Oa09, Oa14, Oa15,
Oa20 and Oa21 have no MERIS band.

The store records its band set in its root attributes: ``sensor`` "OLCI" for an OLCI store
(no ``sensor``: MERIS bands, as every store made before OLCI products were read), and, once an
OLCI product is merged into a MERIS store, ``olci_bands`` (the Oa band feeding each of its
bands) and ``approximate_bands``. The product table names the sensor of each non-MERIS
product (``sensor``; none: MERIS). A store of MERIS products only is written as before.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ..bands import (
    APPROXIMATE_MATCHES,
    MERIS,
    MERIS_TO_OLCI,
    OLCI,
    BandTable,
    Sensor,
    band_table,
    olci_band_of_meris,
)
from ..errors import OptionsError

#: the root attribute naming the band set (absent: MERIS)
SENSOR_KEY = "sensor"
#: the root attributes of a MERIS store that holds OLCI products
OLCI_BANDS_KEY = "olci_bands"
APPROXIMATE_KEY = "approximate_bands"
#: what the store says of an approximate match
APPROXIMATE_NOTE = ("OLCI products contribute to each MERIS band their band of the same centre "
                    "and width; {pairs}: the nearest OLCI band, not the same band")


def store_sensor(attrs: Mapping[str, Any]) -> Sensor:
    """The band set of a store from its root attributes (no ``sensor``: MERIS)."""
    return Sensor(str(attrs.get(SENSOR_KEY, Sensor.MERIS.value)))


def product_sensor(entry: Mapping[str, Any]) -> Sensor:
    """The sensor of a product table entry (no ``sensor``: MERIS)."""
    return Sensor(str(entry.get(SENSOR_KEY, Sensor.MERIS.value)))


def band_set_of(sensors: Iterable[Sensor], asked: Sensor | str | None = None) -> Sensor:
    """The band set of a new store: ``asked`` if given, else OLCI when every product is OLCI,
    else MERIS."""
    if asked is not None:
        return Sensor(str(asked).upper())
    found = set(sensors)
    return Sensor.OLCI if found and found == {Sensor.OLCI} else Sensor.MERIS


def parse_band_set(value: Sensor | str | None) -> Sensor | None:
    """``value`` as a band set ("MERIS", "OLCI", any case), None kept; OptionsError else."""
    if value is None:
        return None
    try:
        return Sensor(str(value).upper())
    except ValueError:
        raise OptionsError(f"band set {value!r}: choose MERIS or OLCI") from None


def refusal(band_set: Sensor, path: object) -> str:
    """The message of a MERIS product given to an OLCI store."""
    lone = ", ".join(OLCI.name(b) for b in range(1, OLCI.n_bands + 1)
                     if b not in MERIS_TO_OLCI)
    return (f"{path}: a MERIS product cannot join a synthesis of {band_set.value} bands "
            f"(Oa01..Oa21; {lone} have no MERIS band): synthesize MERIS and OLCI products "
            "into a store of MERIS bands (band set MERIS)")


@dataclass(frozen=True)
class BandPlan:
    """The bands of one product for a store: ``sources[k]`` is the product band feeding store
    band ``bands[k]``; ``ndvi`` the product's red and near-infrared bands (665, 865 nm)."""

    sensor: Sensor
    bands: tuple[int, ...]
    sources: tuple[int, ...]
    ndvi: tuple[int, int]

    def needed(self, with_ndvi: bool) -> tuple[int, ...]:
        """The product bands sampled: the sources, and the NDVI bands if ``with_ndvi``."""
        return tuple(sorted(set(self.sources) | (set(self.ndvi) if with_ndvi else set())))

    def source(self, band: int) -> int:
        """The product band feeding store band ``band``."""
        return self.sources[self.bands.index(band)]


def band_plan(band_set: Sensor | str, sensor: Sensor | str, bands: Sequence[int]) -> BandPlan:
    """How a product of ``sensor`` feeds store ``bands`` of ``band_set`` (module docstring);
    OptionsError for a MERIS product and an OLCI store."""
    band_set, sensor = Sensor(band_set), Sensor(sensor)
    table = band_table(sensor)
    if band_set is sensor:
        sources = tuple(int(b) for b in bands)
    elif band_set is Sensor.MERIS and sensor is Sensor.OLCI:
        sources = tuple(olci_band_of_meris(int(b)) for b in bands)
    else:
        raise OptionsError(refusal(band_set, "the product"))
    return BandPlan(sensor, tuple(int(b) for b in bands), sources, table.ndvi)


def band_names(band_set: Sensor | str, bands: Sequence[int]) -> list[str]:
    """``M07``, ``Oa08``: the names of store ``bands``."""
    table = band_table(band_set)
    return [table.name(int(b)) for b in bands]


def matching_attributes(bands: Sequence[int]) -> dict[str, Any]:
    """What a MERIS store holding OLCI products says of its bands: the Oa band feeding each
    of them (``olci_bands``) and the approximate matches (``approximate_bands``, with a
    note)."""
    pairs = {MERIS.name(b): OLCI.name(olci_band_of_meris(b)) for b in bands}
    approximate = [MERIS.name(b) for b in bands if b in APPROXIMATE_MATCHES]
    out: dict[str, Any] = {OLCI_BANDS_KEY: pairs, APPROXIMATE_KEY: approximate}
    if approximate:
        out["band_matching"] = APPROXIMATE_NOTE.format(pairs=", ".join(
            f"{m} ~ {pairs[m]} ({_facts(MERIS, m)} for {_facts(OLCI, pairs[m])})"
            for m in approximate))
    return out


def _facts(table: BandTable, name: str) -> str:
    """``761.6/3.7 nm``: centre and width of the band ``name`` of ``table``."""
    k = table.names.index(name)
    return f"{table.centres[k]:g}/{table.widths[k]:g} nm"


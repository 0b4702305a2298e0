"""The sensors the package reads and their spectral bands: one definition of each band table,
band name, the MERIS <-> OLCI band matching, the true-colour bands and the NDVI bands.

Bands are numbered 1..n per sensor, as the products number them (MERIS 1..15, ``M01``..``M15``;
OLCI 1..21, ``Oa01``..``Oa21``). MERIS centres and widths are those of the Scaling Factor
GADS printed in Appendix A of the *MERIS Geometry Handbook* (the N1 products' own values);
OLCI's are the nominal ones of the *Sentinel-3 OLCI User Guide*. Imports nothing of the
package.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum


class Sensor(StrEnum):
    """The instrument a Level 1 product comes from."""

    MERIS = "MERIS"
    OLCI = "OLCI"


@dataclass(frozen=True)
class BandTable:
    """The bands of one sensor: names, centre wavelengths and widths (nm), band ``b`` at
    index ``b - 1``; the bands of a true-colour composite (red, green, blue) and of the NDVI
    (red, near infrared), as band numbers."""

    sensor: Sensor
    names: tuple[str, ...]
    centres: tuple[float, ...]
    widths: tuple[float, ...]
    true_colour: tuple[int, int, int]
    ndvi: tuple[int, int]

    @property
    def n_bands(self) -> int:
        return len(self.names)

    def name(self, band: int) -> str:
        """``M07``, ``Oa08``: the name of band ``band`` (1..n_bands)."""
        if not 1 <= band <= self.n_bands:
            raise ValueError(f"{self.sensor} band must be 1..{self.n_bands}, got {band}")
        return self.names[band - 1]


#: MERIS: Appendix A's centre wavelengths and bandwidths (nm) of bands 1..15
MERIS = BandTable(
    sensor=Sensor.MERIS,
    names=tuple(f"M{b:02d}" for b in range(1, 16)),
    centres=(412.545, 442.401, 489.744, 509.700, 559.634, 619.620, 664.640, 680.902,
             708.426, 753.472, 761.606, 778.498, 864.833, 884.849, 899.860),
    widths=(9.930, 9.946, 9.965, 9.971, 9.983, 9.991, 9.994, 7.493,
            9.996, 7.493, 3.742, 15.000, 19.999, 9.990, 9.989),
    true_colour=(7, 5, 2),  # 665, 560, 442 nm
    ndvi=(7, 13),  # 665, 865 nm (handbook section 3.1)
)  # fmt: skip

#: OLCI: nominal centre wavelengths and widths (nm) of Oa01..Oa21
OLCI = BandTable(
    sensor=Sensor.OLCI,
    names=tuple(f"Oa{b:02d}" for b in range(1, 22)),
    centres=(400.0, 412.5, 442.5, 490.0, 510.0, 560.0, 620.0, 665.0, 673.75, 681.25,
             708.75, 753.75, 761.25, 764.375, 767.5, 778.75, 865.0, 885.0, 900.0, 940.0,
             1020.0),
    widths=(15.0, 10.0, 10.0, 10.0, 10.0, 10.0, 10.0, 10.0, 7.5, 7.5,
            10.0, 7.5, 2.5, 3.75, 2.5, 15.0, 20.0, 10.0, 10.0, 20.0,
            40.0),
    true_colour=(8, 6, 3),  # Oa08 665, Oa06 560, Oa03 442.5 nm
    ndvi=(8, 17),  # Oa08 665, Oa17 865 nm
)  # fmt: skip

BAND_TABLES: dict[Sensor, BandTable] = {Sensor.MERIS: MERIS, Sensor.OLCI: OLCI}
#: the most bands a product of any sensor has (OLCI's 21)
MAX_BANDS = max(t.n_bands for t in BAND_TABLES.values())

#: MERIS band b -> the OLCI band of the same centre and width (index b - 1): M01..M07 =
#: Oa02..Oa08, M08 = Oa10, M09 = Oa11, M10 = Oa12, M11 ~ Oa13 (761.25/2.5 for MERIS's
#: 760.625/3.75: the nearest, not the same), M12 = Oa16, M13 = Oa17, M14 = Oa18, M15 = Oa19
MERIS_TO_OLCI: tuple[int, ...] = (2, 3, 4, 5, 6, 7, 8, 10, 11, 12, 13, 16, 17, 18, 19)
#: the MERIS bands whose OLCI match is the nearest band, not the same band
APPROXIMATE_MATCHES: frozenset[int] = frozenset({11})


def band_table(sensor: Sensor | str) -> BandTable:
    """The band table of ``sensor`` ("MERIS" or "OLCI")."""
    return BAND_TABLES[Sensor(sensor)]


def olci_band_of_meris(band: int) -> int:
    """The OLCI band matching MERIS band ``band`` (1..15) (:data:`MERIS_TO_OLCI`)."""
    MERIS.name(band)
    return MERIS_TO_OLCI[band - 1]


def meris_band_of_olci(band: int) -> int | None:
    """The MERIS band OLCI band ``band`` (1..21) matches, or None (Oa01, Oa09, Oa14, Oa15,
    Oa20, Oa21 have none)."""
    OLCI.name(band)
    return MERIS_TO_OLCI.index(band) + 1 if band in MERIS_TO_OLCI else None

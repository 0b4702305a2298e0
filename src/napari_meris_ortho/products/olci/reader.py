"""Read a Sentinel-3 OLCI Level 1B product (``OL_1_EFR___``/``OL_1_ERR___``; directory or zip
archive) into the product contract (``products.protocol.MerisProduct``).

The SAFE machinery is the MERIS ``.SEN3`` reader's (``sen3.reader.read_members`` with the OLCI
facts of ``layout``): every variable decoded from its own CF attributes, fill values masked (a
band's ``no_data_count`` 65535), columns mirrored into the N1 order, per-pixel geolocation, tie
points from ``tie_geo_coordinates.nc`` and ``tie_geometries.nc`` (and ``tie_meteo.nc``). What
OLCI adds:

- 21 bands ``Oa01``..``Oa21``; tie points on every row and every 64 (EFR) or 16 (ERR) columns;
- tie-point heights: the tie files carry none, so ``dem_alt`` is the product's own per-pixel
  ``altitude`` at the tie points (tie column k is image column k x 64 or k x 16);
- the tie points moved half a pixel onto the pixel centres (``layout.TIE_COLUMN_SHIFT``), so
  tie point (i, k) is pixel (i, k x DJ) of the N1 order, as for MERIS;
- ``quality_flags`` of either baseline (``layout.FlagBaseline``): the L1b flags (invalid, land,
  coastline, bright, ...) as for MERIS; ``saturated``: uint32 bits, bit b-1 for band b, from
  ``saturated_OaNN`` (before baseline 2.24; since then saturated samples are the band's fill
  value and the bits are 0).
"""

from __future__ import annotations

import os
from functools import cached_property

import numpy as np

from ...bands import OLCI, Sensor
from ...errors import OlciFormatError, Sen3FormatError
from ..n1.format import Resolution
from ..sen3.layout import flag_coding
from ..sen3.members import Members
from ..sen3.reader import MerisSen3Product, Sen3Kind, read_members
from .layout import (
    N_BANDS,
    OLCI_TYPES,
    FlagBaseline,
    baseline_of,
    flag_table,
    foreign_type_of,
    product_type_of,
    radiance_file,
    radiance_variable,
    required_files,
    tie_points_on_pixels,
)

#: tie-point values read at the pixel centres already (the pixels' own altitude) or derived
_NOT_SHIFTED = frozenset({"dem_alt", "dem_rough"})


class OlciL1bProduct(MerisSen3Product):
    """An opened OLCI Level 1B product; build with :func:`read_olci`. The interface of
    ``sen3.MerisSen3Product`` with 21 bands (``Oa01``..``Oa21``), ``baseline`` (the flag
    coding) and ``saturated`` as uint32 bits."""

    sensor = Sensor.OLCI
    n_bands = OLCI.n_bands
    band_names = OLCI.names

    def __repr__(self) -> str:
        return f"<OlciL1bProduct {self.product_type} {self.width}x{self.height} ({self.path})>"

    @cached_property
    def quality_coding(self) -> dict[str, int]:
        """meaning -> mask of ``quality_flags``, from the file's ``flag_masks`` and
        ``flag_meanings`` (the per-band baseline's table when it has none)."""
        attrs = self.variables["quality_flags"]
        if attrs.get("flag_masks") is None or attrs.get("flag_meanings") is None:
            return flag_table(FlagBaseline.PER_BAND)
        return flag_coding(attrs)

    @property
    def baseline(self) -> FlagBaseline:
        """The flag coding of the product (``saturated_OaNN`` per band, or since 2.24)."""
        return baseline_of(self.quality_coding)

    @cached_property
    def saturated(self) -> np.ndarray:
        """uint32 (H, W): bit b-1 set where band b is saturated (``saturated_OaNN``); all 0
        for the 2.24 baseline, whose saturated samples are the bands' fill values."""
        from ..sen3.layout import _translate

        coding = self.quality_coding
        pairs = [(coding.get(f"saturated_Oa{b:02d}", 0), 1 << (b - 1))
                 for b in range(1, N_BANDS + 1)]
        return _translate(self.quality_flags, [p for p in pairs if p[0]], np.uint32)

    def esa_columns(self, a: np.ndarray) -> np.ndarray:
        """An image of this product (rows, columns[, ...]) in ESA's column order (the file's:
        ESA pixel x is N1 column width - 1 - x), e.g. to compare with SNAP's pixel (x, y)."""
        return np.ascontiguousarray(np.asarray(a)[:, ::-1]) if self.mirrored else np.asarray(a)


def _adjust(tie_points: dict[str, np.ndarray], dj: int, mirrored: bool
            ) -> dict[str, np.ndarray]:
    """ESA's tie points moved onto the pixel centres (``layout.tie_points_on_pixels``), all
    but those read at the pixels already (``dem_alt``); the N1 order when ``mirrored``. The
    DEM corrections are derived after (``sen3.reader``)."""
    moved = tie_points_on_pixels({k: v for k, v in tie_points.items()
                                  if k not in _NOT_SHIFTED}, dj, n1_order=mirrored)
    return {**tie_points, **moved}


def _olci_widest(res: Resolution) -> int:
    return res.width


#: OLCI Level 1B products
OLCI_KIND = Sen3Kind(
    name="OLCI", n_bands=N_BANDS, band_file=radiance_file, band_variable=radiance_variable,
    types=OLCI_TYPES, widest=_olci_widest, wavelengths=OLCI.centres, bandwidths=OLCI.widths,
    sun_flux=(float("nan"),) * N_BANDS, product_class=OlciL1bProduct, detectors=None,
    tie_altitude=False, adjust_tie_points=_adjust)
OlciL1bProduct.kind = OLCI_KIND


def sentinel3_type(members: Members) -> str | None:
    """The Sentinel-3 product type of a SAFE product: its manifest's ``productType`` (the
    product name when it has none), or None when neither names one."""
    try:
        root = members.manifest()
    except Sen3FormatError:
        root = None
    if root is not None:
        for el in root.iter():
            if el.tag.rsplit("}", 1)[-1] == "productType" and el.text:
                return el.text.strip()
    name = members.path.name if members.prefix is None else members.prefix
    return name if (product_type_of(name) or foreign_type_of(name)) else None


def read_olci(path: str | os.PathLike[str]) -> OlciL1bProduct:
    """Open an OLCI Level 1B product: a ``.SEN3`` directory (or its ``xfdumanifest.xml``) or a
    zip archive of one. Its type from the manifest's ``productType`` (else the name); every
    member checked (``sen3.reader.read_members``).
    :class:`~napari_meris_ortho.errors.OlciFormatError` for a Sentinel-3 product of another
    kind (OLCI Level 2, SYNERGY, SLSTR...),
    :class:`~napari_meris_ortho.errors.Sen3FormatError` for a missing, truncated or damaged
    member."""
    members = Members(path)
    found = sentinel3_type(members) or ""
    product_type = product_type_of(found)
    if product_type is None:
        foreign = foreign_type_of(found) or foreign_type_of(members.path.name)
        what = foreign or f"product type {found!r}" if found else "no product type"
        raise OlciFormatError(members.path, f"{what}: not an OLCI Level 1B product "
                              "(OL_1_EFR___ or OL_1_ERR___)")
    missing = [f for f in required_files() if not members.exists(f)]
    if missing:
        raise OlciFormatError(members.path, f"missing member file(s): {', '.join(missing)}")
    try:
        product: OlciL1bProduct = read_members(members, OLCI_KIND, product_type)
    except OSError as exc:
        raise Sen3FormatError(members.path, f"cannot read: {exc.strerror or exc}") from None
    return product

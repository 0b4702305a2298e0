"""What every Level 1 product offers, whatever its sensor and format (the contract of
``read_product``): a MERIS N1 file (``n1.MerisL1bProduct``) or ``.SEN3`` directory
(``sen3.MerisSen3Product``), an OLCI Level 1B ``.SEN3`` (``olci.OlciL1bProduct``).

``sensor`` (``bands.Sensor``), ``n_bands`` (MERIS 15, OLCI 21) and ``band_names`` (``M01``..,
``Oa01``..) say whose bands they are; bands are numbered 1..``n_bands``.
Arrays are in the stored column order (ARCHITECTURE.md "Conventions"); tie points in physical
units (``geometry.tiepoints.TiePoints``); ``counts(b)`` are the stored uint16 values of band b
(1..n_bands), radiance = counts x ``scaling.radiance[b - 1]`` (Scaling Factor GADS, Appendix A;
a ``.SEN3``'s ``scale_factor``: one per band),
except where they equal ``no_data_count(b)`` (no data, kept out of every resampling);
``mph``/``sph``: the N1 header records (Appendix A), or their fields a ``.SEN3`` carries.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from ..bands import Sensor
from ..geometry.tiepoints import ProductGeometry, TiePoints
from .n1.format import Resolution, ScalingFactors


def radiance_of_counts(counts: np.ndarray, scale: float, no_data: int | None) -> np.ndarray:
    """Radiance of stored counts as defined above: counts x ``scale`` (float32), NaN where the
    counts equal ``no_data`` (None: none). Any shape, a 0-d selection included."""
    out = np.asarray(counts).astype(np.float32)
    out *= np.float32(scale)
    if no_data is not None:
        out[np.asarray(counts) == no_data] = np.nan
    return out


@runtime_checkable
class MerisProduct(ProductGeometry, Protocol):
    """A Level 1 product as the mapping, the synthesis and the viewer read it."""

    @property
    def sensor(self) -> Sensor: ...
    @property
    def n_bands(self) -> int: ...
    @property
    def band_names(self) -> Sequence[str]: ...
    @property
    def path(self) -> Path: ...
    @property
    def product_type(self) -> str: ...
    @property
    def product_name(self) -> str: ...
    @property
    def resolution(self) -> Resolution: ...
    @property
    def tie_points(self) -> TiePoints: ...
    @property
    def scaling(self) -> ScalingFactors: ...
    @property
    def wavelengths(self) -> Sequence[float]: ...
    @property
    def bandwidths(self) -> Sequence[float]: ...
    @property
    def first_line_time(self) -> np.datetime64 | None: ...
    @property
    def line_times(self) -> np.ndarray: ...
    @property
    def tie_point_times(self) -> np.ndarray: ...
    @property
    def n_tie_lines(self) -> int: ...
    @property
    def n_tie_columns(self) -> int: ...
    @property
    def mph(self) -> Mapping[str, Any]: ...
    @property
    def sph(self) -> Mapping[str, Any]: ...
    @property
    def line_interval_s(self) -> float: ...
    @property
    def flags(self) -> np.ndarray: ...
    @property
    def has_pixel_geolocation(self) -> bool: ...
    @property
    def saturated(self) -> np.ndarray | None:
        """Per-band saturation bits (H, W), bit b-1: band b: uint16 for MERIS (15 bands),
        uint32 for OLCI (21 bands; all 0 in products of the single ``saturated`` flag, where
        saturated samples are the band's fill value), or None."""

    def no_data_count(self, band: int) -> int | None:
        """The value ``counts(band)`` holds at no-data pixels (a ``_FillValue``), or None."""

    def counts(self, band: int) -> np.ndarray: ...
    def radiance(self, band: int, lines: slice | None = None) -> np.ndarray: ...
    def pixel_longitude(self, lines: slice | None = None) -> np.ndarray: ...
    def pixel_latitude(self, lines: slice | None = None) -> np.ndarray: ...
    def pixel_altitude(self, lines: slice | None = None) -> np.ndarray: ...

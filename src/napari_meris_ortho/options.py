"""The modes of orthorectification and synthesis, one definition each (handbook sections 3.1-3.4).

Every mode is a ``StrEnum``: the API keeps accepting the plain strings ("dem", "bicubic", ...),
the CLI offers ``choices(Enum)`` and the napari widget lists the same values; the numba kernels get
the integer ``code`` at the boundary. ``OrthoOptions`` gathers the checked options of one
``orthorectify`` run. This module is a bottom room: it imports nothing of the package but
``errors``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import TypeVar

from .errors import OptionsError


class Elevation(StrEnum):
    """Heights of the output points (section 3.1 "Digital elevation data", MERSYN ``-ort``)."""

    NONE = "none"  # no orthorectification (MERSYN -ort NO)
    TIEPOINTS = "tiepoints"  # tie-point dem_alt at the antecedent
    DEM = "dem"  # the DEMs at the output point, tried in order, then the tie points


class Parallax(StrEnum):
    """Radii of the parallax (geodetic) correction (eq. 6a, 2c', 6b')."""

    HANDBOOK = "handbook"  # sphere R = 6 370 997 m (MERSYN, BEAM)
    ELLIPSOID = "ellipsoid"  # WGS84 meridian M and prime-vertical N radii
    ELLIPSOID_H = "ellipsoid_h"  # M + h and N + h (measurements only, not offered to users)

    @property
    def code(self) -> int:
        """Kernel code (``engine.location.parallax_factors``)."""
        return _PARALLAX_CODES[self]


class Geolocation(StrEnum):
    """Direct location model: the tie points (positions interpolated as eq. 4a-4b or as unit
    vectors, plus the parallax) or the product's own per-pixel terrain-corrected geolocation."""

    BILINEAR = "bilinear"  # latitude and longitude bilinearly (MERSYN, BEAM)
    ECEF = "ecef"  # the tie points' unit vectors bilinearly
    PIXEL = "pixel"  # per-pixel lon/lat of FRG/FSG N1 and .SEN3 products (engine.pixelgeo)

    @property
    def code(self) -> int:
        """Kernel code of the tie-point interpolation (0, 1); PIXEL is 2 and never reaches the
        tie-point kernels (``ortho`` hands such runs to ``engine.pixelgeo``)."""
        return {"bilinear": 0, "ecef": 1, "pixel": 2}[self.value]

    @classmethod
    def default_for(cls, parallax: Parallax) -> Geolocation:
        """Bilinear with the handbook parallax, ecef with the ellipsoid ones."""
        return cls.BILINEAR if parallax is Parallax.HANDBOOK else cls.ECEF


class SearchMethod(StrEnum):
    """How the prediction/correction finds the antecedents (section 3.2, ``engine.predcorr``)."""

    PRIMARY = "primary"  # primary grid of exact inverses + Newton steps (fast)
    HANDBOOK = "handbook"  # MERSYN's facet search inside the loop (reference)


class Sampling(StrEnum):
    """Resampling of the product at the antecedents (section 3.1 "Retrieve the antecedent")."""

    NEAREST = "nearest"  # MERSYN
    BILINEAR = "bilinear"  # 2 x 2 pixels
    BICUBIC = "bicubic"  # 4 x 4 pixels, Keys kernel a = -0.5

    @property
    def taps(self) -> int:
        """Pixels per axis the kernel reads (kernel code of ``engine.resample``)."""
        return {"nearest": 1, "bilinear": 2, "bicubic": 4}[self.value]

    @property
    def margin(self) -> tuple[int, int]:
        """Product lines the kernel reads before floor(l) and after it."""
        return (1, 2) if self is Sampling.BICUBIC else (0, 1)


class MergeRule(StrEnum):
    """Selection algorithm of a synthesis (section 3.1, MERSYN use cases 1 and 2)."""

    MIN_RADIANCE = "min-radiance"
    MAX_NDVI = "max-ndvi"


class StoreCodec(StrEnum):
    """Codec pipeline of a new synthesis store's full-resolution bands and NDVI: zstd alone
    (Zarr v3 core codecs: every Zarr reader) or a delta filter then zstd (``numcodecs.delta``:
    smaller, but not in the Zarr v3 specification; zarr-python reads it)."""

    ZSTD = "zstd"
    DELTA_ZSTD = "delta-zstd"


_PARALLAX_CODES = {Parallax.HANDBOOK: 0, Parallax.ELLIPSOID: 1, Parallax.ELLIPSOID_H: 2}
#: what users are offered (CLI ``--parallax``, widget)
PARALLAX_CHOICES = (Parallax.HANDBOOK, Parallax.ELLIPSOID)

E = TypeVar("E", bound=StrEnum)

_WHAT = {Elevation: "elevation source", Parallax: "parallax model",
         Geolocation: "geolocation interpolation", SearchMethod: "search method",
         Sampling: "sampling method", MergeRule: "algorithm", StoreCodec: "store codec"}


def choices(enum: Iterable[E]) -> list[str]:
    """The string values of an enum (CLI ``choices=``, widget combo boxes)."""
    return [str(m.value) for m in enum]


def parse(enum: type[E], value: object) -> E:
    """``enum(value)`` or an OptionsError naming the mode and its choices."""
    try:
        if isinstance(value, str):
            return enum(value)
    except ValueError:
        pass
    names = choices(enum)
    raise OptionsError(f"unknown {_WHAT.get(enum, enum.__name__)} {value!r}: choose "
                       f"{', '.join(names[:-1])} or {names[-1]}")


#: bands of a MERIS product (the default of ``n_bands``); an OLCI product has 21
MERIS_BAND_COUNT = 15


@dataclass(frozen=True)
class OrthoOptions:
    """The checked options of one ``orthorectify`` run (MERSYN checks parameters first, 3.1)."""

    elevation: Elevation = Elevation.DEM
    sampling: Sampling = Sampling.NEAREST
    parallax: Parallax = Parallax.HANDBOOK
    geolocation: Geolocation = Geolocation.BILINEAR
    method: SearchMethod = SearchMethod.PRIMARY
    tolerance: float = 0.01
    bands: tuple[int, ...] = tuple(range(1, MERIS_BAND_COUNT + 1))
    diagnostics: bool = False

    @classmethod
    def parse(cls, *, elevation: object = "dem", sampling: object = "nearest",
              parallax: object = "handbook", geolocation: object | None = None,
              method: object = "primary", tolerance: object = 0.01,
              bands: Sequence[int] | None = None, diagnostics: bool = False,
              n_dems: int = 0, n_bands: int = 15) -> OrthoOptions:
        """Options from user values; OptionsError on the first inconsistent one; ``n_bands``:
        the product's bands (15 MERIS, 21 OLCI; ``bands`` None: all of them)."""
        elev = parse(Elevation, elevation)
        if elev is not Elevation.DEM and n_dems > 0:
            raise OptionsError(
                f"DEMs given with elevation {elev.value!r}: DEMs are only used with elevation "
                "'dem'")
        if not (isinstance(tolerance, (int, float)) and math.isfinite(tolerance)
                and tolerance > 0):
            raise OptionsError(f"tolerance must be > 0 product pixels, got {tolerance!r}")
        par = parse(Parallax, parallax)
        geo = (Geolocation.default_for(par) if geolocation is None
               else parse(Geolocation, geolocation))
        return cls(elev, parse(Sampling, sampling), par, geo, parse(SearchMethod, method),
                   float(tolerance), check_bands(bands, n_bands), bool(diagnostics))

    @classmethod
    def of(cls, options: OrthoOptions | None = None, *, n_dems: int = 0, n_bands: int = 15,
           **values: object) -> OrthoOptions:
        """``options`` (default: the defaults) with ``values`` (the keywords of ``parse``)
        replacing its fields, all checked again with the number of DEMs and the product's
        bands: the one check of the options of ``orthorectify``, ``precompute``,
        ``synthesize``, the CLI and the widget. For a product of other than 15 bands (OLCI),
        options that hold the default band list (all 15) and no ``bands`` in ``values`` take
        all ``n_bands`` bands."""
        base = options.values() if options is not None else {}
        if n_bands != MERIS_BAND_COUNT and values.get("bands") is None \
                and base.get("bands", cls.bands) == cls.bands:
            base = {**base, "bands": None}
        return cls.parse(**{**base, **values}, n_dems=n_dems,  # type: ignore[arg-type]
                         n_bands=n_bands)

    def values(self) -> dict[str, object]:
        """The options as ``parse`` keywords."""
        return {"elevation": self.elevation, "sampling": self.sampling,
                "parallax": self.parallax, "geolocation": self.geolocation,
                "method": self.method, "tolerance": self.tolerance, "bands": self.bands,
                "diagnostics": self.diagnostics}


def _sensor_of(n_bands: int) -> str:
    return {15: "MERIS ", 21: "OLCI "}.get(n_bands, "")


def _band_range(n_bands: int) -> str:
    """How messages name the bands of a product of ``n_bands`` bands."""
    return f"{_sensor_of(n_bands)}bands are 1..{n_bands}"


def parse_band_list(text: str, n_bands: int = MERIS_BAND_COUNT) -> tuple[int, ...] | None:
    """A band list as users type it: "7,5,2" or "7 5 2" -> (7, 5, 2) in that order; "all" or
    "" -> None (all bands of the product). OptionsError naming the text otherwise (the CLI's
    ``--bands`` and the widget's field); ``n_bands``: the highest band number accepted (15 for
    MERIS, 21 for OLCI products)."""
    words = text.replace(",", " ").split()
    if not words or (len(words) == 1 and words[0].lower() == "all"):
        return None
    try:
        values = tuple(int(w) for w in words)
    except ValueError:
        raise OptionsError(f"bands {text!r}: expected {_sensor_of(n_bands)}band numbers "
                           f"1..{n_bands} separated by "
                           "commas, e.g. 7,5,2") from None
    if any(not 1 <= v <= n_bands for v in values):
        raise OptionsError(f"bands {text!r}: {_band_range(n_bands)}")
    return values


def check_bands(bands: Sequence[int] | None, n_bands: int = MERIS_BAND_COUNT
                ) -> tuple[int, ...]:
    """Sorted distinct bands 1..``n_bands`` (None: all of them; 15 for MERIS, 21 for OLCI
    products); OptionsError otherwise."""
    chosen = list(range(1, n_bands + 1)) if bands is None else [int(b) for b in bands]
    bad = [b for b in chosen if not 1 <= b <= n_bands]
    if bad or not chosen:
        raise OptionsError(f"bands must be 1..{n_bands} ({_band_range(n_bands)}), got "
                           f"{list(bands or [])}")
    return tuple(sorted(set(chosen)))

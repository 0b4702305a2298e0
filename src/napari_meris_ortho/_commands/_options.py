"""Options shared by ``meris-ortho map`` and ``synthesize``: output grid, heights, sampling, bands.

The output grid (CRS, pixel size, upper-left/lower-right corners: Appendix C "SETTING PIXEL SIZE",
"COMPUTING IMAGE SIZE AND ORIGIN"), the elevation source and DEMs (section 3.4), the resampling
and the band list are defined and checked here once, before any product is read (Appendix C
parameter checks); a bad value raises ``OptionsError`` (exit code 2, one line).
"""

from __future__ import annotations

import argparse
import math
from functools import partial
from typing import Any

from ..errors import OptionsError
from ..options import Elevation, OrthoOptions, Sampling, choices, parse_band_list


def parse_bands(text: str, n_bands: int = 15) -> list[int] | None:
    """argparse type of ``--bands``: "3,5,7" or "3 5 7" -> [3, 5, 7], "all" -> None (all
    bands of the product); ``options.parse_band_list`` with ``n_bands`` (15 MERIS; a command
    that reads OLCI products too takes 21 here and checks them against the product)."""
    if not text.strip():  # an empty shell variable, not a choice of all bands
        raise argparse.ArgumentTypeError(f"no band given: band numbers 1..{n_bands} separated "
                                         "by commas, or all")
    try:
        values = parse_band_list(text, n_bands)
    except OptionsError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return None if values is None else list(values)


def add_bands_option(p: Any, help: str, n_bands: int = 15) -> None:
    """``--bands LIST``, band numbers 1..``n_bands`` (:func:`parse_bands`)."""
    p.add_argument("--bands", type=partial(parse_bands, n_bands=n_bands), default=None,
                   metavar="LIST", help=help)


#: what a ``--dem`` entry may be (dem, dem.copernicus, dem.geoid)
DEM_ENTRY_HELP = (
    "PATH: GeoTIFF/VRT, SRTM30 .DEM, a directory of GETASSE30, SRTM30 or Copernicus GLO-30/90 "
    "tiles; DATUM: egm96 or egm2008 (heights above that geoid) or ellipsoid; default: SRTM30 and "
    "Copernicus egm96, GETASSE30 ellipsoid, GeoTIFF from its vertical CRS (else ellipsoid, "
    "with a warning). EGM96 comes from proj-data's egm96_15.gtx")


def add_height_options(p: Any, dem_help: str, elevation_help: str) -> None:
    """``--dem`` (repeatable) and ``--elevation none|tiepoints|dem`` (default dem; given
    without a default value, so that ``ortho_options`` tells an explicit ``dem`` apart)."""
    p.add_argument("--dem", action="append", default=[], metavar="PATH[:DATUM]",
                   help=f"{dem_help}. {DEM_ENTRY_HELP}")
    p.add_argument("--elevation", choices=choices(Elevation), default=None, help=elevation_help)


def add_sampling_option(p: Any, help: str) -> None:
    p.add_argument("--sampling", choices=choices(Sampling), default="nearest", help=help)


#: the default grid of ``map`` and a new synthesis, as their --help states it
DEFAULT_GRID = (
    "Default grid: EPSG:4326, MERSYN's geographic grid, with square pixels of the product's "
    "column spacing at nadir as an angle on the sphere R = 6370997 m (0.002338 deg FR, "
    "0.009353 deg RR; 260 m north-south, about 180 m east-west at 46 N), its upper-left corner "
    "the corner of the smallest rectangle holding the product's segment. The napari widget "
    "defaults to the UTM zone of the footprint instead (--crs utm here): square metric pixels "
    "of 260 m / 1040 m, which is what a viewer measures distances and areas on. In a projected "
    "CRS the default upper-left corner is rounded out to a multiple of the pixel size, so that "
    "the grids of different products line up.")


def add_grid_options(p: Any) -> None:
    """``--like RASTER``, ``--crs``, ``--pixel-size``, ``--ul X Y``, ``--lr X Y`` (a parser or
    argument group); left out, ``--crs`` is None (``grid_from_args`` tells it apart from a
    given one)."""
    p.add_argument("--like", default=None, metavar="REFERENCE.tif",
                   help="take the CRS, transform and size of this raster (GeoTIFF or any GDAL "
                   "raster), as rio warp --like: the output is comparable pixel for pixel with "
                   "it (not with --crs, --pixel-size, --ul, --lr)")
    p.add_argument("--crs", default=None,
                   help="output CRS: what PROJ reads (EPSG:32632, WKT, a PROJ string), or utm: "
                   "the UTM zone of the (first) product's footprint centre (default EPSG:4326, "
                   "MERSYN's; the napari widget's: utm)")
    p.add_argument("--pixel-size", type=float, default=None, metavar="SIZE",
                   help="pixel size in CRS units (default: the column spacing at nadir, 260 m "
                   "FR / 1040 m RR; in degrees 0.002338 FR / 0.009353 RR)")
    p.add_argument("--ul", type=float, nargs=2, default=None, metavar=("X", "Y"),
                   help="upper-left corner of the output (CRS units)")
    p.add_argument("--lr", type=float, nargs=2, default=None, metavar=("X", "Y"),
                   help="lower-right corner of the output (CRS units)")
    p.add_argument("--max-pixels", type=_pixel_count, default=None, metavar="N",
                   help="largest output grid in pixels (default: what fits in 80%% of the "
                   "available memory; synthesize: 65536 chunks of 512 x 512 pixels per layer, "
                   "and the tiles a run writes must fit in the free disk space, which is not "
                   "checked when this is given)")


def positive_int(what: str) -> Any:
    """An argparse type: an integer >= 1, else "'TEXT' is not WHAT" (``what``: "a positive
    integer", "a number of commits >= 1")."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = 0
        if value < 1:
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}")
        return value

    return parse


def _pixel_count(text: str) -> int:
    """argparse type of ``--max-pixels``: a positive count ("2e9" allowed)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 1):
        raise argparse.ArgumentTypeError(f"{text!r} is not a positive pixel count")
    return int(value)


def ortho_options(args: argparse.Namespace, n_bands: int = 15, **values: Any) -> OrthoOptions:
    """The checked ``OrthoOptions`` of ``--elevation``, ``--sampling``, ``--bands``, the
    ``--dem`` list and ``values`` (``OrthoOptions.of``: DEMs only with elevation dem, as MERSYN
    refuses -dem with -ort NO). ``--elevation dem`` given without a ``--dem`` is refused: the
    user asked for DEM heights and named none (left out, the default takes the DEMs given, or
    with none the tie-point heights, as MERSYN)."""
    elevation = args.elevation
    if elevation is None:
        elevation = Elevation.DEM.value
    elif elevation == Elevation.DEM.value and not args.dem:
        raise OptionsError("--elevation dem needs a DEM: name one with --dem PATH (or choose "
                           "--elevation tiepoints)")
    # bands given: checked here up to the most bands of any sensor, against the product's
    # own count when it is read (``ortho.precompute``)
    return OrthoOptions.of(n_dems=len(args.dem), elevation=elevation,
                           sampling=args.sampling, bands=args.bands,
                           n_bands=n_bands if args.bands else 15, **values)


def grid_from_args(args: argparse.Namespace, default_crs: str = "EPSG:4326") -> Any:
    """The ``OutputGrid`` of ``--like`` (a raster's grid; refused with any other grid option),
    or of ``--ul``/``--lr``/``--pixel-size``/``--crs``, or None without corners (then the
    product footprint sets the extent); checks the pixel size and the CRS."""
    from ..geometry.grid import OutputGrid, is_footprint_utm, output_crs

    if getattr(args, "like", None) is not None:
        from ..output.geotiff import raster_grid

        given = [flag for flag, value in (("--crs", args.crs), ("--pixel-size", args.pixel_size),
                                          ("--ul", args.ul), ("--lr", args.lr))
                 if value is not None]
        if given:
            raise OptionsError(f"--like takes the CRS, transform and size from {args.like}: "
                               f"leave out {', '.join(given)}")
        return raster_grid(args.like)
    if args.pixel_size is not None and not (math.isfinite(args.pixel_size)
                                            and args.pixel_size > 0):
        raise OptionsError(f"--pixel-size must be > 0, got {args.pixel_size}")
    crs = args.crs or default_crs
    if not is_footprint_utm(crs):
        crs = output_crs(crs)
    if (args.ul is None) != (args.lr is None):
        raise OptionsError("--ul and --lr need each other")
    if args.ul is None:
        return None
    if is_footprint_utm(crs):
        raise OptionsError("--crs utm takes its zone from the product's footprint; with --ul/--lr "
                           "name the zone (e.g. --crs EPSG:32632)")
    if args.pixel_size is None:
        raise OptionsError("--ul/--lr need --pixel-size")
    return OutputGrid.from_extent(crs, args.ul, args.lr, args.pixel_size)

"""napari readers: MERIS L1b ``.N1`` products and ``.SEN3`` directories (product geometry),
geocoded GeoTIFFs and synthesis stores (directories; ``synthesis_layers``).

A Level 1 product (a MERIS N1 or ``.SEN3``, an OLCI Level 1B ``.SEN3``): its radiance bands
(MERIS 15, OLCI 21) as one multichannel image (band axis first), an RGB quick-look from the
sensor's true-colour bands (``bands.BandTable.true_colour``: MERIS 7, 5, 2; OLCI Oa08, Oa06,
Oa03), the flags as a labels layer; tie points and headers in the layer metadata.
A product wider or longer than ``pyramid.MAX_LEVEL_SIDE`` opens as multiscale layers read on
demand (``pyramid``): napari reads only the lines of the level on screen from an N1's memory
map; a ``.SEN3``'s bands are read whole when first shown (chunked, compressed netCDF: a part
costs the whole decompression) and the last few kept (``WholeBands``), its flags when first
shown; opening reads the three quick-look bands and nothing else.
Arrays stay in the stored (chronological/detector) column order, like MERSYN (ARCHITECTURE.md).

GeoTIFF: every band placed in the world frame (``world`` module doc): north up, pixel centres
right; a raster in another CRS or pixel size than the viewer's geocoded layers is reprojected
onto their grid. A big one on the viewer's grid (our COGs) opens as multiscale layers on its
own overviews, read window by window.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..bands import BandTable, band_table
from ..display import contrast_limits, stretch_channel, stretch_rgb
from ..errors import MerisOrthoError, N1FormatError
from ..geometry.grid import OutputGrid
from ..placement import place_on_frame
from ..products.n1.format import NUM_BANDS
from ..pyramid import (
    LazyArray,
    Selection,
    WholeBands,
    as_index,
    gcps_only,
    geotiff_levels,
    geotiff_rgb_levels,
    has_scale,
    is_rgb,
    level_factors,
    memory_levels,
    north_up,
    physical_bands,
    selection_radiance,
)
from ._qt.insertion import defer_controls, thumbnails_later
from ._qt.waiting import responsively
from .product_layers import quicklook_name
from .status import band_axis_name
from .world import current_viewer, geo_image_kwargs, viewer_frame

if TYPE_CHECKING:
    from ..products.protocol import MerisProduct

LayerData = tuple[Any, dict[str, Any], str]
N1_SUFFIXES = (".n1",)
TIFF_SUFFIXES = (".tif", ".tiff")


def _is_product(path: str | Path) -> bool:
    """An N1 file, a ``.SEN3`` directory or its ``xfdumanifest.xml``."""
    from ..products.sen3 import is_sen3

    p = Path(path)
    return p.suffix.lower() in N1_SUFFIXES or is_sen3(p)


def get_reader(path: str | list[str]) -> Callable[[str | list[str]], list[LayerData]] | None:
    """npe2 reader hook: a reader function when every path is an N1 product (its header starts
    with ``PRODUCT="``), a ``.SEN3`` product or a geocoded raster GDAL opens; None otherwise,
    so that napari falls back to its own readers (a plain TIFF)."""
    paths = [path] if isinstance(path, str | Path) else list(path)
    if not paths or not all(_file_or_directory(p) for p in paths):
        return None
    if all(_readable(Path(p)) for p in paths):
        return read_layers
    from .synthesis_layers import is_store

    if len(paths) == 1 and is_store(paths[0]):
        return read_store
    return None


def read_store(path: str | list[str]) -> list[LayerData]:
    """Read a synthesis store (multiscale layers, winning product as labels)."""
    from .layout import frame_later
    from .synthesis_layers import data_extent, store_layers

    viewer = current_viewer()
    empty = viewer is not None and not len(viewer.layers)
    _current_frame()  # map coordinates and the band slider's names in the status bar
    layers = store_layers(path[0] if isinstance(path, list) else path)
    extent = data_extent(layers)
    if empty and extent is not None:  # napari frames the whole grid: frame what it holds
        frame_later(viewer, *extent)
    if viewer is not None:  # the first pixels before the layers' controls
        defer_controls(viewer, [kind for _, _, kind in layers])
        thumbnails_later(viewer, _hidden_names(layers))
    return layers


def _file_or_directory(path: str | Path) -> bool:
    """True for a regular file or a directory (following links); False for a FIFO, socket or
    device, which reading would block on or consume (``stat`` itself never blocks)."""
    import stat

    try:
        mode = Path(path).stat().st_mode
    except OSError:
        return False
    return stat.S_ISREG(mode) or stat.S_ISDIR(mode)


def _readable(path: Path) -> bool:
    """True for an N1 header, a SEN3 product or a GeoTIFF with a CRS (a cheap look)."""
    from ..products.sen3 import is_sen3

    suffix = path.suffix.lower()
    if suffix in N1_SUFFIXES:
        try:
            with open(path, "rb") as fh:
                return fh.read(9) == b'PRODUCT="'
        except OSError:
            return False
    if is_sen3(path):
        return True
    if suffix in TIFF_SUFFIXES:
        import rasterio
        from rasterio.errors import RasterioError

        try:
            with rasterio.open(path) as ds:
                return ds.crs is not None or gcps_only(ds)
        except (RasterioError, OSError):
            return False
    return False


def read_layers(path: str | list[str]) -> list[LayerData]:
    """Read one or several N1 / GeoTIFF files into napari layer tuples."""
    paths = [path] if isinstance(path, str | Path) else list(path)
    frame = _current_frame()
    layers: list[LayerData] = []
    for p in paths:
        if _is_product(p):
            layers.extend(n1_layers(p, frame))
        else:
            new = geotiff_layers(p, frame)
            layers.extend(new)
            if frame is None and new:
                frame = OutputGrid.from_transform(**_frame_args(new[0][1]))
    viewer = current_viewer()
    if viewer is not None:  # the first pixels before the layers' controls
        defer_controls(viewer, [kind for _, _, kind in layers])
        thumbnails_later(viewer, _hidden_names(layers))
    return layers


def _hidden_names(layers: list[LayerData]) -> list[str]:
    """The names of the image layers that open hidden (their thumbnails: ``thumbnails_later``;
    not a labels layer's: napari's first slicing of one builds its colour textures, a 0.28-0.30 s
    turn after a session's first open)."""
    return [kwargs["name"] for _, kwargs, kind in layers
            if kind == "image" and kwargs.get("visible", True) is False and "name" in kwargs]


def _frame_args(kwargs: dict[str, Any]) -> dict[str, Any]:
    geo = kwargs["metadata"]["geo"]
    return {"crs": geo["crs"], "transform": geo["transform"], "shape": geo["shape"]}


def _current_frame() -> OutputGrid | None:
    """The world frame of the current napari viewer (None without viewer or geocoded layer);
    the viewer's status bar then shows map coordinates (``status``)."""
    viewer = current_viewer()
    if viewer is None:
        return None
    from .._process import unit_registry_from_disk
    from .memory import freeze_at_first_read, trim_after_removals
    from .status import show_map_coordinates

    unit_registry_from_disk()  # before napari makes the first layer, and frozen with it
    freeze_at_first_read(viewer)
    trim_after_removals(viewer)  # what a removed product's or store's layers held goes back
    show_map_coordinates(viewer)
    return viewer_frame(viewer.layers)


# --------------------------------------------------------------------------------------------
# GeoTIFF
# --------------------------------------------------------------------------------------------
def geotiff_layers(path: str | Path, frame: OutputGrid | None = None) -> list[LayerData]:
    """Image layers of a geocoded GeoTIFF placed in the world frame ``frame`` (or its own)."""
    import rasterio
    from rasterio.errors import RasterioIOError

    path = Path(path)
    try:
        with rasterio.open(path) as opened, north_up(opened) as ds:
            if ds.crs is None:
                raise MerisOrthoError(f"{path}: GeoTIFF has no CRS (not geocoded)")
            _check_size(path, ds)
            source = OutputGrid.from_transform(ds.crs, tuple(ds.transform), (ds.height, ds.width))
            names = [d or f"band {i + 1}" for i, d in enumerate(opened.descriptions)]
            meris_bands = [meris_band_of(d, opened.tags(i + 1))
                           for i, d in enumerate(opened.descriptions)]
            tags = opened.tags()
            scaled = has_scale(ds)
            # what the layer's no-data pixels hold: 0 where counts are read as radiances
            # (``_to_physical``), else the file's own value
            nodata = 0.0 if scaled and ds.nodata is not None else ds.nodata
            # on demand from its overviews (else each level reads the whole band: 1.6-2.8 s)
            lazy = (ds is opened and (frame is None or source.same_grid(frame))
                    and bool(ds.overviews(1)) and len(level_factors(ds.height, ds.width)) > 1)
            rgb = is_rgb(ds)
            bands: list[Any] = [] if not lazy else (
                [geotiff_rgb_levels(path, ds)] if rgb else geotiff_levels(path, ds))
            data = None if lazy else responsively(physical_bands, ds)  # read in a thread
            if rgb:  # one layer (transparent where its alpha is 0)
                names, nodata = ["rgb"], None
    except RasterioIOError as exc:
        raise MerisOrthoError(f"{path}: cannot read GeoTIFF ({exc})") from None
    grid = source
    limits: list[tuple[float, float]] | None = None
    if data is not None:
        is_mask = data.dtype.kind in "iu" and data.dtype.itemsize == 1
        fill = 0.0 if nodata is None else nodata
        # reprojected onto the world (GDAL's warp), levels and contrast limits made in a
        # thread, the window kept turning
        bands, grid, limits = responsively(_placed, data, source, frame, is_mask, fill, rgb,
                                           nodata)
        nodata = fill if grid is not source else nodata
    layers = []
    for k, band_name in enumerate(names):
        band = bands[k]
        # "band": the MERIS band (flicker pairs, the writer's description), when the file says
        meta = {"path": str(path), "tags": tags, "nodata": nodata, "file_band": k + 1,
                "source_crs": source.crs, "reprojected": grid is not source}
        if not rgb and meris_bands[k] is not None:
            meta["band"] = meris_bands[k]
        name = path.stem if len(names) == 1 else f"{path.stem} {band_name}"
        kwargs = geo_image_kwargs(grid, name=name, metadata=meta)
        if rgb:
            kwargs["rgb"] = True
            meta.pop("file_band")
        else:
            kwargs["contrast_limits"] = (  # of the coarsest level
                _contrast_limits(np.asarray(band[-1]), nodata) if limits is None else limits[k])
            kwargs["colormap"] = "gray"
        if lazy or isinstance(band, list):
            kwargs["multiscale"] = True
        layers.append((band, kwargs, "image"))
    return layers


def _placed(data: np.ndarray, source: OutputGrid, frame: OutputGrid | None, nearest: bool,
            fill: float, rgb: bool, nodata: float | None
            ) -> tuple[list[Any], OutputGrid, list[tuple[float, float]] | None]:
    """The bands of a raster placed on the world frame (``place_on_frame``), each as its
    levels when bigger than one (``memory_levels``: napari uploads the level that fits the
    canvas), an RGB(A) as one image; the bands' contrast limits (none for an RGB), leaving out
    the value of the pixels placed from nothing (``fill``) or the file's ``nodata``."""
    _import_for_first_layer()
    placed, grid = place_on_frame(data, source, frame, nearest=nearest, nodata=fill)
    skip = fill if grid is not source else nodata
    resampling = "nearest" if nearest else "average"

    def pyramid(image: np.ndarray) -> Any:
        levels = memory_levels(image, skip, resampling, rgb=rgb)
        return levels if len(levels) > 1 else image

    if rgb:
        return [pyramid(np.moveaxis(placed, 0, -1))], grid, None
    return ([pyramid(band) for band in placed], grid,
            [_contrast_limits(band, skip) for band in placed])


def meris_band_of(description: str | None, tags: dict[str, str] | None = None) -> int | None:
    """The MERIS band (1-15) a GeoTIFF band holds: its ``meris_band`` tag (our writers), else
    its description ("MERIS band 7 (664.6 nm)", "band 7 radiance", "b7"); None when neither
    says (a band's place in the file is not a MERIS band)."""
    import re

    found = str((tags or {}).get("meris_band", "")).strip()
    if not found.isdigit():
        match = re.match(r"\s*(?:MERIS\s+)?(?:band\s*|b)(\d{1,2})\b", description or "",
                         re.IGNORECASE)
        found = match.group(1) if match else ""
    band = int(found) if found.isdigit() else 0
    return band if 1 <= band <= NUM_BANDS else None


def _check_size(path: Path, ds: Any) -> None:
    """Refuse a raster whose bands would not fit the memory limit (a sparse 40000 x 40000
    GeoTIFF is a few kB on disk): the bands, their float32 physical values, masks and placed
    copies, and a float64 band for the contrast limits."""
    from ..geometry.grid import check_grid_size

    per_pixel = ds.count * (np.dtype(ds.dtypes[0]).itemsize + 9) + 8
    try:
        check_grid_size(ds.width, ds.height, (abs(ds.transform.a), abs(ds.transform.e)),
                        per_pixel)
    except MerisOrthoError as exc:
        raise MerisOrthoError(f"{path}: {exc}") from None


def _contrast_limits(band: np.ndarray, nodata: float | None) -> tuple[float, float]:
    """Contrast limits of a band, 0 and ``nodata`` excluded (1-99 percentiles)."""
    values = np.asarray(band, np.float64)
    if nodata is not None and nodata != 0:
        values = np.where(values == nodata, 0.0, values)
    return contrast_limits(values, 0.0)


# --------------------------------------------------------------------------------------------
# N1
# --------------------------------------------------------------------------------------------
def n1_layers(path: str | Path, frame: OutputGrid | None = None) -> list[LayerData]:
    """Radiance stack (band axis = the product's band numbers, MERIS 1..15, OLCI 1..21), RGB
    quick-look (the sensor's true-colour bands: MERIS 7, 5, 2; OLCI 8, 6, 3) and flags (named
    bits in the features) of a Level 1 product (MERIS N1 or .SEN3, OLCI .SEN3; FRG/FSG and
    SEN3 products also carry their per-pixel altitude in the metadata), in product geometry
    placed in the world (``frame``, or a new one in the UTM zone of the footprint) by an affine
    fit of its tie points (``_placement``). The radiance stack opens hidden (the opaque RGB
    hides it, and a first open takes 0.84-0.96 s, against 0.87-1.03 s with the stack shown). A
    session's first product is read in a thread while the window turns (``responsively``): its
    readers' imports, the reading and napari's import of xarray for its first layer would hold
    the window 0.5-0.8 s (fr-alps); later ones take 0.05 s, less than the thread costs. The
    placement's warning is given on this thread (napari shows warnings as widgets)."""
    if _imports_pending():
        layers, warning = responsively(_n1_layer_data, path, frame)
    else:
        layers, warning = _n1_layer_data(path, frame)
    if warning:
        import warnings

        warnings.warn(warning, stacklevel=2)
    return layers


def _imports_pending() -> bool:
    """True until this process has read a product (readers and xarray not imported yet)."""
    import sys

    return not {"xarray", "napari_meris_ortho.products.open"} <= sys.modules.keys()


def _import_for_first_layer() -> None:
    """xarray (and pandas), which napari imports when it makes its first image layer."""
    with contextlib.suppress(ImportError):  # napari does without it
        import xarray  # noqa: F401


def _n1_layer_data(path: str | Path, frame: OutputGrid | None
                   ) -> tuple[list[LayerData], str | None]:
    """``n1_layers``'s layers and the placement's warning (None when its fit is good); no Qt."""
    from ..products.open import read_product
    from .ortho_run import name_stamp

    try:
        product = read_product(path)
    except MerisOrthoError:
        raise
    except (OSError, ValueError) as exc:
        raise N1FormatError(path, str(exc)) from None
    meta = n1_metadata(product)
    suffix = f" · {name_stamp(product)}"
    place, warning = _placement(product, frame, meta)
    table = product_bands(product)
    band_axis = {"affine": _with_band_axis(place["affine"]), "units": ("pixel", *place["units"]),
                 "axis_labels": (band_axis_name(table.sensor), *place["axis_labels"])}
    read = radiance_reader(product)  # one band cache for the stack and the quick-look
    radiance = radiance_levels(product, read)
    rgb = quicklook_levels(product, table.true_colour, read=read)
    flags = flag_levels(product)
    multiscale = {"multiscale": len(radiance) > 1}
    _import_for_first_layer()
    return [
        (_one_or_all(radiance), {"name": f"radiance{suffix}", "metadata": meta,
                                 "colormap": "gray", "visible": False, **band_axis,
                                 **multiscale,
                                 "contrast_limits": _contrast_limits(
                                     np.asarray(radiance[-1][table.true_colour[0] - 1]),
                                     None)}, "image"),
        (_one_or_all(rgb), {"name": f"{quicklook_name(table)}{suffix}", "rgb": True,
                            "metadata": meta, **place, **multiscale}, "image"),
        (_one_or_all(flags), {"name": f"flags{suffix}", "metadata": meta, "opacity": 0.4,
                              "visible": False, "features": flag_features(flags[0]), **place,
                              **multiscale}, "labels"),
    ], warning


def _one_or_all(levels: list[Any]) -> Any:
    """A layer's data: its only level, or the list of levels (multiscale)."""
    return levels[0] if len(levels) == 1 else levels


def flag_names(value: int) -> str:
    """The L1b flag bits set in ``value`` (Flags MDS(16)), e.g. 'LAND_OCEAN|INVALID'."""
    from ..products.n1 import FLAG_NAMES

    names = [name for k, name in enumerate(FLAG_NAMES) if int(value) & (1 << k)]
    return "|".join(names) if names else "none"


def flag_features(flags: np.ndarray | LazyArray) -> dict[str, list[Any]]:
    """Features of the flags labels layer: every flag value present and its bit names; of
    flags not read yet (a big ``.SEN3``'s, ``flag_levels``) every byte value's."""
    if isinstance(flags, LazyArray):
        return {"index": list(range(256)), "flags": [flag_names(v) for v in range(256)]}
    counts = np.zeros(256, np.int64)
    for start in range(0, flags.shape[0], 256):  # a block of lines at a time: little memory
        counts += np.bincount(np.asarray(flags[start:start + 256], np.uint8).ravel(),
                              minlength=256)
    present = np.flatnonzero(counts)
    values = sorted({int(v) for v in present} | {0})
    return {"index": values, "flags": [flag_names(v) for v in values]}


def _placement(product: Any, frame: OutputGrid | None, meta: dict[str, Any]
               ) -> tuple[dict[str, Any], str | None]:
    """napari placement of product-geometry layers in the world (``world.product_world``): an
    affine fit of the tie points in the world's CRS, and the warning to give when it is coarse
    (else None); a product opened first founds the world in the UTM zone of its footprint."""
    from .world import WORLD_KEY, geo_metadata, product_world, world_axes

    over_map = frame is not None  # a coarse fit matters when there is a map to overlay
    affine, rms, frame = product_world(product, frame)
    meta[WORLD_KEY] = geo_metadata(frame)
    meta["placement"] = {"affine": affine.tolist(), "rms_error": rms,
                         "note": "approximate: affine fit of the tie points"}
    warning = None
    if over_map and rms > 2.0 * max(frame.dx, frame.dy):
        warning = (f"{Path(product.path).name}: placed on the map by an affine fit of its "
                   f"tie points (RMS {rms:.3g} {'deg' if frame.is_geographic else 'm'}); "
                   "orthorectify it for an exact overlay")
    return {"affine": affine, **world_axes(frame.crs)}, warning


def _with_band_axis(affine: np.ndarray) -> np.ndarray:
    """The 2-D placement with the band axis in front (world band = 1..n_bands)."""
    out = np.eye(4)
    out[0, 3] = 1.0
    out[1:, 1:] = affine
    return out


def product_bands(product: MerisProduct) -> BandTable:
    """The band table of a product's sensor (MERIS for a product that does not say)."""
    return band_table(getattr(product, "sensor", "MERIS"))


def band_label(table: BandTable, band: int, wavelength: float) -> str:
    """A band as the band axis names it after the sensor: 'band 7 (665 nm)' (MERIS, whose
    products number their bands), 'Oa08 (665 nm)' (OLCI, whose products name them)."""
    what = f"band {band}" if table.sensor == "MERIS" else table.name(band)
    return f"{what} ({wavelength:.0f} nm)"


def n1_metadata(product: MerisProduct) -> dict[str, Any]:
    """Tie points and headers of a product, for the layer metadata."""
    table = product_bands(product)
    return {
        "sensor": str(table.sensor), "true_colour": table.true_colour,
        "path": str(product.path), "product_type": product.product_type,
        "mph": dict(product.mph), "sph": dict(product.sph),
        "tie_points": {k: np.asarray(v) for k, v in product.tie_points.items()},
        "lines_per_tie_point": product.lines_per_tie_point,
        "samples_per_tie_point": product.samples_per_tie_point,
        "wavelengths": list(product.wavelengths),
        "band_names": [band_label(table, b, w) for b, w in enumerate(product.wavelengths, 1)],
        "column_order": "stored (chronological/detector)",
        "pixel_geolocation": bool(getattr(product, "has_pixel_geolocation", False)),
    }


#: radiance(band, rows, cols) of a selection (an index or a range per axis)
RadianceReader = Callable[[int, int | range, int | range], np.ndarray]


def radiance_reader(product: MerisProduct) -> RadianceReader:
    """How the layers read radiances: an N1 only the selection's lines (its memory map); any
    other product (a ``.SEN3``) a band whole when first needed, kept in a ``WholeBands``."""
    if not _reads_lines(product):
        return WholeBands(product).radiance

    def read(band: int, rows: int | range, cols: int | range) -> np.ndarray:
        # a decimated level or a tile converts only its own pixels, not whole lines
        return selection_radiance(product, product.counts(band), band, rows, cols)

    return read


def _reads_lines(product: MerisProduct) -> bool:
    """True for an N1 (its bands are memory-mapped: a selection reads only its lines)."""
    from ..products.n1.reader import MerisL1bProduct

    return isinstance(product, MerisL1bProduct)


def radiance_levels(product: MerisProduct, read: RadianceReader | None = None) -> list[Any]:
    """The radiance bands (n_bands, H, W) float32 (``radiance_stack``) and its decimated levels
    (``pyramid``; one level for a small product)."""
    stack = radiance_stack(product, read)
    return stack.levels() if len(_product_factors(product)) > 1 else [stack]


def radiance_stack(product: MerisProduct, read: RadianceReader | None = None) -> LazyArray:
    """The radiance bands as a lazy (n_bands, H, W) float32 array: a selection reads only the
    selected bands (``radiance_reader``: of an N1 only its lines)."""
    radiance = read or radiance_reader(product)

    def read_stack(sel: Selection) -> np.ndarray:
        band, rows, cols = sel
        bands = [band] if isinstance(band, int) else list(band)
        out = np.stack([radiance(b + 1, rows, cols) for b in bands])
        return out[0] if isinstance(band, int) else out

    n_bands = int(getattr(product, "n_bands", NUM_BANDS))
    return LazyArray(read_stack, (n_bands, product.height, product.width), np.float32)


def quicklook_levels(product: MerisProduct,
                     bands: tuple[int, int, int] | None = None,
                     read: RadianceReader | None = None) -> list[Any]:
    """The RGB quick-look (H, W, 3) uint8 of a small product (1-99 % stretch of each band,
    ``stretch_rgb``); of a big one a lazy (H, W, 3)
    uint8 array and its decimated levels, each channel stretched by the 1-99 % limits of the
    coarsest level (``stretch_channel``); ``bands``: the sensor's true colour by default."""
    bands = product_bands(product).true_colour if bands is None else bands
    factors = _product_factors(product)
    radiance = read or radiance_reader(product)
    if len(factors) == 1:
        everything = range(product.height), range(product.width)
        return [stretch_rgb([radiance(b, *everything) for b in bands])]
    f = factors[-1]
    limits = [contrast_limits(radiance(b, range(0, product.height, f),
                                       range(0, product.width, f))) for b in bands]

    def read_rgb(sel: Selection) -> np.ndarray:
        rows, cols, channel = sel
        channels = [channel] if isinstance(channel, int) else list(channel)
        out = [stretch_channel(radiance(bands[c], rows, cols), limits[c]) for c in channels]
        return out[0] if isinstance(channel, int) else np.stack(out, axis=-1)

    rgb = LazyArray(read_rgb, (product.height, product.width, 3), np.uint8)
    return rgb.levels(spatial=(0, 1))


def flag_levels(product: MerisProduct) -> list[Any]:
    """The flags (H, W) uint8 and their decimated views: an N1's are views of its memory map
    (a level reads only the lines on screen); a big ``.SEN3``'s are read when first shown
    (``quality_flags`` decoded whole, kept by the product)."""
    factors = _product_factors(product)
    if _reads_lines(product) or len(factors) == 1:
        flags = np.asarray(product.flags)
        return [flags[::f, ::f] for f in factors]

    def read(sel: Selection) -> np.ndarray:
        rows, cols = sel
        return np.asarray(product.flags[as_index(rows), as_index(cols)])

    return LazyArray(read, (product.height, product.width), np.uint8).levels()


def _product_factors(product: MerisProduct) -> list[int]:
    """The decimation factors of a product's levels (``level_factors``)."""
    return level_factors(product.height, product.width)

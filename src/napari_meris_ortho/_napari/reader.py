"""napari readers: MERIS L1b ``.N1`` products and ``.SEN3`` directories (product geometry),
geocoded GeoTIFFs and synthesis stores (directories; ``synthesis_layers``).

N1: the 15 radiance bands as one multichannel image (band axis first, lazy), an RGB quick-look
from bands 7, 5, 2, the flags as a labels layer; tie points and headers in the layer metadata.
Arrays stay in the stored (chronological/detector) column order, like MERSYN (ARCHITECTURE.md).

GeoTIFF: every band placed in the world frame (``_layers`` module doc): north up, pixel centres
right; a raster in another CRS or pixel size than the viewer's geocoded layers is reprojected
onto their grid.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import MerisOrthoError, N1FormatError
from ..geometry.grid import OutputGrid
from .product_layers import QUICKLOOK_BANDS, contrast_limits, stretch_rgb
from .status import BAND_AXIS
from .world import geo_image_kwargs, place_on_frame, viewer_frame

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
    from .synthesis_layers import store_layers

    return store_layers(path[0] if isinstance(path, list) else path)


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
                return ds.crs is not None
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
    return layers


def _frame_args(kwargs: dict[str, Any]) -> dict[str, Any]:
    geo = kwargs["metadata"]["geo"]
    return {"crs": geo["crs"], "transform": geo["transform"], "shape": geo["shape"]}


def _current_frame() -> OutputGrid | None:
    """The world frame of the current napari viewer (None without viewer or geocoded layer);
    the viewer's status bar then shows map coordinates (``status``)."""
    try:
        import napari

        viewer = napari.current_viewer()
    except Exception:  # no Qt app: plain reading
        return None
    if viewer is None:
        return None
    from .status import show_map_coordinates

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
        with rasterio.open(path) as ds:
            if ds.crs is None:
                raise MerisOrthoError(f"{path}: GeoTIFF has no CRS (not geocoded)")
            _check_size(path, ds)
            data = _physical(ds)
            source = OutputGrid.from_transform(ds.crs, tuple(ds.transform), (ds.height, ds.width))
            names = [d or f"band {i + 1}" for i, d in enumerate(ds.descriptions)]
            tags = ds.tags()
            nodata = ds.nodata
    except RasterioIOError as exc:
        raise MerisOrthoError(f"{path}: cannot read GeoTIFF ({exc})") from None
    is_mask = data.dtype.kind in "iu" and data.dtype.itemsize == 1
    placed, grid = place_on_frame(data, source, frame, nearest=is_mask)
    layers = []
    for k, band_name in enumerate(names):
        band = placed[k]
        meta = {"path": str(path), "tags": tags, "nodata": nodata, "band": k + 1,
                "source_crs": source.crs, "reprojected": grid is not source}
        name = path.stem if len(names) == 1 else f"{path.stem} {band_name}"
        kwargs = geo_image_kwargs(grid, name=name, metadata=meta)
        kwargs["contrast_limits"] = _contrast_limits(band, nodata)
        kwargs["colormap"] = "gray"
        layers.append((band, kwargs, "image"))
    return layers


def _physical(ds: Any) -> np.ndarray:
    """All bands; bands with a GDAL scale/offset (our uint16 counts) as float32 physical
    values (counts x scale + offset, nodata stays 0)."""
    data = ds.read()
    if all(s == 1.0 for s in ds.scales) and all(o == 0.0 for o in ds.offsets):
        return data
    mask = ds.read_masks() == 0
    out = data.astype(np.float32) * np.asarray(ds.scales, np.float32)[:, None, None]
    out += np.asarray(ds.offsets, np.float32)[:, None, None]
    out[mask] = 0
    return out


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
    """Radiance stack (band axis = MERIS band numbers 1..15), RGB quick-look (bands 7, 5, 2)
    and flags (named bits in the features) of a MERIS L1b product (N1 or .SEN3; FRG/FSG and
    SEN3 products also carry their per-pixel altitude in the metadata), in product geometry
    placed in the world (``frame``, or a new one in the UTM zone of the footprint) by an affine
    fit of its tie points (``_placement``)."""
    from ..products.open import read_product
    from .ortho_run import product_stamp

    try:
        product = read_product(path)
    except MerisOrthoError:
        raise
    except (OSError, ValueError) as exc:
        raise N1FormatError(path, str(exc)) from None
    meta = n1_metadata(product)
    suffix = f" · {product_stamp(product)}"
    place = _placement(product, frame, meta)
    band_axis = {"affine": _with_band_axis(place["affine"]), "units": ("pixel", *place["units"]),
                 "axis_labels": (BAND_AXIS, *place["axis_labels"])}
    flags = np.asarray(product.flags)
    return [
        (radiance_stack(product), {"name": f"radiance{suffix}", "metadata": meta,
                                   "colormap": "gray", **band_axis,
                                   "contrast_limits": _contrast_limits(product.radiance(7), None)},
         "image"),
        (quicklook_rgb(product), {"name": f"RGB 7-5-2{suffix}", "rgb": True, "metadata": meta,
                                  **place}, "image"),
        (flags, {"name": f"flags{suffix}", "metadata": meta, "opacity": 0.4, "visible": False,
                 "features": flag_features(flags), **place}, "labels"),
    ]


def flag_names(value: int) -> str:
    """The L1b flag bits set in ``value`` (Flags MDS(16)), e.g. 'LAND_OCEAN|INVALID'."""
    from ..products.n1 import FLAG_NAMES

    names = [name for k, name in enumerate(FLAG_NAMES) if int(value) & (1 << k)]
    return "|".join(names) if names else "none"


def flag_features(flags: np.ndarray) -> dict[str, list[Any]]:
    """Features of the flags labels layer: every flag value present and its bit names."""
    present = np.flatnonzero(np.bincount(np.asarray(flags, np.uint8).ravel(), minlength=256))
    values = sorted({int(v) for v in present} | {0})
    return {"index": values, "flags": [flag_names(v) for v in values]}


def _placement(product: Any, frame: OutputGrid | None, meta: dict[str, Any]) -> dict[str, Any]:
    """napari placement of product-geometry layers in the world (``world.product_world``): an
    affine fit of the tie points in the world's CRS (warned about when it is coarse); a product
    opened first founds the world in the UTM zone of its footprint."""
    from .world import WORLD_KEY, geo_metadata, product_world, world_axes

    over_map = frame is not None  # a coarse fit matters when there is a map to overlay
    affine, rms, frame = product_world(product, frame)
    meta[WORLD_KEY] = geo_metadata(frame)
    meta["placement"] = {"affine": affine.tolist(), "rms_error": rms,
                         "note": "approximate: affine fit of the tie points"}
    if over_map and rms > 2.0 * max(frame.dx, frame.dy):
        import warnings

        warnings.warn(f"{Path(product.path).name}: placed on the map by an affine fit of its "
                      f"tie points (RMS {rms:.3g} {'deg' if frame.is_geographic else 'm'}); "
                      "orthorectify it for an exact overlay", stacklevel=2)
    return {"affine": affine, **world_axes(frame.crs)}


def _with_band_axis(affine: np.ndarray) -> np.ndarray:
    """The 2-D placement with the band axis in front (world band = 1..15)."""
    out = np.eye(4)
    out[0, 3] = 1.0
    out[1:, 1:] = affine
    return out


def n1_metadata(product: MerisProduct) -> dict[str, Any]:
    """Tie points and headers of a product, for the layer metadata."""
    return {
        "path": str(product.path), "product_type": product.product_type,
        "mph": dict(product.mph), "sph": dict(product.sph),
        "tie_points": {k: np.asarray(v) for k, v in product.tie_points.items()},
        "lines_per_tie_point": product.lines_per_tie_point,
        "samples_per_tie_point": product.samples_per_tie_point,
        "wavelengths": list(product.wavelengths),
        "band_names": [f"band {b} ({w:.0f} nm)" for b, w in enumerate(product.wavelengths, 1)],
        "column_order": "stored (chronological/detector)",
        "pixel_geolocation": bool(getattr(product, "has_pixel_geolocation", False)),
    }


def radiance_stack(product: MerisProduct) -> Any:
    """The 15 radiance bands as a lazy (15, H, W) float32 dask array."""
    import dask
    import dask.array as da

    shape = (product.height, product.width)
    bands = [da.from_delayed(dask.delayed(product.radiance)(b), shape, dtype=np.float32)
             for b in range(1, 16)]
    return da.stack(bands)


def quicklook_rgb(product: MerisProduct,
                  bands: tuple[int, int, int] = QUICKLOOK_BANDS) -> np.ndarray:
    """An RGB quick-look (H, W, 3) uint8 from three radiance bands, 1-99 % stretch each."""
    return stretch_rgb([product.radiance(b) for b in bands])

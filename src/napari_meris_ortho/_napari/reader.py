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
from .world import geo_image_kwargs, place_on_frame, viewer_frame

if TYPE_CHECKING:
    from ..io.n1 import MerisL1bProduct

LayerData = tuple[Any, dict[str, Any], str]
N1_SUFFIXES = (".n1",)
TIFF_SUFFIXES = (".tif", ".tiff")


def _is_product(path: str | Path) -> bool:
    """An N1 file, a ``.SEN3`` directory or its ``xfdumanifest.xml``."""
    from ..io.sen3 import is_sen3

    p = Path(path)
    return p.suffix.lower() in N1_SUFFIXES or is_sen3(p)


def get_reader(path: str | list[str]) -> Callable[[str | list[str]], list[LayerData]] | None:
    """npe2 reader hook: a reader function for N1/SEN3 products and GeoTIFFs, else None."""
    paths = [path] if isinstance(path, str | Path) else list(path)
    if not paths:
        return None
    if all(_is_product(p) or Path(p).suffix.lower() in TIFF_SUFFIXES for p in paths):
        return read_layers
    from .synthesis_layers import is_store

    if len(paths) == 1 and is_store(paths[0]):
        return read_store
    return None


def read_store(path: str | list[str]) -> list[LayerData]:
    """Read a synthesis store (multiscale layers, winning product as labels)."""
    from .synthesis_layers import store_layers

    return store_layers(path[0] if isinstance(path, list) else path)


def read_layers(path: str | list[str]) -> list[LayerData]:
    """Read one or several N1 / GeoTIFF files into napari layer tuples."""
    paths = [path] if isinstance(path, str | Path) else list(path)
    frame = _current_frame()
    layers: list[LayerData] = []
    for p in paths:
        if _is_product(p):
            layers.extend(n1_layers(p))
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
    """The world frame of the current napari viewer (None without viewer or geocoded layer)."""
    try:
        import napari

        viewer = napari.current_viewer()
    except Exception:  # no Qt app: plain reading
        return None
    return None if viewer is None else viewer_frame(viewer.layers)


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
def n1_layers(path: str | Path) -> list[LayerData]:
    """Radiance stack, RGB quick-look (bands 7, 5, 2) and flags of a MERIS L1b product (N1 or
    .SEN3; FRG/FSG and SEN3 products also carry their per-pixel altitude in the metadata)."""
    from ..io.product import read_product

    try:
        product = read_product(path)
    except MerisOrthoError:
        raise
    except (OSError, ValueError) as exc:
        raise N1FormatError(path, str(exc)) from None
    meta = n1_metadata(product)
    stem = str(getattr(product, "product_name", "") or Path(path).stem)
    return [
        (radiance_stack(product), {"name": f"{stem} radiance", "metadata": meta,
                                   "colormap": "gray", "axis_labels": ("band", "line", "column"),
                                   "contrast_limits": _contrast_limits(product.radiance(7), None)},
         "image"),
        (quicklook_rgb(product), {"name": f"{stem} RGB 7-5-2", "rgb": True, "metadata": meta},
         "image"),
        (np.asarray(product.flags), {"name": f"{stem} flags", "metadata": meta,
                                     "opacity": 0.4, "visible": False}, "labels"),
    ]


def n1_metadata(product: MerisL1bProduct) -> dict[str, Any]:
    """Tie points and headers of a product, for the layer metadata."""
    return {
        "path": str(product.path), "product_type": product.product_type,
        "mph": dict(product.mph), "sph": dict(product.sph),
        "tie_points": {k: np.asarray(v) for k, v in product.tie_points.items()},
        "lines_per_tie_point": product.lines_per_tie_point,
        "samples_per_tie_point": product.samples_per_tie_point,
        "wavelengths": list(product.wavelengths),
        "column_order": "stored (chronological/detector)",
        "pixel_geolocation": bool(getattr(product, "has_pixel_geolocation", False)),
    }


def radiance_stack(product: MerisL1bProduct) -> Any:
    """The 15 radiance bands as a lazy (15, H, W) float32 dask array."""
    import dask
    import dask.array as da

    shape = (product.height, product.width)
    bands = [da.from_delayed(dask.delayed(product.radiance)(b), shape, dtype=np.float32)
             for b in range(1, 16)]
    return da.stack(bands)


def quicklook_rgb(product: MerisL1bProduct,
                  bands: tuple[int, int, int] = QUICKLOOK_BANDS) -> np.ndarray:
    """An RGB quick-look (H, W, 3) uint8 from three radiance bands, 1-99 % stretch each."""
    return stretch_rgb([product.radiance(b) for b in bands])

"""Layer builders for napari: the world frame, geocoded images and geometry layers.

World frame (one for every geocoded layer)
------------------------------------------
napari's world axes are (row, column) = (y, x) with y growing downwards. Every geocoded layer
(orthorectified outputs, DEMs, reference images) is placed in the coordinates of the output CRS
with **north up**::

    world y = -northing          world x = easting          (geographic CRS: -lat, lon)

A raster with the rasterio transform ``Affine(dx, 0, x0, 0, -dy, y0)`` (``OutputGrid`` convention,
(x0, y0) = upper-left corner) is shown with ``scale = (dy, dx)`` and
``translate = (-y0 + dy/2, x0 + dx/2)``: napari puts data pixel (i, j) centre at
``translate + scale * (i, j)``, which is the world position of the pixel centre
(x0 + (j + 0.5) dx, y0 - (i + 0.5) dy). Layers of different pixel sizes in the same CRS therefore
overlay exactly. A raster in another CRS is reprojected onto the frame's grid on load.

Geometry layers (footprint, tie-point facets, parallax vectors) are built directly in world
coordinates (no scale/translate), from lon/lat projected into the frame's CRS.

The georeference of a layer lives in ``layer.metadata["geo"]``: ``{"crs": WKT, "transform":
(a, b, c, d, e, f), "shape": (rows, cols)}``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import OptionsError

GEO_KEY = "geo"
EARTH_RADIUS_M = 6_370_997.0  # handbook eq. 2 sphere (section 2.4)


@dataclass(frozen=True)
class GeoFrame:
    """A north-up raster grid in a CRS: the world frame shared by the geocoded layers.

    (x0, y0) is the upper-left corner, (dx, dy) the positive pixel sizes (OutputGrid convention).
    """

    crs: str
    x0: float
    y0: float
    dx: float
    dy: float
    width: int
    height: int

    @classmethod
    def from_transform(cls, crs: Any, transform: Sequence[float], shape: Sequence[int]) -> GeoFrame:
        """Build a frame from a rasterio/affine transform (a, b, c, d, e, f) and (rows, cols)."""
        a, b, c, d, e, f = (float(v) for v in tuple(transform)[:6])
        if b != 0.0 or d != 0.0 or a <= 0.0 or e >= 0.0:
            raise OptionsError(f"raster is not north-up (transform {a, b, c, d, e, f})")
        return cls(crs_wkt(crs), c, f, a, -e, int(shape[-1]), int(shape[-2]))

    @classmethod
    def from_grid(cls, grid: Any) -> GeoFrame:
        """Build a frame from an ``engine.grid.OutputGrid`` (crs, x0, y0, dx, dy, width, height)."""
        return cls(crs_wkt(grid.crs), float(grid.x0), float(grid.y0), float(grid.dx),
                   float(grid.dy), int(grid.width), int(grid.height))

    @property
    def transform(self) -> tuple[float, float, float, float, float, float]:
        """The rasterio transform ``Affine(dx, 0, x0, 0, -dy, y0)`` as a 6-tuple."""
        return (self.dx, 0.0, self.x0, 0.0, -self.dy, self.y0)

    @property
    def scale(self) -> tuple[float, float]:
        """napari ``scale`` of a layer on this grid."""
        return (self.dy, self.dx)

    @property
    def translate(self) -> tuple[float, float]:
        """napari ``translate``: world position of the centre of pixel (0, 0)."""
        return (-self.y0 + 0.5 * self.dy, self.x0 + 0.5 * self.dx)

    @property
    def is_geographic(self) -> bool:
        from pyproj import CRS

        return CRS.from_user_input(self.crs).is_geographic

    def metadata(self) -> dict[str, Any]:
        """The ``layer.metadata["geo"]`` entry of a layer on this grid."""
        return {"crs": self.crs, "transform": self.transform, "shape": (self.height, self.width)}

    def same_grid(self, other: GeoFrame, rtol: float = 1e-9) -> bool:
        """True when both frames have the same CRS and pixel size (origins may differ)."""
        return same_crs(self.crs, other.crs) and np.allclose(
            (self.dx, self.dy), (other.dx, other.dy), rtol=rtol, atol=0.0)

    def pixel_centres(self, step: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Rows, cols and CRS (x, y) of the pixel centres on a regular subsample of ``step``."""
        rows = np.arange(step // 2, self.height, step)
        cols = np.arange(step // 2, self.width, step)
        rr, cc = np.meshgrid(rows, cols, indexing="ij")
        x = self.x0 + (cc + 0.5) * self.dx
        y = self.y0 - (rr + 0.5) * self.dy
        return rr.ravel(), cc.ravel(), x.ravel(), y.ravel()


def crs_wkt(crs: Any) -> str:
    """WKT of any CRS input (EPSG int, 'EPSG:32632', pyproj/rasterio CRS, WKT)."""
    from pyproj import CRS

    if hasattr(crs, "to_wkt"):
        return str(crs.to_wkt())
    try:
        return CRS.from_user_input(crs).to_wkt()
    except Exception as exc:  # pyproj.exceptions.CRSError
        raise OptionsError(f"unknown CRS {crs!r}: {exc}") from None


def same_crs(a: Any, b: Any) -> bool:
    """True when two CRS inputs describe the same coordinate system."""
    from pyproj import CRS

    return bool(CRS.from_user_input(crs_wkt(a)) == CRS.from_user_input(crs_wkt(b)))


def to_world(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """CRS (x, y) -> napari world (row, col) = (-y, x), shape (..., 2)."""
    return np.stack([-np.asarray(y, dtype=np.float64), np.asarray(x, dtype=np.float64)], axis=-1)


def from_world(world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """napari world (row, col) -> CRS (x, y)."""
    world = np.asarray(world, dtype=np.float64)
    return world[..., 1], -world[..., 0]


def lonlat_to_crs(lon: np.ndarray, lat: np.ndarray, crs: Any) -> tuple[np.ndarray, np.ndarray]:
    """Project WGS84 lon/lat (degrees) into ``crs`` (always x = easting/lon, y = northing/lat)."""
    from pyproj import CRS, Transformer

    target = CRS.from_user_input(crs_wkt(crs))
    transformer = Transformer.from_crs("EPSG:4326", target, always_xy=True)
    x, y = transformer.transform(np.asarray(lon, np.float64), np.asarray(lat, np.float64))
    return np.asarray(x, np.float64), np.asarray(y, np.float64)


# --------------------------------------------------------------------------------------------
# Frames of the layers in a viewer
# --------------------------------------------------------------------------------------------
def layer_frame(layer: Any) -> GeoFrame | None:
    """The GeoFrame of a geocoded layer (from ``metadata["geo"]``), else None."""
    geo = getattr(layer, "metadata", {}).get(GEO_KEY)
    if not geo:
        return None
    return GeoFrame.from_transform(geo["crs"], geo["transform"], geo["shape"])


def viewer_frame(layers: Iterable[Any]) -> GeoFrame | None:
    """The world frame of a viewer: the grid of its first (bottom-most) geocoded layer."""
    for layer in layers:
        frame = layer_frame(layer)
        if frame is not None:
            return frame
    return None


def geo_image_kwargs(frame: GeoFrame, **extra: Any) -> dict[str, Any]:
    """napari layer kwargs placing an image of ``frame`` in the world frame (see module doc)."""
    metadata = dict(extra.pop("metadata", {}) or {})
    metadata[GEO_KEY] = frame.metadata()
    return {"scale": frame.scale, "translate": frame.translate, "metadata": metadata, **extra}


def reproject_onto(data: np.ndarray, source: GeoFrame, target: GeoFrame, *,
                   nearest: bool = False, nodata: float = 0.0) -> np.ndarray:
    """Reproject a (rows, cols) or (bands, rows, cols) raster onto ``target``'s grid (rasterio)."""
    from rasterio.crs import CRS as RioCRS
    from rasterio.transform import Affine
    from rasterio.warp import Resampling, reproject

    arr = np.asarray(data)
    squeeze = arr.ndim == 2
    src = arr[None] if squeeze else arr
    dtype = src.dtype if src.dtype.kind in "fiu" and src.dtype.itemsize <= 8 else np.float32
    out = np.full((src.shape[0], target.height, target.width), nodata, dtype=dtype)
    method = Resampling.nearest if nearest or src.dtype.kind in "iu" else Resampling.bilinear
    for k in range(src.shape[0]):
        reproject(
            np.ascontiguousarray(src[k], dtype=dtype), out[k],
            src_transform=Affine(*source.transform), src_crs=RioCRS.from_wkt(source.crs),
            dst_transform=Affine(*target.transform), dst_crs=RioCRS.from_wkt(target.crs),
            resampling=method, src_nodata=nodata, dst_nodata=nodata,
        )
    return out[0] if squeeze else out


def place_on_frame(data: np.ndarray, source: GeoFrame, frame: GeoFrame | None,
                   *, nearest: bool = False) -> tuple[np.ndarray, GeoFrame]:
    """Data and grid of a raster placed in the world frame.

    Same CRS and pixel size: kept as is (scale/translate place it). Another CRS or pixel size:
    reprojected onto the frame's grid.
    """
    if frame is None or source.same_grid(frame):
        return data, source
    return reproject_onto(data, source, frame, nearest=nearest), frame


# --------------------------------------------------------------------------------------------
# Geometry layers
# --------------------------------------------------------------------------------------------
def footprint_polygons(tp_lat: np.ndarray, tp_lon: np.ndarray, crs: Any,
                       densify: int = 4) -> list[np.ndarray]:
    """World (row, col) vertices of the segment boundary (section 3.1, fig. 19) in ``crs``.

    The boundary is ``engine.boundary.segment_boundary`` of the tie points; one polygon, or
    several when it is cut at the antimeridian (fig. 20).
    """
    from .engine.boundary import segment_boundary

    boundary = segment_boundary(tp_lat, tp_lon)
    return [to_world(x, y) for x, y in boundary.polygons(crs_wkt(crs), densify=densify)]


def footprint_layer_data(tp_lat: np.ndarray, tp_lon: np.ndarray, crs: Any,
                         name: str = "footprint") -> tuple[list[np.ndarray], dict, str]:
    """A Shapes layer tuple: the footprint boundary polygon(s) with a transparent face."""
    polys = footprint_polygons(tp_lat, tp_lon, crs)
    kwargs = {
        "shape_type": "polygon", "name": name, "face_color": "transparent",
        "edge_color": "yellow", "edge_width": _edge_width(np.concatenate(polys)), "opacity": 1.0,
        "metadata": {"crs": crs_wkt(crs)},
    }
    return polys, kwargs, "shapes"


def facet_polygons(lat: np.ndarray, lon: np.ndarray, crs: Any) -> np.ndarray:
    """World vertices (n_facets, 4, 2) of the tie-point facets (quads of 4 tie points, 3.4)."""
    x, y = lonlat_to_crs(np.asarray(lon), np.asarray(lat), crs)
    w = to_world(x, y)  # (n_lines, n_cols, 2)
    quads = np.stack([w[:-1, :-1], w[:-1, 1:], w[1:, 1:], w[1:, :-1]], axis=2)
    return quads.reshape(-1, 4, 2)


def facets_layer_data(lat: np.ndarray, lon: np.ndarray, crs: Any,
                      name: str = "tie-point facets") -> tuple[list[np.ndarray], dict, str]:
    """A Shapes layer tuple: the grid of tie-point facets (transparent quads)."""
    quads = facet_polygons(lat, lon, crs)
    n_lines, n_cols = np.asarray(lat).shape
    kwargs = {
        "shape_type": "polygon", "name": name, "face_color": "transparent",
        "edge_color": "cyan", "edge_width": _edge_width(quads[0]) * 0.5, "opacity": 0.6,
        "visible": True,
        "features": {
            "tie_line": np.repeat(np.arange(n_lines - 1), n_cols - 1),
            "tie_column": np.tile(np.arange(n_cols - 1), n_lines - 1),
        },
    }
    return list(quads), kwargs, "shapes"


def _edge_width(poly: np.ndarray) -> float:
    """An edge width of about 1/400 of the polygon's extent (world units)."""
    extent = np.ptp(np.asarray(poly).reshape(-1, 2), axis=0).max()
    return float(max(extent / 400.0, 1e-9))


def parallax_vectors(frame: GeoFrame, shift_east: np.ndarray, shift_north: np.ndarray,
                     height: np.ndarray | None = None, *, step: int = 16,
                     exaggeration: float = 1.0, valid: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Parallax shift vectors on a regular subsample of output points (eq. 2, section 2.4).

    Each vector goes from the uncorrected position (ellipsoid point of the tie-point
    interpolation) to the corrected (terrain) position, i.e. along the shift (east, north) in
    metres, times ``exaggeration``. Returns (vectors (n, 2, 2) in world coords, heights (n,)).
    """
    rows, cols, x, y = frame.pixel_centres(step)
    east = np.asarray(shift_east, np.float64)[rows, cols]
    north = np.asarray(shift_north, np.float64)[rows, cols]
    keep = np.isfinite(east) & np.isfinite(north)
    if valid is not None:
        keep &= np.asarray(valid, bool)[rows, cols]
    rows, cols, x, y, east, north = (a[keep] for a in (rows, cols, x, y, east, north))
    if frame.is_geographic:
        lat = np.deg2rad(y)
        dx = np.rad2deg(east / (EARTH_RADIUS_M * np.cos(lat)))
        dy = np.rad2deg(north / EARTH_RADIUS_M)
    else:
        dx, dy = east, north
    dx, dy = dx * exaggeration, dy * exaggeration
    start = to_world(x - dx, y - dy)
    direction = to_world(dx, dy)
    vectors = np.stack([start, direction], axis=1)
    h = np.zeros(len(x)) if height is None else np.asarray(height, np.float64)[rows, cols]
    return vectors, h


def parallax_layer_data(frame: GeoFrame, shift_east: np.ndarray, shift_north: np.ndarray,
                        height: np.ndarray | None = None, *, step: int = 16,
                        exaggeration: float = 10.0, valid: np.ndarray | None = None,
                        name: str = "parallax shift") -> tuple[np.ndarray, dict, str]:
    """A Vectors layer tuple of the parallax shifts, coloured by height (viridis)."""
    vectors, h = parallax_vectors(frame, shift_east, shift_north, height, step=step,
                                  exaggeration=exaggeration, valid=valid)
    kwargs = {
        "name": name, "edge_width": max(frame.dx, frame.dy) * step / 5.0,
        "features": {"height": h}, "edge_color": "height", "edge_colormap": "viridis",
        "vector_style": "arrow", "length": 1.0,
        "metadata": {"exaggeration": exaggeration, "step": step},
    }
    return vectors, kwargs, "vectors"


# --------------------------------------------------------------------------------------------
# Orthorectified results
# --------------------------------------------------------------------------------------------
QUICKLOOK_BANDS = (7, 5, 2)


def contrast_limits(values: np.ndarray, background: float | None = 0.0) -> tuple[float, float]:
    """Contrast limits from the 1-99 percentiles of the valid pixels (background excluded)."""
    v = np.asarray(values, np.float64)
    good = np.isfinite(v)
    if background is not None:
        good &= v != background
    if not good.any():
        return (0.0, 1.0)
    lo, hi = np.percentile(v[good], [1.0, 99.0])
    return (float(lo), float(hi if hi > lo else lo + 1.0))


def stretch_rgb(channels: Sequence[np.ndarray], valid: np.ndarray | None = None) -> np.ndarray:
    """An RGB (H, W, 3) uint8 quick-look, 1-99 % stretch per channel, background black."""
    out = []
    for c in channels:
        c = np.asarray(c, np.float32)
        lo, hi = contrast_limits(c)
        out.append(np.clip((c - lo) / (hi - lo) * 255.0, 0, 255).astype(np.uint8))
    rgb = np.stack(out, axis=-1)
    if valid is not None:
        rgb[~np.asarray(valid, bool)] = 0
    return rgb


def band_layers(bands: dict[int, np.ndarray], frame: GeoFrame, name: str,
                meta: dict[str, Any] | None = None, valid: np.ndarray | None = None
                ) -> list[tuple[Any, dict, str]]:
    """Image layers of radiance bands on ``frame``: an RGB 7-5-2 quick-look when those bands
    are present, then one grey layer per band (background 0)."""
    layers: list[tuple[Any, dict, str]] = []
    base = dict(meta or {})
    if all(b in bands for b in QUICKLOOK_BANDS):
        rgb = stretch_rgb([bands[b] for b in QUICKLOOK_BANDS], valid)
        layers.append((rgb, geo_image_kwargs(frame, name=f"{name} RGB 7-5-2", rgb=True,
                                             metadata=dict(base, bands=QUICKLOOK_BANDS)),
                       "image"))
    for b in sorted(bands):
        data = np.asarray(bands[b])
        kwargs = geo_image_kwargs(frame, name=f"{name} band {b}", colormap="gray",
                                  contrast_limits=contrast_limits(data),
                                  metadata=dict(base, band=b), visible=False)
        layers.append((data, kwargs, "image"))
    return layers


def diagnostic_layers(diagnostics: dict[str, np.ndarray], frame: GeoFrame, name: str,
                      dem_names: Sequence[str] = ()) -> list[tuple[Any, dict, str]]:
    """Iteration-count, elevation and elevation-source images of an OrthoResult (section 3.2,
    Appendix B statistics). Elevation source codes: 0..n-1 DEM index, -1 tie points, -2 none;
    shown as labels 1..n for the DEMs, n+1 tie points, 0 none."""
    layers: list[tuple[Any, dict, str]] = []
    if "iterations" in diagnostics:
        it = np.asarray(diagnostics["iterations"]).astype(np.int16)
        layers.append((it, geo_image_kwargs(
            frame, name=f"{name} iterations", colormap="turbo", visible=False,
            contrast_limits=(-1.0, float(max(int(it.max()), 1)))), "image"))
    if "elevation" in diagnostics:
        h = np.asarray(diagnostics["elevation"], np.float32)
        layers.append((h, geo_image_kwargs(
            frame, name=f"{name} elevation", colormap="gist_earth", visible=False,
            contrast_limits=contrast_limits(h, None)), "image"))
    if "elevation_source" in diagnostics:
        src = np.asarray(diagnostics["elevation_source"]).astype(np.int16)
        n = len(dem_names)
        labels = np.where(src >= 0, src + 1, np.where(src == -1, n + 1, 0)).astype(np.uint8)
        legend = {i + 1: str(d) for i, d in enumerate(dem_names)} | {n + 1: "tie points"}
        layers.append((labels, geo_image_kwargs(
            frame, name=f"{name} elevation source", visible=False, opacity=0.5,
            metadata={"legend": legend}), "labels"))
    return layers


def geometry_layers(tie_points: dict[str, np.ndarray], frame: GeoFrame, name: str,
                    diagnostics: dict[str, np.ndarray] | None = None, *,
                    valid: np.ndarray | None = None, exaggeration: float = 10.0,
                    step: int = 16) -> list[tuple[Any, dict, str]]:
    """Footprint boundary, tie-point facets and (with diagnostics) parallax shift vectors."""
    lat, lon = tie_points["latitude"], tie_points["longitude"]
    fp_data, fp_kwargs, fp_kind = footprint_layer_data(lat, lon, frame.crs,
                                                       name=f"{name} footprint")
    fa_data, fa_kwargs, fa_kind = facets_layer_data(lat, lon, frame.crs,
                                                    name=f"{name} tie-point facets")
    fa_kwargs["visible"] = False
    layers: list[tuple[Any, dict, str]] = [(fa_data, fa_kwargs, fa_kind),
                                            (fp_data, fp_kwargs, fp_kind)]
    if diagnostics and "shift_east_m" in diagnostics:
        layers.append(parallax_layer_data(
            frame, diagnostics["shift_east_m"], diagnostics["shift_north_m"],
            diagnostics.get("elevation"), step=step, exaggeration=exaggeration, valid=valid,
            name=f"{name} parallax shift"))
    return layers


# --------------------------------------------------------------------------------------------
# Moving layers into another world frame (another CRS)
# --------------------------------------------------------------------------------------------
def transform_world(points: np.ndarray, source_crs: Any, target_crs: Any) -> np.ndarray:
    """World (row, col) points of ``source_crs`` -> world points of ``target_crs``."""
    from pyproj import Transformer

    x, y = from_world(points)
    tr = Transformer.from_crs(crs_wkt(source_crs), crs_wkt(target_crs), always_xy=True)
    tx, ty = tr.transform(x, y)
    return to_world(np.asarray(tx), np.asarray(ty))


def move_to_frame(layer: tuple[Any, dict, str], source: GeoFrame, target: GeoFrame
                  ) -> tuple[Any, dict, str]:
    """A layer tuple built on ``source`` placed in the world frame ``target``.

    Rasters (images, labels) are reprojected onto the target grid (nearest for labels and
    integer images, bilinear otherwise); shapes and vectors have their vertices projected.
    """
    data, kwargs, kind = layer
    kwargs = dict(kwargs)
    if kind in ("image", "labels"):
        rgb = bool(kwargs.get("rgb"))
        arr = np.moveaxis(np.asarray(data), -1, 0) if rgb else np.asarray(data)
        nearest = kind == "labels" or arr.dtype.kind in "iu" and not rgb
        out = reproject_onto(arr, source, target, nearest=nearest)
        if rgb:
            out = np.moveaxis(out, 0, -1).astype(np.asarray(data).dtype)
        meta = dict(kwargs.pop("metadata", {}) or {})
        meta["reprojected_from"] = source.metadata()
        kwargs.update(geo_image_kwargs(target, metadata=meta))
        return out, kwargs, kind
    if kind == "shapes":
        return [transform_world(p, source.crs, target.crs) for p in data], kwargs, kind
    if kind == "vectors":
        vec = np.asarray(data, np.float64)
        start = transform_world(vec[:, 0], source.crs, target.crs)
        end = transform_world(vec[:, 0] + vec[:, 1], source.crs, target.crs)
        return np.stack([start, end - start], axis=1), kwargs, kind
    return layer

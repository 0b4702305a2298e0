"""napari sample data: a simulated MERIS FR scene, mapped without and with terrain correction.

The scene is generated on first use by the simulator (``simulate.generate_scene``, cached in
``$MERIS_ORTHO_CACHE`` or ``~/.cache/napari-meris-ortho``) with a napari progress bar; the
two mappings (MERSYN use case 3 with ``-ort NO`` and with the DEM, handbook sections 3.1-3.4)
are computed on each load (about a second for fr-small). Every layer is placed in one world
frame: the output grid in the UTM zone of the footprint (``_layers`` module doc); the DEM and
the reference image are reprojected onto it, so the flicker of handbook section 4.4 compares
them pixel to pixel.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..geometry.grid import OutputGrid
from ..progress import ProgressCallback
from .geometry_layers import geometry_layers
from .product_layers import band_layers, contrast_limits
from .world import geo_image_kwargs, reproject_onto

SAMPLE_BANDS = (2, 5, 7)
REFERENCE_BAND = 7
LayerData = tuple[Any, dict[str, Any], str]


@dataclass
class SampleScene:
    """A generated scene with its two mappings on the same output grid."""

    name: str
    scene: Any
    frame: OutputGrid
    uncorrected: dict[int, np.ndarray]
    orthorectified: dict[int, np.ndarray]
    valid: np.ndarray
    diagnostics: dict[str, np.ndarray]
    tie_points: Mapping[str, np.ndarray]


def _stage(progress: ProgressCallback | None, start: int, span: int) -> ProgressCallback | None:
    """A callback mapping a stage's (done, total) onto [start, start + span] of 100."""
    if progress is None:
        return None
    return lambda done, total: progress(start + int(span * done / max(total, 1)), 100)


def build_sample(name: str, progress: ProgressCallback | None = None,
                 out_dir: str | Path | None = None) -> SampleScene:
    """Generate (or load) scene ``name`` and its uncorrected and orthorectified mappings."""
    from ..engine.boundary import segment_boundary
    from ..geometry.grid import default_grid, utm_crs_for
    from ..ortho import orthorectify
    from ..products.n1 import read_product
    from ..simulate.scene import generate_scene

    scene = generate_scene(name, out_dir=out_dir, progress=_stage(progress, 0, 50))
    product = read_product(scene.product_path)
    tp = product.tie_points
    boundary = segment_boundary(tp["latitude"], tp["longitude"])
    crs = utm_crs_for(float(np.mean(tp["longitude"])), float(np.mean(tp["latitude"])))
    grid = default_grid(boundary, crs=crs, pixel_size=260.0)
    dem = scene.dem_paths["geotiff"]
    flat = orthorectify(product, grid, elevation="none", bands=SAMPLE_BANDS,
                        progress=_stage(progress, 50, 15))
    ortho = orthorectify(product, grid, dems=[dem], elevation="dem", bands=SAMPLE_BANDS,
                         diagnostics=True, progress=_stage(progress, 65, 35))
    if progress is not None:
        progress(100, 100)
    return SampleScene(name, scene, grid, flat.bands, ortho.bands,
                       ortho.valid, ortho.diagnostics, tp)


def _raster_on_frame(path: Path, band: int, frame: OutputGrid) -> np.ndarray:
    """One band of a GeoTIFF reprojected onto the frame's grid (bilinear)."""
    import rasterio

    with rasterio.open(path) as ds:
        data = ds.read(band)
        source = OutputGrid.from_transform(ds.crs, tuple(ds.transform), (ds.height, ds.width))
    return reproject_onto(data.astype(np.float32), source, frame)


def _reference_band_index(path: Path, band: int) -> int:
    """1-based index of MERIS ``band`` in the reference GeoTIFF (descriptions 'band N ...')."""
    import rasterio

    with rasterio.open(path) as ds:
        for i, d in enumerate(ds.descriptions):
            if d and d.split()[:2] == ["band", str(band)]:
                return i + 1
    return 1


def sample_layers(sample: SampleScene) -> list[LayerData]:
    """Reference image, DEM, uncorrected and orthorectified mappings and geometry layers."""
    frame, scene = sample.frame, sample.scene
    layers: list[LayerData] = []
    if scene.reference_path is not None:
        ref = _raster_on_frame(scene.reference_path,
                               _reference_band_index(scene.reference_path, REFERENCE_BAND), frame)
        ref[~sample.valid] = 0
        layers.append((ref, geo_image_kwargs(
            frame, name=f"reference b{REFERENCE_BAND}", colormap="gray",
            contrast_limits=contrast_limits(ref), metadata={"path": str(scene.reference_path)}),
            "image"))
    dem = _raster_on_frame(scene.dem_paths["geotiff"], 1, frame)
    layers.append((dem, geo_image_kwargs(frame, name="DEM", colormap="gist_earth",
                                         contrast_limits=contrast_limits(dem, None),
                                         metadata={"units": "m"}, visible=False), "image"))
    layers += band_layers(sample.uncorrected, frame, "uncorrected",
                          {"elevation": "none"}, sample.uncorrected[7] > 0)
    layers += band_layers(sample.orthorectified, frame, "orthorectified",
                          {"elevation": "dem"}, sample.valid)
    layers += geometry_layers(sample.tie_points, frame, "", sample.diagnostics,
                              valid=sample.valid, exaggeration=10.0,
                              step=max(8, max(frame.width, frame.height) // 60))
    return layers


def _napari_progress(name: str) -> tuple[Any, ProgressCallback]:
    from napari.utils import progress

    bar = progress(total=100, desc=f"MERIS sample {name}")

    def update(done: int, total: int) -> None:
        target = int(100 * done / max(total, 1))
        bar.update(max(target - bar.n, 0))

    return bar, update


def _make(name: str) -> list[LayerData]:
    from .status import show_map_coordinates

    show_map_coordinates(_current_viewer())
    bar, update = _napari_progress(name)
    try:
        return sample_layers(build_sample(name, update))
    finally:
        bar.close()


def _current_viewer() -> Any:
    try:
        import napari

        return napari.current_viewer()
    except Exception:  # no Qt application
        return None


def make_sample_alps() -> list[LayerData]:
    """Sample "fr-alps": the default 2241 x 2241 FR scene (generated on first use)."""
    return _make("fr-alps")


def make_sample_small() -> list[LayerData]:
    """Sample "fr-small": 320 x 513 pixels of the same scene (seconds to generate)."""
    return _make("fr-small")

"""Product layers of the napari front end: radiance bands (an RGB 7-5-2 quick-look and one grey
layer per band) and the diagnostics of an orthorectification (iterations, elevation and its
source), all placed in the world frame (``world``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..display import contrast_limits, stretch_rgb
from ..geometry.grid import OutputGrid
from .world import geo_image_kwargs

QUICKLOOK_BANDS = (7, 5, 2)


def band_layers(bands: dict[int, np.ndarray], frame: OutputGrid, prefix: str,
                meta: dict[str, Any] | None = None, valid: np.ndarray | None = None,
                suffix: str = "") -> list[tuple[Any, dict, str]]:
    """Image layers of radiance bands on ``frame``: an RGB 7-5-2 quick-look when those bands
    are present ("<prefix> RGB 7-5-2<suffix>"), then one grey layer per band
    ("<prefix> b7<suffix>", background 0), hidden under the quick-look; without one, the grey
    layer of the first band given is shown."""
    layers: list[tuple[Any, dict, str]] = []
    base = dict(meta or {})
    limits = {b: contrast_limits(bands[b]) for b in bands}
    quicklook = all(b in bands for b in QUICKLOOK_BANDS)
    shown = None if quicklook or not bands else next(iter(bands))
    if quicklook:
        rgb = stretch_rgb([bands[b] for b in QUICKLOOK_BANDS], valid,
                          [limits[b] for b in QUICKLOOK_BANDS])
        layers.append((rgb, geo_image_kwargs(frame, name=f"{prefix} RGB 7-5-2{suffix}", rgb=True,
                                             metadata=dict(base, bands=QUICKLOOK_BANDS)),
                       "image"))
    for b in sorted(bands):
        data = np.asarray(bands[b])
        kwargs = geo_image_kwargs(frame, name=f"{prefix} b{b}{suffix}", colormap="gray",
                                  contrast_limits=limits[b],
                                  metadata=dict(base, band=b), visible=b == shown)
        layers.append((data, kwargs, "image"))
    return layers


def elevation_source_features(dem_names: Sequence[str]) -> dict[str, list[Any]]:
    """Legend of the elevation-source labels: 0 none, 1..n the DEMs, n+1 the tie points."""
    names = ["none", *(str(d) for d in dem_names), "tie points"]
    return {"index": list(range(len(names))), "source": names}


def diagnostic_layers(diagnostics: dict[str, np.ndarray], frame: OutputGrid, suffix: str = "",
                      dem_names: Sequence[str] = ()) -> list[tuple[Any, dict, str]]:
    """Iteration-count, elevation and elevation-source images of an OrthoResult (section 3.2,
    Appendix B statistics), named "iterations", "elevation", "elevation source" + ``suffix``.
    Elevation source codes: 0..n-1 DEM index, -1 tie points, -2 none; shown as labels 1..n for
    the DEMs, n+1 tie points, 0 none, with the DEM names as features (status bar)."""
    layers: list[tuple[Any, dict, str]] = []
    if "iterations" in diagnostics:
        it = np.asarray(diagnostics["iterations"]).astype(np.int16)
        layers.append((it, geo_image_kwargs(
            frame, name=f"iterations{suffix}", colormap="turbo", visible=False,
            contrast_limits=(-1.0, float(max(int(it.max()), 1)))), "image"))
    if "elevation" in diagnostics:
        h = np.asarray(diagnostics["elevation"], np.float32)
        layers.append((h, geo_image_kwargs(
            frame, name=f"elevation{suffix}", colormap="gist_earth", visible=False,
            contrast_limits=contrast_limits(h, None), metadata={"units": "m"}), "image"))
    if "elevation_source" in diagnostics:
        src = np.asarray(diagnostics["elevation_source"]).astype(np.int16)
        n = len(dem_names)
        labels = np.where(src >= 0, src + 1, np.where(src == -1, n + 1, 0)).astype(np.uint8)
        layers.append((labels, geo_image_kwargs(
            frame, name=f"elevation source{suffix}", visible=False, opacity=0.5,
            features=elevation_source_features(dem_names)), "labels"))
    return layers

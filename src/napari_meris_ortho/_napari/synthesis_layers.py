"""napari layers of a synthesis store: every layer multiscale (the full-resolution arrays and
the overviews written with the store, read lazily chunk by chunk, so a Europe-size synthesis
pans smoothly), and the winning product as a labels layer whose tooltip names the product."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..display import contrast_limits
from ..synthesis import store as st
from ..synthesis.reading import SynthesisStore, open_synthesis
from .world import geo_image_kwargs

LayerData = tuple[Any, dict[str, Any], str]


def is_store(path: str | Path) -> bool:
    """True when ``path`` is an Icechunk repository (a synthesis store, maybe)."""
    return Path(path).is_dir() and st.is_repository(path)


def pyramid(store: SynthesisStore, name: str) -> list[Any]:
    """Lazy zarr arrays of layer ``name``: full resolution, then each overview level."""
    session_store = store.session.store
    levels = [st.open_layer(session_store, name, level) for level in (1, *store.overviews)]
    scale = st.stored_scale(levels[0])
    if scale is None:
        return levels
    import dask.array as da

    # compact band layers: uint16 counts decoded to radiances chunk by chunk, lazily
    return [da.from_zarr(level).astype(np.float32) * np.float32(scale) for level in levels]


def store_layers(path: str | Path, at: str | None = None) -> list[LayerData]:
    """Bands, NDVI, count and winning product of the synthesis ``path`` (at snapshot ``at``)."""
    store = open_synthesis(path, at=at)
    grid = store.grid
    stem = Path(path).name
    meta = {"synthesis": str(path), "snapshot": store.snapshot, "algorithm": store.algorithm}
    layers: list[LayerData] = []
    for name in store.layers():
        levels = pyramid(store, name)
        kwargs = geo_image_kwargs(grid, name=f"{stem} {name}", metadata=dict(meta),
                                  multiscale=len(levels) > 1)
        if name == "product":
            layers.append((levels if len(levels) > 1 else levels[0],
                           {**kwargs, "features": product_features(store), "opacity": 0.5,
                            "visible": False}, "labels"))
            continue
        coarse = np.asarray(levels[-1][:])
        kwargs.update(colormap="gray", visible=name.startswith("band_"),
                      contrast_limits=contrast_limits(coarse, 0.0))
        layers.append((levels if len(levels) > 1 else levels[0], kwargs, "image"))
    return layers


def product_features(store: SynthesisStore) -> dict[str, list[Any]]:
    """Labels features: the product of each index (0: background) and its sensing time."""
    table = sorted(store.products, key=lambda p: int(p["index"]))
    return {"index": [0] + [int(p["index"]) for p in table],
            "product": ["(none)"] + [str(p["product_name"]) for p in table],
            "sensing_start": [""] + [str(p.get("sensing_start", "")) for p in table]}

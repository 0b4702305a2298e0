"""napari layers of a synthesis store: every layer multiscale (the full-resolution arrays and
the overviews written with the store, read lazily chunk by chunk, so a Europe-size synthesis
pans smoothly), and the winning product as a labels layer whose tooltip names the product."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..display import contrast_limits
from ..synthesis import store as st
from ..synthesis.reading import DecodedLayer, SynthesisStore, open_synthesis
from .world import geo_image_kwargs

LayerData = tuple[Any, dict[str, Any], str]


def is_store(path: str | Path) -> bool:
    """True when ``path`` is an Icechunk repository (a synthesis store, maybe)."""
    return Path(path).is_dir() and st.is_repository(path)


def pyramid(store: SynthesisStore, name: str) -> list[Any]:
    """Layer ``name`` at full resolution, then at each overview level: read window by window
    as napari asks (``DecodedLayer``: compact band counts decoded to radiances)."""
    session_store = store.session.store
    return [DecodedLayer(st.open_layer(session_store, name, level))
            for level in (1, *store.overviews)]


def coarse_limits(store: SynthesisStore, name: str, levels: list[Any]) -> tuple[float, float]:
    """Contrast limits from the coarsest level, over the bounding box of its written chunks
    only (``store.written_window``): a Europe-size store holding one product reads 2 of its
    315 coarsest chunks, not all of them (4.6 s of napari's open, on the event loop)."""
    factor = store.overviews[-1] if len(levels) > 1 else 1
    window = st.written_window(store.session.store, name, factor)
    if window is None:
        return (0.0, 1.0)
    r0, r1, c0, c1 = window
    return contrast_limits(levels[-1][r0:r1, c0:c1], 0.0)


def store_layers(path: str | Path, at: str | None = None) -> list[LayerData]:
    """Bands, NDVI, count and winning product of the synthesis ``path`` (at snapshot ``at``).
    Only the last band is visible (the top layer: the bands under it would be drawn, read
    and hidden by it)."""
    store = open_synthesis(path, at=at)
    grid = store.grid
    stem = Path(path).name
    meta = {"synthesis": str(path), "snapshot": store.snapshot, "algorithm": store.algorithm}
    layers: list[LayerData] = []
    top = st.band_layer(store.bands[-1])
    for name in store.layers():
        levels = pyramid(store, name)
        kwargs = geo_image_kwargs(grid, name=f"{stem} {name}", metadata=dict(meta),
                                  multiscale=len(levels) > 1)
        if name == "product":
            layers.append((levels if len(levels) > 1 else levels[0],
                           {**kwargs, "features": product_features(store), "opacity": 0.5,
                            "visible": False}, "labels"))
            continue
        kwargs.update(colormap="gray", visible=name == top,
                      contrast_limits=coarse_limits(store, name, levels))
        layers.append((levels if len(levels) > 1 else levels[0], kwargs, "image"))
    return layers


def product_features(store: SynthesisStore) -> dict[str, list[Any]]:
    """Labels features: the product of each index (0: background) and its sensing time."""
    table = sorted(store.products, key=lambda p: int(p["index"]))
    return {"index": [0] + [int(p["index"]) for p in table],
            "product": ["(none)"] + [str(p["product_name"]) for p in table],
            "sensing_start": [""] + [str(p.get("sensing_start", "")) for p in table]}

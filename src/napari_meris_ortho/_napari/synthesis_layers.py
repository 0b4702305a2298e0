"""napari layers of a synthesis store: every layer multiscale (the full-resolution arrays and
the overviews written with the store, read lazily chunk by chunk, so a Europe-size synthesis
pans smoothly), and the winning product as a labels layer whose tooltip names the product."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..display import contrast_limits
from ..products.n1.format import APPENDIX_A_WAVELENGTHS
from ..synthesis import store as st
from ..synthesis.reading import DecodedLayer, DecodedStack, SynthesisStore, open_synthesis
from .product_layers import NDVI_LEGEND, count_legend
from .status import BAND_AXIS
from .world import geo_image_kwargs

LayerData = tuple[Any, dict[str, Any], str]


def is_store(path: str | Path) -> bool:
    """True when ``path`` is an Icechunk repository (a synthesis store, maybe)."""
    return Path(path).is_dir() and st.is_repository(path)


def pyramids(store: SynthesisStore) -> dict[str, list[DecodedLayer]]:
    """Every layer at full resolution, then at each overview level: read window by window as
    napari asks (``DecodedLayer``: compact band counts decoded to radiances), only where the
    store holds values: the box of the ``count`` layer's written chunks (every product that
    touched a chunk counted there, so it holds every layer's), at each level's scale."""
    levels = (1, *store.overviews)
    session_store = store.session.store
    arrays = st.open_layers(session_store, store.layers(), levels)
    box = st.written_window(session_store, "count", arrays["count", 1])

    def at(level: int, shape: tuple[int, ...]) -> tuple[int, int, int, int] | None:
        if box is None:
            return None
        r0, r1, c0, c1 = box
        return (r0 // level, min(-(-r1 // level), shape[0]),
                c0 // level, min(-(-c1 // level), shape[1]))

    return {name: [DecodedLayer(arrays[name, level],
                                at(level, tuple(arrays[name, level].shape)), known=True,
                                ndvi=name == "ndvi")
                   for level in levels]
            for name in store.layers()}


def coarse_limits(pyramids: dict[str, list[DecodedLayer]]) -> dict[str, tuple[float, float]]:
    """Contrast limits of each layer from its coarsest level, inside the box of the store's
    written chunks only (``DecodedLayer.written``): a Europe-size store holding one product
    reads the 16 of its 315 coarsest chunks inside that box, not all of them (reading all
    would cost 4.6 s of napari's open, on the event loop)."""
    out = {}
    for name, levels in pyramids.items():
        window = levels[-1].written
        if window is None:
            out[name] = (0.0, 1.0)
            continue
        r0, r1, c0, c1 = window
        out[name] = contrast_limits(levels[-1][r0:r1, c0:c1], 0.0)
    return out


def store_layers(path: str | Path, at: str | None = None) -> list[LayerData]:
    """The radiance of the synthesis ``path`` (at snapshot ``at``), its NDVI, count and
    winning product. Bands evenly spaced (all 15, the default; one; 7 and 13) go in one
    ``radiance`` stack whose band axis is the MERIS band number, as an N1's does (one layer
    to insert, not 15: napari inserts a layer in about 0.1 s, on its event loop); others as a
    layer per band, the last one visible (the top layer hides the others)."""
    store = open_synthesis(path, at=at)
    grid = store.grid
    stem = Path(path).name
    names = pyramids(store)
    box = names["count"][0].written
    meta = {"synthesis": str(path), "snapshot": store.snapshot, "algorithm": store.algorithm,
            "data_window": None if box is None else list(box)}
    layers: list[LayerData] = []
    bands = store.bands
    limits = coarse_limits({n: v for n, v in names.items() if n not in ("product", "ndvi")})
    steps = set(np.diff(bands).tolist())
    if len(steps) <= 1:
        step = steps.pop() if steps else 1
        band_names = [st.band_layer(b) for b in bands]
        stack = [DecodedStack([names[n][k] for n in band_names])
                 for k in range(len(names[band_names[0]]))]
        kwargs = geo_image_kwargs(grid, name=f"{stem} radiance", metadata={
            **meta, "band_names": [f"band {b} ({w:.0f} nm)"
                                   for b, w in enumerate(APPENDIX_A_WAVELENGTHS, 1)]},
            multiscale=len(stack) > 1, colormap="gray",
            contrast_limits=(min(limits[n][0] for n in band_names),
                             max(limits[n][1] for n in band_names)))
        kwargs.update(scale=(float(step), *kwargs["scale"]),
                      translate=(float(bands[0]), *kwargs["translate"]),
                      units=("pixel", *kwargs["units"]),
                      axis_labels=(BAND_AXIS, *kwargs["axis_labels"]))
        layers.append((stack if len(stack) > 1 else stack[0], kwargs, "image"))
        names = {n: v for n, v in names.items() if n not in band_names}
    top = st.band_layer(bands[-1])
    band_of = {st.band_layer(b): b for b in bands}
    for name, levels in names.items():
        extra = {"band": band_of[name]} if name in band_of else {}
        kwargs = geo_image_kwargs(grid, name=f"{stem} {name}", metadata={**meta, **extra},
                                  multiscale=len(levels) > 1)
        if name == "product":
            layers.append((levels if len(levels) > 1 else levels[0],
                           {**kwargs, "features": product_features(store), "opacity": 0.5,
                            "visible": False}, "labels"))
            continue
        ndvi = name == "ndvi"  # as the widget shows it
        kwargs.update(colormap="RdYlGn" if ndvi else "gray", visible=name == top,
                      contrast_limits=(-1.0, 1.0) if ndvi else limits[name])
        if ndvi or name == "count":
            key = NDVI_LEGEND if ndvi else count_legend(limits[name][1], "black 0", "white", "")
            kwargs["metadata"] = {**kwargs["metadata"], "legend": key}
        layers.append((levels if len(levels) > 1 else levels[0], kwargs, "image"))
    return layers


def product_features(store: SynthesisStore) -> dict[str, list[Any]]:
    """Labels features: the product of each index (0: background) and its sensing time."""
    table = sorted(store.products, key=lambda p: int(p["index"]))
    return {"index": [0] + [int(p["index"]) for p in table],
            "product": ["(none)"] + [str(p["product_name"]) for p in table],
            "sensing_start": [""] + [str(p.get("sensing_start", "")) for p in table]}


def data_extent(layers: list[LayerData]) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """World box (low and high (row, column) corners) of the pixels a store's layers hold
    (their ``data_window``, rows and columns of the grid); None when empty."""
    if not layers:
        return None
    kwargs = layers[0][1]
    window = kwargs["metadata"].get("data_window")
    if window is None:
        return None
    r0, r1, c0, c1 = window
    (sy, sx), (ty, tx) = kwargs["scale"][-2:], kwargs["translate"][-2:]
    # translate: the centre of pixel (0, 0); the box runs from pixel edge to pixel edge
    return ((ty + (r0 - 0.5) * sy, tx + (c0 - 0.5) * sx),
            (ty + (r1 - 0.5) * sy, tx + (c1 - 0.5) * sx))

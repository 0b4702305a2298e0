"""Product layers of the napari front end: radiance bands (an RGB quick-look of the sensor's
true-colour bands, "RGB 7-5-2" for MERIS, "RGB 8-6-3" for OLCI, and one grey layer per
band) and the diagnostics of an orthorectification (iterations, elevation and its
source), all placed in the world frame (``world``)."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from ..bands import MERIS, BandTable
from ..display import contrast_limits, stretch_rgb
from ..geometry.grid import OutputGrid
from .world import geo_image_kwargs

#: the MERIS quick-look bands (red, green, blue)
QUICKLOOK_BANDS = MERIS.true_colour
#: a band's short label in layer names: "b7" for MERIS band 7; a sensor whose bands are named
#: otherwise gives its own function (an OLCI product: "Oa08")
BandLabel = Callable[[int], str]


def meris_band_label(band: int) -> str:
    """'b7': MERIS band 7 in a layer name."""
    return f"b{band}"


def quicklook_name(table: BandTable) -> str:
    """'RGB 7-5-2' (MERIS), 'RGB 8-6-3' (OLCI): the quick-look layer's name."""
    return "RGB " + "-".join(str(b) for b in table.true_colour)


def one_image_shown(layers: list[tuple[Any, dict, str]]) -> list[tuple[Any, dict, str]]:
    """The first view of a set of layers: only the last visible image (the newest result)
    stays visible, every other image and labels layer hidden, ready to toggle or flicker;
    geometry layers (vectors) untouched, above the images."""
    shown = [k for k, (_, kwargs, kind) in enumerate(layers)
             if kind == "image" and kwargs.get("visible", True)]
    for k, (_, kwargs, kind) in enumerate(layers):
        if kind in ("image", "labels") and (not shown or k != shown[-1]):
            kwargs["visible"] = False
    images = [layer for layer in layers if layer[2] != "vectors"]
    return images + [layer for layer in layers if layer[2] == "vectors"]


def band_layers(bands: dict[int, np.ndarray], frame: OutputGrid, prefix: str,
                meta: dict[str, Any] | None = None, valid: np.ndarray | None = None,
                suffix: str = "", label: BandLabel = meris_band_label,
                table: BandTable = MERIS) -> list[tuple[Any, dict, str]]:
    """Image layers of radiance bands on ``frame``: an RGB quick-look of ``table``'s
    true-colour bands when they are present ("<prefix> RGB 7-5-2<suffix>", OLCI's "RGB 8-6-3"),
    then one grey layer per band ("<prefix> b7<suffix>", ``label`` naming the band; background
    0), hidden under the quick-look; without one, the grey layer of the first band given is
    shown."""
    layers: list[tuple[Any, dict, str]] = []
    base = dict(meta or {})
    limits = {b: contrast_limits(bands[b]) for b in bands}
    colour = table.true_colour
    quicklook = all(b in bands for b in colour)
    shown = None if quicklook or not bands else next(iter(bands))
    if quicklook:
        rgb = stretch_rgb([bands[b] for b in colour], valid, [limits[b] for b in colour])
        layers.append((rgb, geo_image_kwargs(frame, name=f"{prefix} {quicklook_name(table)}"
                                             f"{suffix}", rgb=True,
                                             metadata=dict(base, bands=colour)),
                       "image"))
    for b in sorted(bands):
        data = np.asarray(bands[b])
        kwargs = geo_image_kwargs(frame, name=f"{prefix} {label(b)}{suffix}", colormap="gray",
                                  contrast_limits=limits[b],
                                  metadata=dict(base, band=b), visible=b == shown)
        layers.append((data, kwargs, "image"))
    return layers


#: the colour key of an NDVI layer (RdYlGn over -1..1)
NDVI_LEGEND = "NDVI (band 13 - band 7) / (band 13 + band 7), red -1 → yellow 0 → green +1"


def zero_transparent(name: str, top: float) -> Any:
    """napari colormap ``name`` over contrast limits (0, ``top``) with 0 transparent: a count
    layer's background outside every footprint shows the layers below, not a colour."""
    import numpy as np
    from napari.utils.colormaps import Colormap, ensure_colormap

    colors = np.asarray(ensure_colormap(name).colors, np.float32)
    edge = min(0.5 / max(top, 1.0), 0.5)  # half a count above 0
    controls = np.concatenate([[0.0], edge + (1.0 - edge) * np.linspace(0.0, 1.0, len(colors))])
    return Colormap(colors=np.vstack([[0.0, 0.0, 0.0, 0.0], colors]), controls=controls,
                    name=f"{name} (0 transparent)")


def count_legend(top: float, low: str = "dark purple 1", high: str = "yellow",
                 none: str = "; none: transparent") -> str:
    """The colour key of a count layer: the number of products with a valid pixel."""
    return f"products with a valid pixel, {low} → {high} {top:.0f}{none}"


#: colours of the DEMs in the elevation-source layer, in the order they are tried (then again)
DEM_COLOURS = ("orange", "deepskyblue", "magenta", "lime", "yellow")


def source_colours(n_dems: int) -> dict[int, str]:
    """Label -> colour of the elevation-source layer: the DEMs in ``DEM_COLOURS``, the tie
    points red, none transparent."""
    colours = {k + 1: DEM_COLOURS[k % len(DEM_COLOURS)] for k in range(n_dems)}
    return {0: "transparent", **colours, n_dems + 1: "red"}


def category_colormap(colours: Mapping[int, str]) -> Any:
    """The colours of labels 1..n (``colours[k]``; 0 the transparent background) as napari's
    cyclic label colormap of n + 1 colours, which maps labels 1..n to them one to one. A
    direct (dict) colormap would make napari build a numba typed dict, compiled in the Qt
    thread the first time a layer is drawn (over a second); the cyclic one maps uint8 labels
    with numpy."""
    from napari.utils.colormaps import CyclicLabelColormap

    n = max(colours)
    return CyclicLabelColormap(
        colors=["transparent", *(colours.get(k, "transparent") for k in range(1, n + 1))],
        background_value=0)


def elevation_source_features(dem_names: Sequence[str]) -> dict[str, list[Any]]:
    """Legend of the elevation-source labels: 0 none, 1..n the DEMs, n+1 the tie points."""
    names = ["none", *(str(d) for d in dem_names), "tie points"]
    return {"index": list(range(len(names))), "source": names}


def diagnostic_layers(diagnostics: dict[str, np.ndarray], frame: OutputGrid, suffix: str = "",
                      dem_names: Sequence[str] = ()) -> list[tuple[Any, dict, str]]:
    """Iteration-count, elevation and elevation-source images of an OrthoResult (section 3.2,
    Appendix B statistics), named "iterations", "elevation", "elevation source" + ``suffix``.
    Elevation source codes: 0..n-1 DEM index, -1 tie points, -2 none; shown as labels 1..n for
    the DEMs, n+1 tie points, 0 none, with the DEM names as features (status bar). Outside the
    footprint (iterations -1) every layer is transparent (NaN, label 0), not a colour of its
    scale; each carries its colour key (``metadata["legend"]``, shown by ``legend``)."""
    layers: list[tuple[Any, dict, str]] = []
    outside = None
    if "iterations" in diagnostics:
        raw = np.asarray(diagnostics["iterations"])
        outside = raw < 0
        it = np.where(outside, np.nan, raw).astype(np.float32)
        top = float(max(int(raw.max()), 1))
        layers.append((it, geo_image_kwargs(
            frame, name=f"iterations{suffix}", colormap="turbo", visible=False,
            contrast_limits=(0.0, top), metadata={"legend": (
                f"prediction/correction iterations, dark blue 0 → dark red {top:.0f} "
                "(turbo)")}), "image"))
    if "elevation" in diagnostics:
        h = np.array(diagnostics["elevation"], np.float32)
        if outside is not None:
            h[outside] = np.nan
        lo, hi = contrast_limits(h, None)
        layers.append((h, geo_image_kwargs(
            frame, name=f"elevation{suffix}", colormap="gist_earth", visible=False,
            contrast_limits=(lo, hi), metadata={"units": "m", "legend": (
                f"height of the output points, dark blue {lo:.0f} m → white {hi:.0f} m "
                "(gist_earth)")}), "image"))
    if "elevation_source" in diagnostics:
        src = np.asarray(diagnostics["elevation_source"]).astype(np.int16)
        n = len(dem_names)
        labels = np.where(src >= 0, src + 1, np.where(src == -1, n + 1, 0)).astype(np.uint8)
        colours = source_colours(n)
        names = elevation_source_features(dem_names)["source"]
        key = ", ".join(f"{colours[k]} {name}" for k, name in enumerate(names) if k)
        layers.append((labels, geo_image_kwargs(
            frame, name=f"elevation source{suffix}", visible=False, opacity=0.6,
            features=elevation_source_features(dem_names),
            colormap=category_colormap(colours),
            metadata={"legend": f"heights from: {key}; none: transparent"}), "labels"))
    return layers

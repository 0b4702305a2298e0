"""What the Orthorectify widget runs, without Qt: the checked options, the mapping of every
product (MERSYN use case 3) or a synthesis (use cases 1-2, handbook section 3.1), and the napari
layer tuples of the result in the viewer's world frame (``world``).

Layer names are short and distinct: "ortho b7 · 09-21 09:23" (the product's first line
time without the year: the names fit the layer list), "footprint · ...", "parallax ×10 · ...";
with the per-pixel geolocation "ortho b7 (pixel geolocation) · ..."; the full product name,
path and time are in the layer metadata ("product", "path", "acquired") and the tooltip.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import same_file
from ..bands import MERIS, BandTable, Sensor, band_table
from ..errors import MerisOrthoError, OptionsError
from ..geometry.grid import OutputGrid, same_crs
from ..options import Elevation, MergeRule, OrthoOptions, choices, parse_band_list
from ..progress import ProgressCallback
from ..pyramid import level_factors, memory_levels
from .geometry_layers import geometry_layers, hidden_layer_data
from .product_layers import (
    NDVI_LEGEND,
    band_layers,
    count_legend,
    diagnostic_layers,
    one_image_shown,
    zero_transparent,
)
from .world import geo_image_kwargs, move_to_frame

#: "mapping" orthorectifies every product on its own; the merge rules build a synthesis
MAPPING = "mapping"
ALGORITHMS = (MAPPING, *choices(MergeRule))
#: location models offered: the tie points (parallax from the DEMs) or the product's per-pixel
#: terrain-corrected geolocation (FRG/FSG N1, .SEN3)
GEOLOCATIONS = ("tiepoints", "pixel")
CRS_UTM = "UTM zone of the footprint"
CRS_GEOGRAPHIC = "geographic (EPSG:4326)"
CRS_EPSG = "EPSG code"
#: the CRS, pixel size and grid of an open geocoded layer (CLI ``--like REFERENCE.tif``)
CRS_LIKE = "like a layer"
LayerData = tuple[Any, dict[str, Any], str]


class Cancelled(MerisOrthoError):
    """The user pressed Cancel (or closed the viewer)."""


@dataclass
class RunSettings:
    """Everything the Orthorectify widget asks for (defaults = MERSYN's)."""

    products: list[Path]
    dems: list[Path] = field(default_factory=list)
    elevation: str = "dem"
    algorithm: str = MAPPING
    sampling: str = "nearest"
    crs: str = CRS_UTM
    epsg: int | None = None
    #: the grid of the layer chosen with ``CRS_LIKE``: outputs on it pixel for pixel
    like: OutputGrid | None = None
    pixel_size_m: float = 0.0  # 0: the nominal FR 260 m / RR 1040 m
    #: the bands mapped (None: all); the default is MERIS's quick-look, an OLCI product's is
    #: its own (``default_bands``)
    bands: tuple[int, ...] | None = MERIS.true_colour
    #: location model: "tiepoints" (with the parallax) or "pixel" (FRG/FSG/SEN3 per-pixel
    #: terrain-corrected geolocation; with DEMs, moved back to the ellipsoid and given their
    #: parallax: ``engine.pixeldem``)
    geolocation: str = "tiepoints"
    output: Path | None = None
    #: radii of the parallax correction (eq. 6a, 2c', 6b'; CLI ``--parallax``)
    parallax: str = "handbook"
    #: antecedent search (section 3.2; CLI ``--search``)
    search: str = "primary"
    #: an existing synthesis store to update (CLI ``synthesize --input``): the products are
    #: merged into it (or into a copy at ``output``), its grid and bands kept
    input_store: Path | None = None
    #: a synthesis run keeps the newest this many commits of its store afterwards and frees
    #: what only older ones held (CLI ``synthesize --keep``); 0: every commit is kept
    keep: int = 0
    geometry: bool = True
    exaggeration: float = 10.0
    #: one parallax vector every this many output pixels; 0: about 60 across the grid
    #: (``geometry_layers.vector_step_for``)
    vector_step: int = 0
    #: ground hidden from the sensor by the relief: "mask" (no data) or "keep" (mapped; CLI
    #: ``--hidden``); shown in both as the "hidden ground" layer
    hidden: str = "mask"

    @property
    def pixel(self) -> bool:
        """True with the product's per-pixel geolocation (FRG/FSG/SEN3)."""
        return self.geolocation == "pixel"

    @property
    def synthesis(self) -> bool:
        """True when Run builds or updates a synthesis (a merge rule or an input store)."""
        return self.algorithm != MAPPING or self.input_store is not None

    def mode(self) -> str:
        """What Run will do, in words (the widget shows it before Run)."""
        n = len(self.products)
        what = f"{n} product{'s' if n != 1 else ''}"
        if self.input_store is not None:
            rule = "" if self.algorithm == MAPPING else f" ({self.algorithm})"
            copy = self.output is not None and not same_file(self.output, self.input_store)
            into = f" into a copy at {self.output}" if copy else " in place"
            return f"update synthesis {Path(self.input_store).name}{rule} with {what}{into}"
        if self.algorithm != MAPPING:
            return f"new synthesis ({self.algorithm}) of {what}"
        return f"mapping: orthorectify {what}, one by one"

    @property
    def sensor(self) -> Sensor:
        """OLCI when a product is an OLCI one (its 21 bands accepted), else MERIS."""
        return products_sensor(self.products)

    @property
    def dem_list(self) -> list[str]:
        """The DEMs used (as strings)."""
        return [str(d) for d in self.dems]

    def options(self) -> OrthoOptions:
        """The checked ``OrthoOptions`` of the run (``OrthoOptions.of``, as the CLI)."""
        return OrthoOptions.of(n_dems=len(self.dem_list), elevation=self.elevation,
                               n_bands=band_table(self.sensor).n_bands,
                               sampling=self.sampling, bands=self.bands,
                               geolocation="pixel" if self.pixel else None,
                               parallax=self.parallax, method=self.search,
                               diagnostics=self.geometry, hidden=self.hidden)

    def check(self) -> None:
        """OptionsError/OutputError naming the first missing or inconsistent input."""
        if not self.products:
            raise OptionsError("choose at least one N1 product")
        missing = [str(p) for p in self.products if not Path(p).exists()]
        if missing:
            raise OptionsError(f"N1 product not found: {', '.join(missing)}")
        self.options()
        if self.crs == CRS_LIKE and self.like is None:
            raise OptionsError("output CRS 'like a layer' needs a layer: open a GeoTIFF or an "
                               "orthorectified product and choose it")
        if not self.pixel and self.elevation == Elevation.DEM and not self.dems:
            raise OptionsError("elevation 'dem' needs a DEM: add one, or choose elevation "
                               "'tiepoints' (the product's tie-point heights) or 'none'")
        if isinstance(self.keep, bool) or not isinstance(self.keep, int) or self.keep < 0:
            raise OptionsError(f"keep must be a number of commits (0: all), not {self.keep!r}")
        if self.input_store is not None:
            from ..synthesis.reading import is_synthesis, open_synthesis

            if not is_synthesis(self.input_store):
                raise OptionsError(f"input synthesis {self.input_store}: not a synthesis store")
            rule = open_synthesis(self.input_store).algorithm
            if self.algorithm not in (MAPPING, rule):
                raise OptionsError(f"input synthesis {self.input_store}: is a {rule} synthesis, "
                                   f"cannot update it with {self.algorithm} (choose selection "
                                   f"{rule!r} or 'mapping')")
        if self.output is not None and not self.synthesis:
            from ..ortho.writing import check_geotiff_name, check_outputs

            check_outputs({f"output {k + 1}": path for k, path in enumerate(self.map_outputs())},
                          self.products, self.dem_list)
            check_geotiff_name("output", self.output)

    def map_outputs(self) -> list[Path]:
        """The GeoTIFFs a mapping run writes (one per product); none for a synthesis."""
        if self.output is None or self.synthesis:
            return []
        n = len(self.products)
        return [_output_path(self.output, k, n) for k in range(n)]


#: "7,5,2" -> (7, 5, 2); "all" or "" -> None (all bands); OptionsError otherwise
parse_bands = parse_band_list


def products_sensor(paths: list[Path]) -> Sensor:
    """OLCI when one of ``paths`` is a Sentinel-3 product (by its name or manifest), else
    MERIS: which band numbers the widget accepts and offers."""
    from ..products.open import is_sentinel3

    return Sensor.OLCI if any(Path(p).exists() and is_sentinel3(Path(p)) for p in paths) \
        else Sensor.MERIS


def default_bands(sensor: Sensor | str) -> str:
    """The widget's band list for a sensor's products: its true-colour bands ("7,5,2" MERIS,
    "8,6,3" OLCI: the RGB quick-look)."""
    return ",".join(str(b) for b in band_table(sensor).true_colour)


def output_crs(options: RunSettings, tie_points: Mapping[str, np.ndarray]) -> Any:
    """The output CRS: the UTM zone of the footprint centre (the default), EPSG:4326, the
    given EPSG code or the chosen layer's."""
    from ..geometry.grid import footprint_utm, parse_crs

    if options.crs == CRS_LIKE and options.like is not None:
        return options.like.crs
    if options.crs == CRS_GEOGRAPHIC:
        return parse_crs("EPSG:4326")
    if options.crs == CRS_EPSG:
        if not options.epsg:
            raise OptionsError("output CRS 'EPSG code' needs an EPSG code")
        return parse_crs(f"EPSG:{int(options.epsg)}")
    return footprint_utm(tie_points["latitude"], tie_points["longitude"])


def _pixel_size(options: RunSettings, product: Any, crs: Any) -> float:
    from ..geometry.grid import pixel_size_for

    metres = options.pixel_size_m or float(
        getattr(getattr(product, "resolution", None), "column_spacing_m", 260.0))
    return pixel_size_for(metres, crs)


def name_stamp(product: Any) -> str:
    """'09-21 09:23': the first line time of a product in its layers' names, without the year
    (``product_stamp`` in the tooltip and metadata); its file stem if unknown."""
    stamp = product_stamp(product)
    return stamp[5:] if getattr(product, "first_line_time", None) is not None else stamp


def product_stamp(product: Any) -> str:
    """'2003-09-21 09:23': the first line time of a product (its file stem if unknown)."""
    t = getattr(product, "first_line_time", None)
    if t is None:
        return Path(product.path).stem
    return str(np.datetime_as_string(np.datetime64(t, "m"))).replace("T", " ")


@dataclass
class OrthoRun:
    """What a run produced: per product (or synthesis) its layers' names, values and grid."""

    items: list[dict[str, Any]]
    options: RunSettings
    written: list[Path] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)  # "name: reason" of skipped products
    #: what the user should know (a DEM that gave no height), as the CLI warns
    warnings: list[str] = field(default_factory=list)
    #: commits kept and megabytes freed by a synthesis run's pruning (``RunSettings.keep``)
    pruned: tuple[int, float] | None = None

    def release(self) -> None:
        """Drop the arrays of every item (bands, diagnostics, masks, extra layers) once they are
        in layers: a finished run keeps its grids, tie points, statistics and names only."""
        for item in self.items:
            item.update(bands={}, extra=[], valid=None, diagnostics={}, hidden=None)

    def summary(self) -> str:
        """The status line of a finished run."""
        if not self.options.synthesis:
            n = len(self.items)
            text = f"done: {n} product{'s' if n != 1 else ''} orthorectified"
        else:
            n = sum(1 for item in self.items if item["tie_points"] is not None)
            what = "updated synthesis" if self.options.input_store is not None else "synthesis"
            text = (f"done: {what} ({self.items[0]['meta']['algorithm']}) of {n} "
                    f"product{'s' if n != 1 else ''}")
        if self.warnings:
            text += f"; warning: {'; '.join(self.warnings)}"
        if self.skipped:
            text += f"; skipped {'; '.join(self.skipped)}"
        if self.written:
            text += f"; wrote {', '.join(str(p) for p in self.written)}"
        if self.pruned is not None:
            kept, freed = self.pruned
            commits = f"{kept} commit{'s' if kept != 1 else ''}"
            text += f"; kept the store's newest {commits}, {freed:.1f} MB freed"
        return text


def _item(product: Any, prefix: str = "ortho", **values: Any) -> dict[str, Any]:
    sensor = Sensor(getattr(product, "sensor", Sensor.MERIS))
    meta = {"product": getattr(product, "product_name", ""), "path": str(product.path),
            "sensor": str(sensor),
            "product_type": str(getattr(product, "product_type", "")).strip("_"),
            "acquired": product_stamp(product)}
    return {"prefix": prefix, "suffix": f" · {name_stamp(product)}", "meta": meta,
            "tie_points": product.tie_points, "bands": {}, "extra": [], "valid": None,
            "diagnostics": {}, "stats": {}, "table": band_table(sensor), **values}


def run_orthorectify(options: RunSettings, progress: ProgressCallback | None = None) -> OrthoRun:
    """Run the chosen algorithm (no Qt): mapping of every product, or a synthesis."""
    options.check()
    if not options.synthesis:
        return _run_mapping(options, progress)
    return _run_synthesis(options, progress)


def _run_mapping(options: RunSettings, progress: ProgressCallback | None) -> OrthoRun:
    from ..ortho import precompute, product_grid
    from ..ortho.writing import write_map
    from ..products.open import read_product

    products = [read_product(p) for p in options.products]
    crs = output_crs(options, products[0].tie_points)
    opts = options.options()
    items, written, warnings = [], [], []
    n = len(products)
    for k, product in enumerate(products):
        def part(done: int, total: int, k: int = k) -> None:
            if progress is not None:
                progress(k * 1000 + int(1000 * done / max(total, 1)), n * 1000)

        grid = options.like if options.crs == CRS_LIKE and options.like is not None else \
            product_grid(product, crs, _pixel_size(options, product, crs))
        ante = precompute(product, grid, options.dem_list, options=opts, progress=part,
                          hold_bands=True)  # the layers hold every band (``result``)
        warnings += ante.stats.gap_warnings()
        warnings += [f"DEM {Path(d).name} gave no height for {Path(product.path).name} (outside "
                     "the scene, wrong CRS or only no data)" for d in ante.stats.unused_dems()]
        if options.output is not None:
            written.append(write_map(_output_path(options.output, k, n), ante,
                                     software="napari-meris-ortho widget", order=options.bands))
        result = ante.result()
        # the model after the band ("ortho b7 (pixel geolocation) · ..."): names differ within
        # the width the layer list shows, and differ from the tie-point run's
        extra = {"suffix": f" (pixel geolocation) · {name_stamp(product)}"} \
            if options.pixel else {}
        items.append(_item(product, bands=result.bands, grid=result.grid,
                           valid=result.valid, diagnostics=result.diagnostics,
                           stats=result.stats, hidden=result.hidden, **extra))
    return OrthoRun(items, options, written, warnings=warnings)


def _output_path(output: Path, k: int, n: int) -> Path:
    """The output file of product ``k`` of ``n``: ``output`` itself, or ``OUT_<k+1>.tif``."""
    path = Path(output)
    if n > 1:
        path = path.with_name(f"{path.stem}_{k + 1}{path.suffix or '.tif'}")
    return path


def _readable(paths: list[Path]) -> tuple[list[Any], list[str]]:
    """The products that open, and "name: reason" of those that do not (skipped, like the CLI)."""
    from ..products.open import read_product

    products, skipped = [], []
    for p in paths:
        try:
            products.append(read_product(p))
        except (MerisOrthoError, OSError) as exc:
            skipped.append(f"{Path(p).name}: {exc}")
    return products, skipped


def _run_synthesis(options: RunSettings, progress: ProgressCallback | None) -> OrthoRun:
    """A synthesis of the readable products; read back into memory; a temporary store (no
    output chosen) is removed afterwards."""
    from ..synthesis.api import synthesize

    products, skipped = _readable(options.products)
    if not products:
        raise OptionsError(f"no product could be read ({'; '.join(skipped)})")
    algorithm = None if options.algorithm == MAPPING else options.algorithm
    grid_options: dict[str, Any] = {}
    if options.input_store is None:  # a new synthesis: its grid from the first product
        crs = output_crs(options, products[0].tie_points)
        grid_options = {"crs": crs, "pixel_size": _pixel_size(options, products[0], crs),
                        "bands": options.bands}  # an update keeps its store's bands
        if options.crs == CRS_LIKE and options.like is not None:
            grid_options.update(grid=options.like, crs=None, pixel_size=None)
    temporary = options.output is None and options.input_store is None
    out = (Path(options.output) if options.output is not None
           else Path(options.input_store) if options.input_store is not None
           else Path(tempfile.mkdtemp(prefix="synthesis-")) / "store")
    try:
        result = synthesize(
            [p.path for p in products], out, algorithm=algorithm, input=options.input_store,
            progress=progress, dems=options.dem_list, options=options.options(),
            keep=options.keep if options.keep and not temporary else None, **grid_options)
        skipped += [f"{Path(r.path).name}: {r.error}" for r in result.failed]
        skipped += [f"{Path(r.path).name}: already in the synthesis" for r in result.skipped]
        skipped += [f"{Path(r.path).name}: outside the synthesis grid" for r in result.outside]
        if not result.merged:
            raise OptionsError(f"no product could be merged into the synthesis "
                               f"({'; '.join(skipped)})")
        merged = {str(Path(r.path)) for r in result.merged}
        item = _synthesis_item(out, [p for p in products if str(p.path) in merged])
    finally:
        if temporary:
            shutil.rmtree(out.parent, ignore_errors=True)
    items = [item] + [_item(p, grid=item["grid"]) for p in products if str(p.path) in merged]
    pruned = (None if result.pruned is None
              else (result.pruned.kept, result.pruned.bytes_deleted / 1e6))
    return OrthoRun(items, options, [] if temporary else [out], skipped, pruned=pruned)


def _synthesis_item(path: Path, products: list[Any]) -> dict[str, Any]:
    """The synthesis layers read into memory over the part of the store the run's
    ``products`` changed (``synthesis.tiling.products_window``; a new synthesis on their
    footprint: all of it; an update of a Europe-size store: the products' footprint, not
    15 x 3.2e8 pixels): bands, NDVI (maximum-NDVI rule), count."""
    from ..synthesis.reading import open_synthesis
    from ..synthesis.tiling import products_window

    store = open_synthesis(path)
    algorithm = store.algorithm
    window = products_window(store.grid, products)
    grid, prefix = store.grid.window(*window), f"synthesis {algorithm}"
    count = np.asarray(store.read("count", window))
    extra = []
    if algorithm == MergeRule.MAX_NDVI:
        # NaN where no product is (napari draws it transparent; 0 is an NDVI), its overviews
        # too; hidden: it would cover the RGB, the view a run opens on
        ndvi = np.asarray(store.ndvi(window), np.float32)
        levels = memory_levels(ndvi, np.nan)
        extra.append((levels if len(levels) > 1 else ndvi, geo_image_kwargs(
            grid, name=f"{prefix} NDVI", colormap="RdYlGn", contrast_limits=(-1.0, 1.0),
            visible=False, multiscale=len(levels) > 1,
            metadata={"units": "NDVI (band 13 - band 7) / (band 13 + band 7)",
                      "legend": NDVI_LEGEND}), "image"))
    top = float(max(int(count.max()), 1))
    extra.append((count, geo_image_kwargs(
        grid, name=f"{prefix} count", colormap=zero_transparent("viridis", top), visible=False,
        contrast_limits=(0.0, top),
        metadata={"units": "products", "legend": count_legend(top)}), "image"))
    return {"prefix": prefix, "suffix": "", "meta": {"synthesis": str(path),
                                                     "algorithm": algorithm,
                                                     "window": list(window)},
            "tie_points": None,
            "bands": {b: np.asarray(store.band(b, window)) for b in store.bands},
            "extra": extra, "grid": grid, "valid": count > 0, "diagnostics": {}, "stats": {}}


def run_layers(run: OrthoRun, world: OutputGrid | None = None) -> list[LayerData]:
    """napari layer tuples of a run: bands, diagnostics and geometry, in the world frame, the
    newest image alone visible and the geometry above (``one_image_shown``);
    rasters bigger than ``MAX_LEVEL_SIDE`` multiscale (``multiscale_layer``).

    ``world``: the viewer's frame; results in another CRS are moved into it (reprojected).
    """
    layers: list[LayerData] = []
    _distinct_suffixes(run.items)
    for item in run.items:
        frame = item["grid"]
        item_layers = _item_layers(item, frame, run.options)
        if world is not None and not same_crs(world.crs, frame.crs):
            item_layers = [move_to_frame(layer, frame, world) for layer in item_layers]
        key = run_key(item)
        layers += [_tagged(multiscale_layer(layer), key) for layer in item_layers]
    return one_image_shown(layers)


#: layer metadata key: the product (or synthesis store) a run's layer shows
RUN_KEY = "meris_ortho_source"


def run_key(item: dict[str, Any]) -> str:
    """What a run's item shows: its product's (or store's) path and its layers' name suffix
    (a pixel-geolocation run's differs from a tie-point run's: both stay, to be compared); a
    later run of the same key replaces every layer of this one (``layer_source``)."""
    meta = item.get("meta", {})
    suffix = item.get("base_suffix", item.get("suffix", ""))  # before ``_distinct_suffixes``
    return f"{meta.get('path') or meta.get('synthesis') or ''}|{suffix}"


def layer_source(layer: Any) -> str | None:
    """The ``run_key`` a layer was made for (None: not a run's layer)."""
    value = (getattr(layer, "metadata", None) or {}).get(RUN_KEY)
    return None if value is None else str(value)


def _tagged(layer: LayerData, key: str) -> LayerData:
    data, kwargs, kind = layer
    return data, {**kwargs, "metadata": {**(kwargs.get("metadata") or {}), RUN_KEY: key}}, kind


def _distinct_suffixes(items: list[dict[str, Any]]) -> None:
    """Items of one run sharing a name suffix (two products of one sensing time: an FR and its
    FRG, an N1 and its .SEN3) get their product type too, so no two layers share a name."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for item in items:
        groups.setdefault(item["suffix"], []).append(item)
    for group in groups.values():
        if len(group) < 2:
            continue
        types = [str(item["meta"].get("product_type", "")) for item in group]
        by_type = all(types) and len(set(types)) == len(types)
        for item, kind in zip(group, types, strict=True):
            tag = kind if by_type else Path(str(item["meta"].get("path", ""))).name
            item["base_suffix"] = item["suffix"]
            item["suffix"] = f"{item['suffix']} {tag}"


def multiscale_layer(layer: LayerData) -> LayerData:
    """A raster layer as a pyramid (``pyramid.memory_levels``) when it is bigger than
    ``MAX_LEVEL_SIDE``: napari then uploads the level that fits the canvas, not the full
    resolution, when the layer goes in. Radiances and elevations are averaged as the COG's
    overviews (background 0 ignored), labels and iteration counts decimated."""
    data, kwargs, kind = layer
    if kind not in ("image", "labels") or kwargs.get("multiscale"):
        return layer
    arr = np.asarray(data)
    rgb = bool(kwargs.get("rgb"))
    if len(level_factors(*arr.shape[:2])) == 1:
        return layer
    average = kind == "image" and (rgb or arr.dtype.kind == "f")
    levels = memory_levels(arr, 0.0 if average else None,
                           "average" if average else "nearest", rgb=rgb)
    return levels, {**kwargs, "multiscale": True}, kind


def _item_layers(item: dict[str, Any], frame: OutputGrid, opts: RunSettings) -> list[LayerData]:
    """Layers of one product (or of the synthesis) on its own grid."""
    layers: list[LayerData] = []
    meta = {"stats": item["stats"], "algorithm": opts.algorithm, "elevation": opts.elevation,
            **item["meta"]}
    if item["bands"]:
        table: BandTable = item.get("table", MERIS)
        label = None if table.sensor == Sensor.MERIS else table.name  # "b7" / "Oa08"
        layers += band_layers(item["bands"], frame, item["prefix"], meta, item["valid"],
                              suffix=item["suffix"], table=table,
                              **({"label": label} if label else {}))
    layers += item["extra"]
    hidden = item.get("hidden")
    if hidden is not None and np.any(hidden):  # the ground the sensor cannot see
        layers.append(hidden_layer_data(frame, hidden, name=f"hidden ground{item['suffix']}"))
    if opts.geometry and item["diagnostics"]:
        layers += diagnostic_layers(item["diagnostics"], frame, item["suffix"],
                                    [Path(d).name for d in opts.dems])
    if opts.geometry and item["tie_points"] is not None:
        layers += geometry_layers(item["tie_points"], frame, item["suffix"], item["diagnostics"],
                                  valid=item["valid"], exaggeration=opts.exaggeration,
                                  step=opts.vector_step)
    return layers


__all__ = ["ALGORITHMS", "CRS_EPSG", "CRS_GEOGRAPHIC", "CRS_LIKE", "CRS_UTM", "GEOLOCATIONS",
           "Cancelled",
           "OrthoRun", "RunSettings", "default_bands", "output_crs", "parse_bands",
           "products_sensor", "run_layers",
           "run_orthorectify"]

"""Synthesis of many MERIS products (MERSYN use cases 1 and 2, handbook section 3.1, Appendix C).

Each product is orthorectified onto the synthesis grid, tile by tile, and merged with the
minimum-radiance or maximum-NDVI rule of :mod:`napari_meris_ortho.engine.synthesis`.

On disk a synthesis is a directory::

    DIR/synthesis.json          manifest: grid, algorithm, bands, products, current generation
    DIR/gen-000003/band_07.tif  one float32 GeoTIFF per band (radiance, background 0)
    DIR/gen-000003/ndvi.tif     maximum NDVI on 16 bits (0 background, [-1, 1] -> [1, 65535])
    DIR/gen-000003/count.tif    uint16 number of products that gave a valid pixel
    DIR/.lock                   advisory lock held by the run updating DIR

An update writes a new generation into a hidden temporary directory, renames it, then replaces
the manifest atomically (``os.replace``); a run killed at any moment leaves the previous
generation named by the manifest intact. The previous generation is removed after the switch.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import shutil
import tempfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._atomic import atomic_path, check_writable_dir
from .engine.synthesis import (
    NDVI_NIR_BAND,
    NDVI_RED_BAND,
    merge_maximum_ndvi,
    merge_minimum_radiance,
    validated_pixels,
)
from .errors import DemError, MerisOrthoError, OptionsError, OutputError
from .options import Elevation, MergeRule, Sampling, choices, parse
from .progress import ProgressCallback

log = logging.getLogger("napari_meris_ortho.synthesis")

ALGORITHMS = tuple(choices(MergeRule))
MANIFEST = "synthesis.json"
LOCK = ".lock"
FORMAT = "napari-meris-ortho synthesis"
BLOCK = 256  # GeoTIFF block size; tiles are multiples of it
DEFAULT_TILE = 1024
GDAL_CACHE_MB = 64
ALL_BANDS = tuple(range(1, 16))
_GENERATION = re.compile(r"^gen-(\d{6})$")
#: dataset tag of the band layers explaining their values and the ``sf_rad`` band tag
RADIANCE_NOTE = ("TOA radiance (float32, 0 = background) = counts x sf_rad of the merged "
                 "products (Scaling Factor GADS; several values: products differ); no further "
                 "scaling applies")


# --------------------------------------------------------------------------- grid helpers


def grid_to_dict(grid: Any) -> dict[str, Any]:
    """The output grid as JSON-able values (CRS as WKT)."""
    from .geometry.grid import parse_crs

    return {"crs": parse_crs(grid.crs).to_wkt(), "x0": float(grid.x0),
            "y0": float(grid.y0), "dx": float(grid.dx), "dy": float(grid.dy),
            "width": int(grid.width), "height": int(grid.height)}


def grid_from_dict(values: dict[str, Any]) -> Any:
    """Rebuild an ``engine.grid.OutputGrid`` from :func:`grid_to_dict` values."""
    from .geometry.grid import OutputGrid

    return OutputGrid(values["crs"], values["x0"], values["y0"], values["dx"], values["dy"],
                      int(values["width"]), int(values["height"]))


#: terrain parallax a tile must be within to be orthorectified: ``geometry.earth.MAX_TERRAIN_M``
#: seen at 45 deg view zenith or the product's largest one if larger (section 3.1)
SKIP_VIEW_ZENITH_DEG = 45.0


def terrain_margin_px(product: Any, grid: Any) -> int:
    """Output pixels beyond the zero-height segment boundary that a terrain point of the
    product may reach: ``geometry.earth.MAX_TERRAIN_M`` x tan(max(45 deg, largest view
    zenith)), + 2."""
    from .geometry.grid import terrain_margin_px as margin_px

    tp = product.tie_points
    zenith = max(SKIP_VIEW_ZENITH_DEG, float(np.nanmax(tp["view_zenith"])))
    return margin_px(grid, zenith, float(np.nanmax(np.abs(tp["latitude"]))))


def footprint_window(product: Any, grid: Any, margin: int | None = None
                     ) -> tuple[int, int, int, int] | None:
    """Rows/columns ``(row0, row1, col0, col1)`` of ``grid`` that the product may reach: its
    tie points widened by ``margin`` pixels (default ``terrain_margin_px``); None when
    disjoint."""
    tp = product.tie_points
    lat = np.asarray(tp["latitude"], dtype=np.float64).ravel()
    lon = np.asarray(tp["longitude"], dtype=np.float64).ravel()
    rows, cols = grid.xy_of_lonlat(lon, lat)
    ok = np.isfinite(rows) & np.isfinite(cols)
    if not ok.any():
        return None
    rows, cols = rows[ok], cols[ok]
    margin = terrain_margin_px(product, grid) if margin is None else int(margin)
    row0 = max(0, int(np.floor(rows.min() - margin)))
    row1 = min(grid.height, int(np.ceil(rows.max() + margin)) + 1)
    col0 = max(0, int(np.floor(cols.min() - margin)))
    col1 = min(grid.width, int(np.ceil(cols.max() + margin)) + 1)
    if row0 >= row1 or col0 >= col1:
        return None
    return row0, row1, col0, col1


def tiles(window: tuple[int, int, int, int], tile: int) -> Iterator[tuple[int, int, int, int]]:
    """Tiles of ``tile`` x ``tile`` pixels aligned on multiples of ``tile`` covering ``window``."""
    row0, row1, col0, col1 = window
    for r in range((row0 // tile) * tile, row1, tile):
        for c in range((col0 // tile) * tile, col1, tile):
            yield max(r, row0), min(r + tile, row1), max(c, col0), min(c + tile, col1)


# --------------------------------------------------------------------------- on-disk synthesis


def band_file(band: int) -> str:
    return f"band_{band:02d}.tif"


@dataclass
class SynthesisStore:
    """An existing synthesis directory, read through its manifest (the current generation)."""

    path: Path
    manifest: dict[str, Any]

    @property
    def generation_dir(self) -> Path:
        return self.path / self.manifest["generation"]

    @property
    def algorithm(self) -> str:
        return self.manifest["algorithm"]

    @property
    def bands(self) -> tuple[int, ...]:
        return tuple(self.manifest["bands"])

    @property
    def grid(self) -> Any:
        return grid_from_dict(self.manifest["grid"])

    @property
    def products(self) -> list[dict[str, Any]]:
        return list(self.manifest.get("products", []))

    def files(self) -> dict[str, Path]:
        """Layer name (``band_07``, ``ndvi``, ``count``) -> GeoTIFF path."""
        return {name: self.generation_dir / f"{name}.tif" for name in _layer_names(
            self.bands, self.algorithm)}

    def read(self, name: str, window: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """Read one layer (e.g. ``"band_07"``, ``"ndvi"``, ``"count"``), optionally a window
        ``(row0, row1, col0, col1)``."""
        import rasterio
        from rasterio.windows import Window

        path = self.files().get(name)
        if path is None:
            raise OptionsError(f"{self.path}: synthesis has no layer {name!r}")
        win = None if window is None else Window(window[2], window[0], window[3] - window[2],
                                                 window[1] - window[0])
        with rasterio.open(path) as ds:
            return ds.read(1, window=win)


    def band(self, band: int, window: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """Radiance of MERIS band ``band`` (float32, 0 = background)."""
        return self.read(band_file(band)[:-4], window)

    def ndvi(self, window: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """The maximum-NDVI layer decoded to float32 (Appendix C coding), NaN = background."""
        from .engine.synthesis import ndvi_decode

        return ndvi_decode(self.read("ndvi", window))


def _layer_names(bands: Sequence[int], algorithm: str) -> list[str]:
    names = [band_file(b)[:-4] for b in bands]
    if algorithm == "max-ndvi":
        names.append("ndvi")
    return [*names, "count"]


def open_synthesis(path: str | os.PathLike[str]) -> SynthesisStore:
    """Open the synthesis directory ``path`` (Appendix C: grid, bands from the input synthesis)."""
    root = Path(path)
    manifest_path = root / MANIFEST
    if not manifest_path.is_file():
        raise OptionsError(f"{root}: not a synthesis directory (no {MANIFEST})")
    try:
        manifest = json.loads(manifest_path.read_text())
        if manifest.get("format") != FORMAT:
            raise ValueError("foreign format")
        store = SynthesisStore(root, manifest)
        _ = store.grid, store.bands, store.algorithm
    except (ValueError, KeyError, TypeError) as exc:
        raise OptionsError(f"{manifest_path}: damaged synthesis manifest ({exc})") from None
    missing = [p.name for p in store.files().values() if not p.is_file()]
    if missing:
        raise OptionsError(f"{store.generation_dir}: synthesis layers missing: {missing}")
    return store


def is_synthesis(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` is a directory holding a synthesis manifest."""
    return (Path(path) / MANIFEST).is_file()


def _profile(grid: Any, dtype: str, nodata: float | None) -> dict[str, Any]:
    from affine import Affine
    from pyproj import CRS
    from rasterio.crs import CRS as RioCRS

    return {"driver": "GTiff", "width": int(grid.width), "height": int(grid.height), "count": 1,
            "dtype": dtype, "nodata": nodata,
            "crs": RioCRS.from_wkt(CRS.from_user_input(grid.crs).to_wkt()),
            "transform": Affine(grid.dx, 0.0, grid.x0, 0.0, -grid.dy, grid.y0),
            "tiled": True, "blockxsize": BLOCK, "blockysize": BLOCK, "sparse_ok": True}


def _create_layers(directory: Path, grid: Any, bands: Sequence[int], algorithm: str) -> None:
    """Empty (background) layers of a new synthesis; sparse, so unwritten blocks cost nothing.
    Band layers are described with the MERIS band number and its nominal wavelength."""
    import rasterio

    from .io.geotiff import meris_band_description
    from .io.n1_format import APPENDIX_A_BANDWIDTHS, APPENDIX_A_WAVELENGTHS
    from .ortho import RADIANCE_UNITS

    for name in _layer_names(bands, algorithm):
        dtype, nodata = ("float32", 0.0) if name.startswith("band_") else ("uint16", None)
        if name == "ndvi":
            nodata = 0
        with rasterio.open(directory / f"{name}.tif", "w", **_profile(grid, dtype, nodata)) as ds:
            if name.startswith("band_"):
                b = int(name[5:])
                ds.set_band_description(
                    1, meris_band_description(b, APPENDIX_A_WAVELENGTHS[b - 1]))
                ds.update_tags(1, band=name[5:], meris_band=b, units=RADIANCE_UNITS,
                               wavelength_nm=APPENDIX_A_WAVELENGTHS[b - 1],
                               bandwidth_nm=APPENDIX_A_BANDWIDTHS[b - 1])


class _Layers:
    """The working generation opened for windowed read/update (r+)."""

    def __init__(self, directory: Path, bands: Sequence[int], algorithm: str) -> None:
        import rasterio

        self.bands = tuple(bands)
        self.algorithm = algorithm
        self._ds: dict[str, Any] = {}
        try:
            for name in _layer_names(bands, algorithm):
                self._ds[name] = rasterio.open(directory / f"{name}.tif", "r+")
        except BaseException:
            self.close()
            raise

    def read(self, window: tuple[int, int, int, int]) -> dict[str, np.ndarray]:
        from rasterio.windows import Window

        win = Window(window[2], window[0], window[3] - window[2], window[1] - window[0])
        out = {"count": self._ds["count"].read(1, window=win)}
        out["synthesis"] = np.stack([self._ds[band_file(b)[:-4]].read(1, window=win)
                                     for b in self.bands])
        if self.algorithm == "max-ndvi":
            out["ndvi"] = self._ds["ndvi"].read(1, window=win)
        return out

    def write(self, window: tuple[int, int, int, int], tile: dict[str, np.ndarray]) -> None:
        from rasterio.windows import Window

        win = Window(window[2], window[0], window[3] - window[2], window[1] - window[0])
        for k, b in enumerate(self.bands):
            self._ds[band_file(b)[:-4]].write(tile["synthesis"][k], 1, window=win)
        if self.algorithm == "max-ndvi":
            self._ds["ndvi"].write(tile["ndvi"], 1, window=win)
        self._ds["count"].write(tile["count"], 1, window=win)

    def tag_sources(self, products: Sequence[dict[str, Any]]) -> None:
        """Record the merged products' names and radiance factors ``sf_rad`` (Scaling Factor
        GADS; the layers hold radiances, so no further scaling applies) in the band layers."""
        names = " ".join(str(p.get("product_name") or p.get("product", "")) for p in products)
        for b in self.bands:
            factors = sorted({float(p["sf_rad"][str(b)]) for p in products
                              if str(b) in p.get("sf_rad", {})})
            ds = self._ds[band_file(b)[:-4]]
            ds.update_tags(products=names, radiance=RADIANCE_NOTE)
            ds.update_tags(1, sf_rad=" ".join(repr(f) for f in factors))

    def close(self) -> None:
        for ds in self._ds.values():
            ds.close()
        self._ds.clear()


# --------------------------------------------------------------------------- reports


@dataclass
class ProductReport:
    """Appendix B statistics of one product merged into the synthesis."""

    path: str
    processed: int = 0  # output pixels with an antecedent in the segment
    validated: int = 0  # ... whose flags allow them into the synthesis
    added: int = 0  # ... that replaced the synthesis value (MERSYN added_point_number)
    error: str | None = None
    product_name: str = ""
    sf_rad: dict[int, float] = field(default_factory=dict)  # radiance factor per band

    def lines(self, synthesis_pixels: int) -> list[str]:
        """The log of Appendix B (processed/validated points, share of the synthesis)."""
        if self.error is not None:
            return [f"PRODUCT {self.path}: SKIPPED ({self.error})"]
        total = max(synthesis_pixels, 1)
        seg = max(self.processed, 1)
        return [
            f"PRODUCT {self.path}",
            f"NUMBER OF PROCESSED POINTS IN SEGMENT = {self.processed} "
            f"({100.0 * self.processed / total:.1f}% of synthesis)",
            f"NUMBER OF VALIDATED POINTS IN SEGMENT = {self.validated} "
            f"({100.0 * self.validated / seg:.1f}% of segment) "
            f"({100.0 * self.validated / total:.1f}% of synthesis)",
            f"NUMBER OF ADDED POINTS IN SYNTHESIS = {self.added} "
            f"({100.0 * self.added / total:.1f}% of synthesis)",
        ]

    def as_dict(self) -> dict[str, Any]:
        return {"product": Path(self.path).name, "product_name": self.product_name,
                "processed": self.processed, "validated": self.validated, "added": self.added,
                "sf_rad": {str(b): v for b, v in self.sf_rad.items()}}


@dataclass
class SynthesisResult:
    """Outcome of :func:`synthesize`: the (new) synthesis and one report per product."""

    path: Path
    generation: str | None
    grid: Any
    algorithm: str
    bands: tuple[int, ...]
    reports: list[ProductReport] = field(default_factory=list)

    @property
    def failed(self) -> list[ProductReport]:
        return [r for r in self.reports if r.error is not None]

    @property
    def merged(self) -> list[ProductReport]:
        return [r for r in self.reports if r.error is None]


class _ProductFailed(Exception):
    def __init__(self, index: int, message: str) -> None:
        super().__init__(message)
        self.index = index
        self.message = message


# --------------------------------------------------------------------------- synthesize


def synthesize(products: Sequence[str | os.PathLike[str]], out: str | os.PathLike[str], *,
               algorithm: str | None = None, input: str | os.PathLike[str] | None = None,
               grid: Any = None, crs: Any = None, pixel_size: float | None = None,
               dems: Sequence[Any] = (), elevation: str = "dem", sampling: str = "nearest",
               bands: Sequence[int] | None = None, reject_bright: bool = False,
               tile: int = DEFAULT_TILE, progress: ProgressCallback | None = None,
               ) -> SynthesisResult:
    """Orthorectify ``products`` onto the synthesis grid and merge them (section 3.1 use cases
    1-2, Appendix C) into the synthesis directory ``out``.

    A new synthesis (no ``input``) takes ``grid``, or the first readable product's footprint
    (with ``crs``/``pixel_size``), and ``bands`` (default all 15). With ``input`` (may equal
    ``out``: update in place), grid and bands come from the input synthesis; giving grid options
    or bands too is refused as MERSYN refuses them. A product that cannot be read or
    orthorectified is reported in ``result.failed`` and skipped. ``progress(done, total)`` counts
    products.
    """
    out_dir = Path(out)
    source = _check_options(products, out_dir, algorithm, input, grid, crs, pixel_size, bands,
                            tile, dems, elevation, sampling)
    algorithm = source.algorithm if source is not None else (algorithm or "min-radiance")
    if source is not None:
        bands = source.bands
    else:
        bands = tuple(sorted(set(int(b) for b in (bands or ALL_BANDS))))
    if not out_dir.exists():
        check_writable_dir(out_dir)
        out_dir.mkdir()
    paths = [str(p) for p in products]
    failed: dict[int, str] = {}
    import rasterio

    with contextlib.ExitStack() as locks:
        locks.enter_context(rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE_MB))  # bounded block cache
        locks.enter_context(_locked(out_dir))
        if source is not None and source.path.resolve() != out_dir.resolve():
            locks.enter_context(_locked(source.path))
        _remove_stale(out_dir)
        while True:
            try:
                return _build(paths, out_dir, source, algorithm, tuple(bands), grid, crs,
                              pixel_size, dems, elevation, sampling, reject_bright, tile,
                              progress, failed)
            except _ProductFailed as exc:  # a product broke mid-way: rebuild without it
                failed[exc.index] = exc.message
                log.warning("%s: %s; restarting the synthesis without it", paths[exc.index],
                            exc.message)


@contextlib.contextmanager
def _locked(directory: Path) -> Iterator[None]:
    """Exclusive advisory lock on ``directory/.lock`` (released by the OS if the run dies)."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - no advisory locks (Windows): unguarded
        yield
        return
    try:
        fh = open(directory / LOCK, "a+b")  # held for the whole run
    except OSError as exc:
        raise OutputError(f"{directory}: cannot write in the synthesis directory ({exc})"
                          ) from exc
    try:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise OptionsError(f"{directory}: another synthesis run is using it") from None
        yield
    finally:
        fh.close()


def _check_ortho_options(dems: Sequence[Any], elevation: str, sampling: str) -> None:
    """Refuse bad orthorectification options before any product is read (exit code 2, not a
    failure of every product)."""
    parse(Elevation, elevation)
    parse(Sampling, sampling)
    if dems and elevation != "dem":
        raise OptionsError(f"DEMs given with elevation {elevation!r}: DEMs need elevation 'dem'")
    if dems:
        from .io.dem import DemStack

        DemStack([d for d in dems if not hasattr(d, "sample")]).close()


def _check_options(products: Sequence[Any], out_dir: Path, algorithm: str | None,
                   input: Any, grid: Any, crs: Any, pixel_size: float | None,
                   bands: Sequence[int] | None, tile: int, dems: Sequence[Any],
                   elevation: str, sampling: str) -> SynthesisStore | None:
    """MERSYN's parameter consistency checks (Appendix C)."""
    if algorithm is not None and algorithm not in ALGORITHMS:
        raise OptionsError(f"algorithm {algorithm!r}: expected one of {', '.join(ALGORITHMS)}")
    if not products:
        raise OptionsError("no MERIS product given")
    if tile < BLOCK or tile % BLOCK:
        raise OptionsError(f"tile size {tile}: must be a positive multiple of {BLOCK}")
    if bands is not None:
        bad = [b for b in bands if not 1 <= int(b) <= 15]
        if bad or len(bands) == 0:
            raise OptionsError(f"bands {list(bands)}: MERIS bands are 1..15")
    if pixel_size is not None and not pixel_size > 0:
        raise OptionsError(f"pixel size {pixel_size}: must be positive")
    if crs is not None:
        from .geometry.grid import parse_crs

        parse_crs(crs)
    _check_ortho_options(dems, elevation, sampling)
    if input is None:
        if is_synthesis(out_dir):
            raise OptionsError(f"{out_dir}: already holds a synthesis; pass it as the input "
                               "synthesis to update it, or choose another output directory")
        return None
    if grid is not None or crs is not None or pixel_size is not None or bands is not None:
        raise OptionsError("when an input synthesis is given, the grid (CRS, extent, pixel "
                           "size) and the bands come from it and shall not be given")
    source = open_synthesis(input)
    if algorithm is not None and algorithm != source.algorithm:
        raise OptionsError(f"{input}: is a {source.algorithm} synthesis, cannot update it "
                           f"with {algorithm}")
    if out_dir.resolve() != source.path.resolve() and is_synthesis(out_dir):
        raise OptionsError(f"{out_dir}: already holds another synthesis")
    return source


def _remove_stale(out_dir: Path) -> None:
    """Remove temporary generations of killed runs and generations no manifest names."""
    current = None
    if is_synthesis(out_dir):
        with contextlib.suppress(ValueError, KeyError, OSError):
            current = json.loads((out_dir / MANIFEST).read_text())["generation"]
    for entry in out_dir.iterdir():
        stale_tmp = entry.name.startswith(".gen-") and entry.name.endswith(".tmp")
        stale_gen = _GENERATION.match(entry.name) and entry.name != current
        if entry.is_dir() and (stale_tmp or stale_gen):
            shutil.rmtree(entry, ignore_errors=True)


def _next_generation(source: SynthesisStore | None, out_dir: Path) -> str:
    numbers = [int(m.group(1)) for e in out_dir.iterdir() if (m := _GENERATION.match(e.name))]
    if source is not None:
        m = _GENERATION.match(source.manifest["generation"])
        numbers.append(int(m.group(1)) if m else 0)
    return f"gen-{max(numbers, default=0) + 1:06d}"


def _open_product(path: str) -> Any:
    from .io.n1 import read_product

    return read_product(path)


def _new_grid(product: Any, crs: Any, pixel_size: float | None) -> Any:
    """Grid of a new synthesis: the smallest rectangle holding the first product's segment
    boundary (section 3.1, fig. 19), nominal FR/RR pixel size unless ``pixel_size``."""
    from .engine.boundary import segment_boundary
    from .geometry.grid import FR_PIXEL_SIZE_M, RR_PIXEL_SIZE_M, default_grid

    boundary = segment_boundary(product.tie_points["latitude"], product.tie_points["longitude"])
    resolution = FR_PIXEL_SIZE_M if product.samples_per_tie_point >= 64 else RR_PIXEL_SIZE_M
    return default_grid(boundary, resolution, crs if crs is not None else "EPSG:4326",
                        pixel_size=pixel_size)


def _build(paths: list[str], out_dir: Path, source: SynthesisStore | None, algorithm: str,
           bands: tuple[int, ...], grid: Any, crs: Any, pixel_size: float | None,
           dems: Sequence[Any], elevation: str, sampling: str, reject_bright: bool, tile: int,
           progress: ProgressCallback | None, failed: dict[int, str]) -> SynthesisResult:
    """One attempt at the whole update into a temporary generation, then the atomic switch."""
    reports = [ProductReport(p, error=failed.get(i)) for i, p in enumerate(paths)]
    opened: dict[int, Any] = {}
    if source is not None:
        grid = source.grid
    elif grid is None:
        for i, p in enumerate(paths):
            if i in failed:
                continue
            try:
                opened[i] = _open_product(p)
            except (MerisOrthoError, OSError) as exc:
                failed[i] = reports[i].error = _message(exc)
                continue
            grid = _new_grid(opened[i], crs, pixel_size)
            break
        if grid is None:
            return _report(SynthesisResult(out_dir, None, None, algorithm, bands, reports))

    generation = _next_generation(source, out_dir)
    work = Path(tempfile.mkdtemp(prefix=f".{generation}.", suffix=".tmp", dir=out_dir))
    try:
        if source is not None:
            for src in source.files().values():
                shutil.copyfile(src, work / src.name)
        else:
            _create_layers(work, grid, bands, algorithm)
        layers = _Layers(work, bands, algorithm)
        try:
            merge = _merger(algorithm, bands, dems, elevation, sampling, reject_bright)
            for i, path in enumerate(paths):
                if progress is not None:
                    progress(i, len(paths))
                if reports[i].error is None:
                    _merge_product(i, path, opened.pop(i, None), grid, layers, merge, tile,
                                   reports[i], failed)
                for line in reports[i].lines(grid.width * grid.height):
                    (log.warning if reports[i].error else log.info)(line)
            if progress is not None:
                progress(len(paths), len(paths))
            history = source.products if source is not None else []
            layers.tag_sources(history + [r.as_dict() for r in reports if r.error is None])
        finally:
            layers.close()
        if not any(r.error is None for r in reports):
            shutil.rmtree(work, ignore_errors=True)
            return SynthesisResult(out_dir, None, grid, algorithm, bands, reports)
        _commit(work, out_dir, generation, source, algorithm, bands, grid, reports)
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    return SynthesisResult(out_dir, generation, grid, algorithm, bands, reports)


def _report(result: SynthesisResult) -> SynthesisResult:
    for r in result.failed:
        log.warning("%s: skipped: %s", r.path, r.error)
    return result


def _message(exc: BaseException) -> str:
    return str(exc) or type(exc).__name__


def _merge_product(index: int, path: str, product: Any, grid: Any, layers: _Layers,
                   merge: Callable[[Any, Any, dict[str, np.ndarray], ProductReport],
                                   np.ndarray],
                   tile: int, report: ProductReport, failed: dict[int, str]) -> None:
    """Merge one product tile by tile; a read failure before any write skips it, a failure
    after some tiles were written aborts this attempt (the caller rebuilds without it)."""
    from .engine.boundary import row_spans, segment_boundary

    try:
        product = product if product is not None else _open_product(path)
        report.product_name = str(getattr(product, "product_name", ""))
        report.sf_rad = {b: float(product.scaling.radiance[b - 1]) for b in layers.bands}
        margin = terrain_margin_px(product, grid)
        window = footprint_window(product, grid, margin)
        boundary = segment_boundary(product.tie_points["latitude"],
                                    product.tie_points["longitude"])
    except (MerisOrthoError, OSError) as exc:
        failed[index] = report.error = _message(exc)
        return
    if window is None:
        return
    written = False
    for win in tiles(window, tile):
        tile_grid = grid.window(*win)
        if row_spans(boundary, tile_grid, margin=margin).count == 0:  # beyond any terrain
            continue
        state = layers.read(win)
        try:
            valid = merge(product, tile_grid, state, report)
        except DemError:  # not the product's fault: stop the run (exit 2)
            raise
        except (MerisOrthoError, OSError) as exc:
            if not written:
                failed[index] = report.error = _message(exc)
                return
            raise _ProductFailed(index, _message(exc)) from exc
        changed = _changed_window(win, valid)
        if changed is None:  # no validated pixel in this tile: nothing changed
            continue
        r0, r1, c0, c1 = (changed[0] - win[0], changed[1] - win[0], changed[2] - win[2],
                          changed[3] - win[2])
        layers.write(changed, {k: np.ascontiguousarray(v[..., r0:r1, c0:c1])
                               for k, v in state.items()})
        written = True


def _changed_window(win: tuple[int, int, int, int], valid: np.ndarray
                    ) -> tuple[int, int, int, int] | None:
    """The part of tile ``win`` holding the ``valid`` pixels, widened to whole GeoTIFF blocks
    (so untouched blocks stay unwritten: sparse); None when no pixel is valid."""
    rows = np.flatnonzero(valid.any(axis=1))
    cols = np.flatnonzero(valid.any(axis=0))
    if rows.size == 0:
        return None
    r0 = max(win[0], (win[0] + int(rows[0])) // BLOCK * BLOCK)
    r1 = min(win[1], -(-(win[0] + int(rows[-1]) + 1) // BLOCK) * BLOCK)
    c0 = max(win[2], (win[2] + int(cols[0])) // BLOCK * BLOCK)
    c1 = min(win[3], -(-(win[2] + int(cols[-1]) + 1) // BLOCK) * BLOCK)
    return r0, r1, c0, c1


def _merger(algorithm: str, bands: tuple[int, ...], dems: Sequence[Any], elevation: str,
            sampling: str, reject_bright: bool,
            ) -> Callable[[Any, Any, dict[str, np.ndarray], ProductReport], np.ndarray]:
    """The per-tile step: orthorectify the product on the tile grid and apply the merge rule."""
    from .ortho import orthorectify

    needed = tuple(sorted(set(bands) | ({NDVI_RED_BAND, NDVI_NIR_BAND}
                                        if algorithm == "max-ndvi" else set())))

    def merge(product: Any, tile_grid: Any, state: dict[str, np.ndarray],
              report: ProductReport) -> np.ndarray:
        result = orthorectify(product, grid=tile_grid, dems=dems, elevation=elevation,
                              sampling=sampling, bands=needed, allow_empty=True)
        inside = np.ascontiguousarray(result.valid, dtype=np.bool_)
        flags = np.ascontiguousarray(result.flags, dtype=np.uint8)
        valid = validated_pixels(inside, flags, reject_bright)
        segment = np.stack([np.asarray(result.bands[b], dtype=np.float32) for b in bands])
        report.processed += int(inside.sum())
        report.validated += int(valid.sum())
        if algorithm == "max-ndvi":
            red = np.asarray(result.bands[NDVI_RED_BAND], dtype=np.float32)
            nir = np.asarray(result.bands[NDVI_NIR_BAND], dtype=np.float32)
            report.added += int(merge_maximum_ndvi(state["synthesis"], state["ndvi"],
                                                   state["count"], segment, red, nir, valid))
        else:
            report.added += int(merge_minimum_radiance(state["synthesis"], state["count"],
                                                       segment, valid))
        return valid

    return merge


def _commit(work: Path, out_dir: Path, generation: str, source: SynthesisStore | None,
            algorithm: str, bands: tuple[int, ...], grid: Any,
            reports: list[ProductReport]) -> None:
    """Switch to the new generation: rename it, then replace the manifest atomically."""
    for entry in work.iterdir():  # data on disk before the switch
        with open(entry, "rb") as fh:
            os.fsync(fh.fileno())
    final = out_dir / generation
    os.replace(work, final)
    history = source.products if source is not None else []
    manifest = {"format": FORMAT, "version": 1, "generation": generation,
                "algorithm": algorithm, "bands": list(bands), "grid": grid_to_dict(grid),
                "products": history + [r.as_dict() for r in reports if r.error is None]}
    try:
        with atomic_path(out_dir / MANIFEST) as tmp:
            tmp.write_text(json.dumps(manifest, indent=1))
            with open(tmp, "rb") as fh:
                os.fsync(fh.fileno())
    except OSError as exc:
        raise OutputError(f"{out_dir}: cannot write the synthesis manifest ({exc})") from exc
    _remove_stale(out_dir)

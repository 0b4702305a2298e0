"""Synthesis of many MERIS products (MERSYN use cases 1 and 2, handbook section 3.1, Appendix C).

A synthesis is an Icechunk repository holding Zarr v3 arrays chunked by the output tile
(:mod:`napari_meris_ortho.io.synthesis_store`). The work is split into tasks: one per (product,
output tile) pair -- orthorectify the product on the tile and make its contribution
(:func:`engine.synthesis.segment_state`) -- and one per tile -- merge the contributions into
the stored tile with the associative, commutative rule of :func:`engine.synthesis.combine`
(ties: sensing time, then name) and write it. Tasks run in this process (``workers=0``), on an
embedded ``distributed.LocalCluster`` or on an existing dask cluster (``scheduler``); each tile
task writes into its own fork of the Icechunk session, the forks are merged and the run ends in
one commit listing the products. Only the tiles the products touch are read and written.

A run killed or failed before its commit leaves the store at its previous commit. A product
already in the synthesis (same product name and sensing time) is reported and skipped.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ._atomic import check_writable_dir
from .errors import MerisOrthoError, OptionsError, OutputError
from .io import synthesis_store as st
from .options import Elevation, MergeRule, OrthoOptions, Sampling, choices, parse
from .progress import ProgressCallback

if TYPE_CHECKING:
    from .geometry.grid import OutputGrid
    from .geometry.tiepoints import ProductGeometry
    from .io.dem import DemSource

log = logging.getLogger("napari_meris_ortho.synthesis")

ALGORITHMS = tuple(choices(MergeRule))
BLOCK = 256  # tiles are multiples of it
DEFAULT_TILE = 1024
ALL_BANDS = tuple(range(1, 16))
#: terrain parallax a tile must be within to be orthorectified: ``geometry.earth.MAX_TERRAIN_M``
#: seen at 45 deg view zenith or the product's largest one if larger (section 3.1)
SKIP_VIEW_ZENITH_DEG = 45.0
#: radiance layers: what their values are
RADIANCE_NOTE = ("TOA radiance (float32, 0 = background) = counts x sf_rad of the merged "
                 "products (Scaling Factor GADS, per product in the product table); no "
                 "further scaling applies")
STATUS_MERGED = "merged"
STATUS_FAILED = "failed"
STATUS_ALREADY = "already in the synthesis"


# --------------------------------------------------------------------------- grid helpers


def grid_to_dict(grid: OutputGrid) -> dict[str, Any]:
    """The output grid as JSON-able values (CRS as WKT)."""
    from .geometry.grid import parse_crs

    return {"crs": parse_crs(grid.crs).to_wkt(), "x0": float(grid.x0),
            "y0": float(grid.y0), "dx": float(grid.dx), "dy": float(grid.dy),
            "width": int(grid.width), "height": int(grid.height)}


def grid_from_dict(values: dict[str, Any]) -> OutputGrid:
    """Rebuild an ``geometry.grid.OutputGrid`` from :func:`grid_to_dict` values."""
    from .geometry.grid import OutputGrid

    return OutputGrid(values["crs"], values["x0"], values["y0"], values["dx"], values["dy"],
                      int(values["width"]), int(values["height"]))


def terrain_margin_px(product: ProductGeometry, grid: OutputGrid) -> int:
    """Output pixels beyond the zero-height segment boundary that a terrain point of the
    product may reach: ``geometry.earth.MAX_TERRAIN_M`` x tan(max(45 deg, largest view
    zenith)), + 2."""
    from .geometry.grid import terrain_margin_px as margin_px

    tp = product.tie_points
    zenith = max(SKIP_VIEW_ZENITH_DEG, float(np.nanmax(tp["view_zenith"])))
    return margin_px(grid, zenith, float(np.nanmax(np.abs(tp["latitude"]))))


def footprint_window(product: ProductGeometry, grid: OutputGrid, margin: int | None = None
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
    """Tiles of ``tile`` x ``tile`` pixels aligned on multiples of ``tile`` covering ``window``
    (each clipped to ``window``)."""
    row0, row1, col0, col1 = window
    for r in range((row0 // tile) * tile, row1, tile):
        for c in range((col0 // tile) * tile, col1, tile):
            yield max(r, row0), min(r + tile, row1), max(c, col0), min(c + tile, col1)


def tile_of(piece: tuple[int, int, int, int], tile: int, shape: tuple[int, int]
            ) -> tuple[int, int, int, int]:
    """The whole output tile (one chunk of the store) holding ``piece``."""
    r, c = (piece[0] // tile) * tile, (piece[2] // tile) * tile
    return r, min(r + tile, shape[0]), c, min(c + tile, shape[1])


# --------------------------------------------------------------------------- reading a store


@dataclass
class SynthesisStore:
    """A synthesis store opened at one snapshot (the branch head unless ``--at``)."""

    path: Path
    repo: Any
    snapshot: str
    attrs: dict[str, Any]

    @property
    def session(self) -> Any:
        return self.repo.readonly_session(snapshot_id=self.snapshot)

    @property
    def algorithm(self) -> str:
        return str(self.attrs["algorithm"])

    @property
    def bands(self) -> tuple[int, ...]:
        return tuple(int(b) for b in self.attrs["bands"])

    @property
    def grid(self) -> Any:
        return grid_from_dict(self.attrs["grid"])

    @property
    def tile(self) -> int:
        return int(self.attrs["tile"])

    @property
    def overviews(self) -> list[int]:
        return [int(f) for f in self.attrs.get("overviews", [])]

    @property
    def products(self) -> list[dict[str, Any]]:
        """The product table: entry k - 1 is the product of index k in the ``product`` layer."""
        return list(self.attrs.get("products", []))

    def layers(self) -> list[str]:
        """Layer names (``band_07``, ..., ``ndvi``, ``count``, ``product``)."""
        return st.layer_names(self.bands, self.algorithm)

    def read(self, name: str, window: tuple[int, int, int, int] | None = None,
             level: int = 1) -> np.ndarray:
        """Read one layer, optionally a window ``(row0, row1, col0, col1)``, at overview
        ``level`` (1 = full resolution, else a factor of :attr:`overviews`)."""
        if name not in self.layers():
            raise OptionsError(f"{self.path}: synthesis has no layer {name!r}")
        if level != 1 and level not in self.overviews:
            raise OptionsError(f"{self.path}: no overview level {level} (has {self.overviews})")
        if window is None:
            grid = self.grid
            window = (0, -(-grid.height // level), 0, -(-grid.width // level))
        return st.read_window(self.session.store, [name], window, level)[name]

    def band(self, band: int, window: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """Radiance of MERIS band ``band`` (float32, 0 = background)."""
        return self.read(st.band_layer(band), window)

    def ndvi(self, window: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """The maximum-NDVI layer decoded to float32 (Appendix C coding), NaN = background."""
        from .engine.synthesis import ndvi_decode

        return ndvi_decode(self.read("ndvi", window))

    def product_names(self) -> dict[int, str]:
        """Index in the ``product`` layer -> product name."""
        return {int(p["index"]): str(p["product_name"]) for p in self.products}

    def history(self) -> list[st.Commit]:
        """The synthesis commits up to this snapshot, newest first."""
        return st.history(self.repo, snapshot=self.snapshot)


def open_synthesis(path: str | os.PathLike[str], at: str | None = None) -> SynthesisStore:
    """Open the synthesis store ``path`` at its latest commit, or at snapshot ``at``."""
    root = Path(path)
    repo = st.open_repository(root)
    try:
        session = (repo.readonly_session(snapshot_id=at) if at
                   else repo.readonly_session(branch=st.BRANCH))
    except Exception as exc:  # icechunk's own error types
        what = f"snapshot {at!r}" if at else f"branch {st.BRANCH!r}"
        raise OptionsError(f"{root}: no {what} in the synthesis store ({exc})") from None
    attrs = st.read_attributes(session.store)
    if attrs is None:
        raise OptionsError(f"{root}: not a synthesis store (no synthesis committed there)")
    store = SynthesisStore(root, repo, session.snapshot_id, attrs)
    try:
        _ = store.grid, store.bands, store.algorithm, store.tile
    except (ValueError, KeyError, TypeError) as exc:
        raise OptionsError(f"{root}: damaged synthesis attributes ({exc})") from None
    return store


def is_synthesis(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` is a store holding a committed synthesis."""
    try:
        open_synthesis(path)
    except OptionsError:
        return False
    return True


# --------------------------------------------------------------------------- reports


@dataclass
class ProductReport:
    """Appendix B statistics of one product merged into the synthesis."""

    path: str
    processed: int = 0  # output pixels with an antecedent in the segment
    validated: int = 0  # ... whose flags allow them into the synthesis
    added: int = 0  # ... that this product holds in the synthesis after the run
    error: str | None = None
    product_name: str = ""
    sensing_start: str = ""
    status: str = STATUS_MERGED
    index: int = 0  # 1-based index in the product table (0: not merged)
    sf_rad: dict[int, float] = field(default_factory=dict)  # radiance factor per band

    @property
    def product(self) -> str:
        return Path(self.path).name

    def lines(self, synthesis_pixels: int) -> list[str]:
        """The log of Appendix B (processed/validated points, share of the synthesis)."""
        if self.status == STATUS_ALREADY:
            return [f"PRODUCT {self.path}: SKIPPED ({self.product_name} {self.sensing_start} "
                    f"is already in the synthesis)"]
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

    def table_entry(self) -> dict[str, Any]:
        """The product table entry of a merged product."""
        return {"index": self.index, "product_name": self.product_name,
                "product": self.product, "sensing_start": self.sensing_start,
                "sf_rad": {str(b): v for b, v in self.sf_rad.items()}}

    def commit_entry(self) -> dict[str, Any]:
        """What the commit metadata says of this product."""
        out: dict[str, Any] = {"product_name": self.product_name, "product": self.product,
                               "sensing_start": self.sensing_start, "status": self.status}
        if self.status == STATUS_MERGED:
            out.update(index=self.index, processed=self.processed, validated=self.validated,
                       added=self.added)
        if self.error is not None:
            out["error"] = self.error
        return out


@dataclass
class SynthesisResult:
    """Outcome of :func:`synthesize`: the store, its new snapshot and one report per product."""

    path: Path
    snapshot: str | None
    grid: OutputGrid
    algorithm: str
    bands: tuple[int, ...]
    reports: list[ProductReport] = field(default_factory=list)

    @property
    def failed(self) -> list[ProductReport]:
        return [r for r in self.reports if r.status == STATUS_FAILED]

    @property
    def merged(self) -> list[ProductReport]:
        return [r for r in self.reports if r.status == STATUS_MERGED]

    @property
    def skipped(self) -> list[ProductReport]:
        """Products already in the synthesis (same product name and sensing time)."""
        return [r for r in self.reports if r.status == STATUS_ALREADY]


# --------------------------------------------------------------------------- synthesize


def synthesize(products: Sequence[str | os.PathLike[str]], out: str | os.PathLike[str], *,
               algorithm: str | None = None, input: str | os.PathLike[str] | None = None,
               grid: OutputGrid | None = None, crs: Any = None,
               pixel_size: float | None = None,
               dems: Sequence[DemSource | str | os.PathLike[str]] = (), elevation: str = "dem",
               sampling: str = "nearest",
               bands: Sequence[int] | None = None, reject_bright: bool = False,
               tile: int = DEFAULT_TILE, progress: ProgressCallback | None = None,
               workers: int = 0, scheduler: str | None = None,
               geolocation: str | None = None,
               max_pixels: int | None = None) -> SynthesisResult:
    """Orthorectify ``products`` onto the synthesis grid and merge them (section 3.1 use cases
    1-2, Appendix C) into the synthesis store ``out``: one Icechunk commit.

    A new synthesis (no ``input``) takes ``grid``, or the footprint of the earliest readable
    product (sensing time, then name; with ``crs``/``pixel_size``), and ``bands`` (default all
    15). With ``input`` (may equal ``out``: update in place; else ``input`` is copied to ``out``
    first), grid and bands come from the input synthesis; giving grid options or bands too is
    refused as MERSYN refuses them. A product that cannot be read or orthorectified is reported
    in ``result.failed`` and skipped; one already in the synthesis in ``result.skipped``.

    ``workers``: 0 runs the tasks in this process, N > 0 on an embedded LocalCluster of N
    worker processes; ``scheduler``: address of an existing dask scheduler (the store path and
    the products must then be on storage every worker sees: absolute paths). ``progress(done,
    total)`` is called after each task; an exception raised by it cancels the run (nothing is
    committed). ``geolocation``: the location model of ``orthorectify`` (None: the tie points;
    "pixel": the products' per-pixel geolocation, a product without one fails).
    ``max_pixels``: largest grid of a new synthesis (default: what the free space of the
    output's file system holds, uncompressed); a larger one is an OptionsError.
    """
    from . import _synthesis_run as run

    out_dir = Path(out)
    if geolocation is not None:
        OrthoOptions.parse(geolocation=geolocation, elevation=elevation, n_dems=len(dems))
    source_path = _check_options(products, out_dir, algorithm, input, grid, crs, pixel_size,
                                 bands, tile, dems, elevation, sampling, workers, scheduler)
    if grid is not None and source_path is None:
        _check_grid_size(grid, len(bands or ALL_BANDS), out_dir, max_pixels)
    paths = [str(Path(p).absolute()) if scheduler else str(p) for p in products]
    with run.engine(workers, scheduler) as runner:
        created = _make_dir(out_dir)
        owner = False  # this run holds the lock of out_dir
        try:
            with contextlib.ExitStack() as locks:
                locks.enter_context(st.locked(out_dir))
                owner = True
                if source_path is not None and source_path.resolve() != out_dir.resolve():
                    locks.enter_context(st.locked(source_path))
                target = _target(out_dir, source_path, algorithm)
                result = run.Synthesis(
                    target, paths, algorithm=algorithm, grid=grid, crs=crs,
                    pixel_size=pixel_size, dems=[str(d) for d in dems], elevation=elevation,
                    sampling=sampling, bands=bands, reject_bright=reject_bright, tile=tile,
                    progress=progress, geolocation=geolocation,
                    max_pixels=max_pixels).run(runner)
                if created and result.snapshot is None:  # nothing merged: no store
                    shutil.rmtree(out_dir, ignore_errors=True)
        except BaseException:
            if created and owner and not is_synthesis(out_dir):
                shutil.rmtree(out_dir, ignore_errors=True)
            raise
    return result


def _make_dir(out_dir: Path) -> bool:
    """Create the store directory if missing; True when this run created it."""
    if out_dir.exists():
        if not out_dir.is_dir():
            raise OutputError(f"{out_dir}: exists and is not a directory")
        return False
    check_writable_dir(out_dir)
    try:
        out_dir.mkdir()
    except FileExistsError:  # another run created it meanwhile: the lock decides
        return False
    except OSError as exc:
        raise OutputError(f"{out_dir}: cannot create the synthesis store ({exc})") from exc
    return True


def _target(out_dir: Path, source_path: Path | None, algorithm: str | None) -> Any:
    """Under the lock: the repository to write and its synthesis (None: a new one). The "is
    there already a synthesis" check of a new synthesis is made here, under the lock."""
    from ._synthesis_run import Target

    if source_path is None:
        if st.is_repository(out_dir):
            if is_synthesis(out_dir):
                raise OptionsError(f"{out_dir}: already holds a synthesis; pass it as the input "
                                   "synthesis to update it, or choose another output store")
            return Target(out_dir, st.open_repository(out_dir), None)  # left by a killed run
        if (out_dir / st.OLD_MANIFEST).is_file():
            st.open_repository(out_dir)  # raises: old format
        if any(out_dir.iterdir()):
            raise OptionsError(f"{out_dir}: not empty and not a synthesis store")
        return Target(out_dir, st.create_repository(out_dir), None)
    source = open_synthesis(source_path)
    if algorithm is not None and algorithm != source.algorithm:
        raise OptionsError(f"{source_path}: is a {source.algorithm} synthesis, cannot update "
                           f"it with {algorithm}")
    if source_path.resolve() == out_dir.resolve():
        return Target(out_dir, source.repo, source)
    if any(out_dir.iterdir()):
        raise OptionsError(f"{out_dir}: already holds another synthesis or files")
    _copy_store(source_path, out_dir)
    return Target(out_dir, st.open_repository(out_dir), open_synthesis(out_dir))


def _copy_store(source: Path, out_dir: Path) -> None:
    """Copy the repository ``source`` into the empty ``out_dir`` (all its history)."""
    try:
        for entry in source.iterdir():
            if entry.is_dir():
                shutil.copytree(entry, out_dir / entry.name)
            else:
                shutil.copy2(entry, out_dir / entry.name)
    except OSError as exc:
        for entry in out_dir.iterdir():
            shutil.rmtree(entry, ignore_errors=True)
        raise OutputError(f"{out_dir}: cannot copy the input synthesis ({exc})") from exc


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
                   input: Any, grid: OutputGrid | None, crs: Any, pixel_size: float | None,
                   bands: Sequence[int] | None, tile: int, dems: Sequence[Any],
                   elevation: str, sampling: str, workers: int, scheduler: str | None
                   ) -> Path | None:
    """MERSYN's parameter consistency checks (Appendix C), before any work."""
    if algorithm is not None:
        parse(MergeRule, algorithm)
    if not products:
        raise OptionsError("no MERIS product given")
    if tile < BLOCK or tile % BLOCK:
        raise OptionsError(f"tile size {tile}: must be a positive multiple of {BLOCK}")
    if workers < 0:
        raise OptionsError(f"workers {workers}: must be >= 0 (0: in this process)")
    if scheduler is not None and not out_dir.is_absolute():
        raise OptionsError(f"{out_dir}: with a dask scheduler the store must be on storage "
                           "every worker sees: give an absolute path")
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
        return None
    if grid is not None or crs is not None or pixel_size is not None or bands is not None:
        raise OptionsError("when an input synthesis is given, the grid (CRS, extent, pixel "
                           "size) and the bands come from it and shall not be given")
    source = open_synthesis(input)  # refuse a non-synthesis early (again under the lock)
    if algorithm is not None and algorithm != source.algorithm:
        raise OptionsError(f"{input}: is a {source.algorithm} synthesis, cannot update it "
                           f"with {algorithm}")
    return Path(input)


def _new_grid(product: ProductGeometry, crs: Any, pixel_size: float | None) -> OutputGrid:
    """Grid of a new synthesis: the smallest rectangle holding the product's segment
    boundary (section 3.1, fig. 19), nominal FR/RR pixel size unless ``pixel_size``."""
    from .engine.boundary import segment_boundary
    from .geometry.grid import FR_PIXEL_SIZE_M, RR_PIXEL_SIZE_M, default_grid

    boundary = segment_boundary(product.tie_points["latitude"], product.tie_points["longitude"])
    resolution = FR_PIXEL_SIZE_M if product.samples_per_tie_point >= 64 else RR_PIXEL_SIZE_M
    return default_grid(boundary, resolution, crs if crs is not None else "EPSG:4326",
                        pixel_size=pixel_size)


def _check_grid_size(grid: OutputGrid, n_bands: int, out_dir: Path,
                     max_pixels: int | None) -> None:
    """A new synthesis grid must fit the free space of the output's file system (its layers
    uncompressed: the bands and the bookkeeping layers) or ``max_pixels``."""
    from .geometry.grid import check_grid_size

    parent = out_dir if out_dir.exists() else out_dir.absolute().parent
    try:
        free: int | None = shutil.disk_usage(parent).free
    except OSError:
        free = None
    check_grid_size(grid.width, grid.height, (grid.dx, grid.dy), 4 * (n_bands + 2),
                    max_pixels, free, f"the free space in {parent}")


# --------------------------------------------------------------------------- export


def export_cog(store: SynthesisStore, out: str | os.PathLike[str], *,
               bands: Sequence[int] | None = None, layer: str | None = None,
               progress: ProgressCallback | None = None) -> Path:
    """Write bands (default all of the synthesis) or one other ``layer`` (``ndvi``, ``count``,
    ``product``) of ``store`` as a Cloud-Optimized GeoTIFF (deflate, overviews). The store is
    read tile by tile into a tiled temporary GeoTIFF, then copied with GDAL's COG driver."""
    import tempfile

    import rasterio
    import rasterio.shutil
    from rasterio.errors import RasterioError
    from rasterio.windows import Window

    from ._atomic import atomic_path
    from .io.geotiff import meris_band_description

    if layer is not None and bands is not None:
        raise OptionsError("choose bands or one other layer, not both")
    if layer is not None:
        others = [n for n in store.layers() if not n.startswith("band_")]
        if layer not in others:
            raise OptionsError(f"{store.path}: no layer {layer!r} to export (the synthesis has "
                               f"{', '.join(others)})")
        names, descriptions = [layer], [layer]
    else:
        chosen = list(store.bands) if bands is None else [int(b) for b in bands]
        missing = [b for b in chosen if b not in store.bands]
        if missing:
            raise OptionsError(f"{store.path}: bands {missing} are not in the synthesis "
                               f"(it has {list(store.bands)})")
        names = [st.band_layer(b) for b in chosen]
        descriptions = [meris_band_description(b) for b in chosen]
    grid = store.grid
    dtype = st.layer_dtype(names[0])
    profile = dict(driver="GTiff", width=grid.width, height=grid.height, count=len(names),
                   dtype=dtype, crs=rasterio.crs.CRS.from_wkt(grid.crs.to_wkt()),
                   transform=grid.transform, nodata=0, tiled=True, blockxsize=BLOCK,
                   blockysize=BLOCK, BIGTIFF="IF_SAFER")
    windows = list(tiles((0, grid.height, 0, grid.width), store.tile))
    session_store = store.session.store
    try:
        with tempfile.TemporaryDirectory(dir=Path(out).parent if Path(out).parent.is_dir()
                                         else None) as tmp_dir, \
                atomic_path(out, suffix=".tif") as tmp:
            work = Path(tmp_dir) / "tiles.tif"
            with rasterio.open(work, "w", **profile) as ds:
                ds.update_tags(algorithm=store.algorithm, snapshot=store.snapshot,
                               products=" ".join(store.product_names().values()))
                for i, d in enumerate(descriptions, start=1):
                    ds.set_band_description(i, d)
                for k, w in enumerate(windows):
                    arrays = st.read_window(session_store, names, w)
                    win = Window(w[2], w[0], w[3] - w[2], w[1] - w[0])
                    for i, name in enumerate(names, start=1):
                        ds.write(arrays[name], i, window=win)
                    if progress is not None:
                        progress(k + 1, len(windows) + 1)
            rasterio.shutil.copy(work, tmp, driver="COG", compress="DEFLATE",
                                 blocksize=BLOCK, overview_resampling="nearest",
                                 BIGTIFF="IF_SAFER")
    except (RasterioError, OSError) as exc:
        raise OutputError(f"{out}: cannot write the Cloud-Optimized GeoTIFF ({exc})") from exc
    if progress is not None:
        progress(len(windows) + 1, len(windows) + 1)
    return Path(out)


def message_of(exc: BaseException) -> str:
    return str(exc) or type(exc).__name__


__all__ = ["ALGORITHMS", "MerisOrthoError", "ProductReport", "SynthesisResult",
           "SynthesisStore", "is_synthesis", "open_synthesis", "synthesize"]

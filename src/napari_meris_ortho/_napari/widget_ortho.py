"""Orthorectify widget: MERSYN's use cases in napari (handbook sections 3.1-3.4).

Products (one or several N1 files), an ordered DEM list (tried in order, then the tie points,
section 3.3), the elevation source, the selection algorithm (mapping = use case 3, minimum
radiance or maximum NDVI synthesis = use cases 1-2), sampling, output CRS and pixel size, bands
and an optional output file. The work runs in a thread worker with a napari progress bar and a
cancel button; the result is added in the world frame of ``_layers`` with its geometry layers
(footprint, tie-point facets, parallax shift vectors, iterations, elevation source).
"""

from __future__ import annotations

import tempfile
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from magicgui.types import FileDialogMode
from magicgui.widgets import (
    CheckBox,
    ComboBox,
    Container,
    FileEdit,
    FloatSpinBox,
    Label,
    LineEdit,
    PushButton,
    Select,
    SpinBox,
)

from ..errors import MerisOrthoError, OptionsError
from ..geometry.grid import OutputGrid
from ..options import Elevation, MergeRule, Sampling, choices
from ..progress import ProgressCallback
from .geometry_layers import geometry_layers
from .product_layers import band_layers, diagnostic_layers
from .world import move_to_frame, same_crs, viewer_frame

if TYPE_CHECKING:
    import napari

    from ..io.n1 import MerisL1bProduct
    from ..ortho import OrthoResult

#: "mapping" orthorectifies every product on its own; the merge rules build a synthesis
ALGORITHMS = ("mapping", *choices(MergeRule))
#: location models offered: the tie points (parallax from the DEMs) or the product's per-pixel
#: terrain-corrected geolocation (FRG/FSG N1, .SEN3)
GEOLOCATIONS = ("tiepoints", "pixel")
CRS_UTM = "UTM zone of the footprint"
CRS_GEOGRAPHIC = "geographic (EPSG:4326)"
CRS_EPSG = "EPSG code"
DEM_FILE, DEM_DIR = "GeoTIFF / SRTM30 tile", "GETASSE30 directory"
LayerData = tuple[Any, dict[str, Any], str]


class Cancelled(MerisOrthoError):
    """The user pressed Cancel."""


@dataclass
class RunSettings:
    """Everything the Orthorectify widget asks for (defaults = MERSYN's)."""

    products: list[Path]
    dems: list[Path] = field(default_factory=list)
    elevation: str = "dem"
    algorithm: str = "mapping"
    sampling: str = "nearest"
    crs: str = CRS_UTM
    epsg: int | None = None
    pixel_size_m: float = 0.0  # 0: the nominal FR 260 m / RR 1040 m
    bands: tuple[int, ...] | None = (7, 5, 2)
    #: location model: "tiepoints" (with the parallax) or "pixel" (FRG/FSG/SEN3 per-pixel
    #: terrain-corrected geolocation, no DEM)
    geolocation: str = "tiepoints"
    output: Path | None = None
    geometry: bool = True
    exaggeration: float = 10.0
    vector_step: int = 16


def parse_bands(text: str) -> tuple[int, ...] | None:
    """"7,5,2" -> (7, 5, 2); "all" or "" -> None (all 15 bands). Raises OptionsError."""
    text = text.strip().lower()
    if text in ("", "all"):
        return None
    try:
        bands = tuple(int(t) for t in text.replace(" ", ",").split(",") if t)
    except ValueError:
        raise OptionsError(f"bands must be numbers 1..15 separated by commas, got {text!r}"
                           ) from None
    if not bands or any(not 1 <= b <= 15 for b in bands):
        raise OptionsError(f"bands must be 1..15, got {text!r}")
    return bands


def output_crs(options: RunSettings, tie_points: dict[str, np.ndarray]) -> Any:
    """The output CRS: the UTM zone of the footprint centre, EPSG:4326 or the given EPSG code."""
    from ..geometry.grid import parse_crs, utm_crs_for

    if options.crs == CRS_GEOGRAPHIC:
        return parse_crs("EPSG:4326")
    if options.crs == CRS_EPSG:
        if not options.epsg:
            raise OptionsError("output CRS 'EPSG code' needs an EPSG code")
        return parse_crs(f"EPSG:{int(options.epsg)}")
    lat, lon = tie_points["latitude"], tie_points["longitude"]
    centre_lon = float(np.degrees(np.angle(np.mean(np.exp(1j * np.radians(lon))))))
    return utm_crs_for(centre_lon, float(np.mean(lat)))


def _pixel_size(options: RunSettings, product: MerisL1bProduct, crs: Any) -> float:
    from ..geometry.grid import pixel_size_for

    metres = options.pixel_size_m or float(
        getattr(getattr(product, "resolution", None), "column_spacing_m", 260.0))
    return pixel_size_for(metres, crs)


@dataclass
class OrthoRun:
    """What a run produced: per product, its name, tie points, OrthoResult-like values."""

    items: list[dict[str, Any]]
    options: RunSettings
    written: list[Path] = field(default_factory=list)


def run_orthorectify(options: RunSettings, progress: ProgressCallback | None = None) -> OrthoRun:
    """Run the chosen algorithm (no Qt): mapping of every product, or a synthesis."""
    from ..io.product import read_product

    if not options.products:
        raise OptionsError("choose at least one N1 product")
    if options.elevation != "dem" and options.dems:
        raise OptionsError(f"DEMs are only used with elevation 'dem', not {options.elevation!r}")
    products = [read_product(p) for p in options.products]
    crs = output_crs(options, products[0].tie_points)
    if options.algorithm == "mapping":
        return _run_mapping(products, crs, options, progress)
    return _run_synthesis(products, crs, options, progress)


def _run_mapping(products: list[Any], crs: Any, options: RunSettings,
                 progress: ProgressCallback | None) -> OrthoRun:
    from ..ortho import orthorectify

    items, written = [], []
    n = len(products)
    for k, product in enumerate(products):
        def part(done: int, total: int, k: int = k) -> None:
            if progress is not None:
                progress(k * 1000 + int(1000 * done / max(total, 1)), n * 1000)

        pixel = options.geolocation == "pixel"
        result = orthorectify(
            product, dems=[] if pixel else list(options.dems), elevation=options.elevation,
            sampling=options.sampling, bands=options.bands, diagnostics=options.geometry,
            progress=part, crs=crs, grid=_grid_for(product, crs, options),
            geolocation="pixel" if pixel else None)
        name = Path(product.path).stem + (" pixel-geolocation" if pixel else "")
        items.append({"name": name, "tie_points": product.tie_points,
                      "bands": result.bands, "grid": result.grid, "valid": result.valid,
                      "diagnostics": result.diagnostics, "stats": result.stats})
        if options.output is not None:
            written.append(_write_mapping(result, product, options.output, k, n))
    return OrthoRun(items, options, written)


def _grid_for(product: MerisL1bProduct, crs: Any, options: RunSettings) -> OutputGrid:
    """The default grid (smallest rectangle holding the segment boundary, section 3.1)."""
    from ..engine.boundary import segment_boundary
    from ..geometry.grid import default_grid

    boundary = segment_boundary(product.tie_points["latitude"], product.tie_points["longitude"])
    return default_grid(boundary, crs=crs, pixel_size=_pixel_size(options, product, crs))


def _write_mapping(result: OrthoResult, product: MerisL1bProduct, output: Path, k: int,
                   n: int) -> Path:
    from ..io.geotiff import meris_band_description, write_geotiff

    path = Path(output)
    if n > 1:
        path = path.with_name(f"{path.stem}_{k + 1}{path.suffix or '.tif'}")
    bands = sorted(result.bands)
    return write_geotiff(path, [result.bands[b] for b in bands], result.grid,
                         descriptions=[meris_band_description(b, product.wavelengths[b - 1])
                                       for b in bands])


def _run_synthesis(products: list[Any], crs: Any, options: RunSettings,
                   progress: ProgressCallback | None) -> OrthoRun:
    from ..synthesis import open_synthesis, synthesize

    out = Path(options.output) if options.output else Path(tempfile.mkdtemp(prefix="synthesis-"))
    pixel = options.geolocation == "pixel"
    result = synthesize(
        [p.path for p in products], out, algorithm=options.algorithm, crs=crs,
        pixel_size=_pixel_size(options, products[0], crs),
        dems=[] if pixel else list(options.dems), elevation=options.elevation,
        sampling=options.sampling, bands=options.bands, progress=progress,
        geolocation="pixel" if pixel else None)
    if not result.merged:
        reasons = "; ".join(f"{r.path}: {r.error}" for r in result.failed)
        raise OptionsError(f"no product could be merged into the synthesis ({reasons})")
    store = open_synthesis(out)
    bands = {b: store.read(f"band_{b:02d}") for b in store.bands}
    valid = store.read("count") > 0
    items = [{"name": f"synthesis {options.algorithm}", "tie_points": None, "bands": bands,
              "grid": store.grid, "valid": valid, "diagnostics": {}, "stats": {}}]
    items += [{"name": Path(p.path).stem, "tie_points": p.tie_points, "bands": {},
               "grid": store.grid, "valid": None, "diagnostics": {}, "stats": {}}
              for p in products]
    return OrthoRun(items, options, [out])


def run_layers(run: OrthoRun, world: OutputGrid | None = None) -> list[LayerData]:
    """napari layer tuples of a run: bands, diagnostics and geometry, in the world frame.

    ``world``: the viewer's frame; results in another CRS are moved into it (reprojected).
    """
    layers: list[LayerData] = []
    for item in run.items:
        frame = item["grid"]
        item_layers = _item_layers(item, frame, run.options)
        if world is not None and not same_crs(world.crs, frame.crs):
            item_layers = [move_to_frame(layer, frame, world) for layer in item_layers]
        layers += item_layers
    return layers


def _item_layers(item: dict[str, Any], frame: OutputGrid, opts: RunSettings) -> list[LayerData]:
    """Layers of one product (or of the synthesis) on its own grid."""
    layers: list[LayerData] = []
    meta = {"stats": item["stats"], "algorithm": opts.algorithm, "elevation": opts.elevation}
    if item["bands"]:
        layers += band_layers(item["bands"], frame, item["name"], meta, item["valid"])
    if opts.geometry and item["diagnostics"]:
        layers += diagnostic_layers(item["diagnostics"], frame, item["name"],
                                    [Path(d).name for d in opts.dems])
    if opts.geometry and item["tie_points"] is not None:
        layers += geometry_layers(item["tie_points"], frame, item["name"], item["diagnostics"],
                                  valid=item["valid"], exaggeration=opts.exaggeration,
                                  step=opts.vector_step)
    return layers


def warm_up_in_background() -> None:
    """Compile the engine's numba kernels in a background thread (``warmup``)."""
    from ..warmup import warm_up_in_background as start

    start()


def _import_engine() -> None:
    """Import the engine in the main thread (module-level pyproj objects made here)."""
    from .. import ortho, synthesis  # noqa: F401
    from ..engine import boundary  # noqa: F401
    from ..geometry import grid  # noqa: F401
    from ..io import dem, geotiff, n1  # noqa: F401


def in_python_thread(func: Any, *args: Any) -> Any:
    """Run ``func(*args)`` in a fresh Python thread and return its result (or raise).

    napari's thread workers run on QThreadPool threads whose Python thread state is dropped
    after every job; pyproj's per-thread PROJ context goes with it and the next job on a pooled
    thread crashes inside PROJ (segmentation fault in ``proj_create``, reproduced with a bare
    QRunnable). A Python thread keeps one thread state for the whole job.
    """
    outcome: dict[str, Any] = {}

    def target() -> None:
        try:
            outcome["value"] = func(*args)
        except BaseException as exc:  # re-raised in the worker thread
            outcome["error"] = exc

    thread = threading.Thread(target=target, name="meris-ortho-job", daemon=True)
    thread.start()
    thread.join()
    if "error" in outcome:
        raise outcome["error"]
    return outcome["value"]


class OrthorectifyWidget(Container):
    """The "Orthorectify" dock widget (thread worker, progress bar, cancel)."""

    def __init__(self, viewer: napari.viewer.Viewer) -> None:
        self.viewer = viewer
        self.products = FileEdit(label="products (N1, SEN3 manifest)",
                                 mode=FileDialogMode.EXISTING_FILES,
                                 filter="*.N1 *.n1 xfdumanifest.xml")
        self.dem_kind = ComboBox(label="DEM type", choices=[DEM_FILE, DEM_DIR], value=DEM_FILE)
        self.dem_path = FileEdit(label="DEM", mode=FileDialogMode.EXISTING_FILE)
        self.dem_add = PushButton(text="Add DEM")
        self.dem_list = Select(label="DEMs (in order)", choices=[])
        self.dem_remove = PushButton(text="Remove")
        self.dem_up = PushButton(text="Up")
        self.dem_down = PushButton(text="Down")
        dem_buttons = Container(widgets=[self.dem_remove, self.dem_up, self.dem_down],
                                layout="horizontal", labels=False)
        self.elevation = ComboBox(label="elevation", choices=choices(Elevation),
                                  value=Elevation.DEM.value)
        self.geolocation = ComboBox(label="geolocation", choices=list(GEOLOCATIONS),
                                    value="tiepoints")
        self.algorithm = ComboBox(label="selection", choices=list(ALGORITHMS), value="mapping")
        self.sampling = ComboBox(label="sampling", choices=choices(Sampling),
                                 value=Sampling.NEAREST.value)
        self.crs = ComboBox(label="output CRS", choices=[CRS_UTM, CRS_GEOGRAPHIC, CRS_EPSG],
                            value=CRS_UTM)
        self.epsg = SpinBox(label="EPSG code", value=4326, min=1024, max=999999, visible=False)
        self.pixel_size = FloatSpinBox(label="pixel size (m, 0 = nominal)", value=0.0, min=0.0,
                                       max=100_000.0, step=10.0)
        self.bands = LineEdit(label="bands", value="7,5,2")
        self.geometry = CheckBox(label="geometry layers", value=True)
        self.exaggeration = FloatSpinBox(label="parallax exaggeration", value=10.0, min=0.1,
                                         max=1000.0)
        self.vector_step = SpinBox(label="vector every (px)", value=16, min=1, max=512)
        self.output = FileEdit(label="output (optional)", mode=FileDialogMode.OPTIONAL_FILE,
                               nullable=True)
        self.run_button = PushButton(text="Run")
        self.cancel_button = PushButton(text="Cancel", enabled=False)
        self.status = Label(value="")
        super().__init__(widgets=[
            self.products, self.dem_kind, self.dem_path, self.dem_add, self.dem_list,
            dem_buttons, self.elevation, self.geolocation, self.algorithm, self.sampling,
            self.crs, self.epsg,
            self.pixel_size, self.bands, self.geometry, self.exaggeration, self.vector_step,
            self.output, self.run_button, self.cancel_button, self.status,
        ])
        self._dems: list[Path] = []
        self._cancel = threading.Event()
        self._progress_state = (0, 1)
        self._pbar: Any = None
        self._timer: Any = None
        self.worker: Any = None
        self.last_run: OrthoRun | None = None
        self.dem_kind.changed.connect(self._dem_kind_changed)
        self.dem_add.changed.connect(lambda _=None: self.add_dem(self.dem_path.value))
        self.dem_remove.changed.connect(self._remove_selected)
        self.dem_up.changed.connect(lambda _=None: self._move_selected(-1))
        self.dem_down.changed.connect(lambda _=None: self._move_selected(+1))
        self.crs.changed.connect(lambda v: setattr(self.epsg, "visible", v == CRS_EPSG))
        self.run_button.changed.connect(lambda _=None: self.start())
        self.cancel_button.changed.connect(lambda _=None: self.cancel())
        _import_engine()
        warm_up_in_background()  # numba compiles while the user fills the form

    # ---------------------------------------------------------------- DEM list
    @property
    def dems(self) -> list[Path]:
        """The DEMs in the order they are tried (section 3.3)."""
        return list(self._dems)

    def _sync_dem_list(self, selected: list[Path] | None = None) -> None:
        self.dem_list.choices = [(str(p), p) for p in self._dems]
        self.dem_list.value = [p for p in (selected or []) if p in self._dems]

    def _dem_kind_changed(self, kind: str) -> None:
        self.dem_path.mode = (FileDialogMode.EXISTING_DIRECTORY if kind == DEM_DIR
                              else FileDialogMode.EXISTING_FILE)

    def add_dem(self, path: str | Path | tuple[Path, ...] | None) -> None:
        """Append a DEM (GeoTIFF, SRTM30 tile or GETASSE30 directory) after checking it opens."""
        from ..io.dem import open_dem

        p = Path(path) if isinstance(path, str | Path) else Path()
        if str(p) in ("", ".") or not p.exists():
            self.status.value = f"DEM not found: {path}"
            return
        try:
            open_dem(p).close()
        except MerisOrthoError as exc:
            self.status.value = str(exc)
            return
        if p not in self._dems:
            self._dems.append(p)
        self._sync_dem_list()

    def remove_dem(self, path: Path) -> None:
        self._dems.remove(Path(path))
        self._sync_dem_list()

    def move_dem(self, path: Path, offset: int) -> None:
        """Move a DEM up (offset -1) or down (+1) in the order of preference."""
        i = self._dems.index(Path(path))
        j = min(max(i + offset, 0), len(self._dems) - 1)
        self._dems.insert(j, self._dems.pop(i))
        self._sync_dem_list([Path(path)])

    def _remove_selected(self, _value: Any = None) -> None:
        for p in list(self.dem_list.value):
            self.remove_dem(p)

    def _move_selected(self, offset: int) -> None:
        selected = list(self.dem_list.value)
        for p in selected if offset < 0 else selected[::-1]:
            self.move_dem(p, offset)
        self._sync_dem_list(selected)

    # ---------------------------------------------------------------- options
    def settings(self) -> RunSettings:
        """The widget's values as RunSettings (raises OptionsError on bad input)."""
        chosen = self.products.value
        paths = chosen if isinstance(chosen, tuple) else () if chosen is None else (chosen,)
        products = [Path(p) for p in paths if Path(p).is_file()]
        output = self.output.value if isinstance(self.output.value, Path) else None
        return RunSettings(
            products=products, dems=self.dems, elevation=self.elevation.value,
            geolocation=self.geolocation.value, algorithm=self.algorithm.value,
            sampling=self.sampling.value, crs=self.crs.value,
            epsg=int(self.epsg.value), pixel_size_m=float(self.pixel_size.value),
            bands=parse_bands(self.bands.value), output=output, geometry=self.geometry.value,
            exaggeration=float(self.exaggeration.value), vector_step=int(self.vector_step.value))

    # ---------------------------------------------------------------- running
    def _report(self, done: int, total: int) -> None:
        """Progress callback (worker thread): records the state, raises on cancel."""
        if self._cancel.is_set():
            raise Cancelled("cancelled by the user")
        self._progress_state = (done, total)

    def start(self) -> Any:
        """Start a run in a thread worker; returns the worker (None when options are bad)."""
        from napari.qt.threading import create_worker
        from napari.utils import progress
        from qtpy.QtCore import QTimer

        try:
            options = self.settings()
            if not options.products:
                raise OptionsError("choose at least one N1 product")
        except MerisOrthoError as exc:
            self.status.value = str(exc)
            return None
        _import_engine()
        self._cancel.clear()
        self._progress_state = (0, 1)
        self._pbar = progress(total=1000, desc="Orthorectify")
        self._timer = QTimer()
        self._timer.timeout.connect(self._update_progress)
        self._timer.start(100)
        self.worker = create_worker(
            in_python_thread, run_orthorectify, options, self._report, _start_thread=False,
            _connect={"returned": self._done, "errored": self._failed,
                      "finished": self._finished})
        self.run_button.enabled, self.cancel_button.enabled = False, True
        self.status.value = "running..."
        self.worker.start()
        return self.worker

    @property
    def running(self) -> bool:
        """True from ``start`` until the worker has finished (results added)."""
        return self._pbar is not None

    def cancel(self) -> None:
        """Ask the running worker to stop at its next progress report."""
        self._cancel.set()
        self.status.value = "cancelling..."

    def _update_progress(self) -> None:
        done, total = self._progress_state
        if self._pbar is not None:
            target = int(1000 * done / max(total, 1))
            self._pbar.update(max(target - self._pbar.n, 0))

    def _done(self, run: OrthoRun) -> None:
        self.last_run = run
        for data, kwargs, kind in run_layers(run, viewer_frame(self.viewer.layers)):
            getattr(self.viewer, f"add_{kind}")(data, **kwargs)
        written = f"; wrote {', '.join(str(p) for p in run.written)}" if run.written else ""
        self.status.value = f"done: {len(run.items)} result(s){written}"

    def _failed(self, exc: BaseException) -> None:
        if isinstance(exc, MerisOrthoError):
            self.status.value = str(exc)
        else:
            self.status.value = f"failed: {type(exc).__name__}: {exc}"

    def _finished(self) -> None:
        if self._timer is not None:
            self._timer.stop()
        if self._pbar is not None:
            self._pbar.close()
            self._pbar = None
        self.run_button.enabled, self.cancel_button.enabled = True, False

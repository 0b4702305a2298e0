"""Orthorectify widget: MERSYN's use cases in napari (handbook sections 3.1-3.4).

Products (one or several N1 files), an ordered DEM list (tried in order, then the tie points,
section 3.3), the elevation source, the selection algorithm (mapping = use case 3, minimum
radiance or maximum NDVI synthesis = use cases 1-2), sampling, output CRS and pixel size, bands
and an optional output file. The work (``ortho_run``) runs in a napari thread worker with a
progress bar in the widget and in the activity dock, and a cancel button; closing the viewer
cancels it. Everything heavy (reading, orthorectification, layer data, contrast limits, RGB
stretch, geometry, the napari layer objects) runs in the job (``build_layers``); the Qt thread
only inserts the ready layers (rasters as pyramids), one per event-loop turn and without
making each the active layer, in the world frame (``world``); a rerun replaces the layers of the
same names and every layer an earlier run made of the same product (``layer_source``), removed
one per turn in one napari batch (one garbage collection); Cancel in the middle undoes the
changes made. A finished run keeps nothing alive but its layers. The settings are remembered
(``settings``).
"""

from __future__ import annotations

import contextlib
import gc
import threading
import time
import weakref
from collections.abc import Callable, Collection
from pathlib import Path
from typing import TYPE_CHECKING, Any

from magicgui.types import FileDialogMode
from magicgui.widgets import (
    CheckBox,
    ComboBox,
    Container,
    FileEdit,
    FloatSpinBox,
    LineEdit,
    ProgressBar,
    PushButton,
    Select,
    SpinBox,
)

from .._process import unit_registry_from_disk
from ..bands import Sensor, band_table
from ..errors import MerisOrthoError, OptionsError
from ..options import (
    PARALLAX_CHOICES,
    Elevation,
    Hidden,
    Parallax,
    Sampling,
    SearchMethod,
    choices,
)
from ._qt.closing import OnClose
from ._qt.insertion import (
    SHOW_STEP_MS,
    add_controls,
    append_inactive,
    build_overlays,
    canvas_updates,
    dash_pattern_steps,
    hide_for_now,
    in_turns,
    make_controls,
    polish_controls,
    scene_graph_paused,
    show_in,
    start_after_paint,
    thumbnails_later,
)
from ._qt.waiting import ThreadCall
from .layout import ScrolledForm, StatusLabel, frame_layers
from .legend import glyph_steps, show_legends
from .memory import collections_paused, freeze_long_lived, frozen, thaw, trim_after_removals
from .ortho_run import (
    ALGORITHMS,
    CRS_EPSG,
    CRS_GEOGRAPHIC,
    CRS_LIKE,
    CRS_UTM,
    GEOLOCATIONS,
    MAPPING,
    Cancelled,
    OrthoRun,
    RunSettings,
    default_bands,
    layer_source,
    output_crs,
    parse_bands,
    products_sensor,
    run_layers,
    run_orthorectify,
)
from .settings import remember
from .status import show_map_coordinates
from .world import source_frame, viewer_frame
from .writer import layers_reading

if TYPE_CHECKING:
    import napari

    from ._qt.warm import WarmUp

DEM_FILE, DEM_DIR = "GeoTIFF / SRTM30 tile", "GETASSE30 directory"
#: what the CRS choices mean, the default first
CRS_TOOLTIP = ("coordinate system of the output grid. Default: the UTM zone of the footprint's "
               "centre, in metres as the viewer's world (the CLI's map defaults to geographic "
               "EPSG:4326, as MERSYN). 'like a layer': the CRS, pixel size and grid of an open "
               "GeoTIFF or orthorectified layer")
#: seconds to wait for a cancelled job when the viewer closes
CLOSE_TIMEOUT_S = 60.0

__all__ = ["CRS_EPSG", "CRS_GEOGRAPHIC", "CRS_UTM", "Cancelled", "RunSettings", "OrthoRun",
           "OrthorectifyWidget", "output_crs", "parse_bands", "run_layers", "run_orthorectify"]


def _start_warm_up(widget: OrthorectifyWidget) -> None:
    """The dock's warm-up in idle turns, held back while a run goes on (``warm``); kept on
    the widget, whose later opening steps wait for its first-layer imports."""
    from ._qt.warm import start_warm_up

    ref = weakref.ref(widget)

    def paused() -> bool:
        alive = ref()
        return alive is None or alive.running or bool(alive._queue)

    widget._warm = start_warm_up(paused, widget.native)
    if widget._warm.pieces is not None and not frozen():
        # napari's objects out of the automatic full collections the warm-up's imports set
        # off (0.25 s each in the Qt thread's turn otherwise)
        freeze_long_lived(widget.viewer, collect=False)


def _engine_import_steps() -> list[Callable[[], Any]]:
    """The engine's modules a run needs, leaves first, one step each (about 0.3 s together):
    imported in the main thread (their module-level pyproj objects made there), in turns of the
    event loop after the dock's opening."""
    def grid() -> None:
        from ..geometry import grid  # noqa: F401

    def location() -> None:
        from ..engine import boundary, pixeldem, pixelgeo  # noqa: F401

    def products() -> None:
        from ..products import n1  # noqa: F401

    def mapping() -> None:
        from .. import ortho  # noqa: F401

    def synthesis() -> None:
        from ..synthesis import api  # noqa: F401

    return [grid, location, products, mapping, synthesis]


#: s the dock's opening steps wait after a layer went into the viewer (a user's open: napari
#: draws its first frames and thumbnails), so that none of them (the legend's first draw, the
#: collection before the freeze: 0.2-0.35 s each) falls in what the user waits for
SETTLE_AFTER_INSERT_S = 1.0
#: ms between two tries of the opening's ``freeze_long_lived`` while a run goes on
FREEZE_RETRY_MS = 500


def _while_open(widget: weakref.ref[OrthorectifyWidget],
                method: Callable[[OrthorectifyWidget], Any]) -> Callable[[], None]:
    """A step of the widget's opening: ``method(widget)`` unless the widget has gone."""
    def step() -> None:
        alive = widget()
        if alive is not None and not alive._closed:
            method(alive)
    return step


class _Job(ThreadCall):
    """One run in a plain Python thread (``ThreadCall``: why not napari's pooled worker
    threads), waited for by a napari thread worker; the widget can join it when the viewer
    closes."""

    def __init__(self, func: Any, *args: Any) -> None:
        super().__init__(func, *args, name="meris-ortho-job")

    def __call__(self) -> Any:
        self.start().thread.join()
        return self.outcome()


def build_layers(options: RunSettings, report: Any, check: Any, world: Any,
                 replacing: Collection[str] = ()) -> tuple[OrthoRun, list[Any]]:
    """The whole run off the Qt thread: orthorectification, layer data (contrast limits, RGB
    stretch, reprojection into the viewer's ``world`` frame, geometry) and the napari layer
    objects themselves, so that the Qt thread only inserts them; ``check()`` raises Cancelled
    between layers. The returned run keeps no arrays (``OrthoRun.release``).

    Python's full collection, which holds the GIL (0.1-0.2 s with a session's layers), runs at
    most once here: paused while the layers are made, then run at the end, not in one of their
    insertion turns on the Qt thread; not at all when a layer replaces one of ``replacing`` (the
    viewer's layer names at Run): napari collects after the replaced layers' removal, before
    the insertions."""
    from napari.layers import Layer

    from .status import wrap_status, wrap_tooltip

    run = run_orthorectify(options, report)
    layers = []
    with collections_paused():
        for data, kwargs, kind in run_layers(run, world):
            check()
            layer = Layer.create(data, kwargs, kind)
            wrap_status(layer)  # here, not at its insertion on the Qt thread
            wrap_tooltip(layer)
            layers.append(layer)
    run.release()
    if not any(layer.name in replacing for layer in layers):
        gc.collect()
    return run, layers


class OrthorectifyWidget(ScrolledForm):
    """The "Orthorectify" dock widget (thread worker, progress bar, cancel)."""

    def __init__(self, viewer: napari.viewer.Viewer) -> None:
        self.viewer = viewer
        self._dems: list[Path] = []
        self.products = FileEdit(label="products (N1, SEN3 manifest)",
                                 mode=FileDialogMode.EXISTING_FILES,
                                 filter="*.N1 *.n1 xfdumanifest.xml *.zip *.ZIP",
                                 tooltip="MERIS L1b products: .N1 files (FR/RR, FRG/FSG); "
                                         "MERIS or OLCI Level 1B (EFR/ERR) .SEN3 products: "
                                         "their xfdumanifest.xml or .zip")
        self.dem_kind = ComboBox(label="DEM type", choices=[DEM_FILE, DEM_DIR], value=DEM_FILE,
                                 tooltip="a DEM file, or a directory of GETASSE30 tiles")
        self.dem_path = FileEdit(label="DEM", mode=FileDialogMode.EXISTING_FILE,
                                 tooltip="the DEM to add to the list")
        self.dem_add = PushButton(text="Add DEM", tooltip="check the DEM opens and append it")
        self.dem_list = Select(label="DEMs (in order)", choices=self._dem_choices,
                               tooltip="tried in this order at every output point, then the "
                                       "tie-point heights (section 3.3)")
        self.dem_remove = PushButton(text="Remove", tooltip="remove the selected DEMs")
        self.dem_up = PushButton(text="Up", tooltip="try the selected DEMs earlier")
        self.dem_down = PushButton(text="Down", tooltip="try the selected DEMs later")
        dem_buttons = Container(widgets=[self.dem_remove, self.dem_up, self.dem_down],
                                layout="horizontal", labels=False)
        self.elevation = ComboBox(label="elevation", choices=choices(Elevation),
                                  value=Elevation.DEM.value,
                                  tooltip="heights of the output points: the DEMs, the "
                                          "tie-point heights, or none (no orthorectification)")
        self.geolocation = ComboBox(label="geolocation", choices=list(GEOLOCATIONS),
                                    value="tiepoints",
                                    tooltip="tie points with the parallax from the DEMs, or the "
                                            "product's per-pixel geolocation (FRG/FSG/SEN3; "
                                            "with DEMs, given their parallax)")
        self.algorithm = ComboBox(label="selection", choices=list(ALGORITHMS), value=MAPPING,
                                  tooltip="mapping of every product, or a synthesis keeping the "
                                          "minimum radiance or the maximum NDVI (section 3.1)")
        self.input_store = FileEdit(label="input synthesis (update)",
                                    mode=FileDialogMode.EXISTING_DIRECTORY, nullable=True,
                                    tooltip="an existing synthesis store to update with the "
                                            "products (its grid and bands are kept); output "
                                            "empty: updated in place, else into a copy there")
        self.keep = SpinBox(label="keep commits (0 = all)", value=0, min=0, max=1_000_000,
                            visible=False,
                            tooltip="a synthesis run then keeps the newest this many commits "
                                    "of its store and frees what only older ones held "
                                    "(CLI synthesize --keep); 0: keep every commit")
        self.mode = StatusLabel(value="", label="Run will",
                                tooltip="what Run does with the current choices")
        self.parallax = ComboBox(label="parallax", choices=choices(PARALLAX_CHOICES),
                                 value=Parallax.HANDBOOK.value,
                                 tooltip="parallax radii: handbook sphere R = 6 370 997 m "
                                         "(MERSYN) or the WGS84 meridian and prime-vertical "
                                         "radii (CLI --parallax)")
        self.search = ComboBox(label="search", choices=choices(SearchMethod),
                               value=SearchMethod.PRIMARY.value,
                               tooltip="antecedent search: primary grid + Newton steps (fast) "
                                       "or MERSYN's facet search in the loop (CLI --search)")
        self.sampling = ComboBox(label="sampling", choices=choices(Sampling),
                                 value=Sampling.NEAREST.value,
                                 tooltip="resampling of the product at the antecedents")
        self.hidden = ComboBox(label="hidden ground", choices=choices(Hidden),
                               value=Hidden.MASK.value,
                               tooltip="ground the sensor cannot see behind the relief (with "
                                       "DEMs): mask leaves it no data, keep maps it as MERSYN "
                                       "does; both show it as the hidden-ground layer "
                                       "(CLI --hidden)")
        self.crs = ComboBox(label="output CRS", choices=[CRS_UTM, CRS_GEOGRAPHIC, CRS_EPSG,
                                                         CRS_LIKE],
                            value=CRS_UTM, tooltip=CRS_TOOLTIP)
        self.like = ComboBox(label="like layer", choices=self._like_choices, visible=False,
                             nullable=True,
                             tooltip="an open GeoTIFF or orthorectified layer: its CRS, pixel "
                                     "size and grid (as the CLI's --like REFERENCE.tif), so "
                                     "outputs align with it pixel for pixel")
        self.epsg = SpinBox(label="EPSG code", value=4326, min=1024, max=999999, visible=False,
                            tooltip="EPSG code of the output CRS")
        self.pixel_size = FloatSpinBox(label="pixel size (m, 0 = nominal)", value=0.0, min=0.0,
                                       max=100_000.0, step=10.0,
                                       tooltip="output pixel size; 0: 260 m (FR), 1040 m (RR)")
        self.bands = LineEdit(label="bands", value=default_bands(Sensor.MERIS),
                              tooltip="MERIS bands 1..15, e.g. 7,5,2 (RGB quick-look); OLCI "
                                      "bands 1..21, e.g. 8,6,3 (Oa08, Oa06, Oa03); or all")
        self.geometry = CheckBox(label="geometry layers", value=True,
                                 tooltip="footprint, tie-point facets, parallax vectors, "
                                         "iterations and elevation source")
        self.exaggeration = FloatSpinBox(label="parallax exaggeration", value=10.0, min=0.1,
                                         max=1000.0, tooltip="length factor of the vectors")
        self.vector_step = SpinBox(label="vector every (px, 0 = auto)", value=0, min=0,
                                   max=512, tooltip="one parallax vector every this many "
                                   "pixels; 0: about 60 across the output grid")
        self.output = FileEdit(label="output (optional)", mode=FileDialogMode.OPTIONAL_FILE,
                               nullable=True,
                               tooltip="GeoTIFF (mapping) or synthesis directory to write")
        self.run_button = PushButton(text="Run", tooltip="run in the background")
        self.cancel_button = PushButton(text="Cancel", enabled=False,
                                        tooltip="stop the run at its next step")
        self.progress_bar = ProgressBar(value=0, min=0, max=1000, label="progress",
                                        tooltip="progress of the run")
        self.status = StatusLabel(value="")
        super().__init__(widgets=[
            self.products, self.dem_kind, self.dem_path, self.dem_add, self.dem_list,
            dem_buttons, self.elevation, self.geolocation, self.algorithm, self.input_store,
            self.keep, self.parallax, self.search, self.sampling, self.hidden, self.crs,
            self.epsg, self.like,
            self.pixel_size, self.bands, self.geometry, self.exaggeration, self.vector_step,
            self.output,
        ], footer=[self.mode, self.run_button, self.cancel_button, self.progress_bar,
                   self.status])  # the form scrolls on a short screen, not these
        self._cancel = threading.Event()
        self._closed = False
        self.progress_state = (0, 1)
        self.progress_hook: Any = None  # called with (done, total) from the job thread
        self._active = False  # from Run until the worker has ended
        self._timer: Any = None
        self._job: _Job | None = None
        self.worker: Any = None
        #: layer changes (remove an old layer, append a new one) left to make, one per turn
        self._queue: list[tuple[Any, Any]] = []
        self._warm: WarmUp | None = None  # the dock's warm-up (``_start_warm_up``)
        self._queued, self._summary = 0, ""
        self._hidden: list[Any] = []  # a run's layers waiting to be shown (``_done``)
        self._batch_open = False  # napari's batch of layer removals (``_removals``)
        #: what the queued changes have done so far: (index, layer) removed, layers appended;
        #: a Cancel in the middle undoes them (``_undo_changes``)
        self._removed: list[tuple[int, Any]] = []
        self._appended: list[Any] = []
        self.last_run: OrthoRun | None = None
        remembered = {"elevation": self.elevation, "geolocation": self.geolocation,
                      "algorithm": self.algorithm, "parallax": self.parallax,
                      "search": self.search, "sampling": self.sampling,
                      "hidden": self.hidden, "crs": self.crs,
                      "epsg": self.epsg,
                      "pixel_size": self.pixel_size, "bands": self.bands,
                      "geometry": self.geometry, "exaggeration": self.exaggeration,
                      "vector_step": self.vector_step}
        self.settings_widgets = list(remembered.values())
        for widget in (self.products, self.algorithm, self.input_store, self.output):
            widget.changed.connect(self._show_mode)
        remember("orthorectify", remembered, restored=self._restored)
        self.products.changed.connect(self._products_changed)
        self._show_mode()
        self._crs_changed(self.crs.value)
        self.dem_kind.changed.connect(self._dem_kind_changed)
        self.dem_add.changed.connect(lambda _=None: self.add_dem(self.dem_path.value))
        self.dem_remove.changed.connect(self._remove_selected)
        self.dem_up.changed.connect(lambda _=None: self._move_selected(-1))
        self.dem_down.changed.connect(lambda _=None: self._move_selected(+1))
        self.crs.changed.connect(self._crs_changed)
        for event in (viewer.layers.events.inserted, viewer.layers.events.removed):
            event.connect(lambda _e=None: self.like.reset_choices())
        self._inserted_at = -SETTLE_AFTER_INSERT_S  # when a layer last went in (perf_counter)
        viewer.layers.events.inserted.connect(self._layer_inserted)
        self.run_button.changed.connect(lambda _=None: self.start())
        self.cancel_button.changed.connect(lambda _=None: self.cancel())
        self.native.destroyed.connect(self._shutdown)
        # the dock's close button takes the widget out of the window: a run is cancelled
        # (as by Cancel: layer changes made are undone), not left to go on unseen
        self._closer = OnClose(self.native, self._left_window, destroyed=False)
        show_map_coordinates(viewer)
        show_legends(viewer)
        trim_after_removals(viewer)
        # the rest in turns of the event loop of their own, from the next one on: the dock's
        # opening would be one long turn with them (the engine's imports, napari's units).
        # What a first open needs comes first: napari's units, then the warm-up's imports of
        # napari's first layer; the steps a run needs wait for those imports (sharing the GIL
        # with them, the canvas's first draw of the legend would take a long turn), and the
        # warm-up's kernels for those steps
        this = weakref.ref(self)  # not kept alive by the turns' timers
        in_turns([unit_registry_from_disk,  # napari's units, before its first layer
                  _while_open(this, _start_warm_up),
                  *_engine_import_steps(),
                  *dash_pattern_steps(),  # before the canvas's first draw, which needs them
                  *glyph_steps(self.viewer, paused=lambda: (w := this()) is not None
                               and w._paused_glyphs()),
                  _while_open(this, OrthorectifyWidget._freeze_when_idle),
                  _while_open(this, OrthorectifyWidget._opening_done)],
                 hold=lambda: (w := this()) is not None and w._holding_opening())

    # ---------------------------------------------------------------- output grid
    def _crs_changed(self, value: str) -> None:
        self.epsg.visible = value == CRS_EPSG
        self.like.visible = value == CRS_LIKE
        self.pixel_size.enabled = value != CRS_LIKE  # the layer's pixel size

    def _like_choices(self, _widget: Any = None) -> list[tuple[str, str]]:
        """The layers an output can align with: geocoded rasters (read again at every
        ``reset_choices``)."""
        return [(layer.name, layer.name) for layer in self.viewer.layers
                if source_frame(layer) is not None]

    def like_grid(self) -> Any:
        """The grid of the layer chosen in "like layer" (None: none chosen or gone)."""
        name = self.like.value
        layer = next((la for la in self.viewer.layers if la.name == name), None)
        return None if layer is None else source_frame(layer)

    # ---------------------------------------------------------------- DEM list
    @property
    def dems(self) -> list[Path]:
        """The DEMs in the order they are tried (section 3.3)."""
        return list(self._dems)

    def _dem_choices(self, _widget: Any = None) -> list[tuple[str, Path]]:
        """The list's choices, read again at every napari ``reset_choices``."""
        return [(str(p), p) for p in self._dems]

    def _sync_dem_list(self, selected: list[Path] | None = None) -> None:
        self.dem_list.reset_choices()
        self.dem_list.value = [p for p in (selected or []) if p in self._dems]

    def _dem_kind_changed(self, kind: str) -> None:
        self.dem_path.mode = (FileDialogMode.EXISTING_DIRECTORY if kind == DEM_DIR
                              else FileDialogMode.EXISTING_FILE)

    def add_dem(self, path: str | Path | tuple[Path, ...] | None) -> None:
        """Append a DEM (GeoTIFF, SRTM30 tile or GETASSE30 directory) after checking it opens."""
        from ..dem.stack import open_dem

        p = Path(path) if isinstance(path, str | Path) else Path()
        if str(p) in ("", "."):
            self.status.value = ("no DEM to add: choose a GeoTIFF, an SRTM30 tile or a tile "
                                 "directory")
            return
        if not p.exists():
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
        self.status.value = f"DEM {len(self._dems)} of {len(self._dems)}: {p.name}"

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
    def _paths(self) -> tuple[list[Path], Path | None, Path | None]:
        """Products, output and input store as chosen (empty fields: none)."""
        chosen = self.products.value
        paths = chosen if isinstance(chosen, tuple | list) else () if chosen is None else (chosen,)
        output = self.output.value if isinstance(self.output.value, Path) else None
        store = self.input_store.value if isinstance(self.input_store.value, Path) else None
        return [Path(p) for p in paths], output, store

    def _show_mode(self, _value: Any = None) -> None:
        """Name what Run will do (mapping, new synthesis or update of a store) before Run."""
        products, output, store = self._paths()
        settings = RunSettings(products=products, algorithm=self.algorithm.value,
                               output=output, input_store=store)
        self.mode.value = settings.mode()
        self.keep.visible = settings.synthesis  # pruning a store's commits: syntheses only

    def _products_changed(self, _value: Any = None) -> None:
        """A band list left at one sensor's quick-look bands follows the products' sensor
        ("7,5,2" for MERIS, "8,6,3" for OLCI); a list the user typed stays."""
        sensor = products_sensor(self._paths()[0])
        defaults = {default_bands(other) for other in Sensor}
        if self.bands.value.replace(" ", "") in defaults:
            self.bands.value = default_bands(sensor)

    def settings(self) -> RunSettings:
        """The widget's values as checked RunSettings (raises OptionsError on bad input)."""
        products, output, store = self._paths()
        n_bands = band_table(products_sensor(products)).n_bands
        options = RunSettings(
            products=products, dems=self.dems,
            elevation=self.elevation.value, geolocation=self.geolocation.value,
            algorithm=self.algorithm.value, parallax=self.parallax.value,
            search=self.search.value, input_store=store, keep=int(self.keep.value),
            sampling=self.sampling.value, crs=self.crs.value, epsg=int(self.epsg.value),
            like=self.like_grid() if self.crs.value == CRS_LIKE else None,
            pixel_size_m=float(self.pixel_size.value), bands=parse_bands(self.bands.value, n_bands),
            output=output, geometry=self.geometry.value,
            exaggeration=float(self.exaggeration.value), vector_step=int(self.vector_step.value),
            hidden=self.hidden.value)
        options.check()
        for path in options.map_outputs():  # as File > Save refuses it (``writer``)
            readers = layers_reading(self.viewer, path)
            if readers:
                raise OptionsError(f"output {path}: layer {readers[0]!r} reads from this file; "
                                   "choose another output")
        return options

    # ---------------------------------------------------------------- running
    def _check(self) -> None:
        """Raise Cancelled when the user pressed Cancel or closed the viewer (job thread)."""
        if self._cancel.is_set() or getattr(self.worker, "abort_requested", False):
            raise Cancelled("cancelled by the user")

    def _report(self, done: int, total: int) -> None:
        """Progress callback (job thread): records the state, raises on cancel."""
        self._check()
        self.progress_state = (done, total)
        if self.progress_hook is not None:
            self.progress_hook(done, total)

    def start(self) -> Any:
        """Start a run in a thread worker; returns the worker (None when options are bad)."""
        from napari.qt.threading import create_worker
        from qtpy.QtCore import QTimer

        if self.running:
            return None
        try:
            options = self.settings()
        except MerisOrthoError as exc:
            self.status.value = str(exc)
            return None
        for step in _engine_import_steps():  # (a Run right after the opening: here, not in
            step()                           # the job's thread)
        self._cancel.clear()
        self.progress_state = (0, 1)
        self.progress_bar.value = 0
        # the widget's own bar: napari's ``progress`` builds a bar in its activity dock on the
        # Qt thread at every Run (0.1-0.3 s without an event-loop turn)
        self._active = True
        self._timer = QTimer()
        self._timer.timeout.connect(self._update_progress)
        self._timer.start(100)
        self._job = _Job(build_layers, options, self._report, self._check,
                         viewer_frame(self.viewer.layers),
                         frozenset(layer.name for layer in self.viewer.layers))
        self.worker = create_worker(self._job, _start_thread=False, _connect={
            "returned": self._done, "errored": self._failed, "finished": self._finished})
        self.run_button.enabled, self.cancel_button.enabled = False, True
        self.status.value = "running..."
        start_after_paint(self.worker, lambda: self._closed)
        return self.worker

    @property
    def running(self) -> bool:
        """True from ``start`` until the worker has finished and its layers are all added."""
        return self._active or bool(self._queue)

    def cancel(self) -> None:
        """Ask the running worker to stop at its next progress report."""
        self._cancel.set()
        self.status.value = "cancelling..."

    def _left_window(self) -> None:
        if self.running and not self._closed:
            self.cancel()

    def _shutdown(self, _obj: Any = None) -> None:
        """The widget is destroyed (viewer closed): cancel the job and wait for its thread,
        so that nothing runs or reports into deleted Qt objects."""
        if not hasattr(self, "_cancel"):  # being garbage-collected
            return
        self._closed = True
        thaw()  # the viewer's objects can be collected again
        self._cancel.set()
        if self._job is not None and self._job.thread.is_alive():
            self._job.thread.join(CLOSE_TIMEOUT_S)
        if self._active:
            with contextlib.suppress(RuntimeError):  # Qt objects already deleted
                self._timer.stop()
            self._active = False

    def _update_progress(self) -> None:
        done, total = self.progress_state
        target = int(1000 * done / max(total, 1))
        if self._active:
            self.progress_bar.value = target

    def _done(self, value: tuple[OrthoRun, list[Any]]) -> None:
        """The job's layers are ready: queue the removal of the layers they replace (same
        names, an earlier run) and their insertion, one per event-loop turn (``_step``)."""
        if self._closed:
            return
        run, layers = value
        self.last_run = run
        names = {layer.name for layer in layers}
        sources = {layer_source(layer) for layer in layers} - {None}
        # a rerun replaces every layer an earlier run made of the same products (or store),
        # not only those of the same names: a layer the new settings no longer make (a band
        # left out, geometry off) would seem to describe the new run (and a rerun with fewer
        # bands crashes Mesa's software GL drawing beside such leftovers)
        # top first: a removal that narrows the world slices again the layers left, and the
        # parallax vectors (on top) would redraw their thumbnail in Python (0.09 s)
        replaced = [old for old in self.viewer.layers[::-1]
                    if old.name in names or layer_source(old) in sources]
        # napari collects garbage after every removal (0.1-0.5 s): the removals go in one
        # batch of napari's, one per turn, and the batch ends (one collection) in a turn alone
        removals: list[tuple[Any, Any]] = [(self._remove_layer, old) for old in replaced]
        if removals:
            removals = [(self._removals, True), *removals, (self._removals, False)]
        # the first frames show the new layers one at a time: vispy builds a new visual's
        # shaders at its first draw (software GL under Xvfb: 0.05-0.15 s each), so one frame
        # with all of them is the longest stall of a run
        shown = hide_for_now(layers)
        # each layer's controls in the turn after its insertion (``append_inactive``)
        self._queue = [*removals,
                       *(step for layer in layers
                         for step in ((self._append, layer), (self._make_controls, layer),
                                      (self._polish_controls, layer),
                                      (self._add_controls, layer))),
                       # a labels layer's overlays, not in the scene graph's one rebuild
                       *((self._build_overlays, layer) for layer in layers
                         if type(layer).__name__ == "Labels"),
                       (self._scene_graph, False),
                       *((self._activate, layer) for layer in layers[-1:]),
                       (self._hide_others, layers),
                       (self._frame_result, shown), (self._canvas_updates, True),
                       *(step for layer in shown
                         for step in ((self._show, layer), (self._draw, layer)))]
        self._queued = len(self._queue)
        self._removed, self._appended = [], []
        self._hidden = shown
        self._summary = run.summary()
        self._canvas_updates(False)
        self._schedule_step()

    def _restored(self) -> None:
        """The last session's settings are in the form: a synthesis selection said."""
        if self._closed:
            return
        if self.algorithm.value != MAPPING:  # never a silent switch of the mode
            self.status.value = (f"selection {self.algorithm.value!r} from the last session: "
                                 "Run builds a synthesis")

    def _hide_others(self, layers: list[Any]) -> None:
        """The first view of a run: its newest image alone visible; the images and labels
        layers shown before it (a product's quick-look, an earlier run's) hidden, ready to
        toggle or flicker."""
        ours = set(map(id, layers))
        for layer in self.viewer.layers:
            if (id(layer) not in ours and layer.visible
                    and type(layer).__name__ in ("Image", "Labels")):
                layer.visible = False
                self._removed.append((-1, layer))  # shown again by a Cancel

    def _layer_inserted(self, _event: Any = None) -> None:
        self._inserted_at = time.perf_counter()

    def _holding_opening(self) -> bool:
        """Whether the opening's steps wait: for the warm-up's first-layer imports, and for
        ``SETTLE_AFTER_INSERT_S`` after a layer went in (a user's open: its first frames)."""
        settling = time.perf_counter() - self._inserted_at < SETTLE_AFTER_INSERT_S
        return self._warming_first_layer() or settling

    def _warming_first_layer(self) -> bool:
        """Whether the warm-up is importing what napari's first layer needs."""
        return self._warm is not None and not self._warm.first_layer_ready()

    def _opening_done(self) -> None:
        """The opening's steps are done: the warm-up's kernels may follow."""
        if self._warm is not None:
            self._warm.steps_done()

    def _freeze_when_idle(self) -> None:
        """``freeze_long_lived`` (the engine's modules included), once no run is going on
        (a run's objects are not long-lived)."""
        if self.running:
            from qtpy.QtCore import QTimer

            this = weakref.ref(self)
            QTimer.singleShot(FREEZE_RETRY_MS,
                              _while_open(this, OrthorectifyWidget._freeze_when_idle))
            return
        freeze_long_lived(self.viewer)

    def _paused_glyphs(self) -> bool:
        """The legend's glyphs wait while a run runs (its job, then its layers going in)."""
        return self.running and not self._closed

    def _canvas_updates(self, enabled: bool) -> None:
        canvas_updates(self.viewer, enabled)

    def _build_overlays(self, layer: Any) -> None:
        build_overlays(self.viewer, layer)

    def _make_controls(self, layer: Any) -> None:
        make_controls(self.viewer, layer)

    def _polish_controls(self, layer: Any) -> None:
        polish_controls(self.viewer, layer)

    def _add_controls(self, layer: Any = None) -> None:
        """napari's controls of ``layer`` (None: of every layer appended so far that still has
        a stand-in: before any is selected or removed)."""
        add_controls(self.viewer, self._appended if layer is None else [layer])

    def _scene_graph(self, paused: Any) -> None:
        scene_graph_paused(self.viewer, bool(paused))

    def _append(self, layer: Any) -> None:
        self._scene_graph(True)  # rebuilt once, after the last (``_scene_graph(False)``)
        append_inactive(self.viewer, layer, controls_later=True)
        self._appended.append(layer)

    def _show(self, layer: Any) -> None:
        """Show one of the run's layers (hidden until all were in; ``_done``); the canvas
        draws it in the next turn (``_draw``), not in this one."""
        if layer in self._hidden:
            self._hidden.remove(layer)
        self._canvas_updates(False)
        show_in(self.viewer, [layer])

    def _draw(self, layer: Any) -> None:
        """Let the canvas draw the layer ``_show`` made visible, in a turn of its own: its
        first draw (vispy builds its shaders) is the longest of a run's insertions, and the
        same turn as the showing (its slicing, its thumbnail) added up to one stall."""
        self._canvas_updates(True)

    def _show_hidden(self) -> None:
        """Show at once the run's layers still waiting for their turn (Cancel, an error)."""
        hidden, self._hidden = self._hidden, []
        show_in(self.viewer, hidden)

    def _activate(self, layer: Any) -> None:
        if layer in self.viewer.layers:
            self.viewer.layers.selection.active = layer

    def _removals(self, start: Any) -> None:
        """Start or end napari's batch of layer changes (``LayerList.batched_update``): within
        it a removal does not collect garbage nor rebuild the scene graph; its end does both.
        The selection is emptied first: removing a selected layer restyles the layer buttons."""
        if bool(start) != self._batch_open:
            self._batch_open = bool(start)
            if start:
                self.viewer.layers.selection.clear()
            events = self.viewer.layers.events
            (events.begin_batch if start else events.end_batch)()

    def _remove_layer(self, layer: Any) -> None:
        if layer in self.viewer.layers:
            self._removed.append((self.viewer.layers.index(layer), layer))
            self.viewer.layers.remove(layer)

    def _undo_changes(self) -> int:
        """Cancel while a run's layers go in: take out the new layers appended so far and put
        back the ones they replaced, where they were: the viewer is as before the run, not
        half replaced. Returns the changes undone."""
        self._add_controls()  # napari removes a layer's controls with it
        undone = 0
        for layer in reversed(self._appended):
            if layer in self.viewer.layers:
                self.viewer.layers.remove(layer)
                undone += 1
        for index, layer in reversed(self._removed):
            if index < 0:  # hidden by ``_hide_others``
                layer.visible = True
            elif layer not in self.viewer.layers:
                self.viewer.layers.insert(min(index, len(self.viewer.layers)), layer)
                undone += 1
        self._hidden = [x for x in self._hidden if x in self.viewer.layers]
        self._removed, self._appended = [], []
        return undone

    def _schedule_step(self, delay_ms: int = 1) -> None:
        """The next step on a 1 ms timer: Qt delivers a 0 ms single shot as a posted event,
        which can run right after the previous step, before the timers and paints due."""
        from qtpy.QtCore import QTimer

        QTimer.singleShot(delay_ms, self._step)

    def _step(self) -> None:
        """One queued layer change per event-loop turn, so that the viewer repaints and Cancel
        responds between them; Cancel drops the changes not yet made."""
        if self._closed or not self._queue:
            self._queue = []
            return
        if self._cancel.is_set():
            self._queue = []
            self._removals(False)  # end napari's batch before the layers go back
            undone = self._undo_changes()
            self.status.value = ("cancelled by the user: the viewer is as before the run"
                                 + (f" ({undone} layer changes undone)" if undone else ""))
            self._end()
            return
        change, layer = self._queue.pop(0)
        try:
            change(layer)
        except Exception:
            self._queue = []
            self._end()
            raise
        if self._queue:
            # a shown layer is drawn in the paint that follows: the next change waits for
            # it (a paint and a change within one turn would add up to one stall)
            self._schedule_step(SHOW_STEP_MS if change == self._draw else 1)
            return
        self.progress_bar.value = self.progress_bar.max
        self.status.value = self._summary
        # the thumbnails of the run's hidden images (single bands, diagnostics), after its end
        hidden = [x.name for x in self._appended
                  if type(x).__name__ == "Image" and not x.visible]
        self._end()
        thumbnails_later(self.viewer, hidden)

    def _frame_result(self, layers: list[Any]) -> None:
        """Point the camera at the run's visible ``layers`` (the result, not the whole
        viewer), before the canvas draws them."""
        frame_layers(self.viewer, [layer for layer in layers if layer in self.viewer.layers])

    def _failed(self, exc: BaseException) -> None:
        if self._closed:
            return
        if isinstance(exc, MerisOrthoError):
            self.status.value = str(exc)
        else:
            self.status.value = f"failed: {type(exc).__name__}: {exc}"

    def _finished(self) -> None:
        """The worker has ended (result, error or cancel): drop it and its job, so that nothing
        of the run stays alive but its layers; the buttons come back once the queue is empty."""
        self.worker, self._job = None, None
        if self._closed:
            return
        if self._timer is not None:
            self._timer.stop()
            self._timer = None
        self._active = False
        if not self._queue:
            self._end()

    def _end(self) -> None:
        self._add_controls()  # before the user selects or removes a layer
        self._removed, self._appended = [], []  # the replaced layers may go now
        self._removals(False)  # a batch left open by Cancel
        self._scene_graph(False)
        self._canvas_updates(True)
        self._show_hidden()
        self.run_button.enabled, self.cancel_button.enabled = True, False

"""napari sample data: a simulated MERIS FR scene, mapped without and with terrain correction.

The scene is generated on first use by the simulator (``simulate.generate_scene``, cached in
``$MERIS_ORTHO_CACHE`` or ``~/.cache/napari-meris-ortho``) with a napari progress bar, off the
GUI thread when opened from napari's menu (``SampleLoader``); the
two mappings (MERSYN use case 3 with ``-ort NO`` and with the DEM, handbook sections 3.1-3.4)
are computed on each load (about a second for fr-small). Every layer is placed in one world
frame: the output grid in the UTM zone of the footprint (``_layers`` module doc); the DEM and
the reference image are reprojected onto it, so the flicker of handbook section 4.4 compares
them pixel to pixel.
"""

from __future__ import annotations

import gc
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..display import contrast_limits
from ..geometry.grid import OutputGrid
from ..placement import reproject_onto
from ..progress import ProgressCallback
from ._qt.insertion import (
    SHOW_STEP_MS,
    append_inactive,
    canvas_updates,
    controls_in_turns,
    hide_for_now,
    scene_graph_is_paused,
    scene_graph_paused,
    show_in,
)
from .geometry_layers import geometry_layers
from .layout import frame_layers
from .memory import collections_paused, short_collections
from .ortho_run import multiscale_layer
from .product_layers import band_layers, one_image_shown
from .reader import meris_band_of
from .world import current_viewer, geo_image_kwargs

SAMPLE_BANDS = (2, 5, 7)
REFERENCE_BAND = 7
LayerData = tuple[Any, dict[str, Any], str]


@dataclass
class SampleScene:
    """A generated scene with its two mappings on the same output grid."""

    name: str
    scene: Any
    frame: OutputGrid
    uncorrected: dict[int, np.ndarray]
    orthorectified: dict[int, np.ndarray]
    valid: np.ndarray
    diagnostics: dict[str, np.ndarray]
    tie_points: Mapping[str, np.ndarray]


def _stage(progress: ProgressCallback | None, start: int, span: int) -> ProgressCallback | None:
    """A callback mapping a stage's (done, total) onto [start, start + span] of 100."""
    if progress is None:
        return None
    return lambda done, total: progress(start + int(span * done / max(total, 1)), 100)


def build_sample(name: str, progress: ProgressCallback | None = None,
                 out_dir: str | Path | None = None) -> SampleScene:
    """Generate (or load) scene ``name`` and its uncorrected and orthorectified mappings."""
    from ..engine.boundary import segment_boundary
    from ..geometry.grid import default_grid, utm_crs_for
    from ..ortho import orthorectify
    from ..products.n1 import read_product
    from ..simulate.scene import generate_scene

    scene = generate_scene(name, out_dir=out_dir, progress=_stage(progress, 0, 50))
    product = read_product(scene.product_path)
    tp = product.tie_points
    boundary = segment_boundary(tp["latitude"], tp["longitude"])
    crs = utm_crs_for(float(np.mean(tp["longitude"])), float(np.mean(tp["latitude"])))
    grid = default_grid(boundary, crs=crs, pixel_size=260.0)
    dem = scene.dem_paths["geotiff"]
    flat = orthorectify(product, grid, elevation="none", bands=SAMPLE_BANDS,
                        progress=_stage(progress, 50, 15))
    ortho = orthorectify(product, grid, dems=[dem], elevation="dem", bands=SAMPLE_BANDS,
                         diagnostics=True, progress=_stage(progress, 65, 35))
    if progress is not None:
        progress(100, 100)
    return SampleScene(name, scene, grid, flat.bands, ortho.bands,
                       ortho.valid, ortho.diagnostics, tp)


def _raster_on_frame(path: Path, band: int, frame: OutputGrid) -> np.ndarray:
    """One band of a GeoTIFF reprojected onto the frame's grid (bilinear)."""
    import rasterio

    with rasterio.open(path) as ds:
        data = ds.read(band)
        source = OutputGrid.from_transform(ds.crs, tuple(ds.transform), (ds.height, ds.width))
    return reproject_onto(data.astype(np.float32), source, frame)


def _reference_band_index(path: Path, band: int) -> int:
    """1-based index of MERIS ``band`` in the reference GeoTIFF (``meris_band_of``)."""
    import rasterio

    with rasterio.open(path) as ds:
        for i, d in enumerate(ds.descriptions):
            if meris_band_of(d, ds.tags(i + 1)) == band:
                return i + 1
    return 1


def sample_layers(sample: SampleScene) -> list[LayerData]:
    """Reference image, DEM, uncorrected and orthorectified mappings and geometry layers."""
    frame, scene = sample.frame, sample.scene
    layers: list[LayerData] = []
    if scene.reference_path is not None:
        ref = _raster_on_frame(scene.reference_path,
                               _reference_band_index(scene.reference_path, REFERENCE_BAND), frame)
        ref[~sample.valid] = 0
        layers.append((ref, geo_image_kwargs(
            frame, name=f"reference b{REFERENCE_BAND}", colormap="gray",
            contrast_limits=contrast_limits(ref), metadata={"path": str(scene.reference_path)}),
            "image"))
    dem = _raster_on_frame(scene.dem_paths["geotiff"], 1, frame)
    layers.append((dem, geo_image_kwargs(frame, name="DEM", colormap="gist_earth",
                                         contrast_limits=contrast_limits(dem, None),
                                         metadata={"units": "m"}, visible=False), "image"))
    source = {"path": str(scene.product_path)}  # the flicker's GIF goes beside it
    layers += band_layers(sample.uncorrected, frame, "uncorrected",
                          {"elevation": "none", **source}, sample.uncorrected[7] > 0)
    layers += band_layers(sample.orthorectified, frame, "ortho",
                          {"elevation": "dem", **source}, sample.valid)
    layers += geometry_layers(sample.tie_points, frame, "", sample.diagnostics,
                              valid=sample.valid, exaggeration=10.0)
    # one image shown (the orthorectified quick-look), the geometry above; big rasters as
    # pyramids, as a run's
    return [multiscale_layer(layer) for layer in one_image_shown(layers)]


def _napari_progress(name: str) -> tuple[Any, ProgressCallback]:
    from napari.utils import progress

    bar = progress(total=100, desc=f"MERIS sample {name}")

    def update(done: int, total: int) -> None:
        target = int(100 * done / max(total, 1))
        bar.update(max(target - bar.n, 0))

    return bar, update


def _make(name: str) -> list[LayerData]:
    """The sample's layers. From napari's running event loop (File > Open Sample) the scene is
    built in the background (``SampleLoader``) and a placeholder layer is returned at once;
    from a script or a test (no event loop running yet) the layers are built here."""
    from .._process import unit_registry_from_disk
    from .legend import show_legends
    from .status import show_map_coordinates

    unit_registry_from_disk()  # napari's units, before its first layer (the placeholder)
    viewer = current_viewer()
    show_map_coordinates(viewer)
    show_legends(viewer)  # the key of the selected layer
    if viewer is not None and _event_loop_running():
        return [SampleLoader(name, viewer).placeholder()]
    bar, update = _napari_progress(name)
    try:
        return sample_layers(build_sample(name, update))
    finally:
        bar.close()


def _event_loop_running() -> bool:
    """True inside a running Qt event loop on the GUI thread (napari's menus, not a script)."""
    try:
        from qtpy.QtCore import QThread
        from qtpy.QtWidgets import QApplication
    except ImportError:
        return False
    app, thread = QApplication.instance(), QThread.currentThread()
    return (app is not None and thread is not None and thread is app.thread()
            and thread.loopLevel() > 0)


#: the loaders at work (kept alive until their layers are in the viewer)
_LOADERS: set[SampleLoader] = set()


def loading() -> bool:
    """True while a sample is being built or added in the background."""
    return bool(_LOADERS)


class SampleLoader:
    """A sample built off the GUI thread (simulation, mappings, layer data and napari layer
    objects) with a napari progress bar; its layers are then added one per event-loop turn
    and the placeholder removed. An error ends in the placeholder's name and napari's log."""

    def __init__(self, name: str, viewer: Any) -> None:
        import threading

        from napari.utils import progress
        from qtpy.QtCore import QTimer

        self.name, self.viewer = name, viewer
        self.state: tuple[int, int] = (0, 1)
        self.layers: list[Any] | None = None
        self.error: BaseException | None = None
        self.label = f"MERIS sample {name} (generating...)"
        self._hidden: list[Any] = []  # the visible layers, shown one per frame at the end
        self._sample: list[Any] = []  # all of the sample's layers
        self._bar = progress(total=100, desc=f"MERIS sample {name}")
        self._timer = QTimer()
        self._timer.timeout.connect(self._poll)
        self._timer.start(50)
        self._thread = threading.Thread(target=self._build, name="meris-ortho-sample",
                                        daemon=True)
        _LOADERS.add(self)
        self._thread.start()

    def placeholder(self) -> LayerData:
        """A hidden 1-pixel image named after the sample, removed when the layers arrive."""
        return (np.zeros((1, 1), np.float32), {
            "name": self.label, "visible": False, "contrast_limits": (0.0, 1.0),
            "metadata": {"sample_loader": id(self)}}, "image")

    def _report(self, done: int, total: int) -> None:
        self.state = (done, total)

    def _build(self) -> None:
        from napari.layers import Layer

        try:
            simulate_in_subprocess(self.name, lambda done, total: self._report(
                done // 2, total))  # the simulator's kernels hold the GIL: another process
            data = sample_layers(build_sample(self.name, self._report))
            # as a run's layers: Python's full collection once, here, not in one of the
            # insertion turns (0.19 s there)
            with collections_paused():
                self.layers = [Layer.create(d, kwargs, kind) for d, kwargs, kind in data]
            gc.collect()
        except BaseException as exc:  # shown in the placeholder's name, logged by napari
            self.error = exc

    def _poll(self) -> None:
        done, total = self.state
        self._bar.update(max(int(100 * done / max(total, 1)) - self._bar.n, 0))
        if self._thread.is_alive():
            return
        self._timer.stop()
        self._bar.close()
        if self.error is not None:
            self._rename(f"MERIS sample {self.name} failed: {self.error}")
            _LOADERS.discard(self)
            raise self.error
        # the placeholder out first: beside the sample's layers (metres) its pixels make napari
        # drop the units of every layer (its "Inconsistent units" warning)
        with short_collections():  # napari's collection after a removal: 0.18 s with the
            for layer in self._placeholders():  # sample's layers in, not now
                self.viewer.layers.remove(layer)
        self._sample = list(self.layers or [])
        # shown one per frame once all are in (``insertion.SHOW_STEP_MS``), as a run's layers
        self._hidden = hide_for_now(self.layers or [])
        canvas_updates(self.viewer, False)
        # napari's scene graph rebuilt once, after the last insertion, in a turn of its own
        scene_graph_paused(self.viewer, True)
        self._step()

    def _placeholders(self) -> list[Any]:
        return [x for x in self.viewer.layers if x.metadata.get("sample_loader") == id(self)]

    def _rename(self, text: str) -> None:
        for layer in self._placeholders():
            layer.name = text

    def _step(self) -> None:
        """Add one layer, then come back on the next turn."""
        from qtpy.QtCore import QTimer

        try:
            if self.layers:  # inactive: the layer controls do not switch at every turn
                layer = self.layers.pop(0)
                if append_inactive(self.viewer, layer, controls_later=True):
                    controls_in_turns(self.viewer, [layer], then=self._step)  # a turn each
                else:
                    QTimer.singleShot(1, self._step)  # timers and paints due run in between
                return
            if scene_graph_is_paused(self.viewer):
                scene_graph_paused(self.viewer, False)
                QTimer.singleShot(1, self._step)
                return
            # the camera on the sample before its layers show (napari framed the placeholder)
            frame_layers(self.viewer, [x for x in self._sample if x in self.viewer.layers])
        except Exception:
            self.layers = None
            self._finish()
            raise
        canvas_updates(self.viewer, True)
        self._show_next()

    def _show_next(self) -> None:
        """Show the next of the sample's visible layers; the canvas draws it in the next turn
        (``_draw_shown``), not in this one, as a run's layers (``OrthorectifyWidget._draw``)."""
        from qtpy.QtCore import QTimer

        if self._hidden:
            canvas_updates(self.viewer, False)
            show_in(self.viewer, [self._hidden.pop(0)])
            QTimer.singleShot(1, self._draw_shown)
            return
        self._finish()

    def _draw_shown(self) -> None:
        """Let the canvas draw the layer just shown, then come back after its frame."""
        from qtpy.QtCore import QTimer

        canvas_updates(self.viewer, True)
        QTimer.singleShot(SHOW_STEP_MS, self._show_next)

    def _finish(self) -> None:
        scene_graph_paused(self.viewer, False)
        canvas_updates(self.viewer, True)
        hidden, self._hidden = self._hidden, []
        show_in(self.viewer, hidden)  # an error part-way: what is in shows at once
        # the status bar said the placeholder's "generating..." until the mouse moved
        self.viewer.status = f"MERIS sample {self.name}: {len(self._sample)} layers"
        _LOADERS.discard(self)


def simulate_in_subprocess(name: str, progress: ProgressCallback | None = None) -> None:
    """Generate scene ``name`` into the simulator's cache in another Python process, so that
    its numba kernels (which hold the GIL) never stall napari; progress read from its output.
    A scene already cached costs one process start; an error is raised as SimulationError."""
    import subprocess
    import sys

    from ..errors import MerisOrthoError

    with subprocess.Popen([sys.executable, "-m", __name__, name], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True) as proc:  # its pipes closed after
        assert proc.stdout is not None
        for line in proc.stdout:
            done, _, total = line.partition(" ")
            if progress is not None and done.isdigit() and total.strip().isdigit():
                progress(int(done), int(total))
        error = proc.stderr.read() if proc.stderr is not None else ""
    if proc.returncode != 0:
        raise MerisOrthoError(f"simulation of sample {name} failed: "
                              f"{error.strip().splitlines()[-1] if error.strip() else '?'}")


def _simulate_main(name: str) -> None:
    """``python -m napari_meris_ortho._napari.sample_data NAME``: generate the scene, printing
    "done total" progress lines."""
    from ..simulate.scene import generate_scene

    generate_scene(name, progress=lambda done, total: print(done, total, flush=True))


def make_sample_alps() -> list[LayerData]:
    """Sample "fr-alps": the default 2241 x 2241 FR scene (generated on first use)."""
    return _make("fr-alps")


def make_sample_small() -> list[LayerData]:
    """Sample "fr-small": 320 x 513 pixels of the same scene (seconds to generate)."""
    return _make("fr-small")


if __name__ == "__main__":
    import sys

    _simulate_main(sys.argv[1])

"""Flicker widget: alternate two layers to check superimposability (handbook section 4.4).

Like the REGIST "Flicker" tool of the handbook (fig. 33-35): two layers (orthorectified vs
reference, or uncorrected vs orthorectified) are displayed alternately in the same frame at a
chosen rate, so that sub-pixel displacements become visible; the flicker is exported as an
animated GIF like ``snap0*_REGIST_Flicker_*_anim.gif``. A "Measure disparity" button runs the
ZNCC disparity analysis in a thread worker and shows the global displacement (the handbook's
(+1.2, -4.4) px) and the matched points as vectors.

The flicker key (Shift-F) is declared in the manifest (``keybindings``, command
``toggle_flicker``); the widget binds it on the viewer and unbinds it when it is closed.
"""

from __future__ import annotations

import contextlib
import weakref
from collections.abc import Callable
from functools import cache, partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from magicgui.types import FileDialogMode
from magicgui.widgets import ComboBox, Container, FileEdit, FloatSpinBox, PushButton, SpinBox

from .._atomic import atomic_path
from ..display import fixed
from ..errors import MerisOrthoError, OptionsError
from ..geometry.grid import OutputGrid
from ..placement import Warp, warp
from ..pyramid import full_resolution
from ._qt.closing import OnClose
from ._qt.insertion import start_after_paint
from .layout import StatusLabel, compact_combo
from .ortho_run import RUN_KEY
from .settings import remember
from .world import (
    WORLD_KEY,
    geo_metadata,
    layer_frame,
    layer_scale,
    layer_translate,
    world_axes,
)

if TYPE_CHECKING:
    import napari

DISPARITY_EXAGGERATION = 10.0
DISPARITY_MAX_SIZE = 256  # analyse every step-th pixel above this many lines/columns
DISPARITY_VECTORS_ACROSS = 60  # about this many matched-point vectors across the image

#: the docked flicker widget of each viewer (for the manifest's toggle_flicker command)
_WIDGETS: weakref.WeakValueDictionary[int, FlickerWidget] = weakref.WeakValueDictionary()


@cache
def flicker_key() -> str:
    """The flicker key of the manifest (``keybindings``) in napari's spelling ("Shift-F")."""
    from importlib.resources import files

    import yaml

    manifest = yaml.safe_load(files("napari_meris_ortho").joinpath("napari.yaml").read_text())
    (binding,) = [k for k in manifest["contributions"]["keybindings"]
                  if k["command"].endswith(".toggle_flicker")]
    return str(binding["key"]).replace("+", "-")


FLICKER_KEY = flicker_key()


def toggle_flicker(viewer: napari.viewer.Viewer) -> None:
    """Manifest command: start or stop the flicker of the viewer's Flicker widget."""
    widget = _WIDGETS.get(id(viewer))
    if widget is not None:
        widget.toggle()


def covering(layers: Any, layer_a: Any, layer_b: Any) -> list[Any]:
    """The shown images (and labels) above the lower of the pair, which would hide it: the
    flicker hides them while it runs (geometry layers stay; they are thin)."""
    from napari.layers import Image, Labels

    items = list(layers)
    lowest = min(items.index(layer_a), items.index(layer_b))
    return [x for x in items[lowest + 1:] if x is not layer_a and x is not layer_b
            and x.visible and isinstance(x, Image | Labels)]


def export_flicker_gif(viewer: Any, layer_a: Any, layer_b: Any, path: str | Path, *,
                       rate: float = 2.0, cycles: int = 2) -> Path:
    """Write the flicker of two layers as an animated GIF (2 frames per cycle, ``1/rate`` s each).

    Frames are screenshots of the canvas with only ``layer_a`` then only ``layer_b`` shown
    among the two, as the handbook's flicker animations; the images that would cover them
    (``covering``) hidden meanwhile, the other layers unchanged.
    """
    import imageio.v3 as iio

    if rate <= 0:
        raise OptionsError(f"flicker rate must be positive, got {rate}")
    if cycles < 1:
        raise OptionsError(f"flicker cycles must be at least 1, got {cycles}")
    show_viewer(viewer)
    hidden = covering(viewer.layers, layer_a, layer_b)
    saved = (layer_a.visible, layer_b.visible)
    try:
        for layer in hidden:
            layer.visible = False
        frames = []
        for show_a in (True, False):
            layer_a.visible, layer_b.visible = show_a, not show_a
            frames.append(np.asarray(viewer.screenshot(canvas_only=True, flash=False))[..., :3])
    finally:
        layer_a.visible, layer_b.visible = saved
        for layer in hidden:
            layer.visible = True
    sequence = np.stack(frames * cycles)
    with atomic_path(path, suffix=".gif") as tmp:
        iio.imwrite(tmp, sequence, extension=".gif", duration=int(round(1000.0 / rate)), loop=0)
    return Path(path)


def show_viewer(viewer: Any) -> None:
    """Show the viewer's window before a screenshot (a no-op when it is already shown).

    The canvas of a never-shown viewer has no OpenGL context yet: a screenshot is black and
    leaves vispy's GL state broken (GL_INVALID_VALUE on every later draw, even under Xvfb).
    """
    window = getattr(viewer, "window", None)
    if window is not None:
        window.show()


def layer_band(layer: Any) -> int | None:
    """The MERIS band of a layer: ``metadata["band"]``, else "b7" in its name."""
    import re

    band = getattr(layer, "metadata", {}).get("band")
    if band is not None:
        return int(band)
    found = re.search(r"\bb(\d{1,2})\b", str(layer.name))
    return int(found.group(1)) if found else None


#: the default name of the flicker's GIF
GIF_NAME = "flicker_anim.gif"


def data_directory(layer: Any) -> Path | None:
    """The directory of the file a layer shows (its product, store, GeoTIFF or the sample's
    scene), None when nothing on disk is behind it."""
    meta = getattr(layer, "metadata", {}) or {}
    path = meta.get("path") or meta.get("synthesis") or getattr(
        getattr(layer, "source", None), "path", None)
    if not path:
        return None
    return Path(str(path)).expanduser().absolute().parent


def is_ortho(layer: Any) -> bool:
    """An orthorectified radiance band: "ortho b7 · ..." (widget), "ortho b7" (sample),
    a synthesis's band (the widget's or an opened store's: metadata "synthesis")."""
    from napari.layers import Image

    ours = str(layer.name).startswith("ortho") or "synthesis" in (layer.metadata or {})
    return (isinstance(layer, Image) and not layer.rgb and ours
            and layer_band(layer) is not None)


def default_pair(layers: list[Any]) -> tuple[Any, Any] | None:
    """The check the flicker exists for (handbook section 4.4): A = the newest orthorectified
    band, B = the reference image (same band when there is one); without a reference, the
    previous product's orthorectified band, then the uncorrected one; without an orthorectified
    band, the two top-most images. Two runs of one product with different location models
    (its tie points with the DEMs, its per-pixel geolocation: an OLCI product's "DEM corrected"
    positions) are partners when no other product's band is. None with fewer than two
    images."""
    from napari.layers import Image, Labels

    images = [x for x in layers if isinstance(x, Image | Labels)]
    if len(images) < 2:
        return None
    ortho = [x for x in images if is_ortho(x)]
    references = [x for x in images if str(x.name).startswith("reference")]
    if not ortho:
        return images[-1], images[-2]
    if references:
        bands = {layer_band(r) for r in references}
        a = next((x for x in reversed(ortho) if layer_band(x) in bands), ortho[-1])
        return a, next((r for r in reversed(references) if layer_band(r) == layer_band(a)),
                       references[-1])
    newest = [x for x in ortho if x.metadata.get("path") == ortho[-1].metadata.get("path")]

    def partners(a: Any) -> list[Any]:
        same_band = [x for x in images if x is not a and layer_band(x) == layer_band(a)]
        previous = [x for x in same_band if is_ortho(x)
                    and x.metadata.get("path") != a.metadata.get("path")]
        other_model = [x for x in same_band if is_ortho(x)
                       and x.metadata.get(RUN_KEY) != a.metadata.get(RUN_KEY)]
        return previous or other_model or [x for x in same_band
                                           if str(x.name).startswith("uncorrected")]

    for a in reversed(newest):  # a band of the newest product that has a partner
        if partners(a):
            return a, partners(a)[-1]
    return ortho[-1], [x for x in images if x is not ortho[-1]][-1]


def _disparity_of(data_a: Any, data_b: Any, grids: Warp | None,
                  pixel_size: tuple[float, float] | None) -> Any:
    """The ZNCC disparity (``analysis.disparity``) of two layers' full-resolution data, B
    warped onto A's grid first when ``grids`` is given (GDAL only: no pyproj object in the
    worker's pooled thread); every ``step``-th pixel above ``DISPARITY_MAX_SIZE`` lines or
    columns."""
    from ..analysis.disparity import disparity

    image_a, image_b = (np.asarray(d, np.float32) for d in (data_a, data_b))
    if grids is not None:
        image_b = warp(image_b, grids)
    step = max(1, int(np.ceil(max(image_a.shape) / DISPARITY_MAX_SIZE)))
    return disparity(image_a, image_b, step=step, pixel_size_m=pixel_size)


class FlickerWidget(Container):
    """Alternate two layers at a chosen rate; start/stop, key binding, GIF export, disparity."""

    def __init__(self, viewer: napari.viewer.Viewer) -> None:
        self.viewer = viewer
        self._closed = False
        self.layer_a = compact_combo(ComboBox(
            label="layer A", choices=self._layer_choices, nullable=True,
            tooltip="first layer (e.g. orthorectified or uncorrected)"))
        self.layer_b = compact_combo(ComboBox(
            label="layer B", choices=self._layer_choices, nullable=True,
            tooltip="second layer (e.g. the reference)"))
        self.rate = FloatSpinBox(label="rate (Hz)", value=2.0, min=0.2, max=30.0, step=0.5,
                                 tooltip="frames per second of the flicker")
        self.start_button = PushButton(text=f"Start ({FLICKER_KEY})",
                                       tooltip=f"alternate A and B ({FLICKER_KEY} toggles)")
        self.stop_button = PushButton(text="Stop", tooltip="stop and restore the visibility")
        self.cycles = SpinBox(label="GIF cycles", value=2, min=1, max=50,
                              tooltip="A/B cycles in the exported GIF")
        self.gif_path = FileEdit(label="GIF file", mode=FileDialogMode.OPTIONAL_FILE,
                                 filter="*.gif", value=Path.home() / GIF_NAME,
                                 tooltip="animated GIF to write (default: beside the data "
                                         "of layer A; without a file behind it, in your "
                                         "home directory)")
        self.export_button = PushButton(text="Export GIF", tooltip="write the flicker as a GIF")
        self.disparity_button = PushButton(
            text="Measure disparity", tooltip="ZNCC disparity of B against A (section 4.6), "
                                              "in the background")
        self.status = StatusLabel(value="stopped")
        self.disparity_label = StatusLabel(value="")
        super().__init__(widgets=[
            self.layer_a, self.layer_b, self.rate, self.start_button, self.stop_button,
            self.status, self.cycles, self.gif_path, self.export_button,
            self.disparity_button, self.disparity_label,
        ])
        self.settings_widgets = [self.layer_a, self.layer_b, self.rate, self.cycles,
                                 self.gif_path]
        remember("flicker", {"rate": self.rate, "cycles": self.cycles})
        self._timer = self._make_timer()
        self._showing_a = True
        #: the flickered layers and their visibility before the flicker (``stop`` restores it)
        self._saved_visibility: list[tuple[Any, bool]] | None = None
        self.disparity_worker: Any = None
        self.start_button.changed.connect(self.start)
        self.stop_button.changed.connect(self.stop)
        self.rate.changed.connect(self._set_interval)
        self.export_button.changed.connect(self._export_clicked)
        self._gif_chosen = False  # the user's own GIF path: kept whatever A becomes
        self._gif_default = Path.home() / GIF_NAME
        self.gif_path.changed.connect(self._gif_changed)
        self.layer_a.changed.connect(self._gif_beside_a)
        self.disparity_button.changed.connect(self._disparity_clicked)
        viewer.layers.events.inserted.connect(self._refresh_choices)
        viewer.layers.events.removed.connect(self._refresh_choices)
        viewer.bind_key(FLICKER_KEY, self._toggle_key, overwrite=True)
        _WIDGETS[id(viewer)] = self
        self._closer = OnClose(self.native, self.close_widget)
        self._default_pair()

    def close_widget(self) -> None:
        """The widget was removed or destroyed: stop, unbind the key, forget the viewer."""
        if getattr(self, "_closed", True):  # closed, or being garbage-collected
            return
        self._closed = True
        with contextlib.suppress(RuntimeError):  # the timer may be deleted already
            self._timer.stop()
        if any(func == self._toggle_key for func in self.viewer.keymap.values()):
            self.viewer.bind_key(FLICKER_KEY, None)
        if _WIDGETS.get(id(self.viewer)) is self:
            del _WIDGETS[id(self.viewer)]
        for event in (self.viewer.layers.events.inserted, self.viewer.layers.events.removed):
            event.disconnect(self._refresh_choices)

    # ---------------------------------------------------------------- layer choices
    def _layer_choices(self, _widget: Any = None) -> list[tuple[str, Any]]:
        from napari.layers import Image, Labels

        return [(layer.name, layer) for layer in self.viewer.layers
                if isinstance(layer, Image | Labels)]

    def _refresh_choices(self, event: Any = None) -> None:
        self.layer_a.reset_choices()
        self.layer_b.reset_choices()
        if self.running and not self._pair_present():
            self.stop()
        inserted = getattr(event, "type", "") == "inserted"
        # a new orthorectified band (a run just ended) brings the default pair back
        self._default_pair(force=inserted and not self.running and is_ortho(event.value))

    def _default_pair(self, force: bool = False) -> None:
        """Pre-select ``default_pair`` when nothing (or a removed layer) is selected, or when
        ``force`` (a new orthorectified layer)."""
        pair = default_pair(list(self.viewer.layers))
        if pair is None:
            return
        a, b = pair
        if force or self.layer_a.value is None:
            self.layer_a.value = a
        if force or self.layer_b.value is None or self.layer_b.value is self.layer_a.value:
            self.layer_b.value = b if b is not self.layer_a.value else a

    def _pair_present(self) -> bool:
        return all(x.value in self.viewer.layers for x in (self.layer_a, self.layer_b))

    def _pair(self) -> tuple[Any, Any]:
        a, b = self.layer_a.value, self.layer_b.value
        if a is None or b is None:
            raise OptionsError("flicker needs two layers: choose layer A and layer B")
        if a is b:
            raise OptionsError(f"flicker needs two different layers (both are {a.name!r})")
        return a, b

    # ---------------------------------------------------------------- flicker
    def _make_timer(self) -> Any:
        from qtpy.QtCore import QTimer

        timer = QTimer()
        timer.timeout.connect(self.step)
        return timer

    @property
    def running(self) -> bool:
        return bool(self._timer.isActive())

    def _set_interval(self, _value: Any = None) -> None:
        self._timer.setInterval(max(1, int(round(1000.0 / float(self.rate.value)))))

    def start(self, _value: Any = None) -> None:
        """Start alternating layer A and layer B."""
        try:
            a, b = self._pair()
        except MerisOrthoError as exc:
            self.status.value = str(exc)
            return
        if not self.running:
            hidden = covering(self.viewer.layers, a, b)
            self._saved_visibility = [(a, a.visible), (b, b.visible),
                                      *((x, True) for x in hidden)]
            for layer in hidden:
                layer.visible = False
        self._showing_a = False
        self.step()
        self._set_interval()
        self._timer.start()
        self.status.value = f"flickering {a.name} / {b.name} at {self.rate.value:g} Hz"

    def stop(self, _value: Any = None) -> None:
        """Stop the flicker and restore the visibility of the flickered layers, and of those it
        hid, still in the viewer (one removed while it flickered: the other one's)."""
        self._timer.stop()
        for layer, visible in self._saved_visibility or []:
            if layer in self.viewer.layers:
                layer.visible = visible
        self._saved_visibility = None
        self.status.value = "stopped"

    def step(self) -> None:
        """Show the other layer of the pair (one flicker frame)."""
        a, b = self.layer_a.value, self.layer_b.value
        if a is None or b is None:
            return
        self._showing_a = not self._showing_a
        a.visible, b.visible = self._showing_a, not self._showing_a

    def toggle(self) -> None:
        """Start the flicker, or stop it when it runs."""
        self.stop() if self.running else self.start()

    def _toggle_key(self, _viewer: Any = None) -> None:
        self.toggle()

    # ---------------------------------------------------------------- GIF
    def _gif_changed(self, value: Any) -> None:
        if isinstance(value, str | Path) and Path(value) != self._gif_default:
            self._gif_chosen = True

    def _gif_beside_a(self, _value: Any = None) -> None:
        """The default GIF file beside the data of layer A (until the user chooses one)."""
        place = None if self.layer_a.value is None else data_directory(self.layer_a.value)
        if self._gif_chosen or place is None:
            return
        self._gif_default = place / GIF_NAME
        self.gif_path.value = self._gif_default

    def export_gif(self, path: str | Path | None = None) -> Path:
        """Export the flicker of the chosen pair as an animated GIF."""
        a, b = self._pair()
        was_running = self.running
        if was_running:
            self.stop()
        chosen = path or self.gif_path.value
        if not isinstance(chosen, str | Path):
            raise OptionsError("choose one GIF file to write")
        out = export_flicker_gif(self.viewer, a, b, chosen,
                                 rate=float(self.rate.value), cycles=int(self.cycles.value))
        if was_running:
            self.start()
        return out

    def _export_clicked(self, _value: Any = None) -> None:
        try:
            out = self.export_gif()
        except MerisOrthoError as exc:
            self.status.value = str(exc)
            return
        self.status.value = f"wrote {out}"

    # ---------------------------------------------------------------- disparity
    def _disparity_inputs(self) -> tuple[Any, OutputGrid | None, Callable[[], Any]]:
        """Layer A, its grid and the measurement to run (``_disparity_of``: reading both
        layers whole and the warp of B onto A's grid are left to it, off the Qt thread: 0.11 s
        of the window's time on fr-alps). Checks the pair here (Qt thread)."""
        a, b = self._pair()
        from napari.layers import Labels

        for layer in (a, b):
            if getattr(layer, "rgb", False) or getattr(layer, "multichannel", False):
                raise OptionsError(f"{layer.name!r} is an RGB composite: the disparity "
                                   "compares two single bands (choose a grey band layer)")
            if isinstance(layer, Labels):
                raise OptionsError(f"{layer.name!r} is a labels layer (classes, not "
                                   "radiances): the disparity compares two single bands "
                                   "(choose a grey band layer)")
        frame_a, frame_b = layer_frame(a), layer_frame(b)
        data_a, data_b = full_resolution(a.data), full_resolution(b.data)
        grids = None  # B warped onto A's grid (made here: pyproj on the Qt thread)
        if frame_a is not None and frame_b is not None and frame_a != frame_b:
            grids = Warp.between(frame_b, frame_a)
        elif tuple(data_a.shape) != tuple(data_b.shape):
            raise OptionsError(f"{a.name!r} and {b.name!r} have different shapes and no "
                               "georeference to bring them onto one grid")
        pixel_size = None
        if frame_a is not None and not frame_a.is_geographic:
            pixel_size = (frame_a.dx, frame_a.dy)
        return a, frame_a, partial(_disparity_of, data_a, data_b, grids, pixel_size)

    def measure_disparity(self) -> Any:
        """ZNCC disparity of layer A against layer B (analysis.disparity, section 4.4), here
        and now (scripts). Adds a Vectors layer of the matched points (displacements
        exaggerated x10) and returns the DisparityResult."""
        a, frame, measure = self._disparity_inputs()
        result = measure()
        self._show_disparity(result, a, frame)
        return result

    def start_disparity(self) -> Any:
        """Measure the disparity in a napari thread worker; returns the worker (None when the
        layers are not a valid pair: the reason is shown)."""
        from napari.qt.threading import create_worker

        try:
            a, frame, measure = self._disparity_inputs()
        except MerisOrthoError as exc:
            self.disparity_label.value = str(exc)
            return None
        self.disparity_button.enabled = False
        self.disparity_label.value = f"measuring the disparity of {a.name!r}..."
        self.disparity_worker = create_worker(
            measure, _start_thread=False,
            _connect={"returned": lambda result: self._show_disparity(result, a, frame),
                      "errored": self._disparity_failed, "finished": self._disparity_done})
        start_after_paint(self.disparity_worker, lambda: getattr(self, "_closed", True))
        return self.disparity_worker

    def _disparity_failed(self, exc: BaseException) -> None:
        if not getattr(self, "_closed", True):
            self.disparity_label.value = f"disparity failed: {exc}"

    def _disparity_done(self) -> None:
        if not getattr(self, "_closed", True):
            self.disparity_button.enabled = True

    def _show_disparity(self, result: Any, layer_a: Any, frame: OutputGrid | None) -> None:
        if getattr(self, "_closed", True):
            return
        self._add_disparity_vectors(result, layer_a, frame)
        self.disparity_label.value = _disparity_summary(result)

    def _add_disparity_vectors(self, result: Any, layer_a: Any, frame: OutputGrid | None) -> None:
        """The matched points on layer A's grid, thinned to at most 60 across and one per
        (exaggerated) vector length; edge widths are in data pixels (napari scales them)."""
        vectors = result.napari_vectors(scale=DISPARITY_EXAGGERATION)
        if len(vectors) == 0:
            return
        longest = np.percentile(np.hypot(vectors[:, 1, 0], vectors[:, 1, 1]), 90)
        spacing = max(1, int(np.ceil(max(result.dx.shape) / DISPARITY_VECTORS_ACROSS)),
                      int(np.ceil(longest)))
        keep = (vectors[:, 0, 0] % spacing == 0) & (vectors[:, 0, 1] % spacing == 0)
        vectors = vectors[keep]
        if len(vectors) == 0:
            return
        kwargs: dict[str, Any] = {
            "name": f"disparity ×{DISPARITY_EXAGGERATION:g} {layer_a.name}",
            "edge_color": "magenta", "edge_width": max(1.0, spacing / 10.0),
            "vector_style": "arrow",
            "metadata": {"exaggeration": DISPARITY_EXAGGERATION, "spacing_px": spacing},
        }
        if frame is not None:  # in layer A's world: map coordinates in the status bar
            kwargs.update(scale=layer_scale(frame), translate=layer_translate(frame),
                          **world_axes(frame.crs))
            kwargs["metadata"][WORLD_KEY] = geo_metadata(frame)
        self.viewer.add_vectors(vectors, **kwargs)

    def _disparity_clicked(self, _value: Any = None) -> None:
        self.start_disparity()


def _disparity_summary(result: Any) -> str:
    """One line: the global displacement (mean of the candidates, section 4.6) in pixels."""
    n = int(np.count_nonzero(result.candidate))
    if n == 0:
        return "no candidate point above the confidence threshold"
    dx, dy = result.global_displacement
    return (f"global displacement dX = {fixed(dx, 2, sign=True)} px, "
            f"dY = {fixed(dy, 2, sign=True)} px ({n} points)")

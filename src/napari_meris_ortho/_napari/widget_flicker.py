"""Flicker widget: alternate two layers to check superimposability (handbook section 4.4).

Like the REGIST "Flicker" tool of the handbook (fig. 33-35): two layers (orthorectified vs
reference, or uncorrected vs orthorectified) are displayed alternately in the same frame at a
chosen rate, so that sub-pixel displacements become visible; the flicker is exported as an
animated GIF like ``snap0*_REGIST_Flicker_*_anim.gif``. A "Measure disparity" button runs the
ZNCC disparity analysis and shows the global displacement (the handbook's (+1.2, -4.4) px).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from magicgui.types import FileDialogMode
from magicgui.widgets import ComboBox, Container, FileEdit, FloatSpinBox, Label, PushButton, SpinBox

from .._atomic import atomic_path
from ..errors import MerisOrthoError, OptionsError
from ..geometry.grid import OutputGrid
from .world import layer_frame, layer_scale, layer_translate, reproject_onto

if TYPE_CHECKING:
    import napari

FLICKER_KEY = "Shift-F"
DISPARITY_EXAGGERATION = 10.0
DISPARITY_MAX_SIZE = 256  # analyse every step-th pixel above this many lines/columns


def export_flicker_gif(viewer: Any, layer_a: Any, layer_b: Any, path: str | Path, *,
                       rate: float = 2.0, cycles: int = 2) -> Path:
    """Write the flicker of two layers as an animated GIF (2 frames per cycle, ``1/rate`` s each).

    Frames are screenshots of the canvas with only ``layer_a`` then only ``layer_b`` shown
    among the two (other layers unchanged), as the handbook's flicker animations.
    """
    import imageio.v3 as iio

    if rate <= 0:
        raise OptionsError(f"flicker rate must be positive, got {rate}")
    if cycles < 1:
        raise OptionsError(f"flicker cycles must be at least 1, got {cycles}")
    show_viewer(viewer)
    saved = (layer_a.visible, layer_b.visible)
    try:
        frames = []
        for show_a in (True, False):
            layer_a.visible, layer_b.visible = show_a, not show_a
            frames.append(np.asarray(viewer.screenshot(canvas_only=True, flash=False))[..., :3])
    finally:
        layer_a.visible, layer_b.visible = saved
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


class FlickerWidget(Container):
    """Alternate two layers at a chosen rate; start/stop, key binding, GIF export, disparity."""

    def __init__(self, viewer: napari.viewer.Viewer) -> None:
        self.viewer = viewer
        self.layer_a = ComboBox(label="layer A", choices=self._layer_choices, nullable=True)
        self.layer_b = ComboBox(label="layer B", choices=self._layer_choices, nullable=True)
        self.rate = FloatSpinBox(label="rate (Hz)", value=2.0, min=0.2, max=30.0, step=0.5)
        self.start_button = PushButton(text=f"Start ({FLICKER_KEY})")
        self.stop_button = PushButton(text="Stop")
        self.cycles = SpinBox(label="GIF cycles", value=2, min=1, max=50)
        self.gif_path = FileEdit(label="GIF file", mode=FileDialogMode.OPTIONAL_FILE,
                                 filter="*.gif", value=Path("flicker_anim.gif"))
        self.export_button = PushButton(text="Export GIF")
        self.disparity_button = PushButton(text="Measure disparity")
        self.status = Label(value="stopped")
        self.disparity_label = Label(value="")
        super().__init__(widgets=[
            self.layer_a, self.layer_b, self.rate, self.start_button, self.stop_button,
            self.status, self.cycles, self.gif_path, self.export_button,
            self.disparity_button, self.disparity_label,
        ])
        self._timer = self._make_timer()
        self._showing_a = True
        self._saved_visibility: tuple[bool, bool] | None = None
        self.start_button.changed.connect(self.start)
        self.stop_button.changed.connect(self.stop)
        self.rate.changed.connect(self._set_interval)
        self.export_button.changed.connect(self._export_clicked)
        self.disparity_button.changed.connect(self._disparity_clicked)
        viewer.layers.events.inserted.connect(self._refresh_choices)
        viewer.layers.events.removed.connect(self._refresh_choices)
        viewer.bind_key(FLICKER_KEY, self._toggle_key, overwrite=True)
        self._default_pair()

    # ---------------------------------------------------------------- layer choices
    def _layer_choices(self, _widget: Any = None) -> list[tuple[str, Any]]:
        from napari.layers import Image, Labels

        return [(layer.name, layer) for layer in self.viewer.layers
                if isinstance(layer, Image | Labels)]

    def _refresh_choices(self, _event: Any = None) -> None:
        self.layer_a.reset_choices()
        self.layer_b.reset_choices()
        if self.running and not self._pair_present():
            self.stop()
        self._default_pair()

    def _default_pair(self) -> None:
        """Pre-select the two top-most images when nothing (or a removed layer) is selected."""
        layers = [layer for _, layer in self._layer_choices()]
        if len(layers) < 2:
            return
        if self.layer_a.value is None:
            self.layer_a.value = layers[-1]
        if self.layer_b.value is None or self.layer_b.value is self.layer_a.value:
            self.layer_b.value = next(x for x in reversed(layers) if x is not self.layer_a.value)

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
            self._saved_visibility = (a.visible, b.visible)
        self._showing_a = False
        self.step()
        self._set_interval()
        self._timer.start()
        self.status.value = f"flickering {a.name} / {b.name} at {self.rate.value:g} Hz"

    def stop(self, _value: Any = None) -> None:
        """Stop the flicker and restore the layers' visibility."""
        self._timer.stop()
        if self._saved_visibility is not None and self._pair_present():
            self.layer_a.value.visible, self.layer_b.value.visible = self._saved_visibility
        self._saved_visibility = None
        self.status.value = "stopped"

    def step(self) -> None:
        """Show the other layer of the pair (one flicker frame)."""
        a, b = self.layer_a.value, self.layer_b.value
        if a is None or b is None:
            return
        self._showing_a = not self._showing_a
        a.visible, b.visible = self._showing_a, not self._showing_a

    def _toggle_key(self, _viewer: Any = None) -> None:
        self.stop() if self.running else self.start()

    # ---------------------------------------------------------------- GIF
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
    def measure_disparity(self) -> Any:
        """ZNCC disparity of layer A against layer B (analysis.disparity, section 4.4).

        Layer B is reprojected onto layer A's grid when they differ. Adds a Vectors layer of the
        matched points (displacements exaggerated x10) and returns the DisparityResult.
        """
        from ..analysis.disparity import disparity

        a, b = self._pair()
        frame_a, frame_b = layer_frame(a), layer_frame(b)
        image_a, image_b = np.asarray(a.data, np.float32), np.asarray(b.data, np.float32)
        if frame_a is not None and frame_b is not None and frame_a != frame_b:
            image_b = reproject_onto(image_b, frame_b, frame_a)
        elif image_a.shape != image_b.shape:
            raise OptionsError(f"{a.name!r} and {b.name!r} have different shapes and no "
                               "georeference to bring them onto one grid")
        step = max(1, int(np.ceil(max(image_a.shape) / DISPARITY_MAX_SIZE)))
        pixel_size = None
        if frame_a is not None and not frame_a.is_geographic:
            pixel_size = (frame_a.dx, frame_a.dy)
        result = disparity(image_a, image_b, step=step, pixel_size_m=pixel_size)
        self._add_disparity_vectors(result, a, frame_a)
        self.disparity_label.value = _disparity_summary(result)
        return result

    def _add_disparity_vectors(self, result: Any, layer_a: Any, frame: OutputGrid | None) -> None:
        vectors = result.napari_vectors(scale=DISPARITY_EXAGGERATION)
        if len(vectors) == 0:
            return
        kwargs: dict[str, Any] = {
            "name": f"disparity {layer_a.name}", "edge_color": "magenta", "edge_width": 1.0,
            "vector_style": "arrow", "metadata": {"exaggeration": DISPARITY_EXAGGERATION},
        }
        if frame is not None:
            kwargs.update(scale=layer_scale(frame), translate=layer_translate(frame))
            kwargs["edge_width"] = max(frame.dx, frame.dy)
        self.viewer.add_vectors(vectors, **kwargs)

    def _disparity_clicked(self, _value: Any = None) -> None:
        try:
            self.measure_disparity()
        except MerisOrthoError as exc:
            self.disparity_label.value = str(exc)


def _disparity_summary(result: Any) -> str:
    """One line: the global displacement (mean of the candidates, section 4.6) in pixels."""
    n = int(np.count_nonzero(result.candidate))
    if n == 0:
        return "no candidate point above the confidence threshold"
    dx, dy = result.global_displacement
    return f"global displacement dX = {dx:+.2f} px, dY = {dy:+.2f} px ({n} points)"

"""Layout of the plugin's widgets: docks of a fixed width, text never widens them; the camera
framed on a result. How layers go into the viewer: ``_qt.insertion``.

A QLabel without word wrap asks for the width of its whole text, and a QComboBox for its
longest item: a long status message, path or layer name would widen the dock from 477 to
1066 px.
Labels wrap at spaces and ignore their text width (the full text is also their tooltip);
combo boxes ask for ``COMBO_CHARS`` characters and elide the rest.
"""

from __future__ import annotations

from typing import Any

from magicgui.widgets import Container, Label

#: characters a combo box asks room for (longer layer names are elided)
COMBO_CHARS = 24


#: share of the screen's height a scrolled form claims at least (the rest of it scrolls)
FORM_SCREEN_SHARE = 0.4


class ScrolledForm(Container):
    """A magicgui ``Container`` whose rows scroll above a footer that stays in view (its
    action rows: Run, Cancel, progress, status). The Orthorectify widget needs 812 px of
    height, 1181 px with the Flicker dock below it: napari's window would grow past a 1080-line
    screen to give them. The form claims at most ``FORM_SCREEN_SHARE`` of the screen's height
    and scrolls the rest when the window is shorter. ``native`` is the widget napari docks: the
    scroll area and the footer (napari docks a container's ``native``)."""

    def __init__(self, *, footer: list[Any], **kwargs: Any) -> None:
        self._docked: Any = None
        super().__init__(**kwargs)
        from qtpy.QtCore import Qt
        from qtpy.QtWidgets import QApplication, QFrame, QScrollArea, QVBoxLayout, QWidget

        self.footer = Container(widgets=footer)
        form = self._widget._mgui_get_native_widget()
        scroll = QScrollArea()
        scroll.setWidgetResizable(True)
        scroll.setFrameShape(QFrame.Shape.NoFrame)
        scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        scroll.setWidget(form)
        screen = QApplication.primaryScreen()
        if screen is not None:
            share = int(FORM_SCREEN_SHARE * screen.availableGeometry().height())
            scroll.setMinimumHeight(min(form.minimumSizeHint().height(), share))
        docked = QWidget()
        layout = QVBoxLayout(docked)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(0)
        layout.addWidget(scroll)
        layout.addWidget(self.footer.native)
        self._docked = docked

    @property
    def native(self) -> Any:
        return self._docked if self._docked is not None else super().native


class StatusLabel(Label):
    """A magicgui ``Label`` that wraps its text and never asks for more width than the dock
    has; its tooltip is the full text (an unbroken path may be clipped, the tooltip shows it)."""

    def __init__(self, **kwargs: Any) -> None:
        from qtpy.QtWidgets import QSizePolicy

        super().__init__(**kwargs)
        native = self.native
        native.setWordWrap(True)
        policy = QSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)
        policy.setHeightForWidth(True)
        native.setSizePolicy(policy)
        native.setMinimumWidth(1)
        native.setToolTip(str(self.value))

    @property
    def value(self) -> Any:
        return Label.value.fget(self)  # type: ignore[attr-defined]

    @value.setter
    def value(self, value: Any) -> None:
        Label.value.fset(self, value)  # type: ignore[attr-defined]
        self.native.setToolTip(str(value))
        self.fit()

    def fit(self) -> None:
        """Ask for the height of the wrapped text at the label's width (the dock's scroll
        area does not pass height-for-width on)."""
        native = self.native
        native.setMinimumHeight(max(native.heightForWidth(max(native.width(), 100)), 0))


def compact_combo(combo: Any) -> Any:
    """A magicgui ``ComboBox`` asking room for ``COMBO_CHARS`` characters, not its longest item."""
    from qtpy.QtCore import Qt
    from qtpy.QtWidgets import QComboBox

    native = combo.native
    native.setSizeAdjustPolicy(QComboBox.SizeAdjustPolicy.AdjustToMinimumContentsLengthWithIcon)
    native.setMinimumContentsLength(COMBO_CHARS)
    native.view().setTextElideMode(Qt.TextElideMode.ElideMiddle)
    return combo


def camera_of(viewer: Any) -> Any:
    """The viewer's camera: ``viewer.scene.camera`` (napari 0.9 deprecates ``viewer.camera``),
    ``viewer.camera`` in earlier napari."""
    return getattr(viewer, "scene", viewer).camera


def frame_extent(viewer: Any, low: Any, high: Any) -> None:
    """Point the camera at the world box ``low``..``high`` (its last two axes: row, column),
    the box filling 95 % of the canvas."""
    import numpy as np

    low, high = np.asarray(low, np.float64)[-2:], np.asarray(high, np.float64)[-2:]
    size = np.where(np.isclose(high - low, 0.0), 1.0, high - low)
    camera = camera_of(viewer)
    camera.center = tuple(float(v) for v in (low + high) / 2.0)
    canvas = np.asarray(viewer.canvas.size, np.float64)
    camera.zoom = float(0.95 * np.min(canvas / size))


def frame_layers(viewer: Any, layers: list[Any]) -> None:
    """Point the camera at ``layers`` (not the whole viewer); nothing without layers."""
    import numpy as np

    if not layers:
        return
    if max(layer.ndim for layer in layers) == viewer.dims.ndim:
        viewer.fit_to_view(layers=layers)
        return
    # 2-D layers over a band stack (an opened N1): napari 0.9's fit_to_view(layers=...)
    # indexes their 2-D extent with the viewer's 3-D displayed axes; frame them directly
    extents = np.array([np.asarray(layer.extent.world, np.float64)[:, -2:] for layer in layers])
    frame_extent(viewer, extents[:, 0].min(axis=0), extents[:, 1].max(axis=0))


def frame_later(viewer: Any, low: Any, high: Any) -> None:
    """:func:`frame_extent` at the next turn of the event loop: after napari has added the
    layers a reader returned (and reset its view to all of them). No-op without Qt."""
    try:
        from qtpy.QtCore import QTimer
    except ImportError:  # pragma: no cover - napari always has Qt
        return
    QTimer.singleShot(0, lambda: frame_extent(viewer, low, high))

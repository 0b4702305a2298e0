"""Screenshots of what a new user sees first (docs/images/first_view_*.png): the whole napari
window, 1920 x 1080, after File > Open Sample > fr-small and after a default Orthorectify run of
fr-small's product with its DEM, the whole scene in view, with the key of the selected layer
(parallax vectors, iterations, elevation source).

Needs an X display with OpenGL; without one the script re-runs itself under ``xvfb-run`` at
1920 x 1080. Usage::

    python scripts/first_view_screenshots.py [--out docs/images]
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from make_screenshots import _close_toasts, _process_events, _run_widget

ROOT = Path(__file__).resolve().parents[1]
SCREEN = (1920, 1080)


def _ensure_display() -> None:
    if os.environ.get("DISPLAY"):
        return
    xvfb = shutil.which("xvfb-run")
    if xvfb is None:
        sys.exit("first_view_screenshots: no DISPLAY and no xvfb-run (apt-get install xvfb)")
    os.environ.pop("QT_QPA_PLATFORM", None)
    screen = f"-screen 0 {SCREEN[0]}x{SCREEN[1]}x24"
    os.execv(xvfb, [xvfb, "-a", "-s", screen, sys.executable, *sys.argv])


def _viewer():
    import napari

    viewer = napari.Viewer(show=True)
    viewer.window.resize(*SCREEN)  # the whole screen (Xvfb has no window manager)
    _process_events(1.5)
    return viewer


def _select(viewer, prefix: str) -> None:
    """Show and select the newest layer whose name starts with ``prefix`` (its key shows); the
    layer selected before it hidden again, unless it is a geometry layer."""
    before = viewer.layers.selection.active
    if before is not None and type(before).__name__ != "Vectors":
        before.visible = False
    layer = next(x for x in reversed(viewer.layers) if x.name.startswith(prefix))
    layer.visible = True
    viewer.layers.selection.active = layer
    _process_events(1.0)


def _save(viewer, out: Path, name: str) -> Path:
    import time

    from napari_meris_ortho._napari import legend

    end = time.monotonic() + 30.0  # the key waits for its glyphs (rendered after a run)
    while viewer in legend._PREPARING and time.monotonic() < end:
        _process_events(0.2)
    _close_toasts(viewer)
    viewer.reset_view()
    _process_events(1.0)
    path = out / name
    viewer.screenshot(str(path), canvas_only=False)
    print(f"wrote {path}")
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=str(ROOT / "docs" / "images"))
    args = parser.parse_args(argv)
    _ensure_display()
    os.environ["NAPARI_CONFIG"] = os.path.join(tempfile.mkdtemp(prefix="screens-"),
                                               "settings.yaml")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene("fr-small")

    viewer = _viewer()  # File > Open Sample > fr-small
    viewer.open_sample("napari-meris-ortho", "fr-small")
    _process_events(3.0)
    _select(viewer, "parallax")
    _save(viewer, out, "first_view_sample.png")
    viewer.close()

    viewer = _viewer()  # the widget's defaults, the product and its DEM
    viewer.open(str(scene.product_path), plugin="napari-meris-ortho")
    _, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    widget.products.value = [scene.product_path]
    widget.add_dem(scene.dem_paths["geotiff"])
    _process_events(1.0)
    _run_widget(widget)
    _save(viewer, out, "first_view_run.png")  # the newest image shown, parallax selected
    for prefix, name in (("iterations", "first_view_iterations.png"),
                         ("elevation source", "first_view_elevation_source.png")):
        _select(viewer, prefix)
        _save(viewer, out, name)
    viewer.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Screenshots and flicker GIFs of the napari plugin for the README tour (docs/images/).

A real run: the sample scene is generated (or taken from the cache), mapped without and with
terrain correction, shown in a napari viewer, and captured. Needs an X display with OpenGL;
without one the script re-runs itself under ``xvfb-run`` (never Qt's offscreen platform, which
has no OpenGL context for napari's canvas). Usage::

    python scripts/make_screenshots.py [--scene fr-alps] [--out docs/images]
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SIZE = (1500, 1000)


def _ensure_display() -> None:
    if os.environ.get("DISPLAY"):
        return
    xvfb = shutil.which("xvfb-run")
    if xvfb is None:
        sys.exit("make_screenshots: no DISPLAY and no xvfb-run (apt-get install xvfb)")
    os.environ.pop("QT_QPA_PLATFORM", None)
    os.execv(xvfb, [xvfb, "-a", "-s", "-screen 0 2000x1300x24", sys.executable, *sys.argv])


def _only(viewer, *names: str) -> None:
    for layer in viewer.layers:
        layer.visible = layer.name in names


def _centre_on(viewer, layer, row: int, col: int, half_width_px: int) -> None:
    """Centre the camera on pixel (row, col) of ``layer``, about 2 x half_width_px across."""
    centre = np.asarray(layer.translate) + np.asarray(layer.scale) * (row, col)
    camera = viewer.scene.camera if hasattr(viewer, "scene") else viewer.camera
    camera.center = tuple(centre)
    canvas_px = min(viewer.window._qt_viewer.canvas.size)
    camera.zoom = canvas_px / (2 * half_width_px * layer.scale[0])


def _full(layer) -> np.ndarray:
    """A raster layer's full-resolution data (the first level of a multiscale layer)."""
    return np.asarray(layer.data[0] if layer.multiscale else layer.data)


def _zoom_on_peak(viewer, half_width_px: int = 70) -> tuple[float, float]:
    """Centre the camera on the highest DEM pixel, showing about 2 x half_width_px pixels."""
    dem = viewer.layers["DEM"]
    valid = _full(viewer.layers["orthorectified b7"]) > 0
    heights = np.where(valid, _full(dem), -np.inf)
    row, col = np.unravel_index(np.argmax(heights), heights.shape)
    _centre_on(viewer, dem, int(row), int(col), half_width_px)
    return float(heights[row, col]), float(dem.scale[0])


def _zoom_on_large_shifts(viewer, half_width_px: int) -> None:
    """Centre the camera on the window of largest total parallax shift (vectors of the top
    fifth of lengths as candidate centres)."""
    vectors = viewer.layers["parallax ×10"]
    ref = viewer.layers["reference b7"]
    pixels = (vectors.data[:, 0] - np.asarray(ref.translate)) / np.asarray(ref.scale)
    length = np.hypot(vectors.data[:, 1, 0], vectors.data[:, 1, 1])
    candidates = pixels[length >= np.percentile(length, 80)]
    inside = np.all(np.abs(candidates[:, None, :] - pixels[None, :, :]) < half_width_px, axis=2)
    row, col = np.round(candidates[np.argmax(inside @ length)])
    _centre_on(viewer, ref, int(row), int(col), half_width_px)


def _zoom_on_parallax(viewer, half_width_px: int = 70) -> tuple[float, float]:
    """Centre the camera where the parallax is large and the uncorrected mapping differs most
    from the reference: among the vectors of the largest shifts (top fifth), the window of
    least correlation between "uncorrected b7" and "reference b7". Returns (shift in m,
    correlation)."""
    vectors = viewer.layers["parallax ×10"]
    ref, flat = viewer.layers["reference b7"], viewer.layers["uncorrected b7"]
    ends = vectors.data[:, 0] + vectors.data[:, 1]  # terrain positions (world)
    shift = np.hypot(vectors.data[:, 1, 0], vectors.data[:, 1, 1]) / vectors.metadata[
        "exaggeration"]
    pixels = np.round((ends - np.asarray(ref.translate)) / np.asarray(ref.scale)).astype(int)
    best = None
    for k in np.argsort(shift)[::-1][: max(10, len(shift) // 5)]:
        r, c = pixels[k]
        win = (slice(max(r - half_width_px, 0), r + half_width_px),
               slice(max(c - half_width_px, 0), c + half_width_px))
        a, b = _full(ref)[win], _full(flat)[win]
        inside = (a > 0) & (b > 0)
        if inside.size == 0 or inside.mean() < 0.95:
            continue
        corr = float(np.corrcoef(a[inside], b[inside])[0, 1])
        if best is None or corr < best[0]:
            best = (corr, int(r), int(c), float(shift[k]))
    if best is None:
        raise SystemExit("make_screenshots: no area of large parallax inside the footprint")
    corr, row, col, metres = best
    _centre_on(viewer, ref, row, col, half_width_px)
    return metres, corr


def _gif_correlation(path: Path) -> float:
    """Correlation of the two frames of a flicker GIF (grey levels): 1 = no visible jump."""
    import imageio.v3 as iio

    frames = iio.imread(path, index=None)[..., :3].astype(np.float64).mean(axis=-1)
    return float(np.corrcoef(frames[0].ravel(), frames[1].ravel())[0, 1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="fr-alps", choices=["fr-alps", "fr-small"])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images")
    args = parser.parse_args(argv)
    _ensure_display()
    # fresh napari settings: the widgets show their defaults, not remembered values
    os.environ["NAPARI_CONFIG"] = str(Path(tempfile.mkdtemp(prefix="napari-")) / "settings.yaml")

    import napari
    from napari_meris_ortho._napari.widget_flicker import FlickerWidget, export_flicker_gif

    args.out.mkdir(parents=True, exist_ok=True)
    viewer = napari.Viewer(title=f"napari-meris-ortho: {args.scene}")
    viewer.window.show()
    viewer.window.resize(*SIZE)
    viewer.open_sample("napari-meris-ortho", args.scene)
    viewer.scale_bar.visible = True  # layers in metres: the bar reads km
    viewer.scale_bar.font_size = 14
    viewer.scale_bar.box = True
    wrote = []

    _only(viewer, "orthorectified RGB 7-5-2", "footprint", "facets")
    viewer.layers["facets"].visible = True
    viewer.reset_view()
    viewer.screenshot(str(args.out / "ortho_rgb_footprint.png"), flash=False)
    wrote.append("ortho_rgb_footprint.png")

    _only(viewer, "DEM", "parallax ×10", "footprint")
    viewer.layers["DEM"].colormap = "gray"
    viewer.layers["parallax ×10"].opacity = 1.0
    _zoom_on_large_shifts(viewer, half_width_px=450)
    viewer.screenshot(str(args.out / "parallax_vectors.png"), flash=False)
    wrote.append("parallax_vectors.png")

    peak, pixel = _zoom_on_peak(viewer)
    shift_m, window_corr = _zoom_on_parallax(viewer)
    correlations = {}
    for name, pair in (("flicker_uncorrected_vs_reference.gif",
                        ("uncorrected b7", "reference b7")),
                       ("flicker_ortho_vs_reference.gif",
                        ("orthorectified b7", "reference b7"))):
        _only(viewer, *pair)
        a, b = (viewer.layers[n] for n in pair)
        b.contrast_limits = a.contrast_limits
        export_flicker_gif(viewer, a, b, args.out / name, rate=2.0, cycles=2)
        correlations[name] = _gif_correlation(args.out / name)
        wrote.append(name)
    jump, still = (correlations["flicker_uncorrected_vs_reference.gif"],
                   correlations["flicker_ortho_vs_reference.gif"])
    print(f"flicker area: parallax shift {shift_m:.0f} m, window correlation {window_corr:.3f}; "
          f"frame correlation uncorrected "
          f"{jump:.3f}, orthorectified {still:.3f}")
    if not jump < still - 0.05:
        print("make_screenshots: the uncorrected flicker does not jump visibly", file=sys.stderr)
        return 1

    viewer.reset_view()
    _only(viewer, "orthorectified RGB 7-5-2", "footprint")
    viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    _, flicker = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Flicker")
    assert isinstance(flicker, FlickerWidget)
    flicker.layer_a.value = viewer.layers["reference b7"]
    flicker.layer_b.value = viewer.layers["orthorectified b7"]
    result = flicker.measure_disparity()
    viewer.layers[-1].visible = False
    viewer.window.resize(1900, 1150)
    viewer.reset_view()
    from napari.utils.notifications import notification_manager
    from qtpy.QtWidgets import QApplication

    notification_manager.records.clear()
    from napari._qt.dialogs.qt_notification import NapariQtNotification

    for toast in viewer.window._qt_window.findChildren(NapariQtNotification):
        toast.close()  # e.g. the PyQt5 deprecation notice over the canvas
    for _ in range(20):
        QApplication.processEvents()
    viewer.screenshot(str(args.out / "widgets.png"), canvas_only=False, flash=False)
    wrote.append("widgets.png")

    dx, dy = result.global_displacement
    print(f"scene {args.scene}: highest point {peak:.0f} m, pixel {pixel:.0f} m")
    print(f"disparity orthorectified vs reference: dX {dx:+.2f} px, dY {dy:+.2f} px "
          f"({int(result.candidate.sum())} points)")
    print("wrote", ", ".join(str(args.out / w) for w in wrote))
    viewer.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

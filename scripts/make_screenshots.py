"""Screenshots and flicker GIFs of the napari plugin for the documentation (docs/images/).

A real run: the sample scene is generated (or taken from the cache), mapped without and with
terrain correction, shown in a napari viewer, and captured; then the Orthorectify widget maps
the scene's product with its DEM (the layers of a run), the product is opened with the
plugin's reader, and a synthesis store of two cloudy dates of the scene is opened; last an
OLCI scene (``--olci``) is mapped with its DEM and shown with its footprint, tie-point facets
and parallax vectors (``olci_<scene>.png``, 1920 x 1080). Needs an X display with OpenGL;
without one the script re-runs itself under ``xvfb-run`` (Qt's offscreen platform has no
OpenGL context: its screenshots are black). Usage::

    python scripts/make_screenshots.py [--scene fr-alps] [--olci olci-err-andes]
                                       [--only olci] [--out docs/images]
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
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


def _process_events(seconds: float = 0.0) -> None:
    """Let the Qt event loop run (layers inserted a turn at a time, frames drawn)."""
    from qtpy.QtWidgets import QApplication

    end = time.monotonic() + seconds
    while True:
        QApplication.processEvents()
        if time.monotonic() >= end:
            return
        time.sleep(0.02)


def _close_toasts(viewer) -> None:
    """Close napari's notification toasts (they would cover the canvas)."""
    from napari._qt.dialogs.qt_notification import NapariQtNotification
    from napari.utils.notifications import notification_manager

    notification_manager.records.clear()
    for toast in viewer.window._qt_window.findChildren(NapariQtNotification):
        toast.close()
    _process_events(0.3)


def _run_widget(widget, timeout: float = 600.0) -> None:
    """Start a run of the Orthorectify widget and wait until its last layer is in."""
    if widget.start() is None:
        raise SystemExit(f"make_screenshots: the widget refused the run: {widget.status.value}")
    end = time.monotonic() + timeout
    while widget.running:
        if time.monotonic() > end:
            raise SystemExit("make_screenshots: the Orthorectify run did not finish")
        _process_events(0.1)
    if not str(widget.status.value).startswith("done"):
        raise SystemExit(f"make_screenshots: the run failed: {widget.status.value}")
    _process_events(1.0)  # the hidden layers' thumbnails, the last frames


def _season(scene: str, n: int = 2) -> list[str]:
    """``n`` cloudy dates of ``scene`` (N1 files told apart by their file counter)."""
    from napari_meris_ortho.simulate.scene import generate_scene

    no_exports = {"getasse30": False, "getasse30_beam": False, "srtm30": False,
                  "geotiff_utm": False, "reference": False}
    return [str(generate_scene({"base": scene, "exports": no_exports, "file_counter": k + 1,
                                "clouds": {"fraction": 0.4, "scale_km": 20.0,
                                           "seed": 10 * (k + 1)}}).product_path)
            for k in range(n)]


def _named(viewer, prefix: str):
    """The first layer whose name starts with ``prefix`` (run layers carry a time stamp)."""
    for layer in viewer.layers:
        if layer.name.startswith(prefix):
            return layer
    raise SystemExit(f"make_screenshots: no layer named {prefix}...")


def _only_prefixed(viewer, *prefixes: str) -> None:
    for layer in viewer.layers:
        layer.visible = any(layer.name.startswith(p) for p in prefixes)


def _gif_correlation(path: Path) -> float:
    """Correlation of the two frames of a flicker GIF (grey levels): 1 = no visible jump."""
    import imageio.v3 as iio

    frames = iio.imread(path, index=None)[..., :3].astype(np.float64).mean(axis=-1)
    return float(np.corrcoef(frames[0].ravel(), frames[1].ravel())[0, 1])


def _run_and_readers(viewer, ortho, args) -> list[str]:
    """The layers of an Orthorectify run, an N1 opened with the reader, a synthesis store."""
    from napari_meris_ortho import synthesize
    from napari_meris_ortho.simulate.scene import generate_scene

    wrote = []
    scene = generate_scene(args.scene)
    for layer in viewer.layers:
        layer.visible = False
    ortho.products.value = [scene.product_path]
    ortho.add_dem(scene.dem_paths["geotiff"])
    _run_widget(ortho)
    _only_prefixed(viewer, "ortho RGB 7-5-2", "footprint ·", "parallax ×10 ·")
    viewer.reset_view()
    _close_toasts(viewer)
    viewer.screenshot(str(args.out / "orthorectify_run.png"), canvas_only=False, flash=False)
    wrote.append("orthorectify_run.png")

    _only_prefixed(viewer, "iterations", "footprint ·")
    viewer.screenshot(str(args.out / "iterations.png"), flash=False)
    wrote.append("iterations.png")

    viewer.window.remove_dock_widget("all")
    viewer.window.resize(*SIZE)
    viewer.layers.clear()
    _process_events(1.0)
    viewer.open(str(scene.product_path), plugin="napari-meris-ortho")
    _process_events(2.0)  # controls, overlays and thumbnails come in the turns after
    _named(viewer, "flags").visible = True
    viewer.reset_view()
    _close_toasts(viewer)
    viewer.screenshot(str(args.out / "reader_n1.png"), canvas_only=False, flash=False)
    wrote.append("reader_n1.png")

    store = Path(tempfile.mkdtemp(prefix="meris-screens-")) / "season"
    try:
        synthesize(_season(args.scene), store, algorithm="max-ndvi", elevation="tiepoints",
                   crs="utm", workers=0)
        viewer.layers.clear()
        _process_events(1.0)
        viewer.open(str(store), plugin="napari-meris-ortho")
        _process_events(2.0)
        product = _named(viewer, "season product")
        product.visible = True
        viewer.reset_view()
        _close_toasts(viewer)
        viewer.screenshot(str(args.out / "synthesis_store.png"), canvas_only=False, flash=False)
        wrote.append("synthesis_store.png")
        viewer.layers.clear()
        _process_events(0.5)
    finally:
        shutil.rmtree(store.parent, ignore_errors=True)
    return wrote


#: the window of the OLCI screenshot
OLCI_SIZE = (1920, 1080)
#: the OLCI screenshot's view across (m): its facets (one tie row high) stay apart
OLCI_VIEW_M = 400_000.0


def _olci_screenshot(scene_name: str, out: Path) -> str:
    """An OLCI scene mapped by the Orthorectify widget with its DEM: the true-colour map
    (Oa08, Oa06, Oa03) under its footprint, tie-point facets and parallax vectors, in a
    1920 x 1080 window. Returns the file name."""
    import napari
    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene(scene_name)
    viewer = napari.Viewer(title=f"napari-meris-ortho: {scene_name}")
    viewer.window.show()
    viewer.window.resize(*OLCI_SIZE)
    viewer.scale_bar.visible = True
    viewer.scale_bar.box = True
    _, ortho = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    ortho.products.value = [scene.product_path]
    ortho.add_dem(scene.dem_paths["geotiff"])
    _run_widget(ortho, timeout=1800.0)
    _only_prefixed(viewer, "ortho RGB 8-6-3", "footprint ·", "facets ·", "parallax ×")
    parallax = _named(viewer, "parallax ×")
    parallax.opacity = 1.0
    _named(viewer, "facets ·").opacity = 0.5
    viewer.layers.selection.active = parallax  # its key in the corner
    # the tie points are on every row: the facets are read on a part of the swath, from its
    # western edge (the footprint) to the longest parallax vector
    length = np.hypot(parallax.data[:, 1, 0], parallax.data[:, 1, 1])
    west = parallax.data[int(np.argmin(parallax.data[:, 0, 1])), 0]
    longest = parallax.data[int(np.argmax(length)), 0]
    across = max(OLCI_VIEW_M, 1.4 * float(np.abs(longest - west).max()))
    camera = viewer.camera
    camera.center = tuple(0.5 * (west + longest) - (0.0, 0.1 * across))
    camera.zoom = min(viewer.window._qt_viewer.canvas.size) / across
    _close_toasts(viewer)
    name = f"olci_{scene_name.removeprefix('olci-').replace('-', '_')}.png"
    viewer.screenshot(str(out / name), canvas_only=False, flash=False)
    print(f"{scene_name}: {parallax.name}, {len(parallax.data)} vectors, the longest "
          f"{length.max() / parallax.metadata['exaggeration']:.0f} m; "
          f"{ortho.status.value}")
    viewer.close()
    return name


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="fr-alps", choices=["fr-alps", "fr-small"])
    parser.add_argument("--olci", default="olci-err-andes",
                        choices=["olci-err-andes", "olci-efr-alps"])
    parser.add_argument("--only", choices=["olci"], default=None,
                        help="only the OLCI screenshot")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images")
    args = parser.parse_args(argv)
    _ensure_display()
    # fresh napari settings: the widgets show their defaults, not remembered values
    os.environ["NAPARI_CONFIG"] = str(Path(tempfile.mkdtemp(prefix="napari-")) / "settings.yaml")

    import napari
    from napari_meris_ortho._napari.widget_flicker import FlickerWidget, export_flicker_gif

    args.out.mkdir(parents=True, exist_ok=True)
    if args.only == "olci":
        print("wrote", args.out / _olci_screenshot(args.olci, args.out))
        return 0
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
    _, ortho = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    _, flicker = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Flicker")
    assert isinstance(flicker, FlickerWidget)
    flicker.layer_a.value = viewer.layers["reference b7"]
    flicker.layer_b.value = viewer.layers["orthorectified b7"]
    result = flicker.measure_disparity()
    viewer.layers[-1].visible = False
    viewer.window.resize(1900, 1150)
    viewer.reset_view()
    _close_toasts(viewer)  # any notification napari shows over the canvas
    viewer.screenshot(str(args.out / "widgets.png"), canvas_only=False, flash=False)
    wrote.append("widgets.png")

    wrote += _run_and_readers(viewer, ortho, args)
    viewer.close()
    wrote.append(_olci_screenshot(args.olci, args.out))

    dx, dy = result.global_displacement
    print(f"scene {args.scene}: highest point {peak:.0f} m, pixel {pixel:.0f} m")
    print(f"disparity orthorectified vs reference: dX {dx:+.2f} px, dY {dy:+.2f} px "
          f"({int(result.candidate.sum())} points)")
    print("wrote", ", ".join(str(args.out / w) for w in wrote))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Screenshot of the hidden-ground layer for the documentation (docs/images/hidden_ground.png).

A real run: the Orthorectify widget maps the steep scene (``fr-steep``, generated or taken
from the cache) with its DEM; the screenshot shows the RGB composite with the "hidden ground"
layer over it, framed on the range. Needs an X display with OpenGL; without one the script
re-runs itself under ``xvfb-run`` (as ``make_screenshots.py``). Usage::

    python scripts/make_hidden_screenshot.py [--hidden mask|keep] [--out docs/images]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from make_screenshots import (
    ROOT,
    _centre_on,
    _close_toasts,
    _ensure_display,
    _full,
    _named,
    _only_prefixed,
    _process_events,
    _run_widget,
)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hidden", default="mask", choices=["mask", "keep"])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images")
    args = parser.parse_args(argv)
    _ensure_display()
    os.environ["NAPARI_CONFIG"] = str(Path(tempfile.mkdtemp(prefix="napari-")) / "settings.yaml")

    import napari
    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene("fr-steep")
    args.out.mkdir(parents=True, exist_ok=True)
    viewer = napari.Viewer(title="napari-meris-ortho: fr-steep, hidden ground")
    viewer.window.show()
    viewer.window.resize(1900, 1000)
    viewer.scale_bar.visible = True
    viewer.scale_bar.box = True
    _, ortho = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    ortho.products.value = [scene.product_path]
    ortho.add_dem(scene.dem_paths["geotiff"])
    ortho.hidden.value = args.hidden
    _run_widget(ortho)
    _only_prefixed(viewer, "ortho RGB 7-5-2", "hidden ground", "footprint ·")
    hidden = _named(viewer, "hidden ground")
    viewer.layers.selection.active = hidden
    # framed on the densest hidden ground: the columns of most hidden points, 300 px across
    mask = _full(hidden) > 0
    counts = np.convolve(mask.sum(axis=0), np.ones(300), mode="same")
    col = int(np.argmax(counts))
    rows = np.flatnonzero(mask[:, max(col - 150, 0):col + 150].any(axis=1))
    _centre_on(viewer, hidden, int(np.median(rows)), col, 170)
    _process_events(0.5)
    _close_toasts(viewer)
    out = args.out / "hidden_ground.png"
    viewer.screenshot(str(out), canvas_only=False, flash=False)
    print(f"hidden ground: {hidden.metadata.get('hidden_points')} points; wrote {out}")
    viewer.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

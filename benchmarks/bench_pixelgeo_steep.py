"""Pixel geolocation on steep terrain: seen ground left unmapped, error on seen ground and over
all mapped points, hidden ground reported, beside the tie points + DEM.

The scene's SEN3 (per-pixel truth geolocation) mapped with ``geolocation="pixel"``, without and
with the scene's DEM (``engine.pixeldem``), on the grid of the tie-point + DEM run; every output
point whose true antecedent lies in the product is checked against ``true_antecedent`` and
classed seen/hidden by marching its line of sight towards the satellite over the truth DEM.
A benchmark, not a test: ``python benchmarks/bench_pixelgeo_steep.py
[--scene fr-steep] [--set JSON]``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time

import numpy as np


def main() -> None:
    from napari_meris_ortho.ortho import orthorectify
    from napari_meris_ortho.simulate.geocorrected import write_geocorrected
    from napari_meris_ortho.simulate.scene import generate_scene

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scene", default="fr-steep")
    ap.add_argument("--set", default=None, help="JSON overrides of the scene config")
    args = ap.parse_args()
    cfg = {"base": args.scene, **json.loads(args.set)} if args.set else args.scene
    scene = generate_scene(cfg)
    g = scene.geometry
    with tempfile.TemporaryDirectory() as tmp:
        sen3 = write_geocorrected(scene, fsg=False, out_dir=tmp)["sen3"]
        t0 = time.perf_counter()
        ref = orthorectify(scene.product_path, dems=[scene.dem_paths["geotiff"]], bands=[7],
                           parallax="ellipsoid", diagnostics=True)
        t_ref = time.perf_counter() - t0
        t0 = time.perf_counter()
        pix = orthorectify(sen3, grid=ref.grid, geolocation="pixel", bands=[7],
                           diagnostics=True)
        t_pix = time.perf_counter() - t0
        t0 = time.perf_counter()
        pdem = orthorectify(sen3, grid=ref.grid, dems=[scene.dem_paths["geotiff"]],
                            geolocation="pixel", parallax="ellipsoid", bands=[7],
                            diagnostics=True)
        t_pdem = time.perf_counter() - t0
    lon, lat = ref.grid.lonlat()
    h = scene.dem_height(lon, lat)
    tl, tc = scene.true_antecedent(lon, lat, h)
    inside = ((tl >= -0.5) & (tl < g.lines - 0.5) & (tc >= -0.5) & (tc < g.columns - 0.5)
              & np.isfinite(h))
    seen = np.zeros(inside.shape, bool)
    seen[inside] = scene.seen_from_sensor(lon[inside], lat[inside], h[inside], tl[inside],
                                          tc[inside])
    hidden = inside & ~seen
    print(f"{scene.name}: {inside.sum()} output points with their antecedent in the product, "
          f"{hidden.sum()} hidden ({100 * hidden.mean() / max(inside.mean(), 1e-12):.2f} %)")
    print(f"{'model':<24} {'seen unmapped':>15} {'RMS seen':>9} {'p99':>6} {'max':>6} "
          f"{'RMS all':>8} {'max all':>8} {'reported hidden (true)':>23} {'hidden dropped':>15} "
          f"{'time s':>7}")
    for label, r, seconds in (("tie points + DEM", ref, t_ref), ("SEN3 pixel", pix, t_pix),
                              ("SEN3 pixel + DEM", pdem, t_pdem)):
        e = np.hypot(r.diagnostics["line"] - tl, r.diagnostics["col"] - tc)
        es, ea = e[r.valid & seen], e[r.valid & inside]
        it = r.diagnostics["iterations"]
        lost = int(np.sum(seen & ~r.valid))
        print(f"{label:<24} {lost:>7} ({100 * lost / seen.sum():.3f} %) "
              f"{np.sqrt(np.mean(es ** 2)):9.4f} {np.percentile(es, 99):6.3f} {es.max():6.3f} "
              f"{np.sqrt(np.mean(ea ** 2)):8.4f} {ea.max():8.3f} "
              f"{int(np.sum(it == -2)):>13} ({int(np.sum((it == -2) & hidden))}) "
              f"{int(np.sum(hidden & (it == -1))):>15} {seconds:7.2f}")


if __name__ == "__main__":
    main()

"""Accuracy and speed of the mapping of simulated OLCI scenes, beside a MERIS scene of the
same size.

Per OLCI scene (default ``olci-efr-alps`` and ``olci-err-andes``), on every 7th point of the
output grid: the error (px of the product) against the simulator's ``true_antecedent`` of the
DEM mode (tie-point geolocation + the scene's DEM, handbook and ellipsoid parallax) and of the
per-pixel geolocation on the same grid, and the holes: points whose true antecedent lies in
the product and that the sensor sees (``SimulatedScene.seen_from_sensor``), left unmapped
and not found hidden by the run (the hidden ground is no data: ``hidden="mask"``). Then
the time of ``meris-ortho map`` (DEM mode, one band, a GeoTIFF on the default grid, whose size
is printed) of the scene and of a MERIS scene of as many pixels at the same resolution
(``fr-alps`` 2241 or ``rr-segment`` 1121 columns wide, as many lines as needed).
A benchmark, not a test: ``python benchmarks/bench_olci.py [--scene NAME ...]``.
"""

from __future__ import annotations

import argparse
import logging
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: the MERIS scene beside each OLCI resolution and its width (the widest MERIS FR/RR lines)
MERIS_OF = {"EFR": ("fr-alps", 2241), "ERR": ("rr-segment", 1121)}
NO_EXPORTS = {"srtm30": False, "getasse30": False, "getasse30_beam": False,
              "geotiff_utm": False, "reference": False}


def errors(scene, result, stride: int = 7) -> tuple[np.ndarray, int]:
    """Distance (px) to the truth of every ``stride``-th mapped point, and the holes (seen
    ground left unmapped) among the ``stride``-th points of the grid."""
    pick = np.zeros(result.valid.shape, bool)
    pick.ravel()[::stride] = True
    lon, lat = result.grid.lonlat()
    h = scene.dem_height(lon[pick], lat[pick])
    tl, tc = scene.true_antecedent(lon[pick], lat[pick], h)
    g = scene.geometry
    inside = ((tl >= 0.0) & (tl <= g.lines - 1.0) & (tc >= 0.0) & (tc <= g.columns - 1.0)
              & np.isfinite(h))
    seen = np.zeros_like(inside)
    seen[inside] = scene.seen_from_sensor(lon[pick][inside], lat[pick][inside], h[inside],
                                          tl[inside], tc[inside])
    inside &= seen
    ok = result.valid[pick]
    e = np.hypot(result.diagnostics["line"][pick][ok] - tl[ok],
                 result.diagnostics["col"][pick][ok] - tc[ok])
    found_hidden = (result.hidden[pick] if result.hidden is not None
                    else np.zeros_like(ok))
    return e, int(np.count_nonzero(inside & ~ok & ~found_hidden))


def map_seconds(product: Path, dem: Path, out: Path) -> tuple[float, float]:
    """Wall time of ``meris-ortho map`` (DEM mode, band Oa08/M07 at 665 nm, one GeoTIFF on
    the default grid) and the size of that grid (million pixels)."""
    import rasterio

    band = "8" if product.suffix == ".SEN3" else "7"
    cmd = [sys.executable, "-m", "napari_meris_ortho.cli", "map", str(product), "-o", str(out),
           "--dem", str(dem), "--bands", band, "--quiet"]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True)
    seconds = time.perf_counter() - t0
    with rasterio.open(out) as ds:
        return seconds, ds.width * ds.height / 1e6


def run(name: str, work: Path) -> list[tuple]:
    from napari_meris_ortho.ortho import orthorectify
    from napari_meris_ortho.simulate.scene import generate_scene

    scene = generate_scene(name)
    dem = scene.dem_paths["geotiff"]
    g = scene.geometry
    rows = []
    ref = None
    for label, kw in (("DEM, handbook parallax", {"parallax": "handbook"}),
                      ("DEM, ellipsoid parallax", {"parallax": "ellipsoid"})):
        t0 = time.perf_counter()
        r = orthorectify(scene.product_path, dems=[dem], bands=[8], diagnostics=True, **kw)
        seconds = time.perf_counter() - t0
        if ref is None:
            ref = r
        e, holes = errors(scene, r)
        rows.append((name, label, e, holes, seconds))
    assert ref is not None
    t0 = time.perf_counter()
    r = orthorectify(scene.product_path, grid=ref.grid, geolocation="pixel", bands=[8],
                     diagnostics=True)
    seconds = time.perf_counter() - t0
    e, holes = errors(scene, r)
    rows.append((name, "pixel geolocation", e, holes, seconds))
    meris_name, width = MERIS_OF[g.product_type[5:8]]
    lines = int(round(g.lines * g.columns / width))
    meris = generate_scene({"base": meris_name, "lines": lines, "exports": NO_EXPORTS})
    t_olci = map_seconds(scene.product_path, dem, work / f"{name}.tif")
    t_meris = map_seconds(meris.product_path, meris.dem_paths["geotiff"],
                          work / f"{name}-meris.tif")
    return rows, t_olci, t_meris, f"{meris_name} {lines} x {width}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scene", action="append", default=None)
    args = ap.parse_args()
    # the fill values of the simulated invalid pixels are reported by the reader: not here
    logging.getLogger("napari_meris_ortho").setLevel(logging.ERROR)
    print(f"{'scene':<15} {'mode':<24} {'RMS px':>8} {'p99 px':>8} {'max px':>8} "
          f"{'holes':>6} {'run s':>7}")
    timings = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.scene or ["olci-efr-alps", "olci-err-andes"]:
            rows, t_olci, t_meris, meris = run(name, Path(tmp))
            for scene, mode, e, holes, seconds in rows:
                print(f"{scene:<15} {mode:<24} {np.sqrt(np.mean(e ** 2)):8.4f} "
                      f"{np.percentile(e, 99):8.4f} {e.max():8.3f} {holes:6d} {seconds:7.2f}",
                      flush=True)
            timings.append((name, t_olci, meris, t_meris))
    print(f"\n{'scene':<15} {'map s':>7} {'grid Mpx':>9}   {'MERIS scene':<22} {'map s':>7} "
          f"{'grid Mpx':>9}")
    for name, (t_olci, px_olci), meris, (t_meris, px_meris) in timings:
        print(f"{name:<15} {t_olci:7.2f} {px_olci:9.1f}   {meris:<22} {t_meris:7.2f} "
              f"{px_meris:9.1f}")


if __name__ == "__main__":
    main()

"""Whole-call time of ``meris-ortho map`` onto grids the segment fills only in part, beside
gdalwarp on the same grid: a fixed regional extent (the grid of a time series) and a polar
stereographic map of an Arctic RR segment, against the product's own grid.

    .venv/bin/python benchmarks/bench_extent.py [--json FILE] [--repeat N]

Cases (bands 7, 5, 2, or ``--bands``; DEM mode for meris-ortho; gdalwarp: ``-geoloc`` on
pyepr's geolocation, no terrain correction, nearest neighbour, zstd COG, all cores):
- fr-alps on its own UTM 33N grid (260 m);
- fr-alps on a fixed LAEA Europe extent (EPSG:3035, 4000 x 4000 km at 300 m: 13334 x 13334 px,
  the segment covers 2 % of it);
- an Arctic RR segment (1121 x 8001 lines from 79 N, simulated once and cached) in EPSG:3995.

Run it with ``PYTHONPATH=OTHER/src`` to time another version of the package (the map command
runs as ``python -m napari_meris_ortho.cli`` in the same environment).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).parent))
from bench_ortho import run_gdalwarp, run_map

#: an Arctic descending RR segment: 8001 lines (23.5 min of orbit) from 79 N at 20 E, flat
ARCTIC = {"base": "rr-segment", "name": "rr-arctic",
          "orbit": {"direction": "descending", "nadir_lat": 79.0, "nadir_lon": 20.0},
          "date": "2003-06-21", "lines": 8001,
          "dem": {"spacing_deg": 0.02, "margin_deg": 0.5},
          "terrain": {"plain_height": 200, "ranges": [], "seas": [], "lakes": []},
          "exports": {"getasse30": False, "getasse30_beam": False, "srtm30": False,
                      "geotiff_utm": False, "reference": False}}
#: the bands mapped (those of the other benchmarks' RGB; gdalwarp holds every band it warps)
BANDS = (7, 5, 2)
EUROPE = ("EPSG:3035", (2_500_000.0, 5_500_000.0), (6_500_000.0, 1_500_000.0), 300.0)


def cases() -> list[tuple[str, Any, Any]]:
    """(label, scene, grid) of each case."""
    from napari_meris_ortho.engine.boundary import segment_boundary
    from napari_meris_ortho.geometry.grid import OutputGrid, default_grid
    from napari_meris_ortho.geometry.tiepoints import TiePointGrid
    from napari_meris_ortho.products.open import read_product
    from napari_meris_ortho.simulate.scene import generate_scene

    alps = generate_scene("fr-alps")
    arctic = generate_scene(ARCTIC)

    def own(scene: Any, crs: str, size: float) -> Any:
        tp = TiePointGrid.from_product(read_product(scene.product_path))
        return default_grid(segment_boundary(tp.latitude, tp.longitude), size, crs)

    crs, ul, lr, size = EUROPE
    return [("fr-alps, own UTM 33N grid", alps, own(alps, "EPSG:32633", 260.0)),
            ("fr-alps, LAEA Europe extent", alps, OutputGrid.from_extent(crs, ul, lr, size)),
            ("Arctic RR segment, EPSG:3995", arctic, own(arctic, "EPSG:3995", 1040.0))]


def grid_args(grid: Any) -> list[str]:
    x0, y0, x1, y1 = grid.bounds
    return ["--crs", grid.crs.to_string(), "--ul", repr(x0), repr(y1), "--lr", repr(x1),
            repr(y0), "--pixel-size", repr(grid.dx)]


def median_row(rows: list[dict]) -> dict:
    out = dict(rows[0])
    for key in ("wall_s", "peak_rss_mb", "cpu_s"):
        out[key] = statistics.median(r[key] for r in rows)
    out["wall_range"] = (min(r["wall_s"] for r in rows), max(r["wall_s"] for r in rows))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", default=None, metavar="FILE")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-gdalwarp", action="store_true")
    ap.add_argument("--bands", default=",".join(map(str, BANDS)),
                    help="bands mapped by both tools (default 7,5,2)")
    args = ap.parse_args(argv)
    bands = tuple(int(b) for b in args.bands.split(","))
    results = []
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        for label, scene, grid in cases():
            dem = scene.dem_paths["geotiff"]
            extra = [*grid_args(grid), "--bands", ",".join(map(str, bands))]
            run_map(scene.product_path, tmp / "warm.tif", dem, *extra)  # kernels, page cache
            ours = median_row([run_map(scene.product_path, tmp / "ours.tif", dem, *extra)
                               for _ in range(args.repeat)])
            row = {"case": label, "grid": [grid.height, grid.width], "meris_ortho": ours}
            if not args.no_gdalwarp:
                row["gdalwarp"] = median_row([run_gdalwarp(scene, grid, tmp, bands)
                                              for _ in range(args.repeat)])
            results.append(row)
            print(f"{label}: {grid.height} x {grid.width} px, meris-ortho map "
                  f"{ours['wall_s']:.2f} s ({ours['wall_range'][0]:.2f}-"
                  f"{ours['wall_range'][1]:.2f}), {ours['peak_rss_mb']:.0f} MB"
                  + (f"; gdalwarp {row['gdalwarp']['wall_s']:.2f} s, "
                     f"{row['gdalwarp']['peak_rss_mb']:.0f} MB" if "gdalwarp" in row else ""),
                  flush=True)
    print()
    print("| case | grid (px) | meris-ortho map, DEM: s (range), peak MB "
          "| gdalwarp -geoloc, no terrain: s, peak MB |")
    print("|---|---|---|---|")
    for r in results:
        o = r["meris_ortho"]
        g = r.get("gdalwarp")
        print(f"| {r['case']} | {r['grid'][0]} x {r['grid'][1]} | {o['wall_s']:.2f} "
              f"({o['wall_range'][0]:.2f}-{o['wall_range'][1]:.2f}), {o['peak_rss_mb']:.0f} | "
              + (f"{g['wall_s']:.2f}, {g['peak_rss_mb']:.0f} |" if g else "- |"))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Generation time of simulated scenes: fr-alps under a minute, fr-small in seconds.

    .venv/bin/python benchmarks/bench_simulate.py [--scenes fr-small fr-alps] [--keep DIR]

Each scene is generated from scratch into a temporary directory (numba kernels are compiled
once, before the clock starts, with a tiny scene). Prints one row per scene: wall time, CPU
time, product size, pixels per second, and the target. A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numba

from napari_meris_ortho.simulate import generate_scene

TARGETS = {"fr-alps": 60.0, "fr-small": 10.0}
WARMUP = {"base": "fr-small", "lines": 16, "columns": 65,
          "exports": {"getasse30": False, "getasse30_beam": False, "srtm30": False,
                      "geotiff_utm": False, "reference": False}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["fr-small", "fr-alps"])
    parser.add_argument("--keep", type=Path, default=None,
                        help="write the scenes there instead of a temporary directory")
    args = parser.parse_args()
    root = args.keep or Path(tempfile.mkdtemp(prefix="bench-simulate-"))
    try:
        generate_scene(WARMUP, out_dir=root / "warmup")
        print(f"numba threads: {numba.get_num_threads()}")
        print(f"{'scene':<20}{'wall s':>9}{'cpu s':>9}{'pixels':>12}{'px/s':>12}{'target s':>10}")
        for name in args.scenes:
            out = root / name
            shutil.rmtree(out, ignore_errors=True)
            t0, c0 = time.perf_counter(), time.process_time()
            scene = generate_scene(name, out_dir=out)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            g = scene.geometry
            pixels = g.lines * g.columns
            target = TARGETS.get(name)
            verdict = "" if target is None else ("  ok" if wall < target else "  SLOW")
            print(f"{name:<20}{wall:9.1f}{cpu:9.1f}{pixels:12d}{pixels / wall:12.0f}"
                  f"{target if target else '-':>10}{verdict}")
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()

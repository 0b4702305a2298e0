"""Stress: SIGKILL a synthesis update at random moments, then open the store from a fresh process.

    python benchmarks/stress_kill.py [--trials 100] [--min 0.1] [--max 1.2] [--seed 26]
                                     [--cold-numba] [--dir DIR]

Setup: three small simulated FR products of the fr-small area (the test products of
``tests/test_cli_synthesize.py``); a maximum-NDVI synthesis S of the first (bands 7, 13, 256-px
tiles, tie-point heights). Each trial starts ``meris-ortho synthesize P2 P3 --input S --out S
--workers 0`` in a new session, SIGKILLs its process group after a random delay in
[--min, --max] s, then starts a fresh Python process that opens S with
``open_synthesis`` and reads every layer (and the decoded NDVI), and records that reader's
exit code (-6 = SIGABRT). A commit that landed is reset away (branch back to the first
commit) so every trial kills the same update. ``--cold-numba`` gives every killed update and
reader a numba cache directory of its own run (``NUMBA_CACHE_DIR``) that starts empty at the
first trial, so the kills fall in the middle of numba compiling and writing cache entries.
``--no-writer``: the baseline, the same readers with no update started or killed;
``--probe``: readers that open five sessions and exit (the exit race below, more often);
``--no-settle``: readers without the exit hook ``store.settle_at_exit``, to show what it
prevents.

A killed update leaves the store readable: every reader after a kill is expected to exit 0,
with a warm numba cache (kills 0.1-1.2 s in) or a cold one (``--cold-numba``, kills up to
25 s in). A reader may abort at its exit without any writer: ``--probe --no-writer
--no-settle --trials 400`` shows a few readers in a hundred exiting -6, ``--probe --no-writer
--trials 400`` none. A core dump of such a reader shows a tokio thread of Icechunk in
``pyo3_async_runtimes::set_result`` -> ``loop.call_soon_threadsafe`` -> ``sock.send``
re-taking the GIL after the main thread began finalizing -> ``PyThread_exit_thread`` ->
``abort`` (https://github.com/python/cpython/issues/87135); ``store.settle_at_exit`` waits
for such threads to leave Python.

Prints, per outcome, the count of trials: the update's fate ("killed", or "exit N" when it
ended before the kill) and the reader's exit code; any reader that did not exit 0 has its
stderr tail printed. Exit status 1 when some reader did not exit 0.
"""

from __future__ import annotations

import argparse
import collections
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: a fresh process: open the store and read every layer at full resolution (argv[2] "0": the
#: exit hook ``store.settle_at_exit`` left out: ``--no-settle``)
READER = """
import sys
from napari_meris_ortho.synthesis import store as st
from napari_meris_ortho.synthesis.reading import open_synthesis
if sys.argv[2] == "0":
    st._SETTLE_REGISTERED.append(True)
store = open_synthesis(sys.argv[1])
total = 0
for name in store.layers():
    total += int(store.read(name).astype("int64").sum() != 0)
if store.algorithm == "max-ndvi":
    store.ndvi()
print(len(store.history()), total)
"""
#: the exit probe: five read-only sessions of the store, one window read in each, and exit
#: (the moment a Rust thread of Icechunk may still run Python code)
PROBE = """
import sys
import zarr
from napari_meris_ortho.synthesis import store as st
if sys.argv[2] == "0":
    st._SETTLE_REGISTERED.append(True)
repo = st.open_repository(sys.argv[1])
for _ in range(5):
    session = repo.readonly_session(branch="main")
    zarr.open_array(session.store, path="band_07", mode="r")[0:300, 0:300]
"""
COMMON = ["--elevation", "tiepoints", "--tile", "256", "--workers", "0"]
GRID = ["--crs", "EPSG:4326", "--ul", "13.45", "46.70", "--lr", "14.26", "46.19",
        "--pixel-size", "0.0015"]


def products() -> list[str]:
    """The three cloudy variants of the fr-small piece (cached by the simulator)."""
    from napari_meris_ortho.simulate.scene import generate_scene

    no_exports = {"getasse30": False, "getasse30_beam": False, "srtm30": False,
                  "geotiff_utm": False, "reference": False}
    out = []
    for k in (1, 2, 3):
        cfg = {"base": "fr-small", "lines": 128, "columns": 193, "first_column": 1150,
               "exports": no_exports, "file_counter": k + 1,
               "clouds": {"fraction": 0.4, "scale_km": 12.0, "seed": 10 * k}}
        out.append(str(generate_scene(cfg).product_path))
    return out


def cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "napari_meris_ortho.cli", "-q", *args]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--min", type=float, default=0.1, help="earliest kill (s)")
    ap.add_argument("--max", type=float, default=1.2, help="latest kill (s)")
    ap.add_argument("--seed", type=int, default=26)
    ap.add_argument("--cold-numba", action="store_true",
                    help="a numba cache of this run's own, empty at the start")
    ap.add_argument("--no-writer", action="store_true",
                    help="baseline: no update is started or killed, only the readers run")
    ap.add_argument("--probe", action="store_true",
                    help="readers: the exit probe (PROBE) instead of reading every layer")
    ap.add_argument("--no-settle", action="store_true",
                    help="readers without the exit hook store.settle_at_exit")
    ap.add_argument("--dir", default=None, help="work directory (default: a temporary one)")
    args = ap.parse_args()

    work = Path(args.dir or tempfile.mkdtemp(prefix="meris-ortho-stress-"))
    work.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "PYTHONFAULTHANDLER": "1"}  # a crashing reader prints its threads
    if args.cold_numba:
        env["NUMBA_CACHE_DIR"] = str(work / "numba-cache")
    prods = products()
    store = work / "S"
    if not store.exists():
        subprocess.run(cli("synthesize", prods[0], "--out", str(store), "--bands", "7,13",
                           "--algorithm", "max-ndvi", *GRID, *COMMON), check=True, env=env)
    from napari_meris_ortho.synthesis.reading import open_synthesis

    base = open_synthesis(store).snapshot
    update = cli("synthesize", *prods[1:], "--input", str(store), "--out", str(store), *COMMON)
    rng = random.Random(args.seed)
    outcomes: collections.Counter[tuple[str, int]] = collections.Counter()
    failures = []
    t_start = time.monotonic()
    for trial in range(args.trials):
        delay = rng.uniform(args.min, args.max)
        writer = "none"
        if not args.no_writer:
            proc = subprocess.Popen(update, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL, start_new_session=True, env=env)
            try:
                proc.wait(timeout=delay)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=60)
            writer = (f"killed at {delay:.1f}s" if proc.returncode == -signal.SIGKILL
                      else f"exit {proc.returncode}")
        reader = subprocess.run([sys.executable, "-c", PROBE if args.probe else READER,
                                 str(store), "0" if args.no_settle else "1"], env=env,
                                capture_output=True, text=True, timeout=600)
        outcomes[(writer.split(" at")[0], reader.returncode)] += 1
        if reader.returncode != 0:
            failures.append((trial, writer, reader.returncode, reader.stderr[-1500:]))
            print(f"trial {trial}: writer {writer}, reader exit {reader.returncode}",
                  flush=True)
        repo = open_synthesis(store).repo
        if open_synthesis(store).snapshot != base:
            repo.reset_branch("main", base)
    elapsed = time.monotonic() - t_start
    print(f"{args.trials} trials in {elapsed:.0f} s (kills {args.min}-{args.max} s after start"
          f"{', cold numba cache' if args.cold_numba else ''}; work dir {work})")
    print("writer   reader-exit  trials")
    for (writer, code), n in sorted(outcomes.items()):
        print(f"{writer:8s} {code:11d}  {n}")
    for trial, writer, code, err in failures:
        print(f"--- trial {trial} ({writer}): reader exit {code}\n{err}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())

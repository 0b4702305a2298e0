"""Ctrl-C and SIGTERM at any moment of ``meris-ortho map`` on a medium scene: "interrupted",
exit code 130 (143 for SIGTERM), no traceback, no new output, the old output untouched and no
``.part`` file left. Offsets span the whole run (imports, numba cache loading, DEM sampling,
prediction/correction, writing), as fractions of a first uninterrupted run's duration."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from napari_meris_ortho.products.n1 import read_product
from ortho_samples import make_dem, make_product

pytestmark = pytest.mark.slow

#: signal offsets as fractions of an uninterrupted run
FRACTIONS = (0.0, 0.03, 0.08, 0.15, 0.25, 0.4, 0.55, 0.7, 0.85)
OLD = b"the output of an earlier run"


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("signals")
    prod = make_product(d / "medium.N1", height=640, width=1025, lon0=15.0)
    tp = read_product(prod).tie_points
    dem = make_dem(d / "dem.tif", tp["longitude"].min() - 0.3, tp["latitude"].min() - 0.3,
                   tp["longitude"].max() + 0.3, tp["latitude"].max() + 0.3)  # fmt: skip
    return prod, dem


def _start(scene, out_dir):
    prod, dem = scene
    out = out_dir / "out.tif"
    out.write_bytes(OLD)
    argv = [sys.executable, "-m", "napari_meris_ortho.cli", "map", str(prod), "-o", str(out),
            "--dem", str(dem), "--diagnostics", "--stats-json", str(out_dir / "stats.json"),
            "--sampling", "bilinear"]  # fmt: skip
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)


def _before_our_handlers(text: str) -> bool:
    """Nothing on stderr, or Python's KeyboardInterrupt traceback from module imports that
    never reached ``cli.console_main`` (the signal came before ``meris-ortho`` could install
    its handlers: interpreter start-up, the first 50-70 ms)."""
    if not text:
        return True
    lines = text.strip().splitlines()
    return (lines[0].startswith("Traceback") and lines[-1] == "KeyboardInterrupt"
            and ", in console_main" not in text and ", in main" not in text)


def _left(out_dir) -> list[str]:
    return sorted(p.name for p in out_dir.iterdir())


@pytest.mark.timeout(900)
def test_signals_at_many_offsets_leave_nothing(scene, tmp_path):
    # the offsets are fractions of a warm run: on a clean checkout the first run also compiles
    # (or loads) the numba caches and may take several times longer than the runs that follow,
    # which would push most offsets past their end
    durations = []
    for name in ("first", "second"):
        first = tmp_path / name
        first.mkdir()
        start = time.perf_counter()
        proc = _start(scene, first)
        _, err = proc.communicate(timeout=600)
        durations.append(time.perf_counter() - start)
        assert proc.returncode == 0, err.decode()[-2000:]
        assert _left(first) == ["out.tif", "out_diagnostics.tif", "stats.json"]
    duration = min(durations)

    interrupted = 0
    for n, fraction in enumerate(FRACTIONS):
        sig = signal.SIGTERM if n == len(FRACTIONS) - 1 else signal.SIGINT
        out_dir = tmp_path / f"run{n}"
        out_dir.mkdir()
        proc = _start(scene, out_dir)
        try:
            proc.wait(timeout=fraction * duration)
        except subprocess.TimeoutExpired:
            proc.send_signal(sig)
        _, err = proc.communicate(timeout=300)
        text = err.decode()
        complete = ["out.tif", "out_diagnostics.tif", "stats.json"]
        if proc.returncode == 0:  # the signal came after the end: all outputs complete
            assert _left(out_dir) == complete
            continue
        if proc.returncode == -sig and _left(out_dir) == complete:
            # after main() returned and restored the default handlers: the run had committed
            assert "wrote" in text, (fraction, text[-2000:])
            continue
        if proc.returncode == -sig and _before_our_handlers(text):
            # during the interpreter's start-up or the package's first imports: Python's own
            # default (silent, or its KeyboardInterrupt); nothing of ours has run yet
            assert _left(out_dir) == ["out.tif"]
            assert (out_dir / "out.tif").read_bytes() == OLD
            continue
        interrupted += 1
        word = "interrupted" if sig == signal.SIGINT else "terminated"
        assert proc.returncode == 128 + sig, (fraction, proc.returncode, text[-2000:])
        assert text.strip().endswith(f"meris-ortho: {word}"), (fraction, text[-2000:])
        assert "Traceback" not in text and "Error" not in text, (fraction, text[-2000:])
        assert _left(out_dir) == ["out.tif"], (fraction, _left(out_dir))
        assert (out_dir / "out.tif").read_bytes() == OLD
    assert interrupted >= len(FRACTIONS) - 3, durations  # the last offsets may fall after the end

"""A process that used a synthesis store ends cleanly, never dying of
SIGABRT: Icechunk resolves futures from its own Rust threads, which run Python code
(``loop.call_soon_threadsafe``) and may still do so when the main thread ends; the exit waits
for them (``store.settle_at_exit``) instead of letting CPython ``pthread_exit`` them during
finalization, which aborts the process (gdb: ``take_gil`` -> ``PyThread_exit_thread`` ->
``__pthread_unwind`` -> ``abort`` in a tokio thread inside ``pyo3_async_runtimes::set_result``)."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

#: a thread Python did not start (pthread_create through ctypes) runs Python code for 0.3 s
#: while the main thread ends after 0.05 s: the marker is written only if the exit waits
FOREIGN_THREAD = """
import ctypes, sys, time
from pathlib import Path
from napari_meris_ortho.synthesis import store as st

marker = Path(sys.argv[1])
if sys.argv[2] == "store":
    st.create_repository(marker.parent / "repo")  # Icechunk used: the exit hook is in place
CALLBACK = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.c_void_p)

def work(_):
    time.sleep(0.3)
    marker.write_text("left Python")
    return None

callback = CALLBACK(work)
thread = ctypes.c_ulong()
assert ctypes.CDLL(None).pthread_create(ctypes.byref(thread), None, callback, None) == 0
time.sleep(0.05)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="pthread_create via glibc")
def test_exit_waits_for_foreign_threads_in_python(tmp_path) -> None:
    marker = tmp_path / "marker"
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", FOREIGN_THREAD, str(marker), "store"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert marker.read_text() == "left Python"
    assert time.perf_counter() - t0 < 60.0
    # without a store (no Icechunk, no hook) the thread is cut off at finalization, which is
    # what aborts a process whose cut-off thread has Rust frames
    marker.unlink()
    done = subprocess.run([sys.executable, "-c", FOREIGN_THREAD, str(marker), "none"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and not marker.exists()


def test_settle_at_exit_returns_at_once_when_no_foreign_thread_runs_python() -> None:
    from napari_meris_ortho.synthesis import store as st

    t0 = time.perf_counter()
    st.settle_at_exit()
    assert time.perf_counter() - t0 < 0.05

"""Closing the viewer while the Orthorectify widget runs cancels the job; Python exits cleanly
(not aborted with exit code 134)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

pytestmark = pytest.mark.slow

SCRIPT = textwrap.dedent("""
    import sys
    import threading

    import napari
    from qtpy.QtCore import QTimer

    product, dem = sys.argv[1], sys.argv[2]
    viewer = napari.Viewer()
    _, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    widget.products.value = [product] * 40
    widget.add_dem(dem)
    widget.bands.value = "all"
    assert widget.start() is not None, widget.status.value
    seen = []

    def poll():
        done, total = widget.progress_state
        if done > 0 and not seen:
            seen.append((done, total))
            print(f"closing at {done}/{total}", flush=True)
            viewer.close()

    timer = QTimer()
    timer.timeout.connect(poll)
    timer.start(20)
    napari.run()
    assert seen and seen[0][0] < seen[0][1], seen
    print("viewer closed; running:", widget.running, flush=True)
    # an interactive session goes on after the window closed: let the job end
    from qtpy.QtWidgets import QApplication

    app = QApplication.instance()
    for _ in range(200_000):
        if not widget.running:
            break
        app.processEvents()
        threading.Event().wait(0.005)
    print("job ended; running:", widget.running, flush=True)
""")


def test_closing_the_viewer_mid_run_exits_cleanly(tiny_n1, tiny_dem, tmp_path):
    script = tmp_path / "close_mid_run.py"
    script.write_text(SCRIPT)
    env = dict(os.environ)  # DISPLAY of pytest-xvfb's Xvfb
    env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
    env["NAPARI_CONFIG"] = str(tmp_path / "napari" / "settings.yaml")  # not the user's settings
    proc = subprocess.run([sys.executable, str(script), str(tiny_n1), str(tiny_dem)],
                          capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr[-3000:]
    assert "closing at" in proc.stdout
    assert "job ended; running: False" in proc.stdout
    assert "wrapped C/C++ object" not in proc.stderr
    assert "Traceback" not in proc.stderr

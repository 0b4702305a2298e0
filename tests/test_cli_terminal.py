"""Terminal hygiene: header text and messages with control characters are printed escaped,
progress bars appear only on a terminal (no carriage-return fragments in a log), and absurd
record times print as such instead of raising OverflowError in ``info``."""

from __future__ import annotations

import datetime as dt
import os
import subprocess
import sys

import numpy as np
import pytest
from n1_mutants import patch_text
from n1_samples import sample_inputs

from napari_meris_ortho._terminal import printable
from napari_meris_ortho.cli import main
from napari_meris_ortho.products.n1 import read_product, write_product
from ortho_samples import make_product


@pytest.fixture(scope="module")
def product(tmp_path_factory):
    path = tmp_path_factory.mktemp("term") / "rr.N1"
    return write_product(path, **sample_inputs("MER_RR__1P", 40, 33))


def test_printable_escapes_control_characters():
    assert printable("plain text 123") == "plain text 123"
    assert printable("a\x1b[2Jb\rc\x07\x7f") == "a\\x1b[2Jb\\rc\\x07\\x7f"


def test_info_escapes_header_text(product, tmp_path, capsys):
    data = patch_text(product.read_bytes(), b'PROC_CENTER="MORTHO"', b'PROC_CENTER="\x1b[2J\r\x07"')
    path = tmp_path / "esc.N1"
    path.write_bytes(data)
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "Processing     \\x1b[2J\\r\\x07," in out
    assert not any(c in out for c in "\x1b\r\x07")


def test_error_messages_are_escaped(tmp_path, capsys):
    name = tmp_path / "evil\x1b]0;title\x07.N1"
    assert main(["info", str(name)]) == 2
    err = capsys.readouterr().err
    assert "evil\\x1b]0;title\\x07.N1" in err and "\x1b" not in err and "\x07" not in err


def test_info_with_absurd_line_times(product, tmp_path, capsys):
    data = bytearray(product.read_bytes())
    offset = read_product(product).dsd("Radiance MDS(1)").offset
    data[offset : offset + 4] = np.array([2**31 - 1], ">i4").tobytes()  # days of line 1
    path = tmp_path / "times.N1"
    path.write_bytes(bytes(data))
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "First line     (not a valid time)  (18554258713" in out


def test_no_progress_bar_fragments_on_a_pipe(tmp_path):
    prod = make_product(tmp_path / "p.N1", height=130, width=321, lon0=15.0, nadir_col=-800.0)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.run(
        [sys.executable, "-m", "napari_meris_ortho.cli", "map", str(prod), "-o",
         str(tmp_path / "out.tif"), "--bands", "1", "--elevation", "tiepoints"],
        capture_output=True, env=env, timeout=600,
    )  # fmt: skip
    err = proc.stderr.decode()
    assert proc.returncode == 0, err
    assert "\r" not in err and "\x1b" not in err
    assert "wrote " in err  # the log itself is there


def _in_a_terminal(args: list[str], cols: int = 100) -> str:
    """What ``meris-ortho ARGS`` writes to a pseudo-terminal ``cols`` wide (stdout and stderr)."""
    import fcntl
    import pty
    import struct
    import termios

    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 30, cols, 0, 0))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.Popen([sys.executable, "-m", "napari_meris_ortho.cli", *args],
                            stdin=slave, stdout=slave, stderr=slave, env=env)
    os.close(slave)
    chunks = []
    while True:
        try:
            data = os.read(master, 65536)
        except OSError:  # the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    os.close(master)
    assert proc.wait(timeout=600) == 0, b"".join(chunks).decode(errors="replace")
    return b"".join(chunks).decode(errors="replace")


def _screen(raw: str) -> list[str]:
    """The lines a terminal shows of ``raw`` (carriage returns overwrite, escapes dropped)."""
    import re

    lines: list[str] = []
    for line in re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", raw).replace("\r\n", "\n").split("\n"):
        shown: list[str] = []
        col = 0
        for part in re.split(r"(\r)", line):
            if part == "\r":
                col = 0
                continue
            shown[col:col + len(part)] = part
            col += len(part)
        lines.append("".join(shown).rstrip())
    return lines


def _bars(raw: str) -> str:
    """Every state a bar was drawn in (the text between carriage returns)."""
    return "\n".join(raw.replace("\r\n", "\n").replace("\r", "\n").split("\n"))


def test_map_in_a_terminal_has_a_bar_per_stage_then_the_report(tmp_path):
    """Bars name the stages (reading, locating, writing band k of n) and count rows and
    bands; each is cleared before the Appendix B report, whose lines start at column 0."""
    prod = make_product(tmp_path / "p.N1", height=130, width=321, lon0=15.0, nadir_col=-800.0)
    out = tmp_path / "out.tif"
    raw = _in_a_terminal(["map", str(prod), "-o", str(out), "--bands", "1,2,3",
                          "--elevation", "tiepoints"])
    bars = _bars(raw)
    assert "reading the product and DEMs" in bars
    assert "locating (prediction/correction)" in bars and " rows [" in bars
    assert "resampling, writing band 1 of 3" in bars and "3/3 bands" in bars
    assert "step" not in bars
    screen = _screen(raw)
    assert "SETTING PIXEL SIZE DEFAULT VALUES" in screen  # a line of its own, at column 0
    assert f"wrote {out} (" in "\n".join(screen)
    assert any(line.startswith(f"wrote {out} (") for line in screen)
    assert not any("%|" in line for line in screen)  # no bar left on screen


def test_synthesize_in_a_terminal_shows_the_run_from_the_start(tmp_path):
    """The synthesis bar shows from the start (reading the products, then the tasks with their
    total) and is cleared before the per-product report."""
    products = [str(make_product(tmp_path / f"p{k}.N1", height=130, width=321, lon0=15.0 + k,
                                 nadir_col=-800.0)) for k in range(2)]
    raw = _in_a_terminal(["synthesize", *products, "--out", str(tmp_path / "store"),
                          "--bands", "7,13", "--workers", "0", "--elevation", "tiepoints"])
    bars = _bars(raw)
    assert "reading 2 product(s)" in bars
    assert "products merged 0/2:   0%" in bars  # its total at once
    assert "tasks (tile parts + tile merges)" in bars  # what the bar counts, said
    screen = _screen(raw)
    reports = [line for line in screen if line.startswith("PRODUCT ")]
    assert len(reports) == 2  # the second, of the same name, is reported as already merged
    assert all(r.startswith(f"PRODUCT {p}") for r, p in zip(reports, products, strict=True))
    assert any(line.startswith("synthesis ") and "committed to" in line for line in screen)
    assert not any("%|" in line for line in screen)


def test_synthesize_on_workers_shows_its_bar_then_its_log(tmp_path):
    """On a LocalCluster of 2 workers the bar counts the products merged of n, and the log
    lines that follow start at column 0 with no bar text, escape or worker chatter in them."""
    products = [str(make_product(tmp_path / f"p{k}.N1", height=130, width=321, lon0=15.0 + k,
                                 nadir_col=-800.0,
                                 first_line_time=dt.datetime(2003, 9, 21 + k, 9, 23)))
                for k in range(2)]
    raw = _in_a_terminal(["synthesize", *products, "--out", str(tmp_path / "store"),
                          "--bands", "7,13", "--workers", "2", "--elevation", "tiepoints"])
    bars = _bars(raw)
    assert "products merged 0/2:   0%" in bars
    assert "products merged 2/2" in bars or "committing the synthesis" in bars
    screen = [line for line in _screen(raw) if line]
    reports = [line for line in screen if line.startswith("PRODUCT ")]
    assert len(reports) == 2
    committed = [line for line in screen if line.startswith("synthesis ")]
    assert len(committed) == 1 and "2 product(s) merged" in committed[0]
    first_log = screen.index(reports[0])
    assert all("%|" not in line and "tasks" not in line for line in screen[first_log:])
    assert not any(word in raw for word in ("distributed.", "Traceback", "UserWarning"))


def test_export_bar_counts_bands(tmp_path):
    """export's bar names the band being written and counts bands, not tiles."""
    prod = make_product(tmp_path / "p.N1", height=130, width=321, lon0=15.0, nadir_col=-800.0)
    store = tmp_path / "store"
    _in_a_terminal(["synthesize", str(prod), "--out", str(store), "--bands", "7,13",
                    "--workers", "0", "--elevation", "tiepoints", "--quiet"])
    raw = _in_a_terminal(["export", str(store), "-o", str(tmp_path / "b.tif")])
    bars = _bars(raw)
    assert "writing band 1 of 2" in bars and " bands [" in bars
    assert "tiles" not in bars

"""Terminal hygiene: header text and messages with control characters are printed escaped,
progress bars appear only on a terminal (no carriage-return fragments in a log), and absurd
record times print as such instead of raising OverflowError in ``info``."""

from __future__ import annotations

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

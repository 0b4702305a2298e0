"""_atomic.py: regular targets only, symlinks written through, stale ``.part`` files of killed
runs removed, and a run that fails leaves none of its outputs (replaced files restored)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from napari_meris_ortho._atomic import (
    abort_run,
    atomic_path,
    check_distinct,
    created_directory,
    output_run,
    remove_stale_parts,
)
from napari_meris_ortho.errors import OptionsError, OutputError


def write(path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


@pytest.mark.parametrize("kind", ["fifo", "directory", "device"])
def test_non_regular_targets_are_refused(tmp_path, kind):
    target = {"fifo": tmp_path / "fifo", "directory": tmp_path, "device": "/dev/null"}[kind]
    if kind == "fifo":
        os.mkfifo(target)
    word = {"fifo": "a FIFO", "directory": "a directory", "device": "a character device"}[kind]
    with pytest.raises(OutputError, match=f"exists and is {word}, not a regular file"):
        write(target, "x")
    assert os.path.exists(target) and not os.path.isfile(target)


def test_symlink_is_written_through(tmp_path):
    (tmp_path / "real").mkdir()
    real = tmp_path / "real" / "data.txt"
    real.write_text("old")
    link = tmp_path / "link.txt"
    link.symlink_to(real)
    write(link, "new")
    assert link.is_symlink() and real.read_text() == "new"
    (tmp_path / "fifo").unlink(missing_ok=True)
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "to_fifo").symlink_to(tmp_path / "fifo")
    with pytest.raises(OutputError, match="a FIFO"):
        write(tmp_path / "to_fifo", "x")


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_stale_parts_of_killed_runs_are_removed(tmp_path):
    out = tmp_path / "out.tif"
    dead = _dead_pid()
    stale = [tmp_path / f".out.tif.{dead}-k1llab.tif.part",
             tmp_path / f".out.tif.{dead}-5a5a5a5a.orig.part"]  # fmt: skip
    alive = tmp_path / f".out.tif.{os.getppid()}-xyz.part"  # a running process: kept
    other = tmp_path / f".other.tif.{dead}-abc.part"  # another target: kept
    for p in [*stale, alive, other]:
        p.write_text("partial")
    write(out, "done")
    assert out.read_text() == "done"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["out.tif", alive.name, other.name]
    )
    assert remove_stale_parts(tmp_path / "other.tif") == [other]


def test_failed_run_removes_new_outputs_and_restores_replaced(tmp_path):
    old = tmp_path / "old.txt"
    old.write_text("before")
    new = tmp_path / "new.txt"
    folder = tmp_path / "synthesis"
    # the output's name in the message, not the temporary file's
    with pytest.raises(OutputError, match=r"third.txt: cannot write \(disk full\); nothing was "
                       "written"), output_run():
        write(old, "replaced")
        write(new, "created")
        folder.mkdir()
        created_directory(folder)
        (folder / "tile").write_text("t")
        with atomic_path(tmp_path / "third.txt") as tmp:
            tmp.write_text("half")
            raise OSError(28, "disk full")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.txt"]
    assert old.read_text() == "before"


def test_successful_run_keeps_outputs_and_drops_copies(tmp_path):
    old = tmp_path / "old.txt"
    old.write_text("before")
    with output_run():
        write(old, "replaced")
        write(tmp_path / "new.txt", "created")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new.txt", "old.txt"]
    assert old.read_text() == "replaced"


def test_abort_run_undoes_everything_in_flight(tmp_path):
    old = tmp_path / "old.txt"
    old.write_text("before")
    with pytest.raises(KeyboardInterrupt), output_run():
        write(old, "replaced")
        with atomic_path(tmp_path / "b.txt") as tmp:
            tmp.write_text("half")
            abort_run()  # what the signal handler does before leaving
            assert sorted(p.name for p in tmp_path.iterdir()) == ["old.txt"]
            raise KeyboardInterrupt
    assert old.read_text() == "before"


def test_outputs_distinct_from_inputs_and_each_other(tmp_path):
    product = tmp_path / "p.N1"
    product.write_text("n1")
    (tmp_path / "hard.N1").hardlink_to(product)
    (tmp_path / "soft.N1").symlink_to(product)
    for out in (product, tmp_path / "hard.N1", tmp_path / "soft.N1", tmp_path / "." / "p.N1"):
        with pytest.raises(OptionsError, match="is the input product"):
            check_distinct({"-o": out}, {"input product": [product]})
    with pytest.raises(OptionsError, match="-o .*a.tif and --stats-json .*a.tif are the same"):
        check_distinct({"--stats-json": tmp_path / "a.tif", "-o": tmp_path / "a.tif"}, {})
    check_distinct({"-o": tmp_path / "a.tif", "--stats-json": None}, {"DEM": [product]})


def test_scratch_dir_is_removed_on_abort_and_when_stale(tmp_path):
    from napari_meris_ortho._atomic import scratch_dir

    out = tmp_path / "out.tif"
    with pytest.raises(KeyboardInterrupt), output_run(), scratch_dir(out, ".stage") as stage:
        (stage / "full.tif").write_text("staged")
        assert stage.name.startswith(f".out.tif.{os.getpid()}-")
        abort_run()
        assert list(tmp_path.iterdir()) == []
        raise KeyboardInterrupt
    stale = tmp_path / f".out.tif.{_dead_pid()}-abc.stage.part"  # left by a SIGKILL
    stale.mkdir()
    (stale / "ov2.tif").write_text("x")
    write(out, "done")
    assert [p.name for p in tmp_path.iterdir()] == ["out.tif"]


def test_a_directory_that_takes_no_file_names_the_output(tmp_path):
    """/proc passes the writable-directory check as root but takes no new file: the message
    names the output, not the temporary ``/proc/.out.tif.<pid>-<random>.tif.part``."""
    if not os.access("/proc", os.W_OK):
        pytest.skip("needs /proc to look writable (root)")
    with pytest.raises(OutputError, match=r"^/proc/out.tif: cannot write in /proc \("):
        with atomic_path("/proc/out.tif"):
            pass

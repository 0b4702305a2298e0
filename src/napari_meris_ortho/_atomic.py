"""Atomic output: write to a temporary file in the target directory, then rename.

Policy:

- an output target that exists must be a regular file: a directory, FIFO, device or socket is
  refused (``-o /dev/null`` never replaces the device);
- a symbolic link is followed: the regular file it names is replaced, the link stays;
- temporary files are hidden ``.NAME.PID-XXXX.part`` files next to the target; one whose process
  is gone (a killed run) is removed by the next write to the same target;
- inside :func:`output_run` (one CLI command), outputs renamed into place are remembered: if the
  run fails or is interrupted, :func:`abort_run` removes every new output of the run and puts
  back the files it replaced, so a run leaves all of its outputs or none.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import stat
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from .errors import MerisOrthoError, OptionsError, OutputError

_KINDS = {
    stat.S_IFDIR: "a directory",
    stat.S_IFIFO: "a FIFO",
    stat.S_IFCHR: "a character device",
    stat.S_IFBLK: "a block device",
    stat.S_IFSOCK: "a socket",
}


def _kind(mode: int) -> str:
    return _KINDS.get(stat.S_IFMT(mode), "not a regular file")


def check_input_file(path: str | os.PathLike[str], what: str,
                     error: type[MerisOrthoError] = OptionsError) -> Path:
    """An input file that exists and is a regular file (a FIFO would block its reader
    forever; symlinks followed); ``error`` (OptionsError, DemError...) naming ``what``
    otherwise."""
    p = Path(path)
    try:
        mode = p.stat().st_mode
    except FileNotFoundError:
        raise error(f"{p}: {what} not found") from None
    except OSError as exc:
        raise error(f"{p}: cannot read the {what} ({exc.strerror or exc})") from None
    if not stat.S_ISREG(mode):
        raise error(f"{p}: the {what} is {_kind(mode)}, not a regular file")
    return p


def resolve_target(path: str | os.PathLike[str]) -> Path:
    """The file an output ``path`` writes: symlinks followed; an existing target must be a
    regular file (OutputError otherwise)."""
    out = Path(path)
    real = Path(os.path.realpath(out)) if out.is_symlink() else out
    try:
        mode = real.stat().st_mode
    except FileNotFoundError:
        return real
    except OSError as exc:
        raise OutputError(f"{out}: cannot use as output ({exc.strerror or exc})") from None
    if not stat.S_ISREG(mode):
        raise OutputError(f"{out}: output exists and is {_kind(mode)}, not a regular file")
    return real


def check_writable_dir(path: str | os.PathLike[str]) -> Path:
    """Return the output path if its directory exists and is writable and an existing target is
    a regular file (or a link to one), else raise OutputError."""
    out = Path(path)
    target = resolve_target(out)
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"{out}: output directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{out}: output directory {parent} is not writable")
    try:  # a directory that says writable and takes no file (/proc as root): told now, not
        with tempfile.TemporaryFile(dir=parent):  # after a run; unnamed (O_TMPFILE): a kill
            pass  # leaves nothing there
    except OSError as exc:
        raise OutputError(f"{out}: cannot write in {parent} ({exc.strerror or exc})") from None
    return out


def same_file(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """The same file or directory: one real path, or hard links of one file."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)  # hard links
    except OSError:
        return False


def is_inside(path: Path, directory: Path) -> bool:
    """True when ``path`` (resolved, existing or not) lies below the existing directory
    ``directory`` (resolved)."""
    if not directory.is_dir():
        return False
    inner, outer = os.path.realpath(path), os.path.realpath(directory)
    return inner != outer and inner.startswith(outer.rstrip(os.sep) + os.sep)


def check_distinct(
    outputs: dict[str, str | os.PathLike[str] | None],
    inputs: dict[str, Iterable[str | os.PathLike[str]]],
) -> None:
    """Refuse an output that resolves to an input file, lies inside an input directory (a
    ``.SEN3`` product, a DEM tile directory, a synthesis store), or is another output of the
    same run.

    ``outputs``: option name -> path (None: not requested); ``inputs``: what -> paths.
    """
    given = [(name, Path(p)) for name, p in outputs.items() if p is not None]
    for i, (name, out) in enumerate(given):
        for what, paths in inputs.items():
            for p in paths:
                if same_file(out, Path(p)):
                    raise OptionsError(f"{name} {out} is the {what} {p}: refusing to overwrite "
                                       "an input")
                if is_inside(out, Path(p)):
                    raise OptionsError(f"{name} {out} is inside the {what} {p}: refusing to "
                                       "write into an input")
        for other, out2 in given[:i]:
            if same_file(out, out2):
                raise OptionsError(f"{name} {out} and {other} {out2} are the same file")


# --------------------------------------------------------------------------------------------
# Runs: all outputs or none
# --------------------------------------------------------------------------------------------


@dataclass
class _Commit:
    target: Path
    tmp: Path
    backup: Path | None  #: hard link to the file the output replaced


@dataclass
class _Run:
    live: set[Path] = field(default_factory=set)  #: temporary files being written
    commits: list[_Commit] = field(default_factory=list)
    directories: list[Path] = field(default_factory=list)  #: created by the run


#: temporary files being written outside any run (removed on a signal too)
_LIVE: set[Path] = set()
_RUNS: list[_Run] = []


@contextlib.contextmanager
def output_run() -> Iterator[None]:
    """Group the outputs written inside: on an exception every new one is removed and the
    replaced files are restored; on success the kept copies of replaced files are dropped."""
    run = _Run()
    _RUNS.append(run)
    try:
        yield
    except BaseException:
        _rollback(run)
        raise
    else:
        for c in run.commits:
            if c.backup is not None:
                with contextlib.suppress(OSError):
                    c.backup.unlink()
    finally:
        _RUNS.remove(run)


def created_directory(path: str | os.PathLike[str]) -> None:
    """Note a directory the current run created: a failed run removes it with its content."""
    if _RUNS:
        _RUNS[-1].directories.append(Path(path))


def abort_run() -> None:
    """Undo every active run and remove every temporary file (called by the signal handler)."""
    for run in reversed(_RUNS):
        _rollback(run)
    for tmp in list(_LIVE):
        _remove(tmp)
    _LIVE.clear()


def _rollback(run: _Run) -> None:
    for c in reversed(run.commits):
        with contextlib.suppress(OSError):
            if c.tmp.exists():  # the rename did not happen
                c.tmp.unlink()
                if c.backup is not None:
                    c.backup.unlink()
            elif c.backup is not None:
                os.replace(c.backup, c.target)
            else:
                c.target.unlink()
    run.commits.clear()
    for tmp in list(run.live):
        _remove(tmp)
    run.live.clear()
    for d in reversed(run.directories):
        shutil.rmtree(d, ignore_errors=True)
    run.directories.clear()


_STALE = re.compile(r"\.(\d+)-[^/]*\.part")


def remove_stale_parts(target: Path) -> list[Path]:
    """Remove ``.NAME.PID-*.part`` files next to ``target`` left by a process that is gone."""
    removed = []
    prefix = f".{target.name}."
    with contextlib.suppress(OSError):
        for entry in os.scandir(target.parent if str(target.parent) else "."):
            if not entry.name.startswith(prefix):
                continue
            m = _STALE.fullmatch(entry.name[len(prefix) - 1 :])
            if m is None or _alive(int(m.group(1))):
                continue
            _remove(Path(entry.path))
            removed.append(Path(entry.path))
    return removed


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return pid > 0
    return True


#: errors of writing an output (disk full, quota, read-only, too large, permissions): said
#: with the output's name, not the temporary file's
_WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG, errno.EACCES,
                 errno.EPERM}


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` only on success.

    On any exception the temporary file is removed and ``path`` is left untouched. Inside an
    :func:`output_run` the rename is remembered so that a later failure of the run undoes it.
    """
    check_writable_dir(path)
    out = resolve_target(path)
    remove_stale_parts(out)
    run = _RUNS[-1] if _RUNS else None
    live = run.live if run is not None else _LIVE
    try:
        fd, tmp = tempfile.mkstemp(
            prefix=f".{out.name}.{os.getpid()}-", suffix=suffix + ".part", dir=out.parent
        )
    except OSError as exc:  # not the temporary name: the user named ``path``
        raise OutputError(f"{path}: cannot write in {out.parent} "
                          f"({exc.strerror or exc})") from None
    os.close(fd)
    tmp_path = Path(tmp)
    live.add(tmp_path)
    commit = None
    try:
        yield tmp_path
        if tmp_path.exists():  # mkstemp creates 0600: give the file the usual umask permissions
            os.chmod(tmp_path, 0o666 & ~_umask())
        resolve_target(out)  # still a regular file (or absent) just before the rename
        if run is not None:  # remembered before the rename: a signal may come right after it
            commit = _Commit(out, tmp_path, _keep_copy(out))
            run.commits.append(commit)
        os.replace(tmp_path, out)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp_path.unlink()
        if commit is not None and run is not None and commit in run.commits:
            run.commits.remove(commit)
            if commit.backup is not None:
                with contextlib.suppress(OSError):
                    commit.backup.unlink()
        if isinstance(exc, OSError) and exc.errno in _WRITE_ERRNOS:
            raise OutputError(f"{path}: cannot write ({exc.strerror or exc}); nothing was "
                              "written") from None
        raise
    finally:
        live.discard(tmp_path)


@contextlib.contextmanager
def scratch_dir(beside: str | os.PathLike[str], suffix: str = "") -> Iterator[Path]:
    """A hidden temporary directory ``.NAME.PID-XXXX{suffix}.part`` next to ``beside``, removed
    with its content on exit, on a signal (:func:`abort_run`) or, after a SIGKILL, by the next
    write there."""
    target = Path(beside)
    run = _RUNS[-1] if _RUNS else None
    live = run.live if run is not None else _LIVE
    path = Path(tempfile.mkdtemp(prefix=f".{target.name}.{os.getpid()}-",
                                 suffix=suffix + ".part", dir=target.parent))
    live.add(path)
    try:
        yield path
    finally:
        _remove(path)
        live.discard(path)


def _remove(path: Path) -> None:
    """Remove a temporary file or directory; nothing if it is gone."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(OSError):
            path.unlink()


def _keep_copy(target: Path) -> Path | None:
    """A hidden hard link to the file ``target`` is about to replace (None: no such file)."""
    if not target.exists():
        return None
    backup = target.with_name(f".{target.name}.{os.getpid()}-{os.urandom(4).hex()}.orig.part")
    try:
        os.link(target, backup)
    except OSError:  # no hard links here: the old file cannot be restored after the rename
        return None
    return backup


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _directory_target(path: str | os.PathLike[str]) -> Path:
    """An output directory ``path``: absent (its parent writable) or an existing directory
    (replaced: a rerun rewrites it); anything else there is an OutputError."""
    out = Path(path)
    try:
        mode = out.stat().st_mode
    except FileNotFoundError:
        return check_writable_dir(out)
    except OSError as exc:
        raise OutputError(f"{out}: cannot use as output ({exc.strerror or exc})") from None
    if not stat.S_ISDIR(mode):
        kind = "a regular file" if stat.S_ISREG(mode) else _kind(mode)
        raise OutputError(f"{out}: output exists and is {kind}, not a directory")
    parent = out.parent if str(out.parent) else Path(".")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{out}: output directory {parent} is not writable")
    return out


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary directory next to ``path``; on success it replaces ``path`` (an older
    directory of that name is removed only then). On any exception nothing is left behind."""
    out = _directory_target(path)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".part", dir=out.parent))
    try:
        yield tmp
        os.chmod(tmp, 0o777 & ~_umask())
        if out.is_dir() and not out.is_symlink():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
            os.replace(out, old / out.name)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise

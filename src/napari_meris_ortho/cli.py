"""``meris-ortho`` command line: thin wiring over the engine (subcommands in ``_commands/``).

Every user error (bad file, bad option, unwritable output) ends in one line on stderr and exit
code 2; a run where only some inputs failed exits with code 1. SIGINT (Ctrl-C) and SIGTERM at
any moment end in "meris-ortho: interrupted" and exit code 130 (143 for SIGTERM) with no output
of the run left: the handlers are installed before any heavy import (numba, GDAL), and they
never raise into the running code (a KeyboardInterrupt inside numba's cache loading ends in a
SystemError); they undo the run's outputs and leave at once.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import signal
import sys
from collections.abc import Iterator, Sequence
from importlib import import_module
from typing import NoReturn

from . import __version__
from ._atomic import abort_run, output_run
from ._process import few_collections, start_numba_without_blas, tune_process
from ._terminal import printable, stderr_is_terminal
from .errors import MerisOrthoError

#: subcommand modules; each defines ``register(subparsers)`` which sets ``func`` on its parser.
COMMANDS = ("info", "sample", "map", "synthesize", "synthesis-log", "synthesis-prune", "export",
            "disparity", "demcheck")
#: subcommands that run numba kernels in this process
NUMBA_COMMANDS = ("sample", "map", "synthesize", "disparity", "demcheck")

log = logging.getLogger("napari_meris_ortho")


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:  # argparse's own errors: one line, exit 2
        self.exit(2, f"meris-ortho: error: {message} (usage: {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="meris-ortho",
        description="Orthorectify, synthesize and analyse Envisat MERIS L1b and Sentinel-3 OLCI "
        "Level 1B products.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    _add_logging_options(parser, False)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMANDS:
        import_module(f"napari_meris_ortho._commands.{name.replace('-', '_')}").register(sub)
    for command in sub.choices.values():  # also after the command: "meris-ortho map ... -q"
        _add_logging_options(command, argparse.SUPPRESS)
    return parser


def _add_logging_options(parser: argparse.ArgumentParser, default: object) -> None:
    """``-v``/``--verbose`` and ``-q``/``--quiet``; a command's own take ``default``
    ``SUPPRESS``, so that left out there they keep what was given before the command."""
    parser.add_argument("-v", "--verbose", action="store_true", default=default,
                        help="debug logging")
    parser.add_argument("-q", "--quiet", action="store_true", default=default,
                        help="no progress bars; warnings only")


def _on_signal(signum: int, frame: object) -> None:
    """Undo the run's outputs, say so and leave: exit 128 + signal number (SIGINT: 130)."""
    with contextlib.suppress(Exception):  # whatever happens, the process ends here
        abort_run()
    word = "interrupted" if signum == signal.SIGINT else "terminated"
    with contextlib.suppress(Exception):
        start = "\n" if stderr_is_terminal() else ""  # after a progress bar
        os.write(2, f"{start}meris-ortho: {word}\n".encode())
    os._exit(128 + signum)


@contextlib.contextmanager
def _signals_handled() -> Iterator[None]:
    """SIGINT and SIGTERM handled by :func:`_on_signal` (main thread only; restored after)."""
    previous = {}
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, _on_signal)
    except ValueError:  # not the main thread: leave the signals alone
        pass
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def console_main() -> NoReturn:
    """The ``meris-ortho`` process (console script and ``python -m``): ``main`` in a process
    tuned for one run (``_process``; ``MERIS_ORTHO_NO_TUNING=1`` turns that off)."""
    tune_process()
    code = main(last=True)
    if code:
        # a failed run may leave reads in flight in Icechunk's runtime (zarr stops at the
        # first failed chunk); their Rust threads panic if the interpreter is torn down
        # under them: the error is said and the outputs are undone, so leave at once
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        os._exit(code)
    sys.exit(code)


def main(argv: Sequence[str] | None = None, *, last: bool = False) -> int:
    """Run one ``meris-ortho`` command line (``argv``: without the program name; None: the
    process's). ``last``: the process ends after this run (``console_main``)."""
    command = ""
    with _signals_handled(), few_collections(last):
        try:
            parser = build_parser()
            args = parser.parse_args(argv)
            command = str(args.command)
            quiet = logging.WARNING if args.quiet else logging.INFO
            level = logging.DEBUG if args.verbose else quiet
            logging.basicConfig(level=level, format="%(message)s", stream=sys.stderr)
            if last and args.command in NUMBA_COMMANDS:
                start_numba_without_blas()
            with output_run():
                return int(args.func(args) or 0)
        except MerisOrthoError as exc:
            return _error(exc)
        except BrokenPipeError:  # the reader of our output left (``| head``): as tools do
            with contextlib.suppress(OSError):
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 128 + signal.SIGPIPE
        except OSError as exc:  # file system problems not caught by a reader: still one line
            return _error(exc)
        except MemoryError:
            hint = MEMORY_HINTS.get(command, "")
            return _error("out of memory" + (f" ({hint})" if hint else ""))
        except KeyboardInterrupt:  # signals not delivered through the handler
            print("meris-ortho: interrupted", file=sys.stderr)
            return 130


#: what may help a command that ran out of memory
MEMORY_HINTS = {"map": "a smaller output grid or --bands may help",
                "synthesize": "a smaller --tile or fewer --workers may help",
                "disparity": "a smaller --explore window may help",
                "demcheck": "a larger --bin-width may help"}


def _error(exc: object) -> int:
    print(f"meris-ortho: error: {printable(str(exc))}", file=sys.stderr)
    return 2


if __name__ == "__main__":  # pragma: no cover
    console_main()

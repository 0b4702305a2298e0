"""``meris-ortho`` command line: thin wiring over the engine (subcommands in ``_commands/``).

Every user error (bad file, bad option, unwritable output) ends in one line on stderr and exit
code 2; a run where only some inputs failed exits with code 1.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from importlib import import_module
from typing import NoReturn

from . import __version__
from .errors import MerisOrthoError

#: subcommand modules; each defines ``register(subparsers)`` which sets ``func`` on its parser.
COMMANDS = ("info", "sample", "map", "synthesize", "synthesis-log", "export", "disparity",
            "demcheck")

log = logging.getLogger("napari_meris_ortho")


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:  # argparse's own errors: one line, exit 2
        self.print_usage(sys.stderr)
        self.exit(2, f"meris-ortho: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="meris-ortho",
        description="Orthorectify, synthesize and analyse Envisat MERIS L1b products.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    parser.add_argument(
        "-q", "--quiet", action="store_true", help="no progress bars; warnings only"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMANDS:
        import_module(f"napari_meris_ortho._commands.{name.replace('-', '_')}").register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.DEBUG if args.verbose else logging.WARNING if args.quiet else logging.INFO
    logging.basicConfig(level=level, format="%(message)s", stream=sys.stderr)
    try:
        return int(args.func(args) or 0)
    except MerisOrthoError as exc:
        print(f"meris-ortho: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # file system problems not caught by a reader: still one line
        print(f"meris-ortho: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("meris-ortho: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

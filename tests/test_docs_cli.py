"""The command-line reference (docs/cli.md) is generated from the argument parser, and complete.

The page holds one sphinx-argparse directive over ``napari_meris_ortho.cli.build_parser`` for
the program's own options and one per subcommand, so a new subcommand or option reaches it
without an edit of the page, and a subcommand left out of it fails here. The page says what
each option does only if the parser does: every option and argument has a help text. The
built page itself is checked by ``scripts/build_docs.sh``; these tests need no Sphinx.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from napari_meris_ortho.cli import build_parser

CLI_PAGE = Path(__file__).resolve().parents[1] / "docs" / "cli.md"


def _directives(text: str) -> list[dict[str, str]]:
    """The options of every ``{argparse}`` directive of a MyST page (a flag maps to "")."""
    bodies = re.findall(r"^```\{argparse\}[ \t]*\n(.*?)^```", text, re.M | re.S)
    return [dict(re.findall(r"^:([\w-]+):[ \t]*(.*?)[ \t]*$", body, re.M)) for body in bodies]


def _commands() -> dict[str, argparse.ArgumentParser]:
    """``meris-ortho`` and each of its subcommands, by the command line that runs it."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {"meris-ortho": parser, **{f"meris-ortho {name}": p for name, p in sub.choices.items()}}


def _has_text(text: object) -> bool:
    return isinstance(text, str) and bool(text.strip())


def test_cli_page_is_generated_from_the_parser_for_every_subcommand() -> None:
    directives = _directives(CLI_PAGE.read_text(encoding="utf-8"))
    assert directives, "docs/cli.md has no {argparse} directive"
    for d in directives:
        assert d.get("module") == "napari_meris_ortho.cli", d
        assert d.get("func") == "build_parser", d
        assert d.get("prog") == "meris-ortho", d
    # the program's own options once (its subcommands each in their own section) ...
    top = [d for d in directives if "path" not in d]
    assert len(top) == 1 and "nosubcommands" in top[0]
    # ... and every subcommand of the parser exactly once
    paths = [d["path"] for d in directives if "path" in d]
    subcommands = [name.removeprefix("meris-ortho ") for name in _commands()][1:]
    assert sorted(paths) == sorted(subcommands)


def test_every_option_and_subcommand_has_a_help_text() -> None:
    missing = []
    for command, parser in _commands().items():
        if command != "meris-ortho" and not _has_text(parser.description):
            missing.append(f"{command} (description)")
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                missing += [f"{command} {choice.dest} (help)" for choice
                            in action._choices_actions if not _has_text(choice.help)]
                continue
            if action.help == argparse.SUPPRESS:  # hidden on purpose: not in --help either
                continue
            if not _has_text(action.help):
                missing.append(f"{command} {'/'.join(action.option_strings) or action.dest}")
    assert not missing, f"without a help text: {missing}"

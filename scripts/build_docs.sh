#!/usr/bin/env bash
# Documentation site: install the docs extra into .venv, build the HTML (docs/_build/html) with
# every Sphinx warning an error (nitpicky: unresolved references too), check that the CLI page
# shows every option of the parser, and print the pages built.
# Usage: bash scripts/build_docs.sh [more sphinx-build options]
# The getting-started page is executed at each build (its scene is cached in docs/_build/cache).
set -euo pipefail
cd "$(dirname "$0")/.."
MERIS_ORTHO_NO_WARMUP=1 bash scripts/setup.sh
stamp=.venv/.docs-installed-$(sha1sum pyproject.toml | cut -c1-12)
if [[ ! -f $stamp ]]; then
    .venv/bin/python -m pip install -q -e ".[docs]"
    rm -f .venv/.docs-installed-*
    touch "$stamp"
fi
export PATH="$PWD/.venv/bin:$PATH"
unset QT_QPA_PLATFORM

start=$SECONDS
log=$(mktemp)
trap 'rm -f "$log"' EXIT
# -E and nb_execution_mode=force: every page read again and the executed pages run against the
# code as it is (an incremental build keeps the pages whose source did not change); the
# notebook kernel's notice that its local TCP sockets are not encrypted is left out
set +e
sphinx-build -W --keep-going -n -E -q -b html -D nb_execution_mode=force "$@" \
    docs docs/_build/html 2>&1 \
    | { grep --line-buffered -v "Kernel is running over TCP" || true; } | tee "$log"
status=${PIPESTATUS[0]}
set -e
warnings=$(grep -c -E "(WARNING|ERROR|CRITICAL):" "$log" || true)
echo "sphinx-build: ${warnings} warning(s), $((SECONDS - start)) s"
(( status == 0 )) || exit "$status"

# every option of every command is shown in that command's own part of the CLI page (the page
# is generated from the parser; sphinx-argparse names a command's sections "meris-ortho-map-...")
python - <<'PY'
import argparse
import html
import re
from pathlib import Path

from napari_meris_ortho.cli import build_parser

parser = build_parser()
subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
commands = {"meris-ortho": parser, **{f"meris-ortho {name}": sub
                                      for name, sub in subparsers.choices.items()}}
slugs = {command.replace(" ", "-"): command for command in commands}
shown: dict[str, set[str]] = {command: set() for command in commands}
page = Path("docs/_build/html/cli.html").read_text(encoding="utf-8")
for section in page.split('<section id="')[1:]:
    section_id = section.split('"', 1)[0]
    owners = [slug for slug in slugs if section_id.startswith(slug + "-")]
    if owners:
        shown[slugs[max(owners, key=len)]].update(
            html.unescape(option).strip()
            for kbd in re.findall(r"<kbd>(.*?)</kbd>", section, re.S)
            for option in kbd.split(","))
missing = [f"{command} {option}" for command, p in commands.items()
           for action in p._actions for option in action.option_strings
           if action.help != argparse.SUPPRESS  # hidden on purpose, as in --help
           and option not in ("-h", "--help") and option not in shown[command]]
if missing:
    raise SystemExit("docs/cli.md: options missing from the built page: " + ", ".join(missing))
print(f"CLI page: every option of meris-ortho and of its {len(subparsers.choices)} subcommands")
PY

echo "pages built (docs/_build/html):"
(cd docs/_build/html && find . -name "*.html" -not -path "./_*" -not -name genindex.html \
    -not -name search.html -not -name py-modindex.html | sed 's|^\./|  |' | sort)

"""The tree speaks of the code, to its users: no development history in its text files.

The README, the docs, the package, the tests, the benchmarks, the scripts and the napari-hub
page describe what the tool does and why. They never refer to this project's numbered
development rounds or issues, to the review of a round, to the machine's load at the time of a
measurement, to a commit hash as the source of a figure, or to files outside the repository (the
reference notes beside it). Another project's issue is cited by its URL. CHANGELOG.md is history
by design and is not scanned.

The scanner is tested on planted files too, so that a broken scanner cannot pass silently. This
file is scanned as well: the forbidden phrases below are built by concatenation, never written out.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

#: what is scanned, relative to the repository (a missing one is skipped)
SCANNED = ("README.md", "docs", "src", "tests", "benchmarks", "scripts", ".napari-hub")
#: suffixes of the text files scanned
TEXT_SUFFIXES = {".py", ".md", ".rst", ".txt", ".sh", ".toml", ".yaml", ".yml", ".json", ".cfg"}
#: directories never scanned: generated (Sphinx builds, caches), not written by hand
SKIPPED_DIRS = {"__pycache__", "_build", "build", ".pytest_cache", ".mypy_cache", ".ruff_cache",
                ".ipynb_checkpoints", "node_modules"}

_HEX = r"(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}"  # a digit and a letter: no number

#: (rule, pattern): each pattern matches one kind of development history
RULES: tuple[tuple[str, re.Pattern[str]], ...] = (
    ("a numbered development round",
     re.compile(r"\b(?:stops?|rounds?|sitt[i]ngs?)\s+\d+\b", re.I)),
    ("an issue by number (cite another project's by URL)",
     re.compile(r"(?<![/\w])(?:issues?\s+#?\d+(?:\s*(?:,|and)\s*#?\d+)*\b|#\d{1,5}\b(?![0-9a-f]))",
                re.I)),
    ("an issue of another project by number (cite it by URL)",
     re.compile(r"(?<![/\w])gh-\d+\b", re.I)),
    ("the review of a round", re.compile(r"\bQA\s+of\b", re.I)),
    ("a work period of the project", re.compile(r"\bsitt[i]ngs?\b", re.I)),
    ("the machine's load at a measurement", re.compile(r"\bload\s+aver[a]ge\b", re.I)),
    ("a development round", re.compile(r"\bthis\s+stop\b", re.I)),
    ("where a finding was made", re.compile(r"\bfound\s+at\s+stop\b", re.I)),
    ("a commit hash as a source",
     re.compile(r"\b(?:commit|commits|at|since|revision|rev|in|of)\s+[`'\"(\[]*" + _HEX + r"\b"
                r"|\b" + _HEX + r"[`'\")\]]*\s+(?:commit|revision)\b", re.I)),
    ("a file outside the repository",
     re.compile(r"\.\./shared\b|\bshared/reference\b|\bNOTES\.md\b")),
)


def scanned_files(root: Path = REPO, parts: Iterable[str] = SCANNED) -> list[Path]:
    """The text files under ``parts`` of ``root`` (files or directories; missing: none)."""
    found: list[Path] = []
    for part in parts:
        top = root / part
        if top.is_file():
            found.append(top)
            continue
        if not top.is_dir():
            continue
        for path in sorted(top.rglob("*")):
            rel = path.relative_to(top).parts
            if any(p in SKIPPED_DIRS for p in rel[:-1]):
                continue
            if path.is_file() and path.suffix in TEXT_SUFFIXES:
                found.append(path)
    return found


def scan_text(text: str) -> list[tuple[int, str, str]]:
    """(line number, rule, matched text) of every piece of development history in ``text``."""
    hits = []
    for number, line in enumerate(text.splitlines(), 1):
        for rule, pattern in RULES:
            hits += [(number, rule, m.group(0)) for m in pattern.finditer(line)]
    return hits


def scan(files: Iterable[Path], root: Path = REPO) -> list[str]:
    """``file:line: matched text (rule)`` of every hit in ``files``, paths relative to ``root``."""
    report = []
    for path in files:
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:  # a binary file under a text suffix: nothing to read
            continue
        name = path.relative_to(root) if path.is_relative_to(root) else path
        report += [f"{name}:{number}: {found!r} ({rule})"
                   for number, rule, found in scan_text(text)]
    return report


# ------------------------------------------------------------------------------ the tree


def test_the_tree_carries_no_development_history():
    hits = scan(scanned_files())
    assert not hits, "development history in the tree:\n" + "\n".join(hits)


def test_the_changelog_is_not_scanned():
    assert REPO / "CHANGELOG.md" not in scanned_files()


def test_the_scan_covers_the_package_the_tests_and_this_file():
    files = scanned_files()
    assert Path(__file__).resolve() in files
    assert REPO / "src" / "napari_meris_ortho" / "cli.py" in files
    assert all(f.suffix in TEXT_SUFFIXES for f in files)


# ------------------------------------------------------------------------------ the scanner

#: every forbidden phrase, built by concatenation so that this file does not carry it
PLANTED = [
    "as decided at " + "st" + "op 12",
    "the second " + "rou" + "nd 3 of work",
    "(" + "iss" + "ue 24, item 2)",
    "the geoid (" + "iss" + "ues 11, 26)",
    "fixed in " + "#" + "42",
    "CPython " + "gh" + "-87135",
    "the " + "Q" + "A of the plugin",
    "in the fourth " + "sit" + "ting",
    "with a " + "load aver" + "age of 3.2",
    "measured " + "this st" + "op",
    "a crash " + "found at st" + "op 52",
    "figures " + "at 3b9" + "35f4",
    "since commit " + "0216e" + "edaf",
    "`a865b" + "ba` commit",
    "see " + "../sha" + "red/reference/notes.txt",
    "format facts in " + "NOT" + "ES.md",
]

#: sentences that say what the code does, with numbers, URLs and hex values that are no history
CLEAN = [
    "Orthorectify a MERIS L1b product onto a UTM grid (handbook section 3.2, eq. 6a).",
    "napari keeps removed Shapes layers alive (https://github.com/napari/napari/issues/2027).",
    "A 1024-pixel tile gathers in about 20 ms, so the bands go one block at a time.",
    "Background 0 is never a radiance; ties are rounded half up, round(x + 0.5).",
    "The overviews stop when the coarsest level fits one block of 512 pixels.",
    "CLOCK_STEP = 3906249810; INT32_FILL = -0x80000000; colour #ffcc00.",
    "sha256 = 9f86d081884c7d659a2feaa0c55ad015a3bf4f1b2b0b822cd15d6c15b0f00a08",
    "A 2241 x 2241 FR scene at 09:23 on 2003-09-21, tie points every 64 pixels.",
    "The session's first layer; the viewer's load is shown as a progress bar.",
]


@pytest.mark.parametrize("phrase", PLANTED)
def test_scanner_reports_each_forbidden_phrase_with_file_and_line(tmp_path, phrase):
    planted = tmp_path / "docs" / "page.md"
    planted.parent.mkdir()
    planted.write_text("# A page\n\nA clean first line.\n" + phrase + "\n")
    report = scan(scanned_files(tmp_path, ["docs"]), tmp_path)
    assert report and all(line.startswith("docs/page.md:4: ") for line in report), report


@pytest.mark.parametrize("sentence", CLEAN)
def test_scanner_passes_a_clean_sentence(sentence):
    assert scan_text(sentence) == []


def test_scanner_reads_every_text_suffix_and_skips_other_files(tmp_path):
    phrase = "iss" + "ue 7"
    for suffix in sorted(TEXT_SUFFIXES) + [".png", ".tif"]:
        (tmp_path / f"f{suffix}").write_text(phrase + "\n")
    (tmp_path / "__pycache__").mkdir()
    (tmp_path / "__pycache__" / "cached.py").write_text(phrase + "\n")
    report = scan(scanned_files(tmp_path, ["."]), tmp_path)
    assert len(report) == len(TEXT_SUFFIXES)
    assert not any(".png" in line or ".tif" in line or "__pycache__" in line for line in report)


def test_scanner_skips_a_missing_part_and_reads_a_single_file(tmp_path):
    (tmp_path / "README.md").write_text("Clean.\n" + "iss" + "ue 9\n")
    report = scan(scanned_files(tmp_path, ["README.md", ".napari-hub"]), tmp_path)
    assert report == ["README.md:2: " + repr("iss" + "ue 9")
                      + " (an issue by number (cite another project's by URL))"]

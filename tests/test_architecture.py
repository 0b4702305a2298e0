"""Import directions between the rooms (docs/ARCHITECTURE.md), read from the source with ``ast``.

geometry, options, errors  <-  io, engine  <-  analysis, simulate  <-  ortho, synthesis
<-  _commands (CLI), _napari (napari). io and engine never import each other.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import napari_meris_ortho

PACKAGE = "napari_meris_ortho"
ROOT = Path(napari_meris_ortho.__file__).parent

#: rooms (first component under the package) each room may import, besides itself
BOTTOM = {"errors", "options", "flags", "geometry", "progress", "_atomic", "cores"}
ALLOWED = {
    "errors": set(),
    "flags": set(),
    "cores": set(),
    "options": {"errors"},
    "geometry": {"errors"},
    "io": BOTTOM,
    "engine": BOTTOM,
}


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module) of every import of the package in ``path``, at any depth
    (function-level imports included)."""
    module = _module_name(path)
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found.append((node.lineno, target))
            # ``from .engine import predcorr``: the names may be modules too
            found += [(node.lineno, f"{target}.{a.name}") for a in node.names]
    return [(line, name) for line, name in found
            if name == PACKAGE or name.startswith(PACKAGE + ".")]


def _room(module: str) -> str:
    """First component under the package; "" for the package root and its ``__version__``
    (``napari_meris_ortho/__init__.py`` imports nothing eagerly)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] != "__version__" else ""


def _files(room: str) -> list[Path]:
    target = ROOT / room
    return sorted(target.rglob("*.py")) if target.is_dir() else [target.with_suffix(".py")]


def test_the_rules_see_every_import():
    """The parser resolves relative imports (a broken resolver would make the rules vacuous)."""
    found = {name for _, name in _imports(ROOT / "ortho.py")}
    assert {"napari_meris_ortho.engine.predcorr", "napari_meris_ortho.geometry.grid",
            "napari_meris_ortho.io.product", "napari_meris_ortho.options"} <= found
    found = {name for _, name in _imports(ROOT / "_napari" / "widget_ortho.py")}
    assert "napari_meris_ortho.ortho" in found and "napari_meris_ortho.synthesis" in found


@pytest.mark.parametrize("room", sorted(ALLOWED))
def test_lower_rooms_import_only_what_lies_below(room):
    bad = []
    for path in _files(room):
        for line, name in _imports(path):
            target = _room(name)
            if target in ("", room) or target in ALLOWED[room]:
                continue
            bad.append(f"{path.relative_to(ROOT)}:{line} imports {name}")
    assert not bad, "\n".join(bad)


def test_io_and_engine_never_import_each_other_nor_the_glue():
    forbidden = {"io": {"engine"}, "engine": {"io"}}
    glue = {"ortho", "synthesis", "_napari", "_commands", "cli", "analysis", "simulate"}
    bad = []
    for room in ("io", "engine"):
        for path in _files(room):
            bad += [f"{path.relative_to(ROOT)}:{line} imports {name}"
                    for line, name in _imports(path) if _room(name) in forbidden[room] | glue]
    assert not bad, "\n".join(bad)


def test_nothing_below_the_front_ends_imports_them():
    bad = []
    for path in sorted(ROOT.rglob("*.py")):
        room = _room(_module_name(path))
        if room in ("_napari", "_commands", "cli"):
            continue
        bad += [f"{path.relative_to(ROOT)}:{line} imports {name}"
                for line, name in _imports(path) if _room(name) in ("_napari", "_commands", "cli")]
    assert not bad, "\n".join(bad)

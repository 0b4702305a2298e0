"""Rooms, floors and import directions (docs/ARCHITECTURE.md), read from the source with ``ast``.

Every room (a top-level module or package of ``napari_meris_ortho``) stands on a floor; a room
imports only rooms on lower floors, so the rooms of one floor (products, dem, output, engine) never
import each other. No module imports, at any depth (function-level imports included), a module that
imports it back (no circle), and no module imports the package it lies in (no back arrow to a
facade). No directory holds more than 15 % of the package's lines. The checkers are tested on a
planted package too, so that a broken checker cannot pass silently.
"""

from __future__ import annotations

import ast
from collections.abc import Iterable
from pathlib import Path

import napari_meris_ortho

PACKAGE = "napari_meris_ortho"
ROOT = Path(napari_meris_ortho.__file__).parent

#: floor of every room: a room imports only rooms on lower floors
FLOORS = {
    "errors": 0, "flags": 0, "cores": 0, "_terminal": 0, "_process": 0,
    "options": 1, "bands": 1, "geometry": 1, "progress": 1, "_atomic": 1, "display": 1,
    "products": 2, "dem": 2, "output": 2, "engine": 2,
    "analysis": 3, "simulate": 3, "pyramid": 3, "placement": 3,
    "ortho": 4,
    "synthesis": 5, "warmup": 5,
    "_commands": 6, "_napari": 6, "cli": 6,
}
#: largest share of the package's lines one directory (or top-level module) may hold
MAX_ROOM_SHARE = 0.15


def _module_name(path: Path, root: Path = ROOT) -> str:
    parts = path.relative_to(root.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, root: Path = ROOT) -> list[tuple[int, str]]:
    """(line, absolute name) of every import of the package in ``path``, at any depth
    (function-level imports included); ``from x import y`` gives ``x`` and ``x.y``."""
    package_name = root.name
    module = _module_name(path, root)
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
            subs = [f"{target}.{a.name}" for a in node.names]
            if not all(_is_module(s, root) for s in subs):
                found.append((node.lineno, target))  # names of the module ``target`` itself
            found += [(node.lineno, s) for s in subs]
    return [(line, name) for line, name in found
            if name == package_name or name.startswith(package_name + ".")]


def _is_module(dotted: str, root: Path) -> bool:
    """``dotted`` names a module or package of the package at ``root``."""
    rel = Path(*dotted.split(".")[1:])
    return (root / rel).with_suffix(".py").is_file() or (root / rel / "__init__.py").is_file()


def _room(module: str) -> str:
    """First component under the package; "" for the package root (``__version__``)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] != "__version__" else ""


def _modules(root: Path) -> dict[str, Path]:
    return {_module_name(p, root): p for p in sorted(root.rglob("*.py"))}


def _resolve(name: str, modules: dict[str, Path]) -> str | None:
    """The module a dotted import name lands in (``a.b.Name`` -> ``a.b``)."""
    while name:
        if name in modules:
            return name
        name = name.rpartition(".")[0]
    return None


def module_graph(root: Path) -> dict[str, set[str]]:
    """module -> the package modules it imports (package roots' lazy facades excluded)."""
    modules = _modules(root)
    graph: dict[str, set[str]] = {}
    for module, path in modules.items():
        targets = {_resolve(n, modules) for _, n in _imports(path, root)}
        graph[module] = {t for t in targets if t and t != module}
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected groups of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def upward_imports(root: Path, floors: dict[str, int]) -> list[str]:
    """Imports of a room on the same or a higher floor, and rooms with no floor."""
    bad = []
    for path in sorted(root.rglob("*.py")):
        room = _room(_module_name(path, root))
        if room == "":
            continue
        if room not in floors:
            bad.append(f"{path.relative_to(root)}: room {room!r} has no floor")
            continue
        for line, name in _imports(path, root):
            target = _room(name)
            if target in ("", room):
                continue
            if target not in floors or floors[target] >= floors[room]:
                bad.append(f"{path.relative_to(root)}:{line} ({room}, floor {floors[room]}) "
                           f"imports {name} (floor {floors.get(target)})")
    return bad


def back_arrows(root: Path) -> list[str]:
    """Imports of the package (``__init__``) a module lies in: a facade must stay on top."""
    bad = []
    for module, path in _modules(root).items():
        if path.name == "__init__.py":
            continue
        ancestors = {module.rsplit(".", k)[0] for k in range(1, module.count(".") + 1)}
        ancestors.discard(root.name)  # the package root: ``__version__`` only
        for line, name in _imports(path, root):
            if name in ancestors:
                bad.append(f"{path.relative_to(root)}:{line} imports its package {name}")
    return bad


def room_lines(root: Path) -> dict[str, int]:
    """Lines of each directory (its own files) and of each top-level module."""
    sizes: dict[str, int] = {}
    for path in root.rglob("*.py"):
        key = (str(path.parent.relative_to(root)) if path.parent != root
               else path.stem)
        sizes[key] = sizes.get(key, 0) + len(path.read_text().splitlines())
    return sizes


# --------------------------------------------------------------------------- the package


def test_the_rules_see_every_import():
    """The parser resolves relative imports (a broken resolver would make the rules vacuous)."""
    found = {name for _, name in _imports(ROOT / "ortho" / "core.py")}
    assert {"napari_meris_ortho.engine.predcorr", "napari_meris_ortho.geometry.grid",
            "napari_meris_ortho.products.protocol", "napari_meris_ortho.options"} <= found
    found = {name for _, name in _imports(ROOT / "_napari" / "widget_ortho.py")}
    assert "napari_meris_ortho.ortho" in found
    assert any(n.startswith("napari_meris_ortho.synthesis.") for n in found)
    graph = module_graph(ROOT)
    assert "napari_meris_ortho.dem.base" in graph["napari_meris_ortho.dem.copernicus"]


def test_every_room_has_a_floor_and_imports_only_below():
    assert not upward_imports(ROOT, FLOORS), "\n".join(upward_imports(ROOT, FLOORS))


def test_no_circle_between_modules():
    found = circles(module_graph(ROOT))
    assert not found, "\n".join(" <-> ".join(c) for c in found)


def test_no_module_imports_its_own_package():
    bad = back_arrows(ROOT)
    assert not bad, "\n".join(bad)


def test_no_room_holds_more_than_its_share():
    sizes = room_lines(ROOT)
    total = sum(sizes.values())
    big = {k: f"{v / total:.1%}" for k, v in sizes.items() if v > MAX_ROOM_SHARE * total}
    assert not big, big


def test_engine_knows_no_files_nor_guis():
    """Arrays in, arrays out: the engine imports no product, DEM, output or front-end room."""
    for path in (ROOT / "engine").rglob("*.py"):
        text = path.read_text()
        for forbidden in ("rasterio", "netCDF4", "napari", "qtpy", "magicgui", "zarr"):
            assert f"import {forbidden}" not in text, f"{path.name} imports {forbidden}"


# --------------------------------------------------------------------------- planted faults


def _plant(tmp_path: Path, files: dict[str, str]) -> Path:
    root = tmp_path / "plant"
    for name, text in files.items():
        p = root / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return root


PLANT_FLOORS = {"errors": 0, "engine": 1, "dem": 1, "ortho": 2}


def test_checkers_find_a_planted_circle(tmp_path: Path):
    root = _plant(tmp_path, {
        "__init__.py": "", "errors.py": "", "dem/__init__.py": "",
        "dem/base.py": "from ..errors import X\n",
        "dem/stack.py": "def f():\n    from .copernicus import C\n",
        "dem/copernicus.py": "from .stack import open_dem\n"})
    found = circles(module_graph(root))
    assert found == [["plant.dem.copernicus", "plant.dem.stack"]]
    assert not upward_imports(root, PLANT_FLOORS)


def test_checkers_find_a_planted_upward_import(tmp_path: Path):
    root = _plant(tmp_path, {
        "__init__.py": "", "errors.py": "", "ortho.py": "from .dem import base\n",
        "dem/__init__.py": "", "dem/base.py": "from ..engine.location import f\n",
        "engine/__init__.py": "", "engine/location.py": "def g():\n    from .. import ortho\n",
        "new_room.py": ""})
    bad = upward_imports(root, PLANT_FLOORS)
    assert any("dem/base.py:1" in b and "engine.location" in b for b in bad)  # same floor
    assert any("engine/location.py:2" in b and "plant.ortho" in b for b in bad)  # upward
    assert any("'new_room' has no floor" in b for b in bad)
    assert not any(b.startswith("ortho.py") for b in bad)


def test_checkers_find_a_planted_back_arrow(tmp_path: Path):
    root = _plant(tmp_path, {
        "__init__.py": "", "synthesis/__init__.py": "from .api import synthesize\n",
        "synthesis/api.py": "def synthesize():\n    pass\n",
        "synthesis/run.py": "from . import api\nfrom ..synthesis import synthesize\n",
        "synthesis/tiling.py": "import plant.synthesis\n"})
    bad = back_arrows(root)
    assert bad == ["synthesis/run.py:2 imports its package plant.synthesis",
                   "synthesis/tiling.py:1 imports its package plant.synthesis"]


def _lines(sizes: dict[str, int]) -> Iterable[str]:
    return (f"{k}: {v}" for k, v in sorted(sizes.items()))


def test_room_sizes_are_measured(tmp_path: Path):
    root = _plant(tmp_path, {"__init__.py": "", "a.py": "x = 1\n" * 3,
                             "big/__init__.py": "", "big/b.py": "y = 2\n" * 20})
    sizes = room_lines(root)
    assert sizes == {"__init__": 0, "a": 3, "big": 20}, list(_lines(sizes))

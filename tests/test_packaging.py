"""The package as pip installs it: the engine, the CLI and the synthesis stand without the viewer
(napari, Qt and magicgui are the ``napari`` extra), and the version has one definition."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from importlib import metadata
from pathlib import Path

import pytest

import napari_meris_ortho

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"
#: top-level modules of the viewer and its toolkits, none of which the core may import
GUI_MODULES = ("napari", "qtpy", "PyQt5", "PyQt6", "PySide2", "PySide6", "magicgui", "vispy",
               "superqt")

#: imports every module of the package outside ``_napari`` and builds the CLI's parser, then
#: prints the GUI modules this loaded
_CORE_IMPORTS = """
import json, pkgutil, sys
import napari_meris_ortho
from napari_meris_ortho.cli import build_parser

build_parser()
packages = [napari_meris_ortho]
while packages:  # pkgutil.walk_packages would import _napari to look inside it
    package = packages.pop()
    for info in pkgutil.iter_modules(package.__path__, package.__name__ + "."):
        if info.name != "napari_meris_ortho._napari":
            module = __import__(info.name, fromlist=["_"])
            if info.ispkg:
                packages.append(module)
gui = tuple(sys.argv[1:])
print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in gui)))
"""


def _env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))


def test_the_core_modules_and_the_parser_import_no_gui():
    """Every module but the plugin's (``_napari``) and the parser of every command load without
    napari, Qt or magicgui: a bare ``pip install napari-meris-ortho`` runs them."""
    done = subprocess.run([sys.executable, "-c", _CORE_IMPORTS, *GUI_MODULES],
                          capture_output=True, text=True, env=_env())
    assert done.returncode == 0, done.stderr[-2000:]
    assert json.loads(done.stdout.splitlines()[-1]) == []


#: runs ``meris-ortho ARGV`` as the console script does and, when the process ends, prints the
#: GUI modules it loaded (``sys.modules``: ``-X importtime`` misses modules that
#: ``importlib.import_module`` loads, as the CLI loads its commands)
_CLI_RUN = """
import atexit, json, runpy, sys
gui = tuple(sys.argv[1:sys.argv.index("--")])
atexit.register(lambda: print(json.dumps(sorted(
    m for m in sys.modules if m.split(".")[0] in gui))))
sys.argv = ["meris-ortho", *sys.argv[sys.argv.index("--") + 1:]]
runpy.run_module("napari_meris_ortho.cli", run_name="__main__", alter_sys=True)
"""


@pytest.mark.parametrize("argv", [["--help"], ["map", "--help"], ["--version"]])
def test_the_cli_imports_no_gui(argv):
    """``meris-ortho --help`` (the console script's own process, every command's parser built)
    imports none of the GUI."""
    done = subprocess.run([sys.executable, "-c", _CLI_RUN, *GUI_MODULES, "--", *argv],
                          capture_output=True, text=True, env=_env())
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith("usage: meris-ortho" if "--help" in argv else "meris-ortho ")
    assert json.loads(done.stdout.splitlines()[-1]) == []


def test_the_cli_runs_with_the_gui_unimportable(tmp_path):
    """With every GUI module made unimportable, as in a venv without the ``napari`` extra,
    ``meris-ortho --help`` and ``info`` still run."""
    blocker = tmp_path / "sitecustomize.py"
    blocker.write_text(f"import sys\nfor name in {GUI_MODULES!r}:\n    sys.modules[name] = None\n")
    env = dict(_env(), PYTHONPATH=os.pathsep.join([str(tmp_path), *sys.path]))
    done = subprocess.run([sys.executable, "-c", "import napari"], capture_output=True,
                          text=True, env=env)
    assert done.returncode != 0 and "ModuleNotFoundError" in done.stderr  # the blocker holds
    for argv in (["--help"], ["info", str(tmp_path / "missing.N1")]):
        done = subprocess.run([sys.executable, "-m", "napari_meris_ortho.cli", *argv],
                              capture_output=True, text=True, env=env)
        assert "Traceback" not in done.stderr, done.stderr[-2000:]
        assert done.returncode == (0 if argv == ["--help"] else 2), done.stderr


def test_version_prints_the_package_version():
    """``meris-ortho --version`` prints the one version: ``napari_meris_ortho.__version__``."""
    done = subprocess.run([sys.executable, "-m", "napari_meris_ortho.cli", "--version"],
                          capture_output=True, text=True, env=_env())
    assert done.returncode == 0, done.stderr
    assert done.stdout == f"meris-ortho {napari_meris_ortho.__version__}\n"
    assert done.stdout == "meris-ortho 0.1.0\n"


def test_the_distribution_takes_its_version_from_the_package():
    """The installed metadata's version is ``__version__``: pyproject.toml reads it from the
    package (``dynamic``), never repeats it."""
    assert metadata.version("napari-meris-ortho") == napari_meris_ortho.__version__
    if not PYPROJECT.is_file():
        pytest.skip("no pyproject.toml beside the tests")
    project = tomllib.loads(PYPROJECT.read_text())
    assert "version" not in project["project"] and "version" in project["project"]["dynamic"]
    dynamic = project["tool"]["setuptools"]["dynamic"]["version"]
    assert dynamic == {"attr": "napari_meris_ortho.__version__"}


def _names(requirements: list[str]) -> set[str]:
    """Distribution names of requirement strings, lowercased, without extras nor versions."""
    names = set()
    for req in requirements:
        name = req.split(";")[0]
        for stop in "[<>=!~ ":
            name = name.split(stop)[0]
        names.add(name.strip().lower())
    return names


def test_the_viewer_is_an_extra():
    """The core dependencies name no GUI package; the ``napari`` extra brings napari with a Qt
    binding (PyQt6, not the deprecated PyQt5), and ``test`` and ``all`` include it."""
    if not PYPROJECT.is_file():
        pytest.skip("no pyproject.toml beside the tests")
    project = tomllib.loads(PYPROJECT.read_text())["project"]
    gui = {"napari", "magicgui", "qtpy", "pyqt5", "pyqt6", "pyside2", "pyside6", "vispy"}
    assert not _names(project["dependencies"]) & gui
    extras = project["optional-dependencies"]
    assert {"napari", "magicgui"} <= _names(extras["napari"])
    assert any(req.startswith("napari[pyqt6]") for req in extras["napari"])
    assert not any("pyqt5" in req.lower() for reqs in extras.values() for req in reqs)
    for extra in ("all", "test"):
        assert any(req.startswith("napari-meris-ortho[") and "napari" in req.split("[")[1]
                   for req in extras[extra]), extra

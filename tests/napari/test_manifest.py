"""The npe2 manifest is valid and every command it names exists."""

from __future__ import annotations

import importlib
from pathlib import Path

import yaml
from npe2 import PluginManifest

import napari_meris_ortho

MANIFEST = Path(napari_meris_ortho.__file__).with_name("napari.yaml")


def test_manifest_validates_with_npe2_cli():
    from npe2.cli import app
    from typer.testing import CliRunner

    result = CliRunner().invoke(app, ["validate", str(MANIFEST)])
    assert result.exit_code == 0, result.output
    assert "valid" in result.output.lower()


def test_manifest_found_through_entry_point():
    manifest = PluginManifest.from_distribution("napari-meris-ortho")
    assert manifest.name == "napari-meris-ortho"
    assert {w.display_name for w in manifest.contributions.widgets} == {"Orthorectify", "Flicker"}
    assert {s.key for s in manifest.contributions.sample_data} == {"fr-alps", "fr-small"}
    patterns = manifest.contributions.readers[0].filename_patterns
    assert "*.N1" in patterns and "*.tif" in patterns


def test_every_command_exists_and_is_callable():
    commands = yaml.safe_load(MANIFEST.read_text())["contributions"]["commands"]
    assert len(commands) == 7
    for command in commands:
        module_name, attr = command["python_name"].split(":")
        target = getattr(importlib.import_module(module_name), attr)
        assert callable(target), command["python_name"]
    ids = {c["id"] for c in commands}
    contributions = yaml.safe_load(MANIFEST.read_text())["contributions"]
    used = [r["command"] for r in contributions["readers"]]
    used += [s["command"] for s in contributions["sample_data"]]
    used += [w["command"] for w in contributions["widgets"]]
    used += [w["command"] for w in contributions["writers"]]
    used += [k["command"] for k in contributions["keybindings"]]
    assert set(used) == ids

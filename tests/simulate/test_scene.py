"""Scene generation refusals (simulate.scene)."""

from __future__ import annotations

import pytest

from napari_meris_ortho.errors import OptionsError
from napari_meris_ortho.simulate.scene import generate_scene


def test_night_pass_is_refused(tmp_path):
    """The ascending node of Envisat's 10:00 orbit crosses 46 N at night: radiances would be
    daylight ones, so the simulator refuses the scene and writes nothing."""
    night = {"base": "fr-small", "lines": 65, "columns": 129,
             "orbit": {"direction": "ascending"}}
    with pytest.raises(OptionsError, match=r"night pass \(sun zenith up to 1[0-9][0-9]\.\d deg"):
        generate_scene(night, out_dir=tmp_path / "night")
    assert not list(tmp_path.rglob("*.N1"))

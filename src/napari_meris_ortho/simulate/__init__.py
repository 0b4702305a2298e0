"""Simulator of MERIS and OLCI L1b products with exact ground truth.

``generate_scene(name_or_config, out_dir=None, progress=None) -> SimulatedScene`` writes an N1
product (via ``products.n1.write_product``) or, for an OLCI scene, an OLCI Level 1B ``.SEN3``
(``olci_product``, via ``products.olci.write_olci``), DEM exports and a reference image, and
returns
the truth: ``true_antecedent(lon, lat, h)``, ``dem_height(lon, lat)``,
``truth_radiance(lon, lat, band)``, ``pixel_geometry(lines, cols)``.

Configs
-------
A scene is a small JSON dict; named scenes are package data,
``napari_meris_ortho/scenes/<name>.json`` (``$MERIS_ORTHO_SCENES`` is looked up first). Resolution:
``DEFAULTS`` <- the ``base`` scene (recursively) <- the given keys, merged recursively for dicts
and replaced otherwise. So overrides are written as::

    generate_scene({"base": "fr-small", "clouds": {"seed": 2, "fraction": 0.3}})

Keys: ``resolution`` (FR/RR; OLCI: EFR/ERR), ``date`` (ISO day), ``orbit`` (``direction``
descending/ascending, ``nadir_lat``/``nadir_lon`` of the geodetic nadir of line 0: moving it
across track gives an adjacent orbit), ``lines``, ``columns`` (64 k + 1 for FR and EFR,
16 k + 1 for RR and ERR), ``first_column``
(signed ground distance of column 0 from the nadir track in columns, positive to the right of
the flight direction; 0 = nadir on the first stored column, -2240 = nadir on the last),
``seed``, ``dem`` (``spacing_deg`` of the truth DEM posts, ``margin_deg``), ``terrain``
(``ranges`` [{from, to, width_km, height}], ``seas`` [{lon, lat, radius_km}], ``lakes``,
``plain_height``, ``snowline``), ``clouds`` (null or {seed, fraction, scale_km}: only the clouds
change with their seed), ``invalid_fraction``, ``glint_angle_deg``, ``exports`` (which DEM
formats and the reference bands). OLCI scenes add ``sensor`` ("OLCI"; MERIS when absent),
``platform`` (S3A/S3B: the Sentinel-3 orbit), ``processing_baseline`` (below "2.24": one
saturation flag per band; from "2.24": ``saturated``/``partially_saturated``, saturated samples
at the fill value) and ``saturated_fraction``; their ``first_column`` is -1196 (EFR) or -299
(ERR) for the whole tilted swath (``olci``).

Outputs go to ``out_dir`` or ``$MERIS_ORTHO_CACHE`` / ``~/.cache/napari-meris-ortho``, in
``<name>-<hash of the resolved config>``; they are deterministic and reused when complete.
"""

from __future__ import annotations

from .scene import (
    SimulatedScene,
    config_hash,
    default_out_dir,
    generate_scene,
    resolve_config,
    scene_geometry,
    scene_names,
)

__all__ = [
    "SimulatedScene",
    "config_hash",
    "default_out_dir",
    "generate_scene",
    "resolve_config",
    "scene_geometry",
    "scene_names",
]

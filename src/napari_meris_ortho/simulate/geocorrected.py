"""Per-pixel geolocated versions of a simulated scene: the AMORGOS-like
``MER_FRG_1P`` (FR) or ``MER_RRG_1P`` (RR) N1 product and the fourth-reprocessing-like
``ME_1_FRG___``/``ME_1_RRG___`` ``.SEN3`` directory.

Both carry the same radiances, flags and tie points as the scene's standard L1b product, plus
the truth geolocation of every pixel centre: the terrain point T where its line of sight first
meets the scene's DEM (``SimulatedScene.pixel_geometry``), i.e. what AMORGOS and the fourth
reprocessing store after removing the parallax.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..progress import ProgressCallback

#: product lines per block of the line-of-sight computation
_CHUNK = 64


def pixel_truth(scene, progress: ProgressCallback | None = None) -> dict[str, np.ndarray]:
    """Truth terrain point of every pixel centre: (H, W) ``longitude``, ``latitude`` (deg) and
    ``altitude`` (m above the ellipsoid)."""
    g = scene.geometry
    out = {k: np.empty((g.lines, g.columns)) for k in ("longitude", "latitude", "altitude")}
    cols = np.arange(g.columns, dtype=np.float64)
    for start in range(0, g.lines, _CHUNK):
        lines = np.arange(start, min(start + _CHUNK, g.lines), dtype=np.float64)
        t = scene.pixel_geometry(lines, cols)
        sl = slice(start, start + lines.size)
        out["longitude"][sl] = (t["t_lon"] + 180.0) % 360.0 - 180.0
        out["latitude"][sl] = t["t_lat"]
        out["altitude"][sl] = t["t_h"]
        if progress is not None:
            progress(start + lines.size, g.lines)
    return out


def write_geocorrected(scene, fsg: bool = True, sen3: bool = True,
                       out_dir: str | os.PathLike[str] | None = None,
                       progress: ProgressCallback | None = None) -> dict[str, Path]:
    """Write the FRG (FR) or RRG (RR) N1 (``"fsg"``) and/or the ``.SEN3`` directory (``"sen3"``)
    of ``scene`` into ``out_dir`` (default: the scene's directory); existing outputs of the same
    product are reused. Returns their paths by kind."""
    from ..products.n1 import read_product, write_product
    from ..products.n1.writer import default_product_name
    from ..products.sen3 import default_sen3_name, write_sen3

    target = Path(out_dir) if out_dir is not None else Path(scene.out_dir)
    target.mkdir(parents=True, exist_ok=True)
    prod = read_product(scene.product_path)
    g = scene.geometry
    start = np.datetime64(g.first_line_datetime.replace(tzinfo=None), "us")
    resolution = "FR" if prod.product_type == "MER_FR__1P" else "RR"
    paths: dict[str, Path] = {}
    amorgos = "MER_FRG_1P" if resolution == "FR" else "MER_RRG_1P"
    if fsg:
        paths["fsg"] = target / default_product_name(amorgos, start, g.lines * g.frame_time)
    if sen3:
        paths["sen3"] = target / default_sen3_name(resolution, start, g.lines * g.frame_time)
    todo = {k: p for k, p in paths.items() if not _newer(p, scene.product_path)}
    if not todo:
        return paths
    geo = pixel_truth(scene)
    counts = [np.ascontiguousarray(prod.counts(b), dtype=np.uint16) for b in range(1, 16)]
    flags = np.ascontiguousarray(prod.flags, dtype=np.uint8)
    det = np.ascontiguousarray(prod.detector_index, dtype=np.int16)
    if "fsg" in todo:
        write_product(todo["fsg"], product_type=amorgos, tie_points=prod.tie_points,
                      counts=counts, flags=flags, detector_index=det,
                      first_line_time=start, line_interval_s=g.frame_time,
                      scaling=prod.scaling, product_name=todo["fsg"].name,
                      pixel_geolocation=geo, progress=progress)
    if "sen3" in todo:
        write_sen3(todo["sen3"], resolution=resolution, tie_points=prod.tie_points,
                   counts=counts, flags=flags, detector_index=det, pixel_geolocation=geo,
                   first_line_time=start, line_interval_s=g.frame_time, scaling=prod.scaling,
                   progress=progress)
    return paths


def _newer(path: Path, than: Path) -> bool:
    """True when ``path`` exists and is not older than ``than`` (the scene's product)."""
    try:
        return path.exists() and path.stat().st_mtime >= Path(than).stat().st_mtime
    except OSError:
        return False

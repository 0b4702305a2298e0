"""Scene configs, generation and the cached SimulatedScene."""

from __future__ import annotations

import copy
import hashlib
import json
import logging
import math
import os
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit, prange

from .._atomic import atomic_path
from ..bands import Sensor
from ..errors import DemError, OptionsError, OutputError
from ..geometry.parallax import stored_corrections
from ..products.olci.layout import EFR, ERR
from ..progress import ProgressCallback
from . import olci, sensor
from .orbit import ENVISAT, SENTINEL3, Orbit, Platform, solve_pass
from .radiometry import (
    CLOUD_SPECTRUM,
    SPECTRA,
    GroundTruth,
    ecmwf_fields,
    make_ground_truth,
    product_radiometry,
    solar_angles,
    truth_radiance_kernel,
)
from .terrain import DemGrid, Terrain, auxiliary_dem, bathymetry, block_max, make_terrain

log = logging.getLogger(__name__)

#: bump when the generator changes its output for a given config (part of the cache key)
GENERATOR_VERSION = 4
RESOLUTIONS = {
    # frame time (s), column spacing (m), tie-point spacing DJ (MERIS: DF = DJ; OLCI: DF = 1),
    # product type
    "FR": (0.044, 260.0, 64, "MER_FR__1P"),
    "RR": (0.176, 1040.0, 16, "MER_RR__1P"),
    "EFR": (EFR.line_interval_s, EFR.column_spacing_m, EFR.samples_per_tie_point, "OL_1_EFR___"),
    "ERR": (ERR.line_interval_s, ERR.column_spacing_m, ERR.samples_per_tie_point, "OL_1_ERR___"),
}
#: the sensor of each resolution; OLCI has tie points on every row
SENSOR_OF_RESOLUTION = {"FR": Sensor.MERIS, "RR": Sensor.MERIS, "EFR": Sensor.OLCI,
                        "ERR": Sensor.OLCI}
PLATFORMS = {"Envisat": ENVISAT, "S3A": SENTINEL3, "S3B": SENTINEL3}
DEFAULTS: dict[str, Any] = {
    "resolution": "FR",
    "date": "2003-09-21",
    "orbit": {"direction": "descending", "nadir_lat": 45.909863, "nadir_lon": 18.014693},
    "lines": 2241,
    "columns": 2241,
    "first_column": 0,
    "seed": 1,
    "dem": {"spacing_deg": 0.0025, "margin_deg": 0.25},
    "terrain": {"ranges": [], "seas": [], "lakes": [], "plain_height": 120.0},
    "clouds": None,
    "invalid_fraction": 2e-5,
    "glint_angle_deg": 50.0,
    "exports": {"getasse30": True, "getasse30_beam": True, "srtm30": True, "geotiff_utm": True,
                "copernicus": False,
                "utm_spacing_m": 250.0, "reference": True, "reference_bands": [5, 7, 13]},
}


# ------------------------------------------------------------------------------------------
# configs
# ------------------------------------------------------------------------------------------


def scene_dirs() -> list[Path]:
    """Where named scene configs are looked up: $MERIS_ORTHO_SCENES, then the package data
    ``napari_meris_ortho/scenes`` (installed with the package, found by importlib.resources)."""
    dirs = []
    if os.environ.get("MERIS_ORTHO_SCENES"):
        dirs.append(Path(os.environ["MERIS_ORTHO_SCENES"]))
    dirs.append(Path(str(resources.files("napari_meris_ortho") / "scenes")))
    return dirs


def scene_names() -> list[str]:
    """Names of the scene configs that can be generated."""
    names: set[str] = set()
    for d in scene_dirs():
        if d.is_dir():
            names.update(p.stem for p in d.glob("*.json"))
    return sorted(names)


def _load_named(name: str) -> dict:
    for d in scene_dirs():
        path = d / f"{name}.json"
        if path.is_file():
            try:
                return json.loads(path.read_text())
            except json.JSONDecodeError as exc:
                raise OptionsError(f"scene config {path}: not valid JSON ({exc})") from None
    raise OptionsError(f"unknown scene {name!r}; known scenes: {', '.join(scene_names())}")


def _merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def resolve_config(name_or_config: str | dict, _depth: int = 0) -> dict:
    """Full config: DEFAULTS <- base scene(s) <- overrides; ``base`` names another scene."""
    if _depth > 8:
        raise OptionsError("scene config: 'base' chain too deep (a cycle?)")
    if isinstance(name_or_config, str):
        cfg = _load_named(name_or_config)
        cfg.setdefault("name", name_or_config)
    elif isinstance(name_or_config, dict):
        cfg = copy.deepcopy(name_or_config)
    else:
        raise OptionsError(f"scene must be a name or a dict, not {type(name_or_config).__name__}")
    base_name = cfg.pop("base", None)
    base = resolve_config(base_name, _depth + 1) if base_name else DEFAULTS
    if base_name and "name" not in cfg:
        cfg["name"] = base_name
    out = _merge(base, cfg)
    _validate(out)
    return out


#: the keys of a ``clouds`` config (None in ``DEFAULTS``: no clouds) and their types
CLOUDS_SCHEMA = {"seed": 0, "fraction": 0.3, "scale_km": 40.0}
#: keys a scene config names itself by, whatever its base
_FREE_KEYS = {"name", "description", "base"}


def check_overrides(base: str, overrides: dict) -> None:
    """Refuse, with one OptionsError naming the key, overrides of scene ``base`` (the CLI's
    ``sample --set``) that name a key the scene does not have, give a value of another type
    than the scene's (a number for a number, an object for an object...), or a fraction
    outside 0..1: each would otherwise end in a Python error deep in the simulator."""
    _check_keys(resolve_config(base), overrides, "")


def _check_keys(base: dict, over: dict, where: str) -> None:
    for key, value in over.items():
        path = f"{where}{key}"
        if not where and key in _FREE_KEYS:
            continue
        if key not in base:
            known = ", ".join(sorted(k for k in base if k not in _FREE_KEYS))
            raise OptionsError(f"--set: unknown scene key {path!r} (known here: {known})")
        have = base[key]
        if have is None and key == "clouds":
            have = CLOUDS_SCHEMA
            if value is None:
                continue
        if isinstance(have, dict):
            if not isinstance(value, dict):
                raise OptionsError(f"--set: {path} must be a JSON object, not {value!r}")
            _check_keys(have, value, f"{path}.")
        elif not _same_kind(have, value):
            raise OptionsError(f"--set: {path} must be {_kind_of(have)}, not {value!r}")
        elif key.endswith("fraction") and not 0.0 <= float(value) <= 1.0:
            raise OptionsError(f"--set: {path} is a fraction 0..1, not {value!r}")


def _same_kind(have: Any, value: Any) -> bool:
    if isinstance(have, bool) or isinstance(value, bool):
        return isinstance(have, bool) and isinstance(value, bool)
    if isinstance(have, int | float):
        return isinstance(value, int | float) and math.isfinite(value)
    return have is None or isinstance(value, type(have))


def _kind_of(have: Any) -> str:
    if isinstance(have, bool):
        return "true or false"
    if isinstance(have, int | float):
        return "a number"
    if isinstance(have, list):
        return "a JSON list"
    return "a string" if isinstance(have, str) else type(have).__name__


def sensor_of(cfg: dict) -> Sensor:
    """The sensor of a config: ``MERIS`` (without a ``sensor`` key) or ``OLCI``."""
    name = cfg.get("sensor", Sensor.MERIS)
    try:
        return Sensor(name)
    except ValueError:
        raise OptionsError(f"scene sensor must be MERIS or OLCI, not {name!r}") from None


def _validate(cfg: dict) -> None:
    if cfg["resolution"] not in RESOLUTIONS:
        raise OptionsError("scene resolution must be FR or RR (MERIS), EFR or ERR (OLCI), "
                           f"not {cfg['resolution']!r}")
    if SENSOR_OF_RESOLUTION[cfg["resolution"]] != sensor_of(cfg):
        raise OptionsError(f"scene resolution {cfg['resolution']} is not one of sensor "
                           f"{sensor_of(cfg)}")
    if sensor_of(cfg) is Sensor.OLCI and cfg.get("platform") not in ("S3A", "S3B"):
        raise OptionsError(f"an OLCI scene's platform is S3A or S3B, not {cfg.get('platform')!r}")
    step = RESOLUTIONS[cfg["resolution"]][2]
    cols = int(cfg["columns"])
    if cols < step + 1 or (cols - 1) % step:
        raise OptionsError(f"scene columns must be {step} k + 1 (tie point on the last column), "
                           f"not {cols}")
    if int(cfg["lines"]) < 2:
        raise OptionsError("scene lines must be at least 2")
    try:
        datetime.fromisoformat(str(cfg["date"]))
    except ValueError:
        raise OptionsError(f"scene date {cfg['date']!r} is not an ISO date") from None


def config_hash(cfg: dict) -> str:
    """Short hash of a resolved config (and the generator version): the cache key."""
    text = json.dumps({"v": GENERATOR_VERSION, "cfg": cfg}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def default_out_dir(cfg: dict) -> Path:
    """``$MERIS_ORTHO_CACHE`` or ``~/.cache/napari-meris-ortho``, then ``<name>-<hash>``."""
    root = os.environ.get("MERIS_ORTHO_CACHE") or Path.home() / ".cache" / "napari-meris-ortho"
    return Path(root) / f"{cfg.get('name', 'scene')}-{config_hash(cfg)}"


# ------------------------------------------------------------------------------------------
# geometry of a config
# ------------------------------------------------------------------------------------------


@dataclass
class SceneGeometry:
    """Orbit and product grid of a config (no terrain)."""

    orbit: Orbit
    t0: float
    frame_time: float
    spacing: float
    first_column: int
    lines: int
    columns: int
    tie_step: int
    product_type: str
    #: product lines between tie-point rows (0: ``tie_step``; OLCI: 1, every row)
    tie_line_step: int = 0
    platform: Platform = ENVISAT

    @property
    def orb(self) -> np.ndarray:
        return self.orbit.params()

    @property
    def grid(self) -> np.ndarray:
        return np.array([self.t0, self.frame_time, self.spacing, float(self.first_column)])

    @property
    def side(self) -> float:
        """+1 when the product lies right of the track (x > 0), else -1."""
        return 1.0 if self.first_column + 0.5 * (self.columns - 1) >= 0 else -1.0

    @property
    def lines_per_tie_point(self) -> int:
        return self.tie_line_step or self.tie_step

    @property
    def n_tie_lines(self) -> int:
        return math.ceil((self.lines - 1) / self.lines_per_tie_point) + 1

    @property
    def tie_lines(self) -> np.ndarray:
        return np.arange(self.n_tie_lines, dtype=np.float64) * self.lines_per_tie_point

    @property
    def tie_cols(self) -> np.ndarray:
        return np.arange(0, self.columns, self.tie_step, dtype=np.float64)

    def line_time(self, line: np.ndarray | float) -> np.ndarray:
        return self.t0 + np.asarray(line, dtype=np.float64) * self.frame_time

    @property
    def first_line_datetime(self) -> datetime:
        return datetime(2000, 1, 1, tzinfo=UTC) + timedelta(seconds=self.t0)


def scene_geometry(cfg: dict) -> SceneGeometry:
    """Solve the orbit pass of the config (the nadir of line 0 over ``orbit.nadir_lat/lon``)."""
    frame_time, spacing, step, ptype = RESOLUTIONS[cfg["resolution"]]
    ob = cfg["orbit"]
    day = datetime.fromisoformat(str(cfg["date"]))
    platform = PLATFORMS[str(cfg.get("platform", "Envisat"))]
    orbit, t0 = solve_pass(day, float(ob["nadir_lat"]), float(ob["nadir_lon"]),
                           ob.get("direction", "descending"), platform)
    return SceneGeometry(orbit=orbit, t0=t0, frame_time=frame_time, spacing=spacing,
                         first_column=int(cfg["first_column"]), lines=int(cfg["lines"]),
                         columns=int(cfg["columns"]), tie_step=step, product_type=ptype,
                         tie_line_step=1 if sensor_of(cfg) is Sensor.OLCI else 0,
                         platform=platform)


_EMPTY_DEM = (np.zeros((2, 2), np.float32), np.array([0.0, 90.0, 1, 1, 8, 100.0, 0, 0]),
              np.zeros((1, 1)), np.zeros((1, 1)))


def locate(geom: SceneGeometry, lines: np.ndarray, cols: np.ndarray,
           dem: tuple[np.ndarray, ...] | None = None) -> np.ndarray:
    """(len(lines), len(cols), 7): E lon, E lat, view zenith, view azimuth, T lon, lat, h."""
    lines = np.ascontiguousarray(lines, dtype=np.float64)
    cols = np.ascontiguousarray(cols, dtype=np.float64)
    out = np.empty((lines.size, cols.size, 7))
    d = dem if dem is not None else _EMPTY_DEM
    sensor.locate_pixels(geom.orb, geom.grid, lines, cols, d[0], d[1], d[2], d[3],
                         dem is not None, geom.side, out)
    return out


def footprint(geom: SceneGeometry, n: int = 33) -> tuple[float, float, float, float]:
    """(lon_min, lat_min, lon_max, lat_max) of the product's ellipsoid points; longitudes
    unwrapped around the first pixel (lon_max may exceed 180 across the antimeridian)."""
    lines = np.linspace(0, geom.lines - 1, n)
    cols = np.linspace(0, geom.columns - 1, n)
    e = locate(geom, lines, cols)
    lon, lat = e[..., 0], e[..., 1]
    ref = lon[0, 0]
    lon = ref + (lon - ref + 180.0) % 360.0 - 180.0
    return float(lon.min()), float(lat.min()), float(lon.max()), float(lat.max())


# ------------------------------------------------------------------------------------------
# the scene
# ------------------------------------------------------------------------------------------


@dataclass
class SimulatedScene:
    """A generated scene: its files and its exact ground truth."""

    config: dict
    out_dir: Path
    product_path: Path
    dem_paths: dict[str, Path]
    reference_path: Path | None
    geometry: SceneGeometry
    dem_grid: DemGrid
    dem: np.ndarray
    truth: GroundTruth
    _geo: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    _model: tuple = field(repr=False, default=())

    def __post_init__(self) -> None:
        self._model = terrain_model(self.dem, self.dem_grid)
        self._geo = self._model[1]

    @property
    def name(self) -> str:
        return str(self.config.get("name", "scene"))

    def true_antecedent(self, lon: Any, lat: Any, h: Any) -> tuple[np.ndarray, np.ndarray]:
        """Fractional product (line, column) whose line of sight passes through the 3-D point
        (lon, lat in deg, h in m above the ellipsoid); exact to better than 0.001 px."""
        lon_a, lat_a, h_a = np.broadcast_arrays(np.asarray(lon, np.float64),
                                                np.asarray(lat, np.float64),
                                                np.asarray(h, np.float64))
        shape = lon_a.shape
        lo = np.ascontiguousarray(lon_a.ravel())
        la = np.ascontiguousarray(lat_a.ravel())
        hh = np.ascontiguousarray(h_a.ravel())
        line = np.empty(lo.size)
        col = np.empty(lo.size)
        g = self.geometry
        t_mid = g.t0 + 0.5 * (g.lines - 1) * g.frame_time
        sensor.true_antecedents(g.orb, g.grid, lo, la, hh, t_mid, line, col)
        return line.reshape(shape), col.reshape(shape)

    def seen_from_sensor(self, lon: np.ndarray, lat: np.ndarray, h: np.ndarray,
                         line: np.ndarray, col: np.ndarray, step: float = 5.0) -> np.ndarray:
        """Truth of visibility: True where no terrain of the truth DEM rises more than 1 m above
        the line of sight from the ground point (lon, lat, h) towards the satellite (view
        angles of the product's tie points at the point's true antecedent (line, col); height
        d / tan(vz) + d^2 / 2R at ground distance d, sampled every ``step`` m: a 20 m step
        misses crests grazed by 1-6 m between samples)."""
        from scipy.ndimage import map_coordinates

        from ..products.open import read_product

        prod = read_product(self.product_path)
        tp = prod.tie_points
        at = np.stack([np.asarray(line) / prod.lines_per_tie_point,
                       np.asarray(col) / prod.samples_per_tie_point])
        tz = np.tan(np.radians(map_coordinates(tp["view_zenith"], at, order=1, mode="nearest")))
        va = np.radians(map_coordinates(tp["view_azimuth"], at, order=1, mode="nearest"))
        hidden = np.zeros(np.shape(lon), bool)
        r = 6371000.0
        top = float(self.dem.max())
        live = np.arange(hidden.size)
        for d in np.arange(step, 12000.0, step):
            ray = h[live] + d / tz[live] + d * d / (2 * r)
            keep = ray < top
            live, ray = live[keep], ray[keep]
            if not live.size:
                break
            x = lon[live] + np.degrees(d * np.sin(va[live]) / (r * np.cos(np.radians(lat[live]))))
            y = lat[live] + np.degrees(d * np.cos(va[live]) / r)
            up = self.dem_height(x, y) > ray + 1.0
            hidden[live[up]] = True
            live = live[~up]
        return ~hidden

    def dem_height(self, lon: Any, lat: Any) -> np.ndarray:
        """Truth DEM height (m above the ellipsoid), bilinear between posts; NaN outside."""
        lon_a, lat_a = np.broadcast_arrays(np.asarray(lon, np.float64),
                                           np.asarray(lat, np.float64))
        out = _sample_dem(self.dem, self._geo, np.ascontiguousarray(lon_a.ravel()),
                          np.ascontiguousarray(lat_a.ravel()))
        return out.reshape(lon_a.shape)

    @property
    def sensor(self) -> Sensor:
        """``MERIS`` or ``OLCI``."""
        return sensor_of(self.config)

    def truth_radiance(self, lon: Any, lat: Any, band: int) -> np.ndarray:
        """Truth TOA radiance (mW m-2 sr-1 nm-1) of ``band`` (MERIS 1..15, OLCI 1..21) at
        ground points."""
        spectra, cloud_spectrum, _ = band_radiometry(self.config)
        n_bands = spectra.shape[1]
        if not 1 <= int(band) <= n_bands:
            raise OptionsError(f"band must be 1..{n_bands}, not {band}")
        lon_a, lat_a = np.broadcast_arrays(np.asarray(lon, np.float64),
                                           np.asarray(lat, np.float64))
        out = np.empty((1, lon_a.size))
        t = self.truth
        truth_radiance_kernel(np.ascontiguousarray(lon_a.ravel()),
                              np.ascontiguousarray(lat_a.ravel()),
                              np.array([int(band) - 1]), t.cover, t.brightness, t.cloud,
                              spectra, cloud_spectrum, self._geo, out)
        return out[0].reshape(lon_a.shape)

    def pixel_geometry(self, lines: Any, cols: Any) -> dict[str, np.ndarray]:
        """Direct model at product pixels (grid of ``lines`` x ``cols``): ellipsoid point E,
        view angles at E and terrain point T (first intersection of the line of sight)."""
        out = locate(self.geometry, np.atleast_1d(lines), np.atleast_1d(cols),
                     self._model)
        keys = ("e_lon", "e_lat", "view_zenith", "view_azimuth", "t_lon", "t_lat", "t_h")
        return {k: out[..., i] for i, k in enumerate(keys)}

    def reference_image(self, band: int) -> np.ndarray:
        """Truth radiance of ``band`` at the DEM posts (the reference image's grid)."""
        lons = self.dem_grid.post_lons
        lats = self.dem_grid.post_lats
        lon2, lat2 = np.meshgrid(lons, lats)
        return self.truth_radiance(lon2, lat2, band).astype(np.float32)


BLOCK = 16


def terrain_model(dem: np.ndarray, grid: DemGrid) -> tuple[np.ndarray, ...]:
    """(dem, geo vector, coarse and fine block maxima): the terrain of the numba kernels."""
    return (dem, grid.geo_vector(dem, BLOCK), block_max(dem, BLOCK),
            block_max(dem, BLOCK // sensor.FINE_DIV))


def _sample_dem(dem: np.ndarray, geo: np.ndarray, lon: np.ndarray,
                lat: np.ndarray) -> np.ndarray:
    out = np.empty(lon.size)
    _sample_dem_kernel(dem, geo, lon, lat, out)
    return out


@njit(cache=True, parallel=True)
def _sample_dem_kernel(dem: np.ndarray, geo: np.ndarray, lon: np.ndarray, lat: np.ndarray,
                       out: np.ndarray) -> None:
    """Bilinear DEM heights at many points (NaN outside the grid)."""
    for i in prange(lon.size):
        out[i] = sensor.dem_bilinear(dem, geo, lon[i], lat[i])


# ------------------------------------------------------------------------------------------
# generation
# ------------------------------------------------------------------------------------------


#: highest sun zenith (deg) of a simulated scene: MERIS measures reflected sunlight only
MAX_SUN_ZENITH = 90.0


def _refuse_night(cfg: dict, geom: SceneGeometry, t_mid: float,
                  bounds: tuple[float, float, float, float]) -> None:
    """OptionsError when the sun is below the horizon somewhere on the footprint: the radiance
    spectra are daylight ones, a night pass would get daylight radiances."""
    lon_min, lat_min, lon_max, lat_max = bounds
    lon = np.array([lon_min, lon_max, lon_min, lon_max, 0.5 * (lon_min + lon_max)])
    lat = np.array([lat_min, lat_min, lat_max, lat_max, 0.5 * (lat_min + lat_max)])
    sz, _ = solar_angles(np.full(lon.size, t_mid), (lon + 180.0) % 360.0 - 180.0, lat)
    if float(np.max(sz)) > MAX_SUN_ZENITH:
        raise OptionsError(
            f"scene {cfg.get('name', '')!r}: night pass (sun zenith up to {float(np.max(sz)):.1f} "
            f"deg on the footprint on {cfg['date']}, {cfg['orbit'].get('direction')} orbit): "
            "MERIS images the day side only; choose a descending daytime pass or another date")


def build_truth(cfg: dict, geom: SceneGeometry) -> tuple[DemGrid, Terrain, GroundTruth]:
    """The DEM grid over the footprint (plus margin), its terrain and radiometric truth."""
    lon_min, lat_min, lon_max, lat_max = footprint(geom)
    margin = float(cfg["dem"]["margin_deg"])
    lat_far = max(abs(lat_min), abs(lat_max)) + margin
    lon_margin = margin / max(math.cos(math.radians(min(lat_far, 89.0))), 0.05)
    grid = DemGrid.covering(lon_min - lon_margin, max(lat_min - margin, -89.9),
                            lon_max + lon_margin, min(lat_max + margin, 89.9),
                            float(cfg["dem"]["spacing_deg"]))
    seed = int(cfg["seed"])
    terrain = make_terrain(grid, cfg["terrain"], seed)
    t_mid = geom.t0 + 0.5 * (geom.lines - 1) * geom.frame_time
    lon_c = grid.lon0 + 0.5 * grid.ncols * grid.spacing
    lat_c = grid.lat0 - 0.5 * grid.nrows * grid.spacing
    _refuse_night(cfg, geom, t_mid, (lon_min, lat_min, lon_max, lat_max))
    sz, sa = solar_angles(np.array(t_mid), np.array(lon_c), np.array(lat_c))
    truth = make_ground_truth(terrain, seed, float(sz), float(sa), cfg.get("clouds"),
                              snowline=float(cfg["terrain"].get("snowline", 2900.0)))
    return grid, terrain, truth


def tie_point_values(geom: SceneGeometry, grid: DemGrid, dem: np.ndarray,
                     seabed: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The Tie points ADS in physical units (handbook section 2.2, eq. 2, Appendix E).

    ``seabed``: bathymetry on the DEM posts (``terrain.bathymetry``): a tie point over the
    open sea (the smoothed DEM 0 there, the sea under it) stores the seabed as a negative
    ``dem_alt``, as real products do; its corrections are 0 (``geometry.parallax``).
    """
    e = locate(geom, geom.tie_lines, geom.tie_cols)
    lon, lat, vz, va = e[..., 0], e[..., 1], e[..., 2], e[..., 3]
    alt, rough = auxiliary_dem(dem, grid.spacing)
    geo = grid.geo_vector(dem, BLOCK)
    flat_lon = np.ascontiguousarray(lon.ravel())
    flat_lat = np.ascontiguousarray(lat.ravel())
    dem_alt = _sample_dem(alt.astype(np.float32), geo, flat_lon, flat_lat).reshape(lon.shape)
    dem_rough = _sample_dem(rough.astype(np.float32), geo, flat_lon, flat_lat).reshape(lon.shape)
    # stored as integers (altitude and roughness factors 1.0, Appendix A): eq. 2 uses those
    dem_alt = np.round(np.nan_to_num(dem_alt))
    dem_rough = np.round(np.nan_to_num(dem_rough))
    if seabed is not None:
        floor = _sample_dem(np.ascontiguousarray(seabed, np.float32), geo, flat_lon, flat_lat)
        floor = np.round(np.nan_to_num(floor.reshape(lon.shape)))
        open_sea = (dem_alt == 0.0) & (floor < 0.0)
        dem_alt = np.where(open_sea, floor, dem_alt)
    times = geom.line_time(geom.tie_lines)[:, None] * np.ones_like(lon)
    sz, sa = solar_angles(times, lon, lat)
    # eq. 2 as operational products store it (Appendix E: lon_corr with the sign opposite to
    # the correction added), 0 over sea
    lat_corr, lon_corr = stored_corrections(dem_alt, vz, va, lat)
    tp = {"latitude": lat, "longitude": lon, "dem_alt": dem_alt, "dem_rough": dem_rough,
          "lat_corr": lat_corr, "lon_corr": lon_corr, "sun_zenith": sz, "sun_azimuth": sa,
          "view_zenith": vz, "view_azimuth": va}
    tp.update(ecmwf_fields(lon, lat))
    return tp


def detector_index(geom: SceneGeometry) -> np.ndarray:
    """Detector (camera pixel) index of each stored column (int16, one row)."""
    full_half = 2240 if geom.product_type == "MER_FR__1P" else 560
    n_det = 3700 if geom.product_type == "MER_FR__1P" else 925
    k = geom.first_column + np.arange(geom.columns) + full_half
    det = np.floor(k * n_det / (2 * full_half + 1)).astype(np.int64)
    return np.clip(det, 0, n_det - 1).astype(np.int16)


def _glint(vz: np.ndarray, va: np.ndarray, sz: np.ndarray, sa: np.ndarray,
           limit: float) -> np.ndarray:
    cos_g = (np.cos(np.radians(vz)) * np.cos(np.radians(sz))
             - np.sin(np.radians(vz)) * np.sin(np.radians(sz)) * np.cos(np.radians(va - sa)))
    return np.degrees(np.arccos(np.clip(cos_g, -1, 1))) < limit


def _chunk_sun(geom: SceneGeometry, lines: np.ndarray,
               out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sun angles of a chunk of lines: exact at its middle line every 16 columns, linear in
    between, the same for every line of the chunk (enough for the glint-risk flag)."""
    mid = lines.size // 2
    w = out.shape[1]
    idx = np.unique(np.append(np.arange(0, w, 16), w - 1))
    sz, sa = solar_angles(np.full(idx.size, float(geom.line_time(lines[mid]))),
                          out[mid, idx, 0], out[mid, idx, 1])
    cols = np.arange(w)
    sa_u = np.degrees(np.unwrap(np.radians(sa)))
    sz_row = np.interp(cols, idx, sz)
    sa_row = np.interp(cols, idx, sa_u) % 360.0
    return np.broadcast_to(sz_row, out.shape[:2]), np.broadcast_to(sa_row, out.shape[:2])


def band_radiometry(cfg: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Class spectra (4, bands), cloud spectrum and radiance scale factors of the config's
    sensor: MERIS 15 bands (Scaling Factor GADS of Appendix A), OLCI 21 bands."""
    if sensor_of(cfg) is Sensor.OLCI:
        return (olci.OLCI_SPECTRA, olci.OLCI_CLOUD_SPECTRUM,
                np.array(olci.SCALE_FACTORS, dtype=np.float64))
    from ..products.n1 import ScalingFactors

    return SPECTRA, CLOUD_SPECTRUM, np.array(ScalingFactors.appendix_a().radiance,
                                             dtype=np.float64)


def render_product(cfg: dict, geom: SceneGeometry, grid: DemGrid, dem: np.ndarray,
                   truth: GroundTruth, progress: ProgressCallback | None = None,
                   chunk: int = 64, terrain_points: np.ndarray | None = None,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Counts (bands, H, W) uint16 and flags (H, W) uint8: the truth at every pixel's T.

    ``terrain_points`` (3, H, W), when given, receives T's longitude, latitude and height."""
    spectra, cloud_spectrum, sf = band_radiometry(cfg)
    model = terrain_model(dem, grid)
    geo = model[1]
    h, w = geom.lines, geom.columns
    counts = np.empty((spectra.shape[1], h, w), np.uint16)
    flags = np.empty((h, w), np.uint8)
    cols = np.arange(w, dtype=np.float64)
    for start in range(0, h, chunk):
        lines = np.arange(start, min(start + chunk, h), dtype=np.float64)
        out = locate(geom, lines, cols, model)
        sz, sa = _chunk_sun(geom, lines, out)
        glint = _glint(out[..., 2], out[..., 3], sz, sa, float(cfg["glint_angle_deg"]))
        sl = slice(start, start + lines.size)
        product_radiometry(np.ascontiguousarray(out[..., 4]), np.ascontiguousarray(out[..., 5]),
                           glint, truth.cover, truth.brightness, truth.cloud, truth.post_flags,
                           spectra, cloud_spectrum, sf, geo, counts[:, sl], flags[sl])
        if terrain_points is not None:
            terrain_points[0, sl] = (out[..., 4] + 180.0) % 360.0 - 180.0
            terrain_points[1, sl] = out[..., 5]
            terrain_points[2, sl] = out[..., 6]
        if progress is not None:
            progress(start + lines.size, h)
    rng = np.random.default_rng(int(cfg["seed"]) + 31)
    n_bad = max(3, int(round(float(cfg["invalid_fraction"]) * h * w)))
    bad_l = rng.integers(0, h, n_bad)
    bad_c = rng.integers(0, w, n_bad)
    counts[:, bad_l, bad_c] = 0
    flags[bad_l, bad_c] = 128
    return counts, flags


# ------------------------------------------------------------------------------------------
# cache and public entry point
# ------------------------------------------------------------------------------------------

MANIFEST = "scene.json"
_TRUTH_ARRAYS = ("dem", "cover", "brightness", "cloud", "post_flags")


def _stage(progress: ProgressCallback | None, start: int, width: int,
           total: int = 100) -> ProgressCallback | None:
    if progress is None:
        return None

    def report(done: int, n: int) -> None:
        progress(start + int(width * done / max(n, 1)), total)

    return report


def _save_npy(path: Path, arr: np.ndarray) -> None:
    with atomic_path(path, suffix=".npy") as tmp:
        with open(tmp, "wb") as fh:
            np.save(fh, arr)


def _load_cached(out_dir: Path, cfg: dict) -> SimulatedScene | None:
    manifest = out_dir / MANIFEST
    if not manifest.is_file():
        return None
    try:
        info = json.loads(manifest.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if info.get("hash") != config_hash(cfg):
        return None
    files = [info["product"], *info["dem_paths"].values(), *info["truth"].values()]
    if info.get("reference"):
        files.append(info["reference"])
    if not all((out_dir / f).exists() for f in files):
        return None
    arrays = {k: np.load(out_dir / v, mmap_mode="r") for k, v in info["truth"].items()}
    return SimulatedScene(
        config=cfg, out_dir=out_dir, product_path=out_dir / info["product"],
        dem_paths={k: out_dir / v for k, v in info["dem_paths"].items()},
        reference_path=out_dir / info["reference"] if info.get("reference") else None,
        geometry=scene_geometry(cfg), dem_grid=DemGrid(**info["dem_grid"]),
        dem=arrays["dem"],
        truth=GroundTruth(cover=arrays["cover"], brightness=arrays["brightness"],
                          cloud=arrays["cloud"], post_flags=arrays["post_flags"]))


def generate_scene(name_or_config: str | dict, out_dir: str | os.PathLike[str] | None = None,
                   progress: ProgressCallback | None = None) -> SimulatedScene:
    """Generate (or load from the cache) a simulated MERIS or OLCI L1b scene with its truth.

    ``name_or_config``: a scene name (``napari_meris_ortho/scenes/<name>.json``) or a config dict,
    possibly ``{"base": "<name>", ...overrides}``. Outputs go to ``out_dir`` (default: the
    cache, see :func:`default_out_dir`); an existing complete output of the same config is
    reused, a missing or incomplete one regenerated.
    """
    cfg = resolve_config(name_or_config)
    target = Path(out_dir) if out_dir is not None else default_out_dir(cfg)
    cached = _load_cached(target, cfg)
    if cached is not None:
        if progress is not None:
            progress(100, 100)
        return cached
    try:
        target.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{target}: cannot create the output directory "
                          f"({exc.strerror or exc})") from None
    geom = scene_geometry(cfg)
    grid, terrain, truth = build_truth(cfg, geom)
    dem = terrain.height
    if progress is not None:
        progress(10, 100)
    if sensor_of(cfg) is Sensor.OLCI:
        from .olci_product import write_olci_scene

        points = np.empty((3, geom.lines, geom.columns))
        counts, flags = render_product(cfg, geom, grid, dem, truth, _stage(progress, 10, 55),
                                       terrain_points=points)
        product_path = write_olci_scene(target, cfg, geom, counts, flags, points,
                                        locate(geom, geom.tie_lines, geom.tie_cols),
                                        _stage(progress, 65, 10))
        del points
    else:
        counts, flags = render_product(cfg, geom, grid, dem, truth, _stage(progress, 10, 55))
        product_path = _write_product(target, cfg, geom, grid, dem, bathymetry(terrain), counts,
                                      flags, _stage(progress, 65, 10))
    del counts
    scene = SimulatedScene(config=cfg, out_dir=target, product_path=product_path,
                           dem_paths={}, reference_path=None, geometry=geom, dem_grid=grid,
                           dem=dem, truth=truth)
    scene.dem_paths, scene.reference_path = _write_exports(target, cfg, scene, terrain,
                                                           _stage(progress, 75, 25))
    truth_files = {}
    for key in _TRUTH_ARRAYS:
        arr = dem if key == "dem" else getattr(truth, key)
        _save_npy(target / f"truth_{key}.npy", np.ascontiguousarray(arr))
        truth_files[key] = f"truth_{key}.npy"
    info = {"hash": config_hash(cfg), "generator_version": GENERATOR_VERSION, "config": cfg,
            "product": product_path.name,
            "dem_paths": {k: str(v.relative_to(target)) for k, v in scene.dem_paths.items()},
            "reference": scene.reference_path.name if scene.reference_path else None,
            "truth": truth_files,
            "dem_grid": {"lon0": grid.lon0, "lat0": grid.lat0, "spacing": grid.spacing,
                         "nrows": grid.nrows, "ncols": grid.ncols}}
    with atomic_path(target / MANIFEST) as tmp:
        tmp.write_text(json.dumps(info, indent=1))
    if progress is not None:
        progress(100, 100)
    return scene


def _write_product(target: Path, cfg: dict, geom: SceneGeometry, grid: DemGrid,
                   dem: np.ndarray, seabed: np.ndarray, counts: np.ndarray, flags: np.ndarray,
                   progress: ProgressCallback | None) -> Path:
    from ..products.n1 import write_product
    from ..products.n1.writer import default_product_name

    tp = tie_point_values(geom, grid, dem, seabed)
    det = np.broadcast_to(detector_index(geom), flags.shape)
    start = np.datetime64(geom.first_line_datetime.replace(tzinfo=None), "us")
    name = default_product_name(geom.product_type, start, geom.lines * geom.frame_time,
                                counter=int(cfg.get("file_counter", 0)))
    for old in target.glob(f"{geom.product_type}*.N1"):  # an older config's product; the
        if old.name != name:  # per-pixel geolocated ones (MER_FRG_1P...) are rewritten after
            old.unlink()
    return write_product(target / name, product_type=geom.product_type, tie_points=tp,
                         counts=[counts[b] for b in range(15)], flags=flags,
                         detector_index=np.ascontiguousarray(det),
                         first_line_time=geom.first_line_datetime.replace(tzinfo=None),
                         line_interval_s=geom.frame_time, product_name=name, progress=progress)


def _write_exports(target: Path, cfg: dict, scene: SimulatedScene, terrain: Terrain,
                   progress: ProgressCallback | None) -> tuple[dict[str, Path], Path | None]:
    from . import exports

    ex = cfg["exports"]
    grid = scene.dem_grid
    sample = scene.dem_height
    sea_geo = grid.geo_vector(scene.dem, BLOCK)
    sea_mask = terrain.sea.astype(np.float32)

    def sea(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        v = _sample_dem(sea_mask, sea_geo, np.ascontiguousarray(lon, np.float64),
                        np.ascontiguousarray(lat, np.float64))
        return v > 0.5

    paths: dict[str, Path] = {}
    steps = [("geotiff", True), ("getasse30", ex.get("getasse30")),
             ("getasse30_beam", ex.get("getasse30_beam")), ("srtm30", ex.get("srtm30")),
             ("geotiff_utm", ex.get("geotiff_utm")), ("copernicus", ex.get("copernicus")),
             ("reference", ex.get("reference"))]
    keys = [k for k, on in steps if on]
    missing = _missing_geoid_grid()
    for key in ("srtm30", "copernicus"):
        if key in keys and missing:
            log.warning("%s DEM export skipped (heights above the geoid): %s", key, missing)
            keys.remove(key)
    reference = None
    for i, key in enumerate(keys):
        if key == "geotiff":
            paths[key] = exports.write_geographic_geotiff(
                target / "dem_truth.tif", grid, scene.dem, descriptions=["height above WGS84"],
                tags=exports.ELLIPSOIDAL)
        elif key == "getasse30":
            paths[key] = exports.write_getasse30(target / "getasse30", sample, grid, "handbook")
        elif key == "getasse30_beam":
            paths[key] = exports.write_getasse30(target / "getasse30_beam", sample, grid, "beam")
        elif key == "srtm30":
            tiles = exports.write_srtm30(target / "srtm30", sample, sea, grid)
            paths[key] = tiles[0] if len(tiles) == 1 else target / "srtm30"
        elif key == "copernicus":
            exports.write_copernicus(target / "copernicus",
                                     exports.geoid_heights(sample, "egm2008"), grid)
            paths[key] = target / "copernicus"
        elif key == "geotiff_utm":
            paths[key] = exports.write_utm_geotiff(target / "dem_utm.tif", sample, grid,
                                                   float(ex.get("utm_spacing_m", 250.0)))
        else:
            bands = [int(b) for b in ex.get("reference_bands", [5, 7, 13])]
            data = np.stack([scene.reference_image(b) for b in bands])
            reference = exports.write_geographic_geotiff(
                target / "reference.tif", grid, np.nan_to_num(data), nodata=0.0,
                descriptions=[f"band {b} radiance" for b in bands])
        if progress is not None:
            progress(i + 1, len(keys))
    return paths, reference


def _missing_geoid_grid() -> str | None:
    """Why the EGM96 grid the geoid-referenced exports need is missing, or None."""
    from ..dem.geoid import EGM96, geoid_grid_path

    try:
        geoid_grid_path(EGM96)
    except DemError as exc:
        return str(exc)
    return None

"""Any raster GDAL reads (GeoTIFF, VRT...) in any CRS: posts at pixel centres, lookups
reprojected with pyproj, nodata honoured, only the window under the requested points read; its
vertical datum from its CRS or ``VERTICAL_DATUM`` tag."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from ..errors import DemError
from ..geometry.grid import pixel_limit
from .base import DemSource, LatticeWindow, _plausible, cut_short, gdal_reason, open_raster
from .copernicus import NAME_RE
from .geoid import EGM96, EGM2008, ELLIPSOID, crs_datum, other_height_datum

log = logging.getLogger(__name__)

_WGS84 = pyproj.CRS.from_epsg(4326)


#: semi-major axes (m) of the Earth's ellipsoids and spheres (WGS84 a = 6 378 137 m, the
#: handbook's sphere R = 6 370 997 m, Clarke 1866 6 378 206.4 m ...); a CRS outside this range
#: is on another body (Mars: 3 396 190 m, the Moon: 1 737 400 m)
EARTH_SEMI_MAJOR_M = (6.3e6, 6.4e6)


def earth_crs(path: str | Path, wkt: str) -> tuple[pyproj.CRS, pyproj.Transformer]:
    """The CRS of the DEM ``path`` (its WKT) and the WGS84 lon/lat -> DEM (x, y) transformer;
    DemError for an engineering (local) CRS, a CRS of another celestial body, or any CRS PROJ
    cannot relate to WGS84: a DEM must be placed on the Earth."""
    try:
        crs = pyproj.CRS.from_user_input(wkt)
    except pyproj.exceptions.CRSError as exc:
        raise DemError(f"{path}: unreadable coordinate reference system ({exc})") from None
    name = crs.name or "unnamed"
    if crs.is_engineering:
        raise DemError(f"{path}: the DEM's CRS {name!r} is an engineering (local) CRS, not "
                       "tied to the Earth: give the DEM in a geographic or projected CRS")
    ellipsoid = crs.ellipsoid
    if ellipsoid is not None and not (
            EARTH_SEMI_MAJOR_M[0] <= ellipsoid.semi_major_metre <= EARTH_SEMI_MAJOR_M[1]):
        raise DemError(f"{path}: the DEM's CRS {name!r} is not on the Earth (ellipsoid "
                       f"{ellipsoid.name!r}, semi-major axis {ellipsoid.semi_major_metre:.0f} m)")
    try:
        return crs, pyproj.Transformer.from_crs(_WGS84, crs, always_xy=True)
    except pyproj.exceptions.ProjError as exc:
        raise DemError(f"{path}: no transformation from WGS84 to the DEM's CRS {name!r} "
                       f"({exc})") from None


# ---------------------------------------------------------------------- GDAL rasters
class RasterSource(DemSource):
    """Any raster GDAL opens (GeoTIFF...), any CRS; posts at pixel centres; nodata honoured."""

    def __init__(self, path: str | Path, band: int = 1) -> None:
        from rasterio.enums import MaskFlags

        self.name = str(path)
        self._band = band
        self._ds = open_raster(path, "DEM")
        ds = self._ds
        t = ds.transform
        if not (all(np.isfinite(tuple(t)[:6])) and abs(t.determinant) > 0):
            raise DemError(f"{path}: invalid georeferencing: pixel size {t.a:g} x {t.e:g} "
                           f"(transform {tuple(t)[:6]})")
        if ds.driver == "ESAT":  # GDAL's Envisat driver: an N1 product picked as a DEM
            raise DemError(f"{path}: an Envisat product (N1), not a DEM: choose it as a "
                           "product; a DEM is a raster of heights (GeoTIFF, SRTM...)")
        if ds.crs is None and ds.gcps[0]:
            raise DemError(f"{path}: the DEM is georeferenced by ground control points only "
                           "(no geotransform): warp it onto a grid first (gdalwarp)")
        if ds.crs is None:
            raise DemError(f"{path}: the DEM has no coordinate reference system")
        if not 1 <= band <= ds.count:
            raise DemError(f"{path}: no band {band}")
        if ds.count > 1 and band == 1:
            raise DemError(f"{path}: {ds.count} bands, not a DEM (a DEM has one band of "
                           "heights; radiance GeoTIFFs are not DEMs)")
        self.n_rows, self.n_cols = ds.height, ds.width
        try:
            self.crs, self._tr = earth_crs(path, ds.crs.to_wkt())
        except DemError:
            ds.close()
            raise
        self.datum = _raster_datum(ds, self.crs)
        self._inv = ~ds.transform
        self._nodata = ds.nodatavals[band - 1]
        #: a mask band (GDAL's internal mask, an alpha band) says which posts are no data,
        #: whatever their values (0 under the mask, as GDAL and QGIS write it)
        self._masked = bool({MaskFlags.per_dataset, MaskFlags.alpha}
                            & set(ds.mask_flag_enums[band - 1]))
        self._scale = float((ds.scales or (1.0,))[band - 1] or 1.0)
        self._offset = float((ds.offsets or (0.0,))[band - 1] or 0.0)
        self._geographic = self.crs.is_geographic
        #: lon/lat are the DEM's x/y (WGS84 geographic DEM): no transformation needed
        self._lonlat = self.crs.equals(_WGS84, ignore_axis_order=True)
        left, bottom, right, top = ds.bounds
        self._x_centre = 0.5 * (left + right)
        self._window: tuple[int, int, np.ndarray] | None = None
        self._prepared = False

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        from rasterio.warp import transform_bounds

        b = self._ds.bounds
        return tuple(transform_bounds(self._ds.crs, "EPSG:4326", *b, densify_pts=21))

    def _to_xy(self, lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """DEM CRS (x, y) of WGS84 (lon, lat), float64."""
        x, y = self._tr.transform(lon, lat, errcheck=False)
        return np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)

    def _to_lattice(self, lon, lat):
        x, y = self._to_xy(lon, lat)
        if self._geographic:
            x = x + 360.0 * np.round((self._x_centre - x) / 360.0)
        a = self._inv
        c = a.a * x + a.b * y + a.c - 0.5
        r = a.d * x + a.e * y + a.f - 0.5
        inside = (r >= -0.5) & (r < self.n_rows - 0.5) & (c >= -0.5) & (c < self.n_cols - 0.5)
        return r, c, inside

    def _read(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """Posts [r0, r1) x [c0, c1) as float heights (float32, float64 for rasters float32
        does not hold exactly; NaN = no data; implausible heights are screened at lookup),
        blocks decoded on all cores (``GDAL_NUM_THREADS``)."""
        import rasterio
        from rasterio.errors import RasterioError
        from rasterio.windows import Window

        raw = np.dtype(self._ds.dtypes[self._band - 1])
        scaled = self._scale != 1.0 or self._offset != 0.0
        direct = not scaled and raw.kind in "iuf" and np.can_cast(raw, np.float32, "safe")
        window = Window(c0, r0, c1 - c0, r1 - r0)
        try:
            with rasterio.Env(GDAL_NUM_THREADS="ALL_CPUS"):  # float32 straight from GDAL
                data = self._ds.read(self._band, window=window,
                                     out_dtype=np.float32 if direct else None)
                masked = (self._ds.read_masks(self._band, window=window) == 0
                          if self._masked else None)
        except (RasterioError, OSError) as exc:
            raise cut_short(self.name, "DEM", gdal_reason(exc)) from exc
        if direct:  # exact conversion: no data compares the same before and after it
            if self._nodata is not None and not np.isnan(self._nodata):
                np.putmask(data, data == self._nodata, np.float32(np.nan))
            if masked is not None:
                data[masked] = np.nan
            return data
        nodata = np.isnan(data) if data.dtype.kind == "f" else np.zeros(data.shape, bool)
        if self._nodata is not None:
            nodata |= data == self._nodata
        if masked is not None:
            nodata |= masked
        dtype = np.result_type(data.dtype, np.float32)
        if scaled:
            data = data * self._scale + self._offset
        data = data.astype(dtype, copy=False)
        data[nodata] = np.nan
        return data

    def _covers(self, r0: int, r1: int, c0: int, c1: int) -> bool:
        w = self._window
        return w is not None and (w[0] <= r0 and w[1] <= c0 and r1 <= w[0] + w[2].shape[0]
                                  and c1 <= w[1] + w[2].shape[1])

    def _fetch(self, rows, cols):
        r0, r1, c0, c1 = int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1
        if not self._covers(r0, r1, c0, c1):
            data = self._read(r0, r1, c0, c1)
            if self._prepared:  # a point beyond the prepared footprint: keep the footprint
                return data[rows - r0, cols - c0].astype(np.float64)
            self._window = (r0, c0, data)
        w = self._window
        assert w is not None
        return w[2][rows - w[0], cols - w[1]].astype(np.float64)

    def prepare(self, lon_min: float, lat_min: float, lon_max: float, lat_max: float) -> None:
        """Read the posts under the WGS84 bounds (plus the bicubic margin) once."""
        from rasterio.errors import RasterioError
        from rasterio.warp import transform_bounds

        if not (lon_max > lon_min and lat_max > lat_min and lon_max - lon_min < 360.0):
            return
        try:
            x0, y0, x1, y1 = transform_bounds("EPSG:4326", self._ds.crs, lon_min, lat_min,
                                              lon_max, lat_max, densify_pts=21)
        except (RasterioError, ValueError):  # outside the DEM CRS's area: read lazily
            return
        if self._geographic:
            shift = 360.0 * np.round((self._x_centre - 0.5 * (x0 + x1)) / 360.0)
            x0, x1 = x0 + shift, x1 + shift
        a = self._inv
        cs = [a.a * x + a.b * y + a.c for x in (x0, x1) for y in (y0, y1)]
        rs = [a.d * x + a.e * y + a.f for x in (x0, x1) for y in (y0, y1)]
        r0 = max(int(np.floor(min(rs))) - 3, 0)
        r1 = min(int(np.ceil(max(rs))) + 3, self.n_rows)
        c0 = max(int(np.floor(min(cs))) - 3, 0)
        c1 = min(int(np.ceil(max(cs))) + 3, self.n_cols)
        if r1 <= r0 or c1 <= c0 or not all(np.isfinite(cs + rs)):
            return
        if (r1 - r0) * (c1 - c0) > pixel_limit(16):  # beyond the memory: read lazily
            return
        self._window = (r0, c0, self._read(r0, r1, c0, c1))
        self._prepared = True

    def lattice_window(self) -> LatticeWindow | None:
        """The prepared float32 window (``prepare``) as plain data; None before ``prepare``
        or for a float64 raster."""
        w = self._window
        if not self._prepared or w is None or w[2].dtype != np.float32:
            return None
        a = self._inv
        return LatticeWindow(
            data=np.ascontiguousarray(w[2]),
            inv=np.array([a.a, a.b, a.c, a.d, a.e, a.f], dtype=np.float64),
            lattice=np.array([w[0], w[1], self.n_rows, self.n_cols], dtype=np.int64),
            wrap_centre=self._x_centre if self._geographic else float("nan"),
            transform=None if self._lonlat else self._to_xy, datum=self.datum)

    def _sample_chunk(self, lon: np.ndarray, lat: np.ndarray, method: str) -> np.ndarray:
        """Bilinear lookups inside the prepared window: four flat gathers (same numbers as the
        generic 2x2 kernel); anything else: the generic path."""
        if method != "bilinear" or not self._prepared:
            return super()._sample_chunk(lon, lat, method)
        out = np.full(lon.size, np.nan)
        idx = np.flatnonzero(np.isfinite(lon) & np.isfinite(lat))
        r, c, inside = self._to_lattice(lon[idx], lat[idx])
        idx, r, c = idx[inside], r[inside], c[inside]
        if idx.size == 0:
            return out
        rf, cf = np.floor(r), np.floor(c)
        ra = np.clip(rf.astype(np.int64), 0, self.n_rows - 1)
        rb = np.clip(rf.astype(np.int64) + 1, 0, self.n_rows - 1)
        ca = np.clip(cf.astype(np.int64), 0, self.n_cols - 1)
        cb = np.clip(cf.astype(np.int64) + 1, 0, self.n_cols - 1)
        if not self._covers(int(ra.min()), int(rb.max()) + 1, int(ca.min()), int(cb.max()) + 1):
            return super()._sample_chunk(lon, lat, method)
        w0, wc0, data = self._window  # type: ignore[misc]
        flat = data.reshape(-1)
        ra, rb = (ra - w0) * data.shape[1], (rb - w0) * data.shape[1]
        ca, cb = ca - wc0, cb - wc0
        fr, fc = r - rf, c - cf
        top = _plausible(flat[ra + ca]) * (1.0 - fc) + _plausible(flat[ra + cb]) * fc
        bottom = _plausible(flat[rb + ca]) * (1.0 - fc) + _plausible(flat[rb + cb]) * fc
        out[idx] = top * (1.0 - fr) + bottom * fr
        return out

    def close(self) -> None:
        self._ds.close()


_WARNED: set[str] = set()


def _raster_datum(ds: Any, crs: pyproj.CRS) -> str | None:
    """Vertical datum of a GDAL raster: its ``VERTICAL_DATUM`` tag, its vertical CRS (another
    gravity-related datum than EGM96/EGM2008 as EGM2008, with a warning), a Copernicus tile by
    its name or a Copernicus VRT (EGM2008); None when unknown."""
    tag = str(ds.tags().get("VERTICAL_DATUM", "")).lower()
    if tag in (EGM96, EGM2008, ELLIPSOID):
        return tag
    datum = crs_datum(crs)
    other = other_height_datum(crs)
    if other is not None and ds.name not in _WARNED:
        _WARNED.add(ds.name)
        log.warning("%s: heights in %s are taken as EGM2008 geoid heights (a national height "
                    "datum lies within a few metres of the geoid); write %s:egm96 or "
                    "%s:ellipsoid to say otherwise", ds.name, other, ds.name, ds.name)
    if datum is None and NAME_RE.match(Path(ds.name).name):
        return EGM2008
    if datum is None and str(ds.name).lower().endswith(".vrt"):
        try:
            if "Copernicus_DSM" in Path(ds.name).read_text(errors="replace"):
                return EGM2008
        except OSError:
            pass
    return datum

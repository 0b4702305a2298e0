"""``export_cog``: layers of a synthesis store as a Cloud-Optimized GeoTIFF.

The bands go through ``ortho.writing.write_map``, the writer of every mapped product: uint16
counts with the GDAL scale of the store's band (``store.band_scales``), or float32 radiances on
request, described as ``meris-ortho map`` describes its bands (wavelengths, units, nodata 0)
with the options and DEMs its runs recorded; an OLCI store's bands are named ``Oa01``..
(``band_name`` tags), and the tags say the sensor of each product (``product_sensors``) and,
for a MERIS store holding OLCI products, the Oa band feeding each band. The NDVI of a
maximum-NDVI synthesis is written as a value a user reads directly: its Appendix C uint16 codes with
the GDAL scale and offset that give NDVI in -1..1 (GDAL, QGIS, rasterio ``masked=True`` then
scaled), or float32 NDVI with nodata NaN. The count and product layers keep their integer type.
Every layer streams from the store one at a time.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import OptionsError
from ..geometry.grid import OutputGrid
from ..progress import ProgressCallback
from . import store as st
from .reading import SynthesisStore, run_tags, runs_described

#: compression of the exported COGs (DEFLATE: read by every GDAL build)
COMPRESS = "deflate"
#: what the uint16 band values are (dataset tag ``radiance``)
STORE_COUNTS_NOTE = ("TOA radiance = counts x scale (GDAL scale = the synthesis store's scale "
                     "of the band, its Appendix A radiance factor); counts 0 = background "
                     "(nodata)")
#: what the NDVI values of each type are (dataset tag ``ndvi``)
NDVI_NOTE = {
    "uint16": "NDVI = code x scale + offset (GDAL scale/offset; Appendix C 16-bit coding, "
              "codes 1..65535 <-> NDVI -1..+1); code 0 = background (nodata)",
    "float32": "NDVI in -1..+1 (float32); NaN = background (nodata)",
}
#: band descriptions of the other layers
LAYER_DESCRIPTIONS = {
    "ndvi": "NDVI (band 13 - band 7) / (band 13 + band 7) of the selected product",
    "ndvi-olci": "NDVI (865 nm - 665 nm) / (865 nm + 665 nm) of the selected product (MERIS "
                 "bands 13 and 7, OLCI Oa17 and Oa08)",
    "count": "number of products with a valid pixel (0 = background)",
    "product": "index (1-based) of the selected product in the products tag (0 = background)",
}


class _StoreBands:
    """The bands of a synthesis as ``write_map`` reads a mapped product, one band read from the
    store at a time: uint16 counts (``counts``) with ``scale_factors``, or float32
    radiances; ``run`` and ``dems``: what the store's commits recorded."""

    stats = None
    diagnostics: dict[str, np.ndarray] = {}

    def __init__(self, store: SynthesisStore, bands: list[int],
                 progress: ProgressCallback | None) -> None:
        from ..bands import Sensor, band_table

        self.store, self.bands, self.progress = store, bands, progress
        session = store.session
        #: the scale of each band's counts: the compact store's ``scale_factor`` (None: a
        #: float32 store, whose radiances are encoded with ``BAND_SCALES``)
        self.stored = {b: st.stored_scale(st.open_layer(session.store, st.band_layer(b)))
                       for b in bands}
        scales = st.band_scales(store.sensor)
        self.scale_factors = {b: self.stored[b] or scales[b] for b in bands}
        #: the bands' names and nominal facts (None: MERIS, Appendix A)
        self.band_table = None if store.sensor is Sensor.MERIS else band_table(store.sensor)
        self.run, self.dems = run_tags(store)

    @property
    def grid(self) -> OutputGrid:
        return self.store.grid

    def _done(self, band: int) -> None:
        if self.progress is not None:
            self.progress(self.bands.index(int(band)) + 1, len(self.bands) + 1)

    def counts(self, bands: Sequence[int]) -> Iterator[np.ndarray]:
        """uint16 counts of ``bands``: the compact store's own; a float32 store's radiances
        encoded with ``BAND_SCALES`` (within half a count)."""
        session = self.store.session
        window = (0, self.grid.height, 0, self.grid.width)
        for b in bands:
            name = st.band_layer(int(b))
            values = st.read_window(session.store, [name], window, decode=False)[name]
            counts = values if self.stored[int(b)] is not None else st.encode_band(
                values, self.scale_factors[int(b)])
            self._done(b)
            yield counts

    def radiance(self, bands: Sequence[int] | None = None) -> dict[int, np.ndarray]:
        out = {}
        for b in self.bands if bands is None else bands:
            out[int(b)] = np.asarray(self.store.band(int(b)), np.float32)
            self._done(b)
        return out


def export_cog(store: SynthesisStore, out: str | os.PathLike[str], *,
               bands: Sequence[int] | None = None, layer: str | None = None,
               dtype: str | None = None,
               progress: ProgressCallback | None = None) -> Path:
    """Write bands (default all of the synthesis) or one other ``layer`` (``ndvi``, ``count``,
    ``product``) of ``store`` as a Cloud-Optimized GeoTIFF (module docstring); atomic.
    ``dtype``: "uint16" (default: counts, NDVI codes, with GDAL scale/offset) or "float32"
    (radiances, NDVI), for the bands and the NDVI only."""
    from .._atomic import check_distinct
    from ..ortho.description import check_dtype
    from ..ortho.writing import check_geotiff_name, write_map

    check_distinct({"output": out}, {"synthesis store": [store.path]})
    check_geotiff_name("output", out)
    if layer is not None and bands is not None:
        raise OptionsError("choose bands or one other layer, not both")
    if dtype is not None:
        check_dtype(dtype)
    if dtype is not None and layer in ("count", "product"):
        raise OptionsError(f"the {layer} layer keeps its integer type: the output type applies "
                           "to the bands and the NDVI")
    tags = {"algorithm": store.algorithm, "snapshot": store.snapshot,
            "products": " ".join(store.product_names().values()), **_sensor_tags(store)}
    if layer is not None:
        others = [n for n in store.layers() if not n.startswith("band_")]
        if layer not in others:
            raise OptionsError(f"{store.path}: no layer {layer!r} to export (the synthesis has "
                               f"{', '.join(others)})")
        path = _write_layer(store, out, layer, tags, dtype or "uint16")
    else:
        chosen = list(store.bands) if bands is None else list(dict.fromkeys(int(b)
                                                                             for b in bands))
        missing = [b for b in chosen if b not in store.bands]
        if missing:
            raise OptionsError(f"{store.path}: bands {missing} are not in the synthesis "
                               f"(it has {list(store.bands)})")
        if (dtype or "uint16") == "uint16":
            tags["radiance"] = STORE_COUNTS_NOTE
        path = write_map(out, _StoreBands(store, chosen, progress), dtype=dtype or "uint16",
                         compress=COMPRESS, metadata=tags,
                         software="napari-meris-ortho export", order=chosen)
    if progress is not None:
        progress(1, 1)
    return path


def _sensor_tags(store: SynthesisStore) -> dict[str, str]:
    """The band set, each product's sensor (in the order of ``products``) and, for a MERIS
    store holding OLCI products, the band matching; nothing for a store of MERIS bands and
    products."""
    from ..bands import Sensor
    from .reading import band_matching

    sensors = store.product_sensors()
    if store.sensor is Sensor.MERIS and all(s == Sensor.MERIS.value for s in sensors.values()):
        return {}
    return {"band_set": store.sensor.value,
            "product_sensors": " ".join(sensors[k] for k in sorted(sensors)),
            **band_matching(store.attrs)}


def _write_layer(store: SynthesisStore, out: str | os.PathLike[str], layer: str,
                 tags: dict[str, Any], dtype: str) -> Path:
    """One other layer (nearest overviews): the NDVI as ``dtype`` (module docstring), count
    and product in their own type, 0 = background."""
    from ..engine.resample import overview_level
    from ..engine.synthesis import NDVI_FACTOR, NDVI_SHIFT, ndvi_decode
    from ..output.geotiff import write_cog

    described = runs_described(store, "napari-meris-ortho export")
    tags = {**tags, **{k: str(v) for k, v in described.items()}}
    kwargs: dict[str, Any] = {"dtype": st.layer_dtype(layer), "nodata": 0}
    key = "ndvi-olci" if layer == "ndvi" and "product_sensors" in tags else layer
    if layer == "ndvi":
        tags["ndvi"] = NDVI_NOTE[dtype]
        if dtype == "float32":
            kwargs = {"dtype": "float32", "nodata": float("nan")}
        else:
            kwargs.update(scales=[NDVI_FACTOR], offsets=[NDVI_SHIFT])

    def one() -> Iterator[np.ndarray]:
        values = np.asarray(store.read(layer))
        yield ndvi_decode(values) if kwargs["dtype"] == "float32" else values

    return write_cog(Path(out), one(), store.grid, count=1, halve=overview_level,
                     descriptions=[LAYER_DESCRIPTIONS[key]], metadata=tags,
                     compress=COMPRESS, overview_resampling="nearest", **kwargs)

"""Reading a synthesis: ``open_synthesis(path, at)`` -> ``SynthesisStore`` at one snapshot."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..bands import Sensor, band_table
from ..errors import OptionsError
from . import store as st
from .bandsets import product_sensor, store_sensor
from .tiling import grid_from_dict

# --------------------------------------------------------------------------- reading a store


@dataclass
class SynthesisStore:
    """A synthesis store opened at one snapshot (the branch head unless ``--at``)."""

    path: Path
    repo: Any
    snapshot: str
    attrs: dict[str, Any]

    @property
    def session(self) -> Any:
        return self.repo.readonly_session(snapshot_id=self.snapshot)

    @property
    def algorithm(self) -> str:
        return str(self.attrs["algorithm"])

    @property
    def bands(self) -> tuple[int, ...]:
        return tuple(int(b) for b in self.attrs["bands"])

    @property
    def sensor(self) -> Sensor:
        """The band set: whose bands the store holds (MERIS ``M01``.., OLCI ``Oa01``..;
        ``bandsets``)."""
        return store_sensor(self.attrs)

    @property
    def band_names(self) -> list[str]:
        """``M07``, ``Oa08``, ...: the names of :attr:`bands`."""
        table = band_table(self.sensor)
        return [table.name(b) for b in self.bands]

    @property
    def grid(self) -> Any:
        return grid_from_dict(self.attrs["grid"])

    @property
    def tile(self) -> int:
        return int(self.attrs["tile"])

    @property
    def overviews(self) -> list[int]:
        return [int(f) for f in self.attrs.get("overviews", [])]

    @property
    def products(self) -> list[dict[str, Any]]:
        """The product table: entry k - 1 is the product of index k in the ``product`` layer,
        with its ``sensor`` ("MERIS", "OLCI")."""
        return [{**p, "sensor": product_sensor(p).value} for p in self.attrs.get("products", [])]

    @property
    def codec(self) -> str:
        """How the full-resolution bands are encoded: a ``StoreCodec`` value ("zstd",
        "delta-zstd"), else the names of the codec pipeline joined by "+" (older stores)."""
        return st.layer_codec(st.open_layer(self.session.store, self.layers()[0]))

    def layers(self) -> list[str]:
        """Layer names (``band_07``, ..., ``ndvi``, ``count``, ``product``)."""
        return st.layer_names(self.bands, self.algorithm)

    def read(self, name: str, window: tuple[int, int, int, int] | None = None,
             level: int = 1) -> np.ndarray:
        """Read one layer, optionally a window ``(row0, row1, col0, col1)``, at overview
        ``level`` (1 = full resolution, else a factor of :attr:`overviews`)."""
        if name not in self.layers():
            raise OptionsError(f"{self.path}: synthesis has no layer {name!r}")
        if level != 1 and level not in self.overviews:
            raise OptionsError(f"{self.path}: no overview level {level} (has {self.overviews})")
        if window is None:
            grid = self.grid
            window = (0, -(-grid.height // level), 0, -(-grid.width // level))
        return st.read_window(self.session.store, [name], window, level)[name]

    def band(self, band: int, window: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """Radiance of MERIS band ``band`` (float32, 0 = background)."""
        return self.read(st.band_layer(band), window)

    def ndvi(self, window: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """The maximum-NDVI layer decoded to float32 (Appendix C coding), NaN = background."""
        from ..engine.synthesis import ndvi_decode

        return ndvi_decode(self.read("ndvi", window))

    def product_names(self) -> dict[int, str]:
        """Index in the ``product`` layer -> product name."""
        return {int(p["index"]): str(p["product_name"]) for p in self.products}

    def product_sensors(self) -> dict[int, str]:
        """Index in the ``product`` layer -> the product's sensor ("MERIS", "OLCI")."""
        return {int(p["index"]): str(p["sensor"]) for p in self.products}

    def sensor_codes(self) -> np.ndarray:
        """Lookup table of the per-pixel sensor: ``codes[product index]`` is the
        ``SENSOR_CODES`` code of the product's sensor (index 0, background: 0)."""
        sensors = self.product_sensors()
        codes = np.zeros(max(sensors, default=0) + 1, np.uint8)
        for index, sensor in sensors.items():
            codes[index] = SENSOR_CODES[Sensor(sensor)]
        return codes

    def sensor_of_pixels(self, window: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """Which sensor each pixel's winning product came from: ``SENSOR_CODES`` (uint8;
        0 = background), from the ``product`` layer and the product table."""
        return sensor_of(self.read("product", window), self.sensor_codes())

    def to_xarray(self) -> Any:
        """The synthesis as a lazy ``xarray.Dataset`` (dask arrays chunked as the store;
        ``output.dataset.grid_dataset``): ``radiance`` (band, y, x; NaN = background) with the
        band numbers and their Appendix A central wavelengths as coordinates, ``ndvi`` decoded
        (Appendix C; maximum NDVI only), ``count`` and ``product`` (index into the dataset's
        ``products`` attribute, 0 = background), the CRS as the CF grid mapping
        ``spatial_ref``. Needs xarray (extra ``xarray``)."""
        import dask.array as da

        from ..engine.synthesis import ndvi_decode
        from ..ortho.antecedents import RADIANCE_UNITS
        from ..output.dataset import grid_dataset, require_xarray
        require_xarray()
        session = self.session

        def lazy(name: str) -> Any:
            array = st.open_layer(session.store, name)
            out = da.from_array(array, chunks=array.chunks, name=f"{self.snapshot}-{name}",
                                asarray=True)
            scale = st.stored_scale(array)
            # compact band layers: counts x the CF scale_factor, chunk by chunk
            return out if scale is None else out.astype(np.float32) * np.float32(scale)

        bands = list(self.bands)
        stack = da.stack([lazy(st.band_layer(b)) for b in bands])
        variables: dict[str, Any] = {
            "radiance": (("band", "y", "x"), da.where(stack == 0, np.float32(np.nan), stack),
                         {"long_name": "TOA radiance of the selected product",
                          "units": RADIANCE_UNITS}),
            "count": (("y", "x"), lazy("count"),
                      {"long_name": "number of products with a valid pixel"}),
            "product": (("y", "x"), lazy("product"),
                        {"long_name": "index (1-based) of the selected product in the "
                         "products attribute (0: background)"}),
        }
        codes = self.sensor_codes()
        variables["sensor"] = (("y", "x"), lazy("product").map_blocks(
            sensor_of, codes, dtype=np.uint8), {
                "long_name": "sensor of the selected product",
                "flag_values": np.array([0, *SENSOR_CODES.values()], np.uint8),
                "flag_meanings": " ".join(["background", *(s.value for s in SENSOR_CODES)])})
        if self.algorithm == "max-ndvi":
            variables["ndvi"] = (("y", "x"), lazy("ndvi").map_blocks(ndvi_decode,
                                                                     dtype=np.float32),
                                 {"long_name": "NDVI of the selected product (Appendix C)"})
        names, sensors = self.product_names(), self.product_sensors()
        span = range(1, max(names, default=0) + 1)
        table = band_table(self.sensor)
        attrs = {"algorithm": self.algorithm, "snapshot": self.snapshot,
                 "products": [names.get(k, "") for k in span],
                 "product_sensors": [sensors.get(k, "") for k in span],
                 "band_set": self.sensor.value, **band_matching(self.attrs),
                 **runs_described(self, "napari-meris-ortho")}
        return grid_dataset(self.grid, variables, bands=bands,
                            wavelengths=[table.centres[b - 1] for b in bands],
                            attrs=attrs, band_names=self.band_names,
                            band_label=f"{self.sensor.value} band")

    def history(self) -> list[st.Commit]:
        """The synthesis commits up to this snapshot, newest first."""
        return st.history(self.repo, snapshot=self.snapshot)


#: the per-pixel sensor codes (``SynthesisStore.sensor_of_pixels``; 0 = background)
SENSOR_CODES: dict[Sensor, int] = {Sensor.MERIS: 1, Sensor.OLCI: 2}


def sensor_of(product: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """The sensor code of each pixel of a ``product`` layer block (``codes``: the lookup
    table of ``SynthesisStore.sensor_codes``; an index beyond it: 0)."""
    index = np.asarray(product)
    inside = (index >= 0) & (index < codes.size)
    return np.where(inside, codes[np.clip(index, 0, codes.size - 1)], 0).astype(np.uint8)


def band_matching(attrs: dict[str, Any]) -> dict[str, Any]:
    """What a store of MERIS bands holding OLCI products says of its bands (``bandsets``:
    the Oa band feeding each, the approximate matches), as text attributes."""
    from .bandsets import APPROXIMATE_KEY, OLCI_BANDS_KEY

    if OLCI_BANDS_KEY not in attrs:
        return {}
    pairs = dict(attrs[OLCI_BANDS_KEY])
    out = {"olci_bands": " ".join(f"{m}={o}" for m, o in pairs.items()),
           "approximate_bands": " ".join(attrs.get(APPROXIMATE_KEY, []))}
    if "band_matching" in attrs:
        out["band_matching"] = str(attrs["band_matching"])
    return out


class DecodedLayer:
    """A layer level read lazily, window by window, straight from its zarr array (no task
    graph: zarr fetches a window's chunks concurrently), compact band counts decoded to
    float32 radiances (``store.decode_band``). With ``known``, ``written`` is the box of the
    chunks that hold values (``store.written_window``; None: no chunk does) and a window is
    read only where it meets that box, the rest is background (0): on a sparse Europe-size
    store, a level's empty windows cost no chunk lookups. An array-like for viewers
    (napari's multiscale levels, its ``LayerDataProtocol``): ``shape``, ``dtype``, ``ndim``,
    ``size``, ``__getitem__``, ``__array__``."""

    def __init__(self, array: Any, written: tuple[int, int, int, int] | None = None, *,
                 known: bool = False, ndvi: bool = False) -> None:
        self.array = array
        self.written = written
        self.known = known  # False: ``written`` unknown, every chunk asked for is read
        self.scale = st.stored_scale(array)
        self.ndvi = ndvi  # the NDVI layer: decoded (Appendix C), NaN = background
        self.shape = tuple(int(n) for n in array.shape)
        self.ndim = len(self.shape)
        self.size = int(np.prod(self.shape))
        self.dtype = np.dtype(np.float32) if self.scale is not None or ndvi else np.dtype(
            st.native_dtype(array))

    def _read(self, key: Any) -> np.ndarray:
        values = np.asarray(self.array[key])
        if self.ndvi:
            from ..engine.synthesis import ndvi_decode

            return ndvi_decode(values)
        return values if self.scale is None else st.decode_band(values, self.scale)

    def __getitem__(self, key: Any) -> np.ndarray:
        box = _box(key, self.shape) if self.known else None
        if box is None:
            return self._read(key)
        r0, r1, c0, c1 = box
        out = np.full((r1 - r0, c1 - c0), np.nan if self.ndvi else 0, self.dtype)
        if self.written is None:
            return out
        w0, w1, v0, v1 = self.written
        i0, i1, j0, j1 = max(r0, w0), min(r1, w1), max(c0, v0), min(c1, v1)
        if i0 < i1 and j0 < j1:
            out[i0 - r0:i1 - r0, j0 - c0:j1 - c0] = self._read((slice(i0, i1), slice(j0, j1)))
        return out

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        values = self[...]
        return values if dtype is None else values.astype(dtype)

    def __len__(self) -> int:
        return self.shape[0]


def _full_key(key: Any, ndim: int) -> tuple[Any, ...]:
    """An index ``key`` as one entry per axis of an ``ndim``-D array (``...`` and the
    missing trailing axes as whole slices)."""
    key = key if isinstance(key, tuple) else (key,)
    if any(k is Ellipsis for k in key):
        at = next(i for i, k in enumerate(key) if k is Ellipsis)
        key = (*key[:at], *(slice(None),) * (ndim + 1 - len(key)), *key[at + 1:])
    return (*key, *(slice(None),) * (ndim - len(key)))


def _box(key: Any, shape: tuple[int, ...]) -> tuple[int, int, int, int] | None:
    """``key`` as rows and columns (row0, row1, col0, col1) of a 2-D array of ``shape`` when
    it is slices of step 1 (or ``...``); None otherwise (integers, arrays, steps)."""
    key = _full_key(key, 2)
    if len(shape) != 2 or len(key) != 2 or not all(isinstance(k, slice) for k in key):
        return None
    (r0, r1, rs), (c0, c1, cs) = (k.indices(n) for k, n in zip(key, shape, strict=True))
    if rs != 1 or cs != 1:
        return None
    return r0, max(r1, r0), c0, max(c1, c0)


class DecodedStack:
    """Band layers of one level as a (band, row, column) array-like, read lazily: a window of
    a band is read from that band's ``DecodedLayer`` only."""

    def __init__(self, layers: list[DecodedLayer]) -> None:
        self.layers = layers
        self.shape = (len(layers), *layers[0].shape)
        self.ndim = 3
        self.size = int(np.prod(self.shape))
        self.dtype = np.dtype(np.float32)

    def __getitem__(self, key: Any) -> np.ndarray:
        band, *rest = _full_key(key, 3)
        window = tuple(rest)
        if isinstance(band, int | np.integer):
            return self.layers[int(band)][window]
        picked = np.arange(len(self.layers))[band]
        if not len(picked):
            return np.zeros((0, *np.broadcast_to(np.float32(0), self.shape[1:])[window].shape),
                            np.float32)
        return np.stack([self.layers[int(k)][window] for k in picked])

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        values = self[...]
        return values if dtype is None else values.astype(dtype)

    def __len__(self) -> int:
        return self.shape[0]


def runs_described(store: SynthesisStore, software: str) -> dict[str, Any]:
    """What the store's runs recorded (``run_tags``: options, DEMs with their datums) and the
    software describing them, with its version: the tags of an export, the attributes of
    ``to_xarray``."""
    from ..ortho.description import dems_text, software_version

    run, dems = run_tags(store)
    return {**run, "dems": dems_text(dems), "software": software,
            "software_version": software_version()}


def run_tags(store: SynthesisStore) -> tuple[dict[str, Any], list[dict[str, str]]]:
    """The options of the store's runs (the same for every commit that recorded them, else
    said to differ) and the DEMs any of them used, in the order first used."""
    commits = [c.run for c in reversed(store.history()) if c.run]
    options: list[dict[str, Any]] = [dict(c["options"]) for c in commits if c.get("options")]
    run: dict[str, Any] = {}
    if options and all(o == options[0] for o in options):
        run = dict(options[0])
    elif options:
        run = {"options": "differ between the commits (meris-ortho synthesis-log)"}
    dems: dict[str, dict[str, str]] = {}
    for c in commits:
        for d in c.get("dems", []):
            dems.setdefault(str(d.get("path")), dict(d))
    return run, list(dems.values())


def open_synthesis(path: str | os.PathLike[str], at: str | None = None) -> SynthesisStore:
    """Open the synthesis store ``path`` at its latest commit, or at snapshot ``at``."""
    root = Path(path)
    repo = st.open_repository(root)
    try:
        session = (repo.readonly_session(snapshot_id=at) if at
                   else repo.readonly_session(branch=st.BRANCH))
    except Exception as exc:  # icechunk's own error types
        if at:  # its message is a multi-line Rust error report: not ours to print
            raise OptionsError(f"{root}: no snapshot {at!r} in the synthesis store (its "
                               "commits: synthesis-log; a pruned commit is gone)") from None
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise OptionsError(f"{root}: no branch {st.BRANCH!r} in the synthesis store "
                           f"({first.strip(' x')})") from None
    attrs = st.read_attributes(session.store)
    if attrs is None:
        raise OptionsError(f"{root}: not a synthesis store (no synthesis committed there)")
    store = SynthesisStore(root, repo, session.snapshot_id, attrs)
    try:
        _ = store.grid, store.bands, store.algorithm, store.tile
    except (ValueError, KeyError, TypeError) as exc:
        raise OptionsError(f"{root}: damaged synthesis attributes ({exc})") from None
    return store


def is_synthesis(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` is a store holding a committed synthesis."""
    try:
        open_synthesis(path)
    except OptionsError:
        return False
    return True

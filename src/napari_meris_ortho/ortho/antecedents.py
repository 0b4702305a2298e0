"""The result of the antecedent search and the bands sampled there.

``Antecedents`` (what ``precompute`` returns) holds the antecedent (line, col) of every output
point; ``counts``, ``radiance`` and ``flags`` sample the product there (section 3.1 "Retrieve
the antecedent"; nearest: one fused gather of all bands), ``result`` gives the ``OrthoResult``
that ``orthorectify`` returns.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyproj
from affine import Affine

from ..bands import BandTable, band_table
from ..geometry.grid import OutputGrid, check_grid_size
from ..options import OrthoOptions, Sampling
from ..products.protocol import MerisProduct
from ..progress import ProgressCallback
from .description import RADIANCE_UNITS, describe_map
from .stats import RunStats

#: bands sampled together when they are streamed to a writer (``writing.write_map``: one pass
#: over the antecedent index for several bands)
GATHER_GROUP = 4


@dataclass
class OrthoResult:
    """Output of ``orthorectify``: bands (radiance float32, 0 = background) on ``grid``.

    ``valid``: points whose antecedent is inside the product; ``flags``: L1b flags (nearest);
    ``diagnostics`` (on request): line, col, elevation, elevation_source, iterations,
    shift_east_m, shift_north_m; ``stats``: what the Appendix B log prints; ``saturated``:
    per-band saturation bits (nearest; bit b-1: band b) of products that carry them (.SEN3).
    A band's no-data pixels (a fill value in the product) are 0 like the background.
    """

    bands: dict[int, np.ndarray]
    grid: OutputGrid
    valid: np.ndarray
    flags: np.ndarray
    stats: RunStats
    diagnostics: dict[str, np.ndarray] = field(default_factory=dict)
    saturated: np.ndarray | None = None
    #: ground hidden from the sensor by the relief (bool; the lines of sight marched over the
    #: DEMs): no data with hidden "mask", mapped with "keep"; None: not looked for (no DEM)
    hidden: np.ndarray | None = None
    #: the bands of the product's sensor (None: MERIS), for the names in ``to_xarray``
    band_table: BandTable | None = None

    @property
    def crs(self) -> pyproj.CRS:
        return self.grid.crs

    @property
    def transform(self) -> Affine:
        return self.grid.transform

    def band_metadata(self) -> list[dict[str, Any]]:
        """Per output band (``self.bands``: ascending), ``band_metadata``; the band values are
        already radiances."""
        return band_metadata(self.stats, list(self.bands))

    def to_xarray(self) -> Any:
        """The result as an ``xarray.Dataset`` (``output.dataset.grid_dataset``): ``radiance``
        (band, y, x; W m-2 sr-1 um-1, NaN where no antecedent is inside the product) with the
        band numbers and central wavelengths as coordinates, ``flags`` (L1b flag bits, CF
        ``flag_masks``), ``valid``, ``hidden`` (ground hidden by the relief, with DEMs) and the
        diagnostics layers (y, x); the CRS as the CF grid
        mapping ``spatial_ref`` (rioxarray reads it). Needs xarray (extra ``xarray``)."""
        from ..flags import FLAG_NAMES
        from ..output.dataset import grid_dataset, require_xarray

        require_xarray()
        bands = sorted(self.bands)
        radiance = np.empty((len(bands), *self.grid.shape), np.float32)
        for k, b in enumerate(bands):
            np.copyto(radiance[k], self.bands[b])
            radiance[k][~self.valid] = np.nan
        meta = {m["meris_band"]: m for m in self.band_metadata()}
        variables: dict[str, Any] = {
            "radiance": (("band", "y", "x"), radiance, {
                "long_name": "TOA radiance", "units": RADIANCE_UNITS,
                "sf_rad": [float(meta[b].get("sf_rad", np.nan)) for b in bands]}),
            "flags": (("y", "x"), self.flags, {
                "long_name": "MERIS L1b flags of the nearest pixel (0: background)",
                "flag_masks": np.array([1 << k for k in range(len(FLAG_NAMES))], np.uint8),
                "flag_meanings": " ".join(n.lower() for n in FLAG_NAMES)}),
            "valid": (("y", "x"), np.asarray(self.valid), {
                "long_name": "antecedent inside the product"}),
        }
        if self.hidden is not None:
            variables["hidden"] = (("y", "x"), np.asarray(self.hidden, bool), {
                "long_name": "ground hidden from the sensor by the relief",
                "hidden": self.stats.hidden})
        for name, values in self.diagnostics.items():
            if name != "hidden" or self.hidden is None:
                variables[name] = (("y", "x"), values, {"long_name": f"diagnostics: {name}"})
        described = describe_map(self.stats, bands, "float32",  # the files' tags
                                 table=self.band_table)
        attrs = {**{k: v for k, v in described.tags().items() if k != "radiance"},
                 **described.run}
        return grid_dataset(self.grid, variables, bands=bands,
                            wavelengths=[meta[b].get("wavelength_nm") for b in bands],
                            attrs={k: str(v) if not isinstance(v, int | float) else v
                                   for k, v in attrs.items()})


def band_metadata(stats: RunStats, bands: Sequence[int]) -> list[dict[str, Any]]:
    """Per band, in the order given: MERIS band number, central wavelength and bandwidth
    (nm), radiance unit and ``sf_rad``, the source product's counts-to-radiance factor
    (Scaling Factor GADS, Appendix A)."""
    out = []
    for b in bands:
        meta: dict[str, Any] = {"meris_band": b, "units": RADIANCE_UNITS}
        for key, name in (("wavelengths", "wavelength_nm"), ("bandwidths", "bandwidth_nm"),
                          ("scale_factors", "sf_rad")):
            value = getattr(stats, key).get(b)
            if value is not None:
                meta[name] = value
        out.append(meta)
    return out


def bytes_per_output_pixel(opts: OrthoOptions, *, hold_bands: bool = True,
                           area_share: float = 1.0) -> float:
    """Memory an output pixel costs, on average over a grid whose search area (the rows and
    columns the segment reaches, ``Antecedents.area``) is ``area_share`` of it.

    Over the area: the antecedent line and column (float32), iterations, nearest-pixel index
    and the hidden-ground mask (17 bytes); streamed to a writer (``writing.write_map``), the
    ``GATHER_GROUP`` uint16 bands gathered at a time and the previous group still in the
    writer (2 x min(bands, 8)).
    Over the whole grid: ``hold_bands`` (``orthorectify``, ``Antecedents.result``), every band
    as float32 with its resampling buffer, the flags and the saturation (8 x bands + 3), else
    the writer's overview levels of its bands in flight (2); the diagnostics layers and their
    float32 copies for writing (48)."""
    n = len(opts.bands)
    area = 17 + (0 if hold_bands else 2 * min(n, 2 * GATHER_GROUP))
    whole = (_held_band_bytes(n) if hold_bands else 2) + (48 if opts.diagnostics else 0)
    return whole + area * float(area_share)


def _held_band_bytes(n_bands: int) -> int:
    """Bytes per output pixel of ``n_bands`` bands held as float32, with the resampling
    buffer of each, the flags (uint8) and the saturation (uint16) (``Antecedents.result``)."""
    return 8 * n_bands + 3


def antecedent_window(line: np.ndarray, col: np.ndarray, n_lines: int, n_cols: int,
                      sampling: str = "nearest") -> tuple[int, int, int, int]:
    """Product lines ``[first, stop)`` and columns ``[col_first, col_stop)`` holding every
    pixel the resampling of the antecedents inside the product reads (section 3.1 "Retrieve
    the antecedent"): min..max antecedent line (column) plus the kernel margin
    (nearest/bilinear: 0 and +1, bicubic: -1 and +2); all 0 when no antecedent is inside."""
    from ..engine.resample import inside_range

    span = inside_range(line, col, n_lines, n_cols)
    if span is None:
        return 0, 0, 0, 0
    before, after = Sampling(sampling).margin

    def window(lo: float, hi: float, n: int) -> tuple[int, int]:
        return (max(int(math.floor(lo)) - before, 0),
                min(int(math.floor(hi)) + 1 + after, n))

    return (*window(span[0], span[1], n_lines), *window(span[2], span[3], n_cols))


#: ``Antecedents`` arrays and their background: antecedent line and column (NaN), iterations
#: (-1: not searched or not solved)
BACKGROUND = {"line": np.nan, "col": np.nan, "iterations": -1}


def on_whole_grid(part: np.ndarray, shape: tuple[int, int], area: tuple[int, int, int, int],
                  background: float) -> np.ndarray:
    """``part``, rows [r0, r1) and columns [c0, c1) (``area``) of a grid of ``shape``, in the
    whole grid with ``background`` around (``part`` itself when it is the whole grid)."""
    if part.shape == tuple(shape):
        return part
    r0, r1, c0, c1 = area
    whole = np.full(shape, background, part.dtype)
    whole[r0:r1, c0:c1] = part
    return whole


@dataclass
class Antecedents:
    """Antecedent (line, col) of every output point of ``grid`` (float32, NaN: background)
    and the product lines ``window`` = [first, stop) they read; ``counts``, ``radiance`` and
    ``flags`` sample the product there (nearest: one fused gather of all bands).

    The search keeps only the ``area`` of the grid it reached (rows [r0, r1), columns [c0, c1):
    ``area_line``, ``area_col``, ``area_iterations``); ``line``, ``col`` and ``iterations`` are
    the whole grid's, built on first use (a segment in a far larger grid costs its own size)."""

    prod: MerisProduct
    grid: OutputGrid
    area: tuple[int, int, int, int]
    area_line: np.ndarray
    area_col: np.ndarray
    area_iterations: np.ndarray
    sampling: Sampling
    bands: list[int]
    stats: RunStats
    diagnostics: dict[str, np.ndarray]
    progress: ProgressCallback | None = None
    t_start: float = field(default_factory=time.perf_counter)
    _index: np.ndarray | None = field(default=None, repr=False)
    _box: tuple[int, int, int, int] | None = field(default=None, repr=False)
    #: the caller's limit of output pixels (``precompute``), for ``result``'s size check
    max_pixels: int | None = None
    #: ``precompute``'s size check counted every band held (``hold_bands``): ``result`` does
    #: not check again
    bands_counted: bool = False
    #: the whole-grid ``line``, ``col``, ``iterations`` built so far (given: the diagnostics')
    whole_grid: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    #: the bands of ``nearest_source`` and their windows' copy (bands, lines, cols)
    _held: tuple[tuple[int, ...], np.ndarray] | None = field(default=None, repr=False)
    #: ground hidden by the relief over the ``area`` (bool), None: not looked for (no DEM)
    area_hidden: np.ndarray | None = None

    @property
    def band_table(self) -> BandTable:
        """The bands of the product's sensor: their names in the files' descriptions."""
        return band_table(getattr(self.prod, "sensor", "MERIS"))

    @property
    def line(self) -> np.ndarray:
        """Antecedent line of every point of the grid (float32, NaN: background)."""
        return self._on_whole_grid("line", self.area_line)

    @property
    def col(self) -> np.ndarray:
        """Antecedent column of every point of the grid (float32, NaN: background)."""
        return self._on_whole_grid("col", self.area_col)

    @property
    def iterations(self) -> np.ndarray:
        """Prediction/correction iterations of every point (int8, -1: background)."""
        return self._on_whole_grid("iterations", self.area_iterations)

    def _on_whole_grid(self, name: str, part: np.ndarray) -> np.ndarray:
        """``part`` (the ``area``) in the whole grid, ``BACKGROUND`` around; once."""
        if name not in self.whole_grid:
            self.whole_grid[name] = on_whole_grid(part, self.grid.shape, self.area,
                                              BACKGROUND[name])
        return self.whole_grid[name]

    @property
    def hidden(self) -> np.ndarray | None:
        """Ground hidden from the sensor by the relief (bool, the whole grid; no data with
        hidden "mask", mapped with "keep"); None when no DEM was marched."""
        if self.area_hidden is None:
            return None
        if "hidden" not in self.whole_grid:
            self.whole_grid["hidden"] = on_whole_grid(self.area_hidden, self.grid.shape,
                                                      self.area, False)
        return self.whole_grid["hidden"]

    @property
    def valid(self) -> np.ndarray:
        """Points whose antecedent is inside the product."""
        return self.iterations >= 0

    @property
    def window(self) -> tuple[int, int]:
        """Product lines [first, stop) the resampling reads (``antecedent_window``)."""
        first, stop = self.stats.product_lines_read
        return int(first), int(stop)

    @property
    def columns(self) -> tuple[int, int]:
        """Product columns [first, stop) the resampling reads (``antecedent_window``)."""
        first, stop = self.stats.product_columns_read
        return int(first), int(stop)

    def _rows(self) -> slice:
        first, stop = self.window
        return slice(first, stop)

    def _cols(self) -> slice:
        first, stop = self.columns
        return slice(first, stop)

    def _extent(self) -> tuple[int, int, int, int]:
        """Rows [r0, r1) and columns [c0, c1) of the grid holding every point with an
        antecedent (``engine.resample.finite_extent``, once): the samplers work there only, the
        rest of the grid is background (a segment in a far larger grid costs its own size).
        Columns over half the area's are widened to the area's: whole rows of the area arrays,
        no copy of the antecedents for the nearest index."""
        from ..engine.resample import finite_extent

        if self._box is None:
            r0, r1, c0, c1 = finite_extent(self.area_line)
            a0, _, b0, b1 = self.area
            if 2 * (c1 - c0) > b1 - b0:
                c0, c1 = 0, b1 - b0
            self._box = (a0 + r0, a0 + r1, b0 + c0, b0 + c1) if r1 > r0 else (0, 0, 0, 0)
        return self._box

    def _points(self) -> tuple[np.ndarray, np.ndarray]:
        """Antecedent (line, col) of the points of ``_extent`` (views)."""
        r0, r1, c0, c1 = self._extent()
        a0, _, b0, _ = self.area
        rows, cols = slice(r0 - a0, r1 - a0), slice(c0 - b0, c1 - b0)
        return self.area_line[rows, cols], self.area_col[rows, cols]

    def _sampled(self, n: int, dtype: Any) -> tuple[np.ndarray, tuple[int, int, int, int] | None]:
        """(n, rows, cols) of ``dtype`` for sampled values and the ``_extent`` to sample in it
        (None: nothing to sample, all background 0): uninitialised when the extent is the whole
        grid, else zeros (the untouched pages of a large grid cost no memory)."""
        nr, nc = self.grid.shape
        box = self._extent()
        if box[1] <= box[0] or self.window[1] <= self.window[0] or n == 0:
            return np.zeros((n, nr, nc), dtype), None
        whole = box == (0, nr, 0, nc)
        return (np.empty if whole else np.zeros)((n, nr, nc), dtype), box

    def _nearest_index(self) -> np.ndarray:
        """Flat pixel index (relative to the window) of the nearest pixel of each point of
        ``_extent``, once."""
        from ..engine.resample import nearest_pixel

        if self._index is None:
            first, stop = self.window
            c_first, c_stop = self.columns
            line, col = self._points()
            self._index = nearest_pixel(line, col, stop - first, c_stop - c_first,
                                        line_offset=first, col_offset=c_first)
        return self._index

    def _timed(self, key: str, t0: float) -> None:
        sec = self.stats.seconds
        sec[key] += time.perf_counter() - t0

    def _gather(self, images: Sequence[Any], dtype: Any, out: np.ndarray,
                box: tuple[int, int, int, int], scales: np.ndarray | None = None,
                stack: np.ndarray | None = None) -> None:
        """The nearest pixel of every point of ``box`` (``_extent``) from ``images`` (their
        window, as ``dtype``; or ``stack``, those windows copied already) into its place in
        ``out`` (images, rows, cols): as they are (``gather``), or times ``scales`` as float32
        (``gather_scaled``)."""
        from ..engine.resample import gather, gather_scaled

        if stack is None:
            stack = self._stack(images, dtype)
        index = self._nearest_index()
        n, nr, nc = out.shape
        r0, r1, c0, c1 = box
        flat = out.reshape(n, nr * nc)
        place = None if (c0, c1) == (0, nc) and r0 == 0 else (c1 - c0, nc, r0 * nc + c0)
        t0 = time.perf_counter()
        if scales is None:
            gather(stack, index, flat, place)
        else:
            gather_scaled(stack, index, scales, flat, place)
        self._timed("resample", t0)

    def _stack(self, images: Sequence[Any], dtype: Any) -> np.ndarray:
        """(n, window lines, window columns) native copy of the window of each image (memmaps
        read here)."""
        from ..engine.resample import copy_window

        t0 = time.perf_counter()
        rows, cols = self._rows(), self._cols()
        out = np.empty((len(images), rows.stop - rows.start, cols.stop - cols.start), dtype)
        for k, im in enumerate(images):
            copy_window(out[k], im[rows, cols])
        self._timed("read_bands", t0)
        return out

    def _no_data(self, bands: Sequence[int]) -> list[int | None]:
        """The stored value of each band's no-data pixels (``MerisProduct.no_data_count``)."""
        return [self.prod.no_data_count(b) for b in bands]

    def _interpolated(self, bands: Sequence[int]) -> list[np.ndarray]:
        """Bilinear/bicubic counts (float32) of ``bands`` at the points of ``_extent``; a
        sample that touches a no-data pixel is no data (0), never a value mixed with a fill."""
        from ..engine.resample import resample_bands, touches

        stack = self._stack([self.prod.counts(b) for b in bands], np.uint16)
        t0 = time.perf_counter()
        line, col = self._points()
        lines = line.astype(np.float64) - self.window[0]
        cols = col.astype(np.float64) - self.columns[0]
        out = resample_bands(list(stack), lines, cols, self.sampling.value)
        for k, fill in enumerate(self._no_data(bands)):
            if fill is not None:
                mask = stack[k] == fill
                if mask.any():
                    out[k][touches(mask, lines, cols, self.sampling.value)] = 0.0
        self._timed("resample", t0)
        return out

    @staticmethod
    def _clear(values: np.ndarray, fills: Sequence[int | None],
               scales: np.ndarray | None = None) -> None:
        """No-data pixels gathered into ``values`` (bands, points) -> 0 (background): the
        count equal to the band's fill (``scales``: the values are fill x scale, float32)."""
        for k, fill in enumerate(fills):
            if fill is None:
                continue
            stored = fill if scales is None else np.float32(fill) * np.float32(scales[k])
            values[k][values[k] == stored] = 0

    def counts(self, bands: Sequence[int] | None = None) -> np.ndarray:
        """uint16 counts (len(bands), rows, cols) at the antecedents, 0 = background; nearest:
        the product's counts; bilinear/bicubic: interpolated counts rounded half up."""
        bands = self.bands if bands is None else [int(b) for b in bands]
        out, box = self._sampled(len(bands), np.uint16)
        if box is None:
            return out
        inside = out[:, box[0]:box[1], box[2]:box[3]]
        if self.sampling is Sampling.NEAREST:
            held = self._held
            if held is not None and set(bands) <= set(held[0]):
                stack = held[1][[held[0].index(b) for b in bands]]
                self._gather([], np.uint16, out, box, stack=stack)
            else:
                self._gather([self.prod.counts(b) for b in bands], np.uint16, out, box)
            self._clear(inside, self._no_data(bands))
            return out
        for k, v in enumerate(self._interpolated(bands)):
            inside[k] = np.clip(np.floor(v + np.float32(0.5)), 0, 65535)
        return out

    def nearest_source(self, bands: Sequence[int]
                       ) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int, int]] | None:
        """What ``counts`` gathers from at the nearest pixel, for a caller that reads some points
        only: the product window of each band's counts (len(bands), window pixels) uint16, the
        flat pixel of every point of the extent (its rows x columns; -1: none) and that extent
        of the grid (rows [r0, r1), columns [c0, c1)); None when there is nothing to sample."""
        if self.sampling is not Sampling.NEAREST:
            raise ValueError("nearest_source: the sampling is not nearest")
        box = self._extent()
        if box[1] <= box[0] or self.window[1] <= self.window[0] or not bands:
            return None
        held = tuple(int(b) for b in bands)
        stack = self._stack([self.prod.counts(b) for b in held], np.uint16)
        self._held = (held, stack)  # ``counts`` of these bands gathers from it (no new copy)
        index = self._nearest_index().reshape(box[1] - box[0], box[3] - box[2])
        return stack.reshape(stack.shape[0], -1), index, box

    def radiance(self, bands: Sequence[int] | None = None) -> dict[int, np.ndarray]:
        """float32 radiances (counts x sf_rad, Scaling Factor GADS) of ``bands``, 0 = background;
        bilinear/bicubic: the interpolated counts, not rounded."""
        bands = self.bands if bands is None else [int(b) for b in bands]
        sf = self.prod.scaling.radiance
        scales = np.array([sf[b - 1] for b in bands])
        out, box = self._sampled(len(bands), np.float32)
        if box is not None:
            inside = out[:, box[0]:box[1], box[2]:box[3]]
            if self.sampling is Sampling.NEAREST:  # counts x sf_rad in one pass, no uint16 copy
                self._gather([self.prod.counts(b) for b in bands], np.uint16, out, box,
                             scales=scales)
                self._clear(inside, self._no_data(bands), scales)
            else:
                for k, v in enumerate(self._interpolated(bands)):
                    inside[k] = v * np.float32(scales[k])
        return {b: out[k] for k, b in enumerate(bands)}

    def flags(self) -> np.ndarray:
        """L1b flags (uint8) of the nearest pixel, 0 = background (any sampling)."""
        return self._nearest([self.prod.flags], np.uint8)

    def saturated(self) -> np.ndarray | None:
        """Per-band saturation bits (bit b-1: band b; the product's type: uint16 MERIS,
        uint32 OLCI) of the nearest pixel, 0 = background; None for a product without them
        (``MerisProduct.saturated``)."""
        sat = self.prod.saturated
        return None if sat is None else self._nearest([sat], sat.dtype)

    def _nearest(self, images: Sequence[Any], dtype: Any) -> np.ndarray:
        """The nearest pixel of one image at the antecedents (rows, cols), 0 = background."""
        out, box = self._sampled(1, dtype)
        if box is not None:
            self._gather(images, dtype, out, box)
        return out[0]

    def finish(self) -> RunStats:
        """Statistics with the engine and total times up to now (Appendix B log)."""
        sec = self.stats.seconds
        sec["engine"] = sec["prediction_correction"] + sec["resample"]
        sec["total"] = time.perf_counter() - self.t_start
        return self.stats

    def result(self) -> OrthoResult:
        """All bands and flags as an ``OrthoResult`` (what ``orthorectify`` returns); first,
        unless ``precompute`` counted them, the grid's size against the memory they take
        (OptionsError, ``check_grid_size``)."""
        if not self.bands_counted:
            check_grid_size(self.grid.width, self.grid.height, (self.grid.dx, self.grid.dy),
                            _held_band_bytes(len(self.bands)), self.max_pixels)
        radiance = self.radiance()
        flags = self.flags()
        if self.progress is not None:
            total = self.grid.height + len(self.bands)
            self.progress(total, total)
        return OrthoResult(radiance, self.grid, self.valid, flags, self.finish(),
                           self.diagnostics, self.saturated(), self.hidden, self.band_table)



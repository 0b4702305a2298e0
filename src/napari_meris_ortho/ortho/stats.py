"""Statistics of an orthorectification run and the Appendix B log that prints them.

``RunStats`` is the one interface between a run (``ortho.core``) and whoever reports it: the
CLI log (``RunStats.log_lines``, Appendix B: pixel size, image size and origin, facet-search
shares, the prediction/correction histogram, the processed points, the elapsed time), the
``--stats-json`` file (``RunStats.to_dict``), napari layer metadata and the output tags.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

#: elevation source codes of the diagnostics (0..n-1: index of the DEM in the list)
SOURCE_TIEPOINTS = -1
SOURCE_NONE = -2
#: the timings of a run (seconds), in the order the log prints them
TIMINGS = ("lonlat", "dem", "prediction_correction", "read_bands", "resample", "engine")


@dataclass
class RunStats:
    """What the Appendix B log prints, plus the options and timings of the run."""

    product: str
    product_name: str
    output_lines: int
    output_columns: int
    crs: str
    ul_x: float
    ul_y: float
    lr_x: float
    lr_y: float
    pixel_width: float
    pixel_height: float
    #: False for elevation "none" (MERSYN ``-ort NO``)
    orthorectification: bool
    #: facet-search counts by case: "same", "4-connex", "8-connex", "all", "not found",
    #: "primary grid" (section 3.4); pixel geolocation: "primary warm/seeded/not found/outside"
    #: and "occluded" (output points on ground hidden from the sensor by the relief)
    facet_search: dict[str, int]
    #: points solved after k iterations of the prediction/correction loop (section 3.2)
    iterations_histogram: list[int]
    processed_points: int
    #: product lines [first, stop) read by the resampling
    product_lines_read: list[int]
    #: product columns [first, stop) read by the resampling
    product_columns_read: list[int]
    output_points: int
    #: points per elevation source: "tiepoints" and "k:NAME" for DEM k (empty: elevation none)
    elevation_sources: dict[str, int]
    #: timings (``TIMINGS`` and "total")
    seconds: dict[str, float]
    bands: list[int]
    wavelengths: dict[int, float]
    bandwidths: dict[int, float]
    #: sf_rad per band: counts to radiance (Scaling Factor GADS, Appendix A)
    scale_factors: dict[int, float]
    elevation: str
    parallax: str
    sampling: str
    geolocation: str
    tolerance: float
    method: str
    margin_px: int
    points_in_boundary: int
    dems: list[str] = field(default_factory=list)
    #: vertical datum of each DEM's heights as read ("ellipsoid", "egm96", "egm2008"; None:
    #: tiles of several datums)
    dem_datums: list[str | None] = field(default_factory=list)
    #: DEM name -> the tiles of its tiling under the footprint it lacks (their points took
    #: the next DEM or the tie points)
    dem_gaps: dict[str, list[str]] = field(default_factory=dict)
    #: what became of ground hidden by the relief: "mask" (no data) or "keep" (mapped)
    hidden: str = "mask"
    #: output points on ground hidden from the sensor by the relief (the lines of sight
    #: marched over the DEMs; the pixel geolocation's own); None: not looked for (no DEM)
    hidden_points: int | None = None

    def gap_warnings(self) -> list[str]:
        """One sentence per DEM that lacks tiles under the footprint."""
        out = []
        for dem, tiles in self.dem_gaps.items():
            names = ", ".join(tiles[:4]) + (f" and {len(tiles) - 4} more" if len(tiles) > 4
                                           else "")
            out.append(f"DEM {dem} has no tile {names} under the footprint (missing, or open "
                       "sea where the tiling has none): those points took the next DEM or the "
                       "tie points")
        return out

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (the ``--stats-json`` file)."""
        return asdict(self)

    def log_lines(self, default_pixel: bool = False) -> list[str]:
        """The Appendix B style log of a mapping run (``default_pixel``: the pixel size was
        not given)."""
        s = self
        out = []
        if default_pixel:
            out.append("SETTING PIXEL SIZE DEFAULT VALUES")
        out += [f"PIXEL HEIGHT = {s.pixel_height:.6f}", f"PIXEL WIDTH  = {s.pixel_width:.6f}",
                "", "COMPUTING IMAGE SIZE AND ORIGIN",
                f"UL: X = {s.ul_x:.6f}  Y = {s.ul_y:.6f}",
                f"LR: X = {s.lr_x:.6f}  Y = {s.lr_y:.6f}",
                f"IMAGE HEIGHT = {s.ul_y - s.lr_y:.6f} ({s.crs} units)",
                f"IMAGE WIDTH  = {s.lr_x - s.ul_x:.6f}",
                f"LINE NUMBER  = {s.output_lines}", f"PIXEL NUMBER = {s.output_columns}"]
        fs = dict(s.facet_search)
        primary = fs.pop("primary grid", None)
        fs.pop("not found", None)
        occluded = fs.pop("occluded", None)
        n = sum(fs.values()) or 1
        nb = fs.get("4-connex", 0) + fs.get("8-connex", 0)
        what = "primary-grid nodes" if primary is not None else "points"
        out.append(f"facet search ({what}): -same= {100 * fs.get('same', 0) / n:.1f}% "
                   f"-neighbour= {100 * nb / n:.1f}% -all= {100 * fs.get('all', 0) / n:.1f}%")
        if primary is not None:
            out.append(f"points predicted from the primary grid = {primary}")
        if s.hidden_points is not None or occluded is not None:  # DEMs or pixel geolocation
            n = s.hidden_points if s.hidden_points is not None else int(occluded or 0)
            what = "mapped, hidden keep" if s.hidden == "keep" else "no antecedent"
            out.append(f"points hidden by the relief ({what}) = {n}")
        sec = s.seconds
        out.append(f"Total elapsed time={sec['total']:.3f} seconds "
                   f"(prediction/correction {sec['prediction_correction']:.3f} s, "
                   f"resampling {sec['resample']:.3f} s, DEM {sec['dem']:.3f} s)")
        out.append("")
        out += histogram_lines(s.iterations_histogram)
        out.append("")
        total = s.output_points or 1
        seg = s.points_in_boundary or 1
        out.append(f"ORTHORECTIFICATION PROCESSING = {'YES' if s.orthorectification else 'NO'}")
        out.append(f"NUMBER OF PROCESSED POINTS IN SEGMENT = {s.processed_points} "
                   f"({100 * s.processed_points / total:.1f}% of image, "
                   f"{100 * s.processed_points / seg:.1f}% of segment boundary)")
        if s.elevation_sources:
            out.append("ELEVATION SOURCES = " + ", ".join(
                f"{k}: {v}" for k, v in s.elevation_sources.items()))
        return out

    def unused_dems(self) -> list[str]:
        """The DEMs of the list that gave no height where one was still wanted (outside the
        product, a wrong CRS tag, only no data or implausible heights): points went on to a
        later DEM or to the tie points. A DEM after ones that answered every point was not
        needed, not unused."""
        counts: dict[int, int] = {}
        later_than: dict[int, int] = {}
        fallback = 0
        for key, count in self.elevation_sources.items():
            index, _, _ = key.partition(":")
            if index.isdigit() and int(index) < len(self.dems):
                counts[int(index)] = count
            else:  # tie points (or none): after every DEM
                fallback += count
        for k in counts:
            later_than[k] = fallback + sum(c for j, c in counts.items() if j > k)
        return [self.dems[k] for k, c in sorted(counts.items()) if c == 0 and later_than[k]]


def histogram_lines(hist: Sequence[int]) -> list[str]:
    """The prediction/correction statistics lines of the Appendix B log."""
    total = sum(hist)
    lines = [f"PREDICTION/CORRECTION LOOP STATISTICS (total processed points = {total})"]
    for k, v in enumerate(hist):
        pct = 100.0 * v / total if total else 0.0
        lines.append(f". ITERATION [{k:2d}] = {v:8d} ({pct:5.1f} %)")
    return lines


def per_band(source: Any, name: str, band_list: list[int]) -> dict[int, float]:
    """``{band: source.<name>[band - 1]}`` (wavelengths, bandwidths, radiance factors)."""
    try:
        values = list(getattr(source, name))
        return {b: float(values[b - 1]) for b in band_list}
    except (AttributeError, IndexError, TypeError, ValueError):
        return {}


def source_counts(sources: np.ndarray, dem_names: Sequence[str] | None,
                  orthorectified: bool) -> dict[str, int]:
    """Points per elevation source (``sources[0]``: tie points, ``sources[k + 1]``: DEM k);
    empty without orthorectification, "tiepoints" only without DEMs."""
    if not orthorectified:
        return {}
    if dem_names is None:
        return {"tiepoints": int(sources.sum())}
    out = {"tiepoints": int(sources[0])}
    for i, name in enumerate(dem_names):
        out[f"{i}:{Path(name).name}"] = int(sources[i + 1])
    return out

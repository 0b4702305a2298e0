"""Orthorectified mapping of a MERIS L1b product (MERSYN use case 3, handbook sections 3.1-3.4).

``orthorectify`` is the glue between the products, the DEMs and the engine, in these rooms:

- ``core``: the orchestration: product and DEMs opened and checked, segment boundary and
  output grid (``product_grid``, the one default grid), the prediction/correction of every
  antecedent by blocks of output rows (``Segment``, ``precompute``, ``orthorectify``);
- ``heights``: the heights of the output points, the DEMs tried in order
  (``dem.stack.DemStack.walk`` with the compiled lookup of ``engine.terrain``);
- ``antecedents``: the antecedents and the bands, flags and diagnostics sampled there
  (``Antecedents``, ``OrthoResult``);
- ``stats``: the run's statistics (``RunStats``) and the Appendix B log that prints them;
- ``description``: what a mapped product's file says of its bands and of the run
  (``describe_map``, ``MapDescription``: band order, wavelengths, units, scale/offset, options,
  DEMs, software version), for the GeoTIFF tags, ``--stats-json`` and xarray alike;
- ``writing``: a mapped product as a file (``write_map``: the COG of ``meris-ortho map``, the
  widget and the synthesis export).

Everything is checked before any heavy work starts.
"""

from .antecedents import (
    RADIANCE_UNITS,
    Antecedents,
    OrthoResult,
    antecedent_window,
    band_metadata,
    bytes_per_output_pixel,
)
from .core import (
    Segment,
    lonlat_bounds,
    open_segment,
    orthorectify,
    precompute,
    product_grid,
)
from .stats import SOURCE_NONE, SOURCE_TIEPOINTS, RunStats, histogram_lines

__all__ = ["RADIANCE_UNITS", "SOURCE_NONE", "SOURCE_TIEPOINTS", "Antecedents", "OrthoResult",
           "RunStats", "Segment", "antecedent_window", "band_metadata",
           "bytes_per_output_pixel", "histogram_lines", "lonlat_bounds", "open_segment",
           "orthorectify", "precompute", "product_grid"]

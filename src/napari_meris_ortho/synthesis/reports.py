"""Appendix B statistics: one ``ProductReport`` per product, the ``SynthesisResult`` of a run."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..geometry.grid import OutputGrid
    from .store import Pruned

log = logging.getLogger("napari_meris_ortho.synthesis")
#: radiance layers: what their values are
RADIANCE_NOTE = ("TOA radiance (float32, 0 = background) = counts x sf_rad of the merged "
                 "products (Scaling Factor GADS, per product in the product table); no "
                 "further scaling applies")
STATUS_MERGED = "merged"
STATUS_FAILED = "failed"
STATUS_ALREADY = "already in the synthesis"
STATUS_OUTSIDE = "outside the synthesis grid"


# --------------------------------------------------------------------------- reports


@dataclass
class ProductReport:
    """Appendix B statistics of one product merged into the synthesis."""

    path: str
    processed: int = 0  # output pixels with an antecedent in the segment
    validated: int = 0  # ... whose flags allow them into the synthesis
    added: int = 0  # ... that this product holds in the synthesis after the run
    error: str | None = None
    product_name: str = ""
    sensing_start: str = ""
    status: str = STATUS_MERGED
    index: int = 0  # 1-based index in the product table (0: not merged)
    sf_rad: dict[int, float] = field(default_factory=dict)  # radiance factor per band
    #: the product's sensor ("MERIS", "OLCI")
    sensor: str = "MERIS"
    hidden: int = 0  # output pixels on ground hidden from it by the relief (never merged)

    @property
    def product(self) -> str:
        return Path(self.path).name

    def lines(self, synthesis_pixels: int) -> list[str]:
        """The log of Appendix B (processed/validated points, share of the synthesis)."""
        if self.status == STATUS_ALREADY:
            return [f"PRODUCT {self.path}: SKIPPED ({self.product_name} {self.sensing_start} "
                    f"is already in the synthesis)"]
        if self.status == STATUS_OUTSIDE:
            return [f"PRODUCT {self.path}: SKIPPED (no point of its footprint falls on the "
                    "synthesis grid)"]
        if self.error is not None:
            return [f"PRODUCT {self.path}: SKIPPED ({self.error})"]
        total = max(synthesis_pixels, 1)
        seg = max(self.processed, 1)
        return [
            f"PRODUCT {self.path}",
            f"NUMBER OF PROCESSED POINTS IN SEGMENT = {self.processed} "
            f"({100.0 * self.processed / total:.1f}% of synthesis)",
            f"NUMBER OF VALIDATED POINTS IN SEGMENT = {self.validated} "
            f"({100.0 * self.validated / seg:.1f}% of segment) "
            f"({100.0 * self.validated / total:.1f}% of synthesis)",
            f"NUMBER OF ADDED POINTS IN SYNTHESIS = {self.added} "
            f"({100.0 * self.added / total:.1f}% of synthesis)",
            f"NUMBER OF POINTS HIDDEN BY THE RELIEF = {self.hidden} (not merged)",
        ]

    def table_entry(self) -> dict[str, Any]:
        """The product table entry of a merged product: ``sf_rad`` per band of the store
        (the factor of the product band feeding it); ``sensor`` for a product of another
        sensor than MERIS (``bandsets``)."""
        return {"index": self.index, "product_name": self.product_name,
                "product": self.product, "sensing_start": self.sensing_start,
                "sf_rad": {str(b): v for b, v in self.sf_rad.items()}, **self._sensor()}

    def _sensor(self) -> dict[str, str]:
        return {} if self.sensor == "MERIS" else {"sensor": self.sensor}

    def commit_entry(self) -> dict[str, Any]:
        """What the commit metadata says of this product."""
        out: dict[str, Any] = {"product_name": self.product_name, "product": self.product,
                               "sensing_start": self.sensing_start, "status": self.status,
                               **self._sensor()}
        if self.status == STATUS_MERGED:
            out.update(index=self.index, processed=self.processed, validated=self.validated,
                       added=self.added, hidden=self.hidden)
        if self.error is not None:
            out["error"] = self.error
        return out


@dataclass
class SynthesisResult:
    """Outcome of :func:`synthesize`: the store, its new snapshot and one report per product."""

    path: Path
    snapshot: str | None
    grid: OutputGrid
    algorithm: str
    bands: tuple[int, ...]
    reports: list[ProductReport] = field(default_factory=list)
    #: what ``synthesize(keep=N)`` pruned after the commit (None: no pruning)
    pruned: Pruned | None = None

    @property
    def failed(self) -> list[ProductReport]:
        return [r for r in self.reports if r.status == STATUS_FAILED]

    @property
    def merged(self) -> list[ProductReport]:
        return [r for r in self.reports if r.status == STATUS_MERGED]

    @property
    def skipped(self) -> list[ProductReport]:
        """Products already in the synthesis (same product name and sensing time)."""
        return [r for r in self.reports if r.status == STATUS_ALREADY]

    @property
    def outside(self) -> list[ProductReport]:
        """Products whose footprint misses the synthesis grid (nothing to merge)."""
        return [r for r in self.reports if r.status == STATUS_OUTSIDE]


def message_of(exc: BaseException) -> str:
    return str(exc) or type(exc).__name__

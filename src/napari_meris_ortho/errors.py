"""Errors that end in one clear message (CLI exit code 2), never a traceback."""

from __future__ import annotations


class MerisOrthoError(Exception):
    """Base of every error caused by the user's input (files, options, outputs)."""


class N1FormatError(MerisOrthoError, ValueError):
    """An ENVISAT N1 file that cannot be read: truncated, foreign, inconsistent or unsupported."""

    def __init__(self, path: object, problem: str) -> None:
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class GeometryError(MerisOrthoError, ValueError):
    """Geometry the location models cannot use (a tie-point grid too small or not covering the
    product, inconsistent tie-point arrays)."""


class Sen3FormatError(MerisOrthoError, ValueError):
    """A ``.SEN3`` (SAFE) MERIS product that cannot be read: a member file missing, a variable
    absent or of the wrong shape, a foreign directory."""

    def __init__(self, path: object, problem: str) -> None:
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class OlciFormatError(Sen3FormatError):
    """A Sentinel-3 product that is not an OLCI Level 1B (EFR/ERR) one (an OLCI Level 2,
    SYNERGY or SLSTR product...), or an OLCI Level 1B product that cannot be read."""


class DemError(MerisOrthoError):
    """A DEM that cannot be opened or read."""


class OptionsError(MerisOrthoError, ValueError):
    """Inconsistent or invalid options (extent, pixel size, CRS, elevation source...)."""


class OutputError(MerisOrthoError):
    """An output that cannot be written (missing or read-only directory...)."""


class MissingDependencyError(MerisOrthoError, ImportError):
    """An optional dependency (an extra of the package) that a requested feature needs is not
    installed; the message says how to install it."""

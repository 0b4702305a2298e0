"""The Sentinel-3 OLCI instrument of the simulator: cameras, detectors, 21 bands, quality flags.

OLCI images a fan of 5 cameras of 740 detectors each (3700 at full resolution), a field of view
of about 68.5 deg tilted 12.6 deg away from the sun (west on the descending pass), so that at the
ground the view zenith runs from about 24 deg on the east edge to about 57 deg on the west edge.
The Level 1B product resamples the detectors onto a grid regular on the ground (EFR 270 m across
at nadir, 294 m along; ERR 4 x 4 binned: 1080 m, 1176 m): this is the simulator's product grid
(``sensor``: columns evenly spaced along the ground line). Near nadir a detector sees about one
column, towards the west edge one detector feeds up to about three columns: ``detector_index``
names, for every pixel, the detector whose instantaneous field of view holds the pixel's line
of sight (-1: none), and repeated samples carry the ``duplicated`` flag.

A pixel's radiance is the truth at its own line of sight (the simulator's resampling is exact);
the detectors only label the pixels and carry the spectral characterisation
(``instrument_data``: ``lambda0``, ``FWHM``, ``solar_flux`` per band and detector).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..bands import OLCI
from ..products.olci.layout import CAMERAS as N_CAMERAS
from ..products.olci.layout import DETECTORS as N_DETECTORS
from ..products.olci.layout import DETECTORS_PER_CAMERA, EFR
from .radiometry import CLOUD_SPECTRUM, SPECTRA, WAVELENGTHS

#: the full-width product grid (``products.olci.layout.EFR``): the signed ground distance (m)
#: of the east and west edges from the nadir track (positive to the right of the flight
#: direction: west on a descending pass); the field of view of the cameras spans these edges
EFR_FIRST_COLUMN = -1196
SWATH_EDGES_M = (EFR_FIRST_COLUMN * EFR.column_spacing_m,
                 (EFR_FIRST_COLUMN + EFR.width - 1) * EFR.column_spacing_m)

N_BANDS = OLCI.n_bands
#: mean solar flux of the bands (mW m-2 nm-1), a smoothed extraterrestrial spectrum
SOLAR_FLUX = (1714.0, 1742.0, 1903.0, 1957.0, 1920.0, 1803.0, 1652.0, 1531.0, 1498.0, 1472.0,
              1408.0, 1266.0, 1255.0, 1248.0, 1239.0, 1186.0, 958.0, 930.0, 895.0, 825.0, 702.0)
#: radiance scale factor of Oa01 (mW m-2 sr-1 nm-1 per count) as ESA's products store it; the
#: other bands' scale factors follow the solar flux (a count covers the same reflectance)
OA01_SCALE_FACTOR = 0.013946459628641605
SCALE_FACTORS = tuple(OA01_SCALE_FACTOR * f / SOLAR_FLUX[0] for f in SOLAR_FLUX)
#: transmission of the absorption bands: O2 A band (Oa13-Oa15), water vapour (Oa20)
ABSORPTION = {13: 0.42, 14: 0.58, 15: 0.80, 20: 0.55}
#: TOA radiance of the classes (water, vegetation, rock, snow) and of clouds at 400 nm and
#: 1020 nm, where MERIS has no band
EDGE_RADIANCE = {400.0: (74.0, 70.0, 80.0, 165.0, 196.0), 1020.0: (2.5, 62.0, 46.0, 40.0, 88.0)}


def olci_spectra() -> tuple[np.ndarray, np.ndarray]:
    """The class spectra (4, 21) and the cloud spectrum (21,) at the OLCI band centres: the MERIS
    spectra outside the O2 band interpolated linearly in wavelength, the edge values above at 400
    and 1020 nm, then the absorption bands scaled by their transmission."""
    keep = [i for i, w in enumerate(WAVELENGTHS) if not 755.0 < w < 770.0]
    lam = [400.0, *(WAVELENGTHS[i] for i in keep), 1020.0]
    rows = np.vstack([SPECTRA, CLOUD_SPECTRUM[None, :]])
    out = np.empty((rows.shape[0], N_BANDS))
    for r in range(rows.shape[0]):
        values = [EDGE_RADIANCE[400.0][r], *(rows[r, i] for i in keep),
                  EDGE_RADIANCE[1020.0][r]]
        out[r] = np.interp(OLCI.centres, lam, values)
    for band, t in ABSORPTION.items():
        out[:, band - 1] *= t
    return np.ascontiguousarray(out[:-1]), np.ascontiguousarray(out[-1])


OLCI_SPECTRA, OLCI_CLOUD_SPECTRUM = olci_spectra()


#: ``processing_baseline`` from which the quality flags carry one ``saturated`` and one
#: ``partially_saturated`` flag (27 April 2023) instead of one saturation flag per band
SINGLE_SATURATION_BASELINE = (2, 24)


def baseline_of(cfg: dict) -> str:
    """The quality-flag coding of a scene config (``products.olci.layout.FlagBaseline``'s
    values): ``per-band`` for a ``processing_baseline`` below 2.24, else ``2.24``."""
    version = str(cfg.get("processing_baseline", "2.24"))
    major, _, minor = version.partition(".")
    return "per-band" if (int(major), int(minor or 0)) < SINGLE_SATURATION_BASELINE else "2.24"


def duplicated(detector: np.ndarray) -> np.ndarray:
    """True where a pixel repeats the detector sample of its neighbour towards column 0 on the
    same row (the resampling's duplicated pixels)."""
    out = np.zeros(detector.shape, bool)
    out[:, 1:] = (detector[:, 1:] == detector[:, :-1]) & (detector[:, 1:] >= 0)
    return out


@dataclass(frozen=True)
class CameraFan:
    """The 5 cameras' field of view in the in-plane look angle psi (rad, positive to the right
    of the flight direction): from ``psi_east`` to ``psi_west`` (the edges on a descending
    pass). Each camera sees one fifth of it; its 740 detectors are regular in the tangent of the
    angle from the camera's boresight (a flat focal plane). Detectors are numbered from the
    west edge, as ESA's columns run (west to east)."""

    psi_east: float
    psi_west: float

    @property
    def field_of_view_deg(self) -> float:
        return math.degrees(self.psi_west - self.psi_east)

    def detector(self, psi: np.ndarray) -> np.ndarray:
        """Detector (0..3699) whose field of view holds look angle ``psi``; -1 outside."""
        psi = np.asarray(psi, dtype=np.float64)
        width = (self.psi_west - self.psi_east) / N_CAMERAS
        from_west = self.psi_west - psi
        cam = np.floor(from_west / width)
        centre = self.psi_west - (cam + 0.5) * width
        u = np.tan(centre - psi) / math.tan(0.5 * width)
        k = np.floor((u + 1.0) * 0.5 * DETECTORS_PER_CAMERA)
        k = np.clip(k, 0, DETECTORS_PER_CAMERA - 1)
        det = (cam * DETECTORS_PER_CAMERA + k).astype(np.int64)
        tol = 1e-12
        outside = (psi < self.psi_east - tol) | (psi > self.psi_west + tol)
        det = np.where(outside, -1, np.clip(det, 0, N_DETECTORS - 1))
        return det.astype(np.int16)


def instrument_data(seed: int) -> dict[str, np.ndarray]:
    """``lambda0``, ``FWHM`` (nm) and ``solar_flux`` (mW m-2 nm-1) per band and detector
    (float32 (21, 3700)): the band centres with a smile of up to 1.2 nm along each camera and a
    camera-to-camera offset, the widths within 3 %, the solar flux at lambda0."""
    rng = np.random.default_rng(seed + 4099)
    x = (np.arange(DETECTORS_PER_CAMERA) + 0.5) / DETECTORS_PER_CAMERA * 2.0 - 1.0
    smile = np.tile(1.2 * x * x, N_CAMERAS)
    offsets = np.repeat(rng.uniform(-0.3, 0.3, N_CAMERAS), DETECTORS_PER_CAMERA)
    lam = np.asarray(OLCI.centres)[:, None] + (smile + offsets)[None, :]
    fwhm = np.asarray(OLCI.widths)[:, None] * np.tile(1.0 + 0.03 * np.cos(np.pi * x),
                                                         N_CAMERAS)[None, :]
    # solar flux slope around each band centre from the neighbouring bands
    flux = np.asarray(SOLAR_FLUX)
    slope = np.gradient(flux, np.asarray(OLCI.centres))
    sun = flux[:, None] + slope[:, None] * (lam - np.asarray(OLCI.centres)[:, None])
    return {"lambda0": lam.astype(np.float32), "FWHM": fwhm.astype(np.float32),
            "solar_flux": sun.astype(np.float32)}

"""MERIS fourth-reprocessing Level 1 products in the Sentinel-3-like SAFE layout (``.SEN3``).

``ENV_ME_1_FRG____<start>_<stop>_..._R_NT____.SEN3`` (FR) / ``ENV_ME_1_RRG____...`` (RR), also
named ``EN1_MDSI_MER_FRS_1P_...``/``EN1_MDSI_MER_RR__1P_...``: a directory (or a ``.zip``
archive of it) of netCDF-4 files and an ``xfdumanifest.xml`` (format spec MER4RP-PFS-001-ACR;
file and variable names as satpy's ``meris_nc_sen3``/``olci_l1b``, SNAP's Sentinel-3 reader and
NASA's ``l1_safe`` read them):

===========================  ===========================================================
``Mnn_radiance.nc``           ``Mnn_radiance`` (rows, columns) uint16, ``scale_factor``,
                              ``add_offset`` 0, ``_FillValue`` 65535, mW.m-2.sr-1.nm-1
``geo_coordinates.nc``        per-pixel ``latitude``/``longitude`` int32 x 1e-6 deg and
                              ``altitude`` int16 m: the *terrain-corrected* position
``instrument_data.nc``        ``detector_index`` (rows, columns) int16; ``solar_flux``,
                              ``lambda0``, ``FWHM`` (bands, detectors)
``qualityFlags.nc``           ``quality_flags`` uint32, CF ``flag_masks``/``flag_meanings``
``tie_geo_coordinates.nc``    tie-point ``latitude``/``longitude`` (ellipsoid) and ``altitude``
``tie_geometries.nc``         ``SZA``, ``OZA`` uint32 and ``SAA``, ``OAA`` int32 (-180..180],
                              x 1e-6 deg; global ``al_subsampling_factor`` (lines per tie point)
                              and ``ac_subsampling_factor`` (columns per tie point)
``tie_meteo.nc``              ``horizontal_wind`` (.., wind_vectors) m s-1, ``sea_level_pressure``
                              hPa, ``total_ozone`` kg m-2, ``humidity`` % (optional, each)
``time_coordinates.nc``       ``time_stamp`` (rows) int64 microseconds since 2000-01-01 (read
                              in its own CF ``units``; 0 or less: no time)
===========================  ===========================================================

Rooms: ``layout`` (names, column order, CF decoding, flag coding), ``members`` (a directory or a
zip archive), ``reader`` (:func:`read_sen3`), ``writer`` (:func:`write_sen3`).
"""

from .layout import (
    GEO_FILE,
    INSTRUMENT_FILE,
    MANIFEST,
    QUALITY_FILE,
    QUALITY_FLAGS,
    SEN3_TYPES,
    TIE_GEO_FILE,
    TIE_GEOMETRY_FILE,
    TIE_METEO_FILE,
    TIME_FILE,
    cf_decode,
    flag_coding,
    l1b_to_quality,
    mirror_columns,
    quality_to_l1b,
    radiance_file,
    radiance_variable,
    required_files,
)
from .members import is_sen3
from .reader import MerisSen3Product, manifest_summary, read_sen3
from .writer import default_sen3_name, write_sen3

__all__ = [
    "GEO_FILE", "INSTRUMENT_FILE", "MANIFEST", "QUALITY_FILE", "QUALITY_FLAGS", "SEN3_TYPES",
    "TIE_GEOMETRY_FILE", "TIE_GEO_FILE", "TIE_METEO_FILE", "TIME_FILE", "MerisSen3Product",
    "cf_decode", "default_sen3_name", "flag_coding", "is_sen3", "l1b_to_quality",
    "manifest_summary", "mirror_columns", "quality_to_l1b", "radiance_file", "radiance_variable",
    "read_sen3", "required_files", "write_sen3",
]

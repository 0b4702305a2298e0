"""``meris-ortho info PRODUCT.N1``: the decoded MPH/SPH summary, the data sets and a tie-point
table like the handbook's Appendix A and E (first and last tie point of every 8th tie-point line,
and of the last one). A file that is not a readable MERIS L1b or OLCI Level 1B product: one
message, exit code 2. ``.SEN3`` directories (MERIS and OLCI): the member files instead of the
DSDs; FRG/FSG and SEN3 products: the extent of their per-pixel geolocation; OLCI: its 21 bands,
the quality-flag coding and every 512th row of its tie points (on every row).
"""

from __future__ import annotations

import argparse
import math
from typing import Any

import numpy as np

from .._terminal import printable
from ..products.n1 import FLAG_NAMES, MerisL1bProduct
from ..products.n1.format import EPOCH_2000
from ..products.open import read_product
from ..products.protocol import MerisProduct
from ._options import positive_int

_RESOLUTION_NAMES = {"FR": "full resolution", "RR": "reduced resolution"}


def register(subparsers: Any) -> None:
    """Add the ``info`` subcommand."""
    p = subparsers.add_parser(
        "info",
        help="describe a MERIS L1b or OLCI Level 1B product (headers, data sets, tie points)",
        description="Print the decoded main and specific product headers of a MERIS L1b N1 "
        "product, its data set descriptors and a tie-point table like the handbook's "
        "Appendix A (first and last tie point of every 8th tie-point line); for a .SEN3 "
        "product (MERIS or OLCI) its member files instead of the data sets.",
    )
    p.add_argument(
        "product", metavar="PRODUCT", help="MERIS L1b product: N1 file (MER_FR__1P, "
        "MER_RR__1P, MER_FRG_1P, MER_FSG_1P, MER_RRG_1P...) or .SEN3 directory (ME_1_FRG___, "
        "ME_1_RRG___), or OLCI Level 1B .SEN3 directory or zip (OL_1_EFR___, OL_1_ERR___)"
    )
    p.add_argument(
        "--every",
        type=positive_int("a positive integer"),
        default=None,
        metavar="N",
        help="tie-point lines in the table: 1, 1+N, 1+2N, ... and the last (default 8; 512 "
        "for OLCI, whose tie points are on every row)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    product = read_product(args.product)
    every = args.every or (8 if product.lines_per_tie_point > 1 else 512)
    print("\n".join(printable(line) for line in describe(product, every=every)))
    return 0


#: record times ``info`` converts to dates: years 1900..2200 (others print as a number only)
_UTC_RANGE_S = (-3.2e9, 6.4e9)


def _utc(seconds: float) -> str:
    if not (math.isfinite(seconds) and _UTC_RANGE_S[0] < seconds < _UTC_RANGE_S[1]):
        return "(not a valid time)"
    t = EPOCH_2000 + np.timedelta64(int(round(seconds * 1e6)), "us")
    return str(t).replace("T", " ") + " UTC"


def describe(product: MerisProduct, every: int = 8) -> list[str]:
    """The lines ``meris-ortho info`` prints."""
    mph, sph = product.mph, product.sph
    res = _RESOLUTION_NAMES.get(product.resolution.name, product.resolution.name)
    members: Any = getattr(product, "members", None)  # a .SEN3 (products.sen3.Members)
    is_dir = members is not None
    size = (sum(members.sizes().values()) if is_dir and not members.archived
            else product.path.stat().st_size)
    times = product.line_times
    lines = [
        f"Product        {product.product_name}",
        f"File           {product.path} ({size} bytes)",
        f"Product type   {product.product_type} ({_level(product)}, {res})",
        f"Size           {product.width} columns x {product.height} lines",
        f"Tie points     {product.n_tie_columns} columns x {product.n_tie_lines} lines, every "
        f"{product.samples_per_tie_point} samples and {product.lines_per_tie_point} lines",
        f"First line     {_utc(times[0])}  ({times[0]:.6f} s since 2000-01-01)",
        f"Last line      {_utc(times[-1])}",
        f"Line interval  {product.line_interval_s:.6f} s",
        f"Processing     {mph.get('PROC_CENTER', '?')}, {mph.get('SOFTWARE_VER', '?')}, "
        f"{mph.get('PROC_TIME', '?')} (stage {mph.get('PROC_STAGE', '?')})",
        f"Sensing        {mph.get('SENSING_START', '?')} to {mph.get('SENSING_STOP', '?')}",
        f"Orbit          phase {mph.get('PHASE', '?')}, cycle {mph.get('CYCLE', '?')}, "
        f"relative orbit {mph.get('REL_ORBIT', '?')}, absolute orbit {mph.get('ABS_ORBIT', '?')}",
        _headers_line(product),
        *_geolocation_lines(product),
        "",
        "Corners (lat, lon)  first sample            middle sample           last sample",
    ]
    for which in ("FIRST", "LAST"):
        cells = []
        for col in ("FIRST", "MID", "LAST"):
            lat, lon = sph.get(f"{which}_{col}_LAT"), sph.get(f"{which}_{col}_LONG")
            if isinstance(lat, int) and isinstance(lon, int):
                cells.append(f"({lat * 1e-6:.6f}, {lon * 1e-6:.6f})")
            else:
                cells.append("?")
        row = f"  {which.lower()} line".ljust(20) + "".join(c.ljust(24) for c in cells)
        lines.append(row.rstrip())
    sf = product.scaling
    if str(getattr(product, "sensor", "MERIS")) == "MERIS":  # the Scaling Factor GADS
        lines += [
            "",
            f"Scaling factors  altitude {sf.altitude:g}, roughness {sf.roughness:g}, "
            f"zonal wind {sf.zonal_wind:g}, meridional wind {sf.merid_wind:g}, "
            f"pressure {sf.atm_pressure:g}, ozone {sf.ozone:g}, humidity {sf.rel_humidity:g}",
            f"Sampling rate    {sf.sampling_rate_us} (1e-6 s)",
        ]
    lines += ["", "Band  wavelength  bandwidth  radiance factor  sun flux"]
    for b in range(_n_bands(product)):
        lines.append(
            f"{b + 1:>4}  {product.wavelengths[b]:8.3f} nm {product.bandwidths[b]:6.3f} nm  "
            f"{sf.radiance[b]:15.6f}  {sf.sun_flux[b]:9.3f}"
        )
    bits = ", ".join(f"{name}={1 << i}" for i, name in enumerate(FLAG_NAMES))
    if is_dir:
        return lines + ["", f"Flags (mapped from quality_flags)  {bits}", *_coding_lines(product),
                        "",
                        *_member_lines(product), "", "Tie points (tie_geo_coordinates.nc, "
                        "tie_geometries.nc; first and last tie point of the tie-point lines)",
                        *tie_point_table(product, every)]
    lines += ["", f"Flags (Flags MDS(16))  {bits}", "", "Data sets"]
    lines.append("  #  DS_NAME                       T  DS_OFFSET   DS_SIZE  NUM_DSR  DSR_SIZE")
    assert isinstance(product, MerisL1bProduct)  # an N1 file (not a .SEN3 directory)
    for i, d in enumerate(product.dsds, start=1):
        if d.is_spare:
            lines.append(f"{i:>3}  (spare)")
        elif d.type == "R":
            lines.append(f"{i:>3}  {d.name:<28}  R  {d.filename}")
        else:
            lines.append(
                f"{i:>3}  {d.name:<28}  {d.type}  {d.offset:>9}  {d.size:>9}  {d.num_dsr:>7}  "
                f"{d.dsr_size:>8}"
            )
    lines += ["", 'DATA SET "Tie points ADS" (first and last tie point of the tie-point lines)']
    lines += tie_point_table(product, every)
    return lines


def _level(product: MerisProduct) -> str:
    """"MERIS Level 1b", "OLCI Level 1B (Sentinel-3A)"."""
    sensor = str(getattr(product, "sensor", "MERIS"))
    if sensor == "MERIS":
        return "MERIS Level 1b"
    name = product.product_name
    platform = f" (Sentinel-3{name[2]})" if name[:2] == "S3" and name[2:3] in "AB" else ""
    return f"{sensor} Level 1B{platform}, {_n_bands(product)} bands"


def _n_bands(product: MerisProduct) -> int:
    return int(getattr(product, "n_bands", 15))


def _coding_lines(product: MerisProduct) -> list[str]:
    """The quality-flag baseline of an OLCI product, else nothing."""
    baseline = getattr(product, "baseline", None)
    if baseline is None:
        return []
    text = ("saturated_Oa01..Oa21 per band (before processing baseline 2.24)"
            if baseline == "per-band" else
            "saturated, partially_saturated (baseline 2.24 on; saturated samples are fill)")
    return [f"Quality flags  {text}"]


def _headers_line(product: MerisProduct) -> str:
    mph = product.mph
    members = getattr(product, "members", None)  # a .SEN3 (products.sen3.Members)
    if members is not None:
        kind = "zip archive" if members.archived else "directory"
        return f"Format         SAFE .SEN3 {kind}, {len(members.sizes())} files"
    return (f"Headers        MPH 1247 bytes, SPH {mph['SPH_SIZE']} bytes, {mph['NUM_DSD']} DSDs, "
            f"{mph.get('NUM_DATA_SETS', '?')} data sets, total {mph['TOT_SIZE']} bytes")


def _geolocation_lines(product: MerisProduct) -> list[str]:
    """Extent of the per-pixel terrain-corrected geolocation (FRG/FSG, SEN3), else nothing."""
    if not getattr(product, "has_pixel_geolocation", False):
        return []
    lon, lat = product.pixel_longitude(), product.pixel_latitude()
    alt = product.pixel_altitude()
    return [f"Geolocation    per pixel, terrain-corrected: lat {np.nanmin(lat):.6f} .. "
            f"{np.nanmax(lat):.6f}, lon {np.nanmin(lon):.6f} .. {np.nanmax(lon):.6f}, "
            f"altitude {np.nanmin(alt):.0f} .. {np.nanmax(alt):.0f} m "
            "(map with --geolocation pixel)"]


def _member_lines(product: MerisProduct) -> list[str]:
    """The member files of a .SEN3 directory or archive with their sizes."""
    members: Any = getattr(product, "members", None)
    out = ["Member files"]
    for name, size in members.sizes().items():
        out.append(f"  {name:<28} {size:>12} bytes")
    return out


def tie_point_table(product: MerisProduct, every: int = 8) -> list[str]:
    """Appendix A/E tie-point table: for tie-point lines 1, 1+every, ... and the last one, the
    date (s since 2000-01-01), then for the FIRST and LAST tie point: (lat, lon), altitude,
    roughness, latitude and longitude corrections (1e-6 deg), sun and view (zenith, azimuth)."""
    tp = product.tie_points
    n = product.n_tie_lines
    rows = sorted(set(range(0, n, every)) | {n - 1})
    head = "No.  Date              "
    part = "{:<24}{:>6} {:>6}  {:>14}  {:>15}  {:<14}  {:<14}"
    title = part.format("(Lat., Lon.)", "Alt.", "Rough.", "Corr. Lat.", "Corr. Lon.",
                        "Sun (Zen., Azi.)", "View (Zen., Azi.)")  # fmt: skip
    out = [head + "FIRST " + title + "   LAST " + title]
    for i in rows:
        cells = []
        for k in (0, product.n_tie_columns - 1):
            cells.append(
                part.format(
                    f"({tp['latitude'][i, k]:.6f}, {tp['longitude'][i, k]:.6f})",
                    f"{tp['dem_alt'][i, k]:.0f}",
                    f"{tp['dem_rough'][i, k]:.0f}",
                    f"{round(tp['lat_corr'][i, k] * 1e6):d} 1e-6",
                    f"{round(tp['lon_corr'][i, k] * 1e6):d} 1e-6",
                    f"({tp['sun_zenith'][i, k]:.1f}, {tp['sun_azimuth'][i, k]:.1f})",
                    f"({tp['view_zenith'][i, k]:.1f}, {tp['view_azimuth'][i, k]:.1f})",
                )
            )
        row = f"{i + 1:<4} {product.tie_point_times[i]:<17.6f} " + "      ".join(cells)
        out.append(row.rstrip())
    return out

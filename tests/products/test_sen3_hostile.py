"""``.SEN3`` products that differ from what our writer makes, as real or hostile files do:
radiances packed in other integer types or unpacked, packing
attributes that are not one number, non-finite geolocation, damaged zip archives. Each is read
with correct values, masked with a warning that counts what was masked, or refused with one
:class:`Sen3FormatError` (CLI exit 2, nothing written). Files are altered with netCDF4 directly
from ``sen3_real`` (written from ESA's documented facts, not by our writer)."""

from __future__ import annotations

import logging
import shutil
import zipfile
from pathlib import Path

import netCDF4
import numpy as np
import pytest
import sen3_real as real

from napari_meris_ortho.cli import main
from napari_meris_ortho.errors import Sen3FormatError
from napari_meris_ortho.products.open import read_product


@pytest.fixture(scope="module")
def product_dir(tmp_path_factory):
    return real.write_real_like(tmp_path_factory.mktemp("real"))


@pytest.fixture(scope="module")
def original(product_dir):
    p = read_product(product_dir)
    return {"M07": p.radiance(7), "lat": p.pixel_latitude()}


@pytest.fixture
def copy(product_dir, tmp_path):
    dst = tmp_path / product_dir.name
    shutil.copytree(product_dir, dst)
    return dst


def _copy(path: Path, name: str, write=None) -> None:
    """Rewrite ``path`` with its global attributes, dimensions and every variable but ``name``
    as stored; ``write(dataset, variable)`` writes ``name`` anew (None: it is left out)."""
    tmp = path.with_suffix(".tmp")
    with netCDF4.Dataset(path) as a, netCDF4.Dataset(tmp, "w") as b:
        b.setncatts({k: a.getncattr(k) for k in a.ncattrs()})
        for dim, d in a.dimensions.items():
            b.createDimension(dim, len(d))
        for vn, v in a.variables.items():
            if vn == name:
                if write is not None:
                    write(b, v)
                continue
            v.set_auto_maskandscale(False)
            at = {k: v.getncattr(k) for k in v.ncattrs()}
            nv = b.createVariable(vn, v.dtype, v.dimensions, fill_value=at.pop("_FillValue", None))
            nv.set_auto_maskandscale(False)
            nv.setncatts(at)
            nv[...] = v[...]
    tmp.replace(path)


def _rewrite(path: Path, name: str, dtype: str, fill, **attrs) -> None:
    """Rewrite variable ``name`` of ``path`` as ``dtype`` holding the same physical values
    (``attrs``: its new scale_factor/add_offset), ``fill`` where they are no data."""
    def repack(b, v) -> None:
        v.set_auto_maskandscale(True)  # the old packing decoded
        at = {k: v.getncattr(k) for k in v.ncattrs()}
        at.pop("_FillValue", None)
        phys = np.ma.filled(v[...].astype(np.float64), np.nan)
        for k in ("scale_factor", "add_offset", "valid_min", "valid_max"):
            at.pop(k, None)
        at.update(attrs)
        nv = b.createVariable(v.name, dtype, v.dimensions, fill_value=fill)
        nv.set_auto_maskandscale(False)
        nv.setncatts(at)
        packed = (phys - float(attrs.get("add_offset", 0.0))) / float(
            attrs.get("scale_factor", 1.0))
        if np.dtype(dtype).kind in "iu":
            packed = np.round(packed)
        packed[np.isnan(phys)] = fill
        nv[...] = packed.astype(dtype)

    _copy(path, name, repack)


def _set(path: Path, name: str, index, value) -> None:
    with netCDF4.Dataset(path, "a") as ds:
        v = ds.variables[name]
        v.set_auto_maskandscale(False)
        v[index] = value


def _cli(args: list[str], capsys) -> tuple[int, str]:
    rc = main(args)
    return rc, capsys.readouterr().err


def test_a_signed_16_bit_radiance_fill_is_no_data(copy, original):
    """int16 radiances with _FillValue -1 (scale 0.01): the fill pixels are NaN, never the
    65535 x 0.01 = 655.35 a uint16 cast makes of them; the others keep their values."""
    f = copy / "M07_radiance.nc"
    _rewrite(f, "M07_radiance", "i2", np.int16(-1), scale_factor=np.float32(0.01))
    _set(f, "M07_radiance", (5, slice(5, 10)), np.int16(-1))
    p = read_product(copy)
    r = p.radiance(7)
    n1_cols = real.WIDTH - 1 - np.arange(5, 10)
    assert np.isnan(r[5, n1_cols]).all()
    assert np.nanmax(r) < 100.0  # the field is 40 +- 20 + 7
    ok = ~np.isnan(original["M07"])
    ok[5, n1_cols] = False
    np.testing.assert_allclose(r[ok], original["M07"][ok], atol=0.0051)
    assert (p.counts(7)[5, n1_cols] == p.no_data_count(7)).all()


def test_unpacked_float_radiances_are_one_error(copy, capsys, tmp_path):
    f = copy / "M07_radiance.nc"
    _rewrite(f, "M07_radiance", "f4", np.float32(np.nan))
    with pytest.raises(Sen3FormatError, match=r"M07_radiance is stored as float32"):
        read_product(copy)
    out = tmp_path / "m.tif"
    rc, err = _cli(["-q", "map", str(copy), "--bands", "7", "-o", str(out)], capsys)
    assert rc == 2 and err.count("\n") == 1 and "float32" in err
    assert not out.exists()


def test_packing_attributes_must_be_one_number(copy):
    with netCDF4.Dataset(copy / "geo_coordinates.nc", "a") as ds:
        ds.variables["latitude"].scale_factor = np.array([1e-6, 1e-6])
    with pytest.raises(Sen3FormatError, match=r"geo_coordinates.nc: scale_factor of 'latitude' "
                                              r"is not one number"):
        read_product(copy)


def test_non_finite_geolocation_is_masked_and_counted(copy, original, caplog):
    f = copy / "geo_coordinates.nc"
    _rewrite(f, "latitude", "f8", np.float64(-999.0))
    _rewrite(f, "longitude", "f8", np.float64(-999.0))
    _set(f, "latitude", (10, 10), np.nan)
    _set(f, "latitude", (11, 11), np.inf)
    _set(f, "latitude", (12, 12), -999.0)
    _set(f, "longitude", (13, 13), np.nan)
    p = read_product(copy)
    with caplog.at_level(logging.WARNING):
        lat, lon = p.pixel_latitude(), p.pixel_longitude()
    assert np.isnan(lat).sum() == 3 and np.isnan(lon).sum() == 1
    assert "3 of 1812657 latitudes" in caplog.text and "1 of 1812657 longitudes" in caplog.text
    ok = ~np.isnan(lat)
    np.testing.assert_allclose(lat[ok], original["lat"][ok], atol=1e-6)


def _zip(src: Path, dst: Path) -> Path:
    with zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(src.iterdir()):
            z.write(f, f"{src.name}/{f.name}")
    return dst


def test_a_corrupt_member_of_a_zip_is_one_error(product_dir, tmp_path, capsys):
    archive = _zip(product_dir, tmp_path / (product_dir.name + ".zip"))
    data = bytearray(archive.read_bytes())
    with zipfile.ZipFile(archive) as z:
        info = z.getinfo(f"{product_dir.name}/M07_radiance.nc")
    start = info.header_offset + 30 + len(info.filename.encode()) + 200
    data[start:start + 300] = bytes(b ^ 0x5A for b in data[start:start + 300])
    archive.write_bytes(bytes(data))
    with pytest.raises(Sen3FormatError, match=r"\.zip!M07_radiance\.nc: cannot read"):
        read_product(archive)
    out = tmp_path / "m.tif"
    rc, err = _cli(["-q", "map", str(archive), "--bands", "7", "-o", str(out)], capsys)
    assert rc == 2 and err.count("\n") == 1 and "M07_radiance.nc: cannot read" in err
    assert not out.exists()


def test_a_truncated_zip_says_so(product_dir, tmp_path):
    archive = _zip(product_dir, tmp_path / (product_dir.name + ".zip"))
    archive.write_bytes(archive.read_bytes()[:-30])
    with pytest.raises(Sen3FormatError, match="truncated or damaged zip archive"):
        read_product(archive)


def _declare_m01(copy: Path, rows: int, columns: int) -> None:
    """M01_radiance.nc declaring rows x columns pixels, never written (a few kB on disk)."""
    f = copy / "M01_radiance.nc"
    with netCDF4.Dataset(f) as a:
        v = a.variables["M01_radiance"]
        attrs = {k: v.getncattr(k) for k in v.ncattrs() if k != "_FillValue"}
        glob = {k: a.getncattr(k) for k in a.ncattrs()}
    f.unlink()
    with netCDF4.Dataset(f, "w") as b:
        b.setncatts(glob)
        b.createDimension("rows", rows)
        b.createDimension("columns", columns)
        v = b.createVariable("M01_radiance", "u2", ("rows", "columns"), zlib=True,
                             chunksizes=(256, 256), fill_value=np.uint16(65535))
        v.setncatts(attrs)


@pytest.mark.parametrize(("rows", "columns", "message"), [
    (40_000, 1121, r"40000 rows: more lines than one orbit \(34661 RR lines\)"),
    (1617, 300_001, r"300001 columns: a ME_1_RRG___ line has at most 1121 columns"),
])
def test_dimensions_no_meris_product_has_are_refused_before_any_read(copy, rows, columns,
                                                                      message):
    """A file of a few kB declaring more lines than one orbit or wider lines than the
    instrument's (a forged product: info would allocate 8 bytes per pixel) is refused at open,
    as N1 products are (``products/n1/checks``)."""
    _declare_m01(copy, rows, columns)
    with pytest.raises(Sen3FormatError, match=message):
        read_product(copy)


def test_a_product_type_that_contradicts_the_detectors_is_refused(tmp_path):
    """The manifest says FR (ME_1_FRG___) over an RR product (925 detectors): refused, not
    mapped with FR's pixel size and timing."""
    d = real.write_real_like(tmp_path, manifest_type="ME_1_FRG___")
    with pytest.raises(Sen3FormatError, match=r"ME_1_FRG___ product, but instrument_data.nc "
                                              r"has 925 detectors \(RR\)"):
        read_product(d)


@pytest.mark.parametrize("stamp", [2**62, -(2**63)])
def test_time_stamps_outside_meris_years_are_interpolated_with_a_count(copy, product_dir, stamp,
                                                                      caplog):
    """time_stamp (microseconds since 2000) of year 146 000 or the int64 minimum (was a
    ValueError from the date formatting): interpolated from the valid rows, with a warning
    that counts them; no valid stamps at all is one error."""
    f = copy / "time_coordinates.nc"
    _set(f, "time_stamp", slice(0, 3), np.int64(stamp))
    _set(f, "time_stamp", 700, np.int64(stamp))
    with caplog.at_level(logging.WARNING):
        times = read_product(copy).line_times
    assert "4 of 1617 time_stamp values" in caplog.text
    np.testing.assert_allclose(times, read_product(product_dir).line_times, rtol=0, atol=1e-6)
    _set(f, "time_stamp", slice(None), np.int64(stamp))
    with pytest.raises(Sen3FormatError, match=r"time_coordinates.nc: 1617 of 1617 time_stamp "
                                              r"values are fill or not MERIS times"):
        read_product(copy)


def test_radiance_fill_pixels_are_counted_in_a_warning(copy, caplog):
    """Fill radiances are no data, and the user is told how many, once per band (the
    product's own fill pixel in M07 plus a 10 x 10 block)."""
    _set(copy / "M07_radiance.nc", "M07_radiance", (slice(100, 110), slice(200, 210)),
         np.uint16(65535))
    p = read_product(copy)
    with caplog.at_level(logging.WARNING):
        r = p.radiance(7)
        p.radiance(7)
        p.radiance(5)
    assert np.isnan(r).sum() == 101
    assert caplog.text.count("101 of 1812657 M07_radiance values") == 1
    assert "M05_radiance" not in caplog.text


def test_an_archive_reads_its_band_members_ahead_in_threads(product_dir, tmp_path):
    """Opening a zip archive inflates its 15 band members in reading threads, in order and at
    most ``READ_AHEAD`` + 1 at a time (``Members.read_ahead``); the product read from the
    archive equals the one read from its directory."""
    import threading

    from napari_meris_ortho.products.sen3.layout import radiance_file
    from napari_meris_ortho.products.sen3.members import READ_AHEAD, Members

    archive = _zip(product_dir, tmp_path / (product_dir.name + ".zip"))
    members = Members(archive)
    names = [radiance_file(b) for b in range(1, 16)]
    threads, held, most = [], [0], [0]
    read_bytes = members.read_bytes

    def reading(name: str) -> bytes:
        threads.append(threading.current_thread().name)
        held[0] += 1
        most[0] = max(most[0], held[0])
        return read_bytes(name)

    members.read_bytes = reading  # type: ignore[method-assign]
    got = []
    for data in members.read_ahead(names):
        got.append(data)
        held[0] -= 1
    with zipfile.ZipFile(archive) as z:
        assert got == [z.read(f"{product_dir.name}/{n}") for n in names]
    assert len(threads) == 15 and all(t.startswith("sen3-read") for t in threads)
    assert most[0] <= READ_AHEAD + 1
    assert list(Members(product_dir).read_ahead(names)) == [None] * 15

    zipped, plain = read_product(archive), read_product(product_dir)
    assert zipped.scaling == plain.scaling and zipped.dtypes == plain.dtypes
    np.testing.assert_array_equal(zipped.counts(9), plain.counts(9))


def _damage_deflate_streams(path: Path) -> int:
    """XOR a few bytes inside every zlib stream (netCDF-4 deflate chunk) of ``path``, as a bad
    disk or an interrupted copy would; the file's HDF5 metadata stays intact. Returns how many
    streams were damaged."""
    import zlib

    data = bytearray(path.read_bytes())
    starts, i = [], 0
    while (i := data.find(b"\x78\x01", i)) >= 0:
        try:
            d = zlib.decompressobj()
            if len(d.decompress(bytes(data[i:i + 65536]))) >= 64:
                starts.append((i, len(data) - len(d.unused_data) - i if d.eof else 64))
        except zlib.error:
            pass
        i += 2
    for start, size in starts:
        mid = start + max(size // 2, 8)
        data[mid:mid + 8] = bytes(b ^ 0x5A for b in data[mid:mid + 8])
    path.write_bytes(bytes(data))
    return len(starts)


@pytest.mark.parametrize("member", ["time_coordinates.nc", "tie_geometries.nc",
                                    "tie_geo_coordinates.nc", "instrument_data.nc"])
def test_a_damaged_annotation_member_is_one_error(copy, member, tmp_path, capsys):
    """A directory product whose annotation member has a damaged data chunk (netCDF raises
    RuntimeError "NetCDF: HDF error"): one Sen3FormatError naming the member, exit 2 from the
    CLI, not a traceback (the band members were already handled so)."""
    assert _damage_deflate_streams(copy / member) >= 1
    with pytest.raises(Sen3FormatError, match=rf"{member}: cannot read"):
        read_product(copy)
    rc, err = _cli(["-q", "info", str(copy)], capsys)
    assert rc == 2 and err.count("\n") == 1 and f"{member}: cannot read" in err
    assert "Traceback" not in err


def test_signed_flag_masks_mean_the_same_bits(copy, product_dir):
    """quality_flags whose flag_masks are stored as int32 (land = -2**31, as a NETCDF4_CLASSIC
    rewrite has them) decode to the same L1b flags as ESA's uint32 masks (no raw
    OverflowError)."""
    from napari_meris_ortho.flags import FLAG_LAND_OCEAN

    path = copy / "qualityFlags.nc"
    with netCDF4.Dataset(path, "a") as ds:
        v = ds.variables["quality_flags"]
        masks = np.asarray(v.getncattr("flag_masks")).astype(np.int64)
        v.setncattr("flag_masks", masks.astype(np.uint32).view(np.int32))
    with netCDF4.Dataset(path) as ds:
        assert np.asarray(ds.variables["quality_flags"].getncattr("flag_masks")).min() < 0
    signed, unsigned = read_product(copy).flags, read_product(product_dir).flags
    assert (unsigned & FLAG_LAND_OCEAN).any()
    np.testing.assert_array_equal(signed, unsigned)


def test_flag_meanings_as_an_array_of_strings(copy, product_dir):
    """flag_meanings stored as an array of strings (one meaning each; an NC_STRING array)
    decodes to the same flags (the array's repr split into words can count as many as the
    masks, and every flag would read 0)."""
    from napari_meris_ortho.flags import FLAG_INVALID, FLAG_LAND_OCEAN
    from napari_meris_ortho.products.sen3.layout import flag_coding

    path = copy / "qualityFlags.nc"
    with netCDF4.Dataset(path, "a") as ds:
        v = ds.variables["quality_flags"]
        words = str(v.getncattr("flag_meanings")).split()
        v.setncattr_string("flag_meanings", words)
    with netCDF4.Dataset(path) as ds:
        assert not isinstance(ds.variables["quality_flags"].getncattr("flag_meanings"), str)
    as_array, plain = read_product(copy).flags, read_product(product_dir).flags
    assert (plain & FLAG_LAND_OCEAN).any() and (plain & FLAG_INVALID).any()
    np.testing.assert_array_equal(as_array, plain)
    coding = flag_coding({"flag_masks": [1, 2], "flag_meanings": np.array([b"a", b"b"])})
    assert coding == {"a": 1, "b": 2}


def test_humidity_on_pressure_levels_is_left_out(copy, product_dir, caplog):
    """``humidity`` on (tie_rows, tie_columns, pressure levels), as OLCI's tie_meteo has it
    and SNAP's MERIS 4RP adapter reads it: the N1 annotation has no levels, so it is left NaN
    (logged) and the rest of the product reads as usual, not refused ("rel_humidity of shape
    (6, 9, 25)")."""
    path = copy / "tie_meteo.nc"
    with netCDF4.Dataset(path) as ds:  # the real-like file has the temperature profile's levels
        rows, cols = (len(ds.dimensions[d]) for d in ds.variables["humidity"].dimensions)
        n = len(ds.dimensions["tie_pressure_levels"])

    def levels(b, v):
        nv = b.createVariable("humidity", "f4", (*v.dimensions, "tie_pressure_levels"))
        nv.setncatts({"units": "%", "long_name": "Relative humidity"})
        nv[:] = np.full((rows, cols, n), 60.0, np.float32)

    _copy(path, "humidity", levels)
    with caplog.at_level(logging.INFO, logger="napari_meris_ortho"):
        p = read_product(copy)
    plain = read_product(product_dir)
    assert np.isnan(p.tie_points["rel_humidity"]).all()
    assert not np.isnan(plain.tie_points["rel_humidity"]).any()
    np.testing.assert_array_equal(p.tie_points["ozone"], plain.tie_points["ozone"])
    np.testing.assert_array_equal(p.counts(7), plain.counts(7))
    assert f"humidity has shape ({rows}, {cols}, {n})" in caplog.text


def _without(path: Path, name: str) -> None:
    """Rewrite ``path`` without variable ``name`` (everything else as stored)."""
    _copy(path, name)


def test_a_tie_grid_without_altitude_takes_the_pixels_altitude(copy, caplog):
    """tie_geo_coordinates.nc without ``altitude`` (no format description at hand says that
    member holds it): the tie points' heights are geo_coordinates.nc's altitude at the tie
    points (line 16 k, column 16 j in the file, then in N1 column order), with a warning; the
    product is not refused ("has no variable 'altitude'")."""
    with netCDF4.Dataset(copy / "geo_coordinates.nc") as ds:
        h, w = ds.variables["altitude"].shape
    rows, cols = np.mgrid[0:h, 0:w]
    heights = ((3 * rows + cols) % 2900).astype(np.int16)
    _set(copy / "geo_coordinates.nc", "altitude", slice(None), heights)
    _without(copy / "tie_geo_coordinates.nc", "altitude")
    with caplog.at_level(logging.WARNING):
        p = read_product(copy)
    assert "has no tie-point altitude" in caplog.text
    step = real.STEP
    lines = np.minimum(np.arange(p.tie_points["dem_alt"].shape[0]) * step, h - 1)
    expected = heights[np.ix_(lines, np.arange(0, w, step))][:, ::-1]
    np.testing.assert_array_equal(p.tie_points["dem_alt"], expected)
    assert p.tie_points["dem_alt"].max() > 1000.0


def test_a_product_wrapped_in_folders_of_an_archive_opens(product_dir, tmp_path):
    """A zip archive that wraps the .SEN3 folder in a folder of its own (a delivery package:
    ``EN1_MDSI_.../<name>.SEN3/...``) opens as the product: the manifest is looked for deeper
    than the archive's root or one folder down (no "no xfdumanifest.xml in it")."""
    archive = tmp_path / "EN1_MDSI_MER_RR__1P_20120406T085654.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("EN1_MDSI_MER_RR__1P_20120406T085654/README.txt", "delivery note")
        for f in sorted(product_dir.iterdir()):
            z.write(f, f"EN1_MDSI_MER_RR__1P_20120406T085654/{product_dir.name}/{f.name}")
    p, plain = read_product(archive), read_product(product_dir)
    assert p.product_type == plain.product_type == "ME_1_RRG___"
    np.testing.assert_array_equal(p.counts(7), plain.counts(7))


def test_time_stamps_in_their_own_units_and_zero_stamps(copy, product_dir, caplog):
    """time_stamp is read in its CF ``units`` (here milliseconds since 1970, the same instants):
    the same line times as ESA's microseconds since 2000; a stamp of 0 or -1 (ocssw's "no
    time") is interpolated and counted, not taken as 2000-01-01; units that are no CF time are
    one error. Ignoring the units would put times 30 years off."""
    from napari_meris_ortho.products.sen3.layout import time_units

    assert time_units("microseconds since 2000-01-01 00:00:00 ") == (1e-6, 0.0)
    assert time_units("seconds since 1970-01-01T00:00:00Z") == (1.0, -946684800.0)
    assert time_units("days since 2000-01-02") == (86400.0, 86400.0)
    # UDUNITS' short forms: one-digit fields
    assert time_units("microseconds since 2000-1-1 0:0:0") == (1e-6, 0.0)
    assert time_units("seconds since 2000-1-1 1:2:3.5") == (1.0, 3723.5)
    assert time_units("furlongs since 2000-01-01") is None and time_units("m") is None
    want = read_product(product_dir).line_times
    f = copy / "time_coordinates.nc"
    with netCDF4.Dataset(f, "a") as ds:
        v = ds.variables["time_stamp"]
        v.set_auto_maskandscale(False)
        v[:] = v[:] // 1000 + 946_684_800_000
        v.setncattr("units", "milliseconds since 1970-01-01 00:00:00")
    np.testing.assert_allclose(read_product(copy).line_times, want, rtol=0, atol=1e-6)

    ours = copy.parent / "zero" / copy.name
    shutil.copytree(product_dir, ours)
    _set(ours / "time_coordinates.nc", "time_stamp", slice(0, 2), np.int64(0))
    _set(ours / "time_coordinates.nc", "time_stamp", 9, np.int64(-1))
    with caplog.at_level(logging.WARNING):
        np.testing.assert_allclose(read_product(ours).line_times, want, rtol=0, atol=1e-6)
    assert "3 of 1617 time_stamp values" in caplog.text
    with netCDF4.Dataset(f, "a") as ds:
        ds.variables["time_stamp"].setncattr("units", "milliseconds after the launch")
    with pytest.raises(Sen3FormatError, match=r"time_coordinates.nc: time_stamp units "
                                              r"'milliseconds after the launch' are not"):
        read_product(copy)


def _reverse_columns(directory: Path) -> None:
    """Every variable of every member with its columns (image or tie-point) reversed: the
    product as a third-party rewrite in the N1 column order would hold it."""
    for f in sorted(directory.glob("*.nc")):
        with netCDF4.Dataset(f, "a") as ds:
            for v in ds.variables.values():
                axes = [i for i, d in enumerate(v.dimensions) if d in ("columns", "tie_columns")]
                if axes:
                    v.set_auto_maskandscale(False)
                    v[...] = np.flip(v[...], axis=axes[0])


def test_a_product_in_the_n1_column_order_is_read_as_it_is(copy, product_dir, caplog):
    """ESA's .SEN3 columns run against the N1 order (the reader mirrors them). A file already
    in the N1 order (a third-party rewrite) is recognised from its tie-point geometry (column
    0 on the left of the flight direction) and read as it is, with a warning: the same arrays
    as ESA's file, not mirrored a second time (east and west swapped)."""
    _reverse_columns(copy)
    with caplog.at_level(logging.WARNING):
        esa = read_product(product_dir)
    assert "N1 column order" not in caplog.text
    with caplog.at_level(logging.WARNING):
        n1 = read_product(copy)
    assert "N1 column order" in caplog.text
    for key, value in esa.tie_points.items():
        np.testing.assert_array_equal(n1.tie_points[key], value, err_msg=key)
    np.testing.assert_array_equal(n1.counts(7), esa.counts(7))
    np.testing.assert_array_equal(n1.flags, esa.flags)
    np.testing.assert_array_equal(n1.pixel_longitude(), esa.pixel_longitude())
    np.testing.assert_array_equal(n1.detector_index, esa.detector_index)


def test_the_column_order_of_real_products():
    """``esa_column_order`` on real tie points: the handbook's Appendix E.1 N1 product
    (MER_FR__1PNUPA20030921_092217, tie lines 1 and 9, first and last column: longitude falls
    from 20.5 to 12.4 deg along a line) is in the N1 order, its mirror in ESA's (the real-like
    .SEN3 of ``sen3_real``, in ESA's order, reads with no warning:
    ``test_a_product_in_the_n1_column_order_is_read_as_it_is``)."""
    from napari_meris_ortho.products.sen3.layout import esa_column_order

    lat = np.array([[50.742379, 51.937422], [49.435929, 50.615694]])
    lon = np.array([[20.514153, 12.372044], [19.924214, 12.001195]])
    assert not esa_column_order(lat, lon)
    assert esa_column_order(lat[:, ::-1], lon[:, ::-1])

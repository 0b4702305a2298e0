"""DEM quality control (DEMCHK, handbook section 5.2, Appendix F)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from napari_meris_ortho.analysis.demcheck import (
    GroundControlPoints,
    demcheck,
    elevation_statistics,
    plot_histogram,
    read_points,
)
from napari_meris_ortho.dem.geoid import geoid_undulation
from napari_meris_ortho.errors import MerisOrthoError, OptionsError

FIXTURES = Path(__file__).parent / "fixtures"

#: summaries printed in Appendix F.2 (nearest), F.3 (bilinear), F.4 (bicubic) and table 4
HANDBOOK_SUMMARY = {
    "f2": (10.828, 32.368, 30.503, -127.560, 100.931),
    "f3": (11.304, 34.017, 32.083, -181.091, 125.763),
    "f4": (12.008, 32.915, 30.646, -172.570, 127.387),
}


def load_fixture(name: str) -> dict[str, np.ndarray]:
    with open(FIXTURES / f"appendix_{name}.csv") as f:
        rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def as_tuple(s) -> tuple[float, ...]:
    return (s.arithmetic_mean, s.quadratic_mean, s.standard_deviation, s.minimum, s.maximum)


@pytest.mark.parametrize("name", ["f2", "f3", "f4"])
def test_statistics_reproduce_appendix_f_summary(name):
    """Section 5.2 formulas applied to the 169 listed GCPs give the printed summary (3 decimals)."""
    d = load_fixture(name)
    assert len(d["gcp"]) == 169
    # the listed DIFFERENCE is GCP - DEM (to the printed rounding)
    assert np.allclose(d["gcp_elevation"] - d["dem_elevation"], d["difference"], atol=1.5e-3)
    s = elevation_statistics(d["gcp_elevation"], d["dem_elevation"])
    assert s.n == 169
    assert as_tuple(s) == pytest.approx(HANDBOOK_SUMMARY[name], abs=6e-4)


def test_standard_deviation_is_population_formula():
    s = elevation_statistics([10.0, 20.0, 30.0, 40.0], [0.0, 0.0, 0.0, 0.0])
    assert s.arithmetic_mean == 25.0
    assert s.quadratic_mean == pytest.approx(np.sqrt(750.0))
    assert s.standard_deviation == pytest.approx(np.sqrt(125.0))
    assert (s.minimum, s.maximum) == (10.0, 40.0)
    nan = elevation_statistics([1.0, 2.0], [np.nan, np.nan])
    assert nan.n == 0 and np.isnan(nan.arithmetic_mean)


def write_geotiff(path: Path, data: np.ndarray, x0: float, y0: float, res: float,
                  nodata: float | None = -9999.0) -> Path:
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0],
                       count=1, dtype="float32", crs="EPSG:4326", nodata=nodata,
                       transform=from_origin(x0, y0, res, res), compress="deflate") as ds:
        ds.write(data.astype(np.float32), 1)
    return path


def appendix_f2_scene(tmp_path: Path) -> tuple[Path, Path]:
    """A 0.05 deg DEM over Europe whose post under each F.2 GCP holds the listed GETASSE30
    height (no data elsewhere), and the 169 GCPs plus 48 points outside it (217 in input)."""
    d = load_fixture("f2")
    res, x0, y0 = 0.05, -10.0, 60.0
    dem = np.full((480, 780), -9999.0)
    rows = np.floor((y0 - d["northing"]) / res).astype(int)
    cols = np.floor((d["easting"] - x0) / res).astype(int)
    dem[rows, cols] = d["dem_elevation"]
    dem_path = write_geotiff(tmp_path / "europe.tif", dem, x0, y0, res)
    k = np.arange(48)
    outside = np.column_stack([35.0 + 0.1 * k, 40.0 + 0.2 * k, 100.0 + k])  # east of the DEM
    points = np.vstack([np.column_stack([d["easting"], d["northing"], d["gcp_elevation"]]),
                        outside])
    pts_path = tmp_path / "EUVN_ETRF.csv"
    with open(pts_path, "w") as f:
        f.write("Longitude;Latitude;Ellipsoidal height\n")
        for lon, lat, h in points:
            f.write(f"{lon:.6f};{lat:.6f};{h:.3f}\n")
    return pts_path, dem_path


def test_demcheck_on_a_dem_reproduces_appendix_f2(tmp_path):
    pts_path, dem_path = appendix_f2_scene(tmp_path)
    result = demcheck(pts_path, [dem_path], methods=("nearest",))
    check = result.methods["nearest"]
    assert len(result.points) == 217
    assert int(check.inside.sum()) == 169
    assert as_tuple(check.statistics) == pytest.approx(HANDBOOK_SUMMARY["f2"], abs=6e-4)
    report = result.report()
    lines = [" ".join(line.split()) for line in report.splitlines()]
    for expected in ("NUMBER OF GCPs IN INPUT : 217", "NUMBER OF PROCESSED GCPs : 169 (77.9%)",
                     "NUMBER OF GCPs OUTSIDE THE DEM : 48 (22.1%)",
                     ". ARITHMETIC MEAN : 10.828", ". QUADRATIC MEAN : 32.368",
                     ". STANDARD DEVIATION : 30.503", ". MINIMUM : -127.560",
                     ". MAXIMUM : 100.931",
                     "1 : 17.073455 52.276957 124.366 111.000 -> 13.366",
                     "37 : 7.209528 45.958605 1683.440 1811.000 -> -127.560",
                     "169 : 12.878945 49.144253 665.937 627.000 -> 38.937"):
        assert expected in lines


def test_interpolation_methods_on_a_plane_and_geoid(tmp_path):
    """On a plane DEM bilinear and bicubic are exact, nearest is not; a geoid grid N adds N."""
    res, x0, y0 = 0.01, 5.0, 47.0
    lat = y0 - (np.arange(200) + 0.5) * res
    lon = x0 + (np.arange(300) + 0.5) * res
    plane = 500.0 + 400.0 * (lon[None, :] - 5.0) - 250.0 * (lat[:, None] - 46.0)
    dem_path = write_geotiff(tmp_path / "plane.tif", plane, x0, y0, res)
    geoid_path = write_geotiff(tmp_path / "geoid.tif", np.full((200, 300), 47.5), x0, y0, res)
    rng = np.random.default_rng(3)
    plon, plat = rng.uniform(5.05, 7.9, 40), rng.uniform(45.1, 46.9, 40)
    truth = 500.0 + 400.0 * (plon - 5.0) - 250.0 * (plat - 46.0)
    pts = GroundControlPoints.from_arrays(np.r_[plon, 9.0], np.r_[plat, 46.0], np.r_[truth, 0.0])
    result = demcheck(pts, dem_path)
    for method in ("bilinear", "bicubic"):
        check = result.methods[method]
        assert check.statistics.n == 40 and not check.inside[-1]
        assert check.statistics.quadratic_mean < 1e-6
    assert 0.5 < result.methods["nearest"].statistics.quadratic_mean < 3.0
    with_geoid = demcheck(pts, [dem_path], methods=("bilinear",), geoid=geoid_path)
    s = with_geoid.methods["bilinear"].statistics
    assert s.arithmetic_mean == pytest.approx(-47.5, abs=1e-6)
    assert s.standard_deviation < 1e-6
    assert "geoid" in with_geoid.report(listing=False)
    # --geoid without a file: EGM96 of dem.geoid, the same as the entry PATH:egm96
    egm = demcheck(pts, [dem_path], methods=("bilinear",), geoid="egm96")
    entry = demcheck(pts, [f"{dem_path}:egm96"], methods=("bilinear",))
    n = geoid_undulation(plon, plat)
    assert 45.0 < n.min()
    np.testing.assert_allclose(egm.methods["bilinear"].dem_heights[:40], truth + n, atol=1e-6)
    np.testing.assert_allclose(entry.methods["bilinear"].dem_heights,
                               egm.methods["bilinear"].dem_heights)
    assert "EGM96 (egm96_15.gtx)" in egm.report(listing=False)
    # an entry naming its datum keeps it under --geoid
    kept = demcheck(pts, [f"{dem_path}:ellipsoid"], methods=("bilinear",), geoid="egm96")
    assert kept.methods["bilinear"].statistics.quadratic_mean < 1e-6


def test_dem_list_second_dem_fills_the_first(tmp_path):
    a = write_geotiff(tmp_path / "a.tif", np.full((10, 10), 100.0), 0.0, 10.0, 1.0)
    b = write_geotiff(tmp_path / "b.tif", np.full((10, 10), 200.0), 10.0, 10.0, 1.0)
    pts = GroundControlPoints.from_arrays([5.0, 15.0, 25.0], [5.0, 5.0, 5.0], [110.0, 190.0, 0.0])
    check = demcheck(pts, [a, b], methods=("nearest",)).methods["nearest"]
    assert check.inside.tolist() == [True, True, False]
    assert check.differences[:2].tolist() == [10.0, -10.0]
    assert (check.statistics.minimum, check.statistics.maximum) == (-10.0, 10.0)


def test_histogram_png(tmp_path):
    pts_path, dem_path = appendix_f2_scene(tmp_path)
    result = demcheck(pts_path, dem_path, methods=("nearest", "bilinear"))
    out = plot_histogram(result, tmp_path / "fig64.png")
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000
    assert not list(tmp_path.glob(".*.part"))
    import imageio.v3 as iio

    assert iio.imread(out).shape[:2] == (450, 800)
    with pytest.raises(MerisOrthoError):
        plot_histogram(result, tmp_path / "missing" / "fig.png")


def test_read_points_formats(tmp_path):
    p = tmp_path / "a.csv"
    p.write_text("# GPS\nid,lat,lon,h\n1,45.5,6.25,1200.5\n2,46.0,7.0,300\n")
    pts = read_points(p)
    assert pts.lon.tolist() == [6.25, 7.0] and pts.lat.tolist() == [45.5, 46.0]
    assert pts.h.tolist() == [1200.5, 300.0]
    q = tmp_path / "b.txt"
    q.write_text("6.25 45.5 1200.5\n7.0 46.0 300\n")
    assert read_points(q).h.tolist() == [1200.5, 300.0]
    listing = tmp_path / "f2.txt"
    listing.write_text(
        "GCP #\tEASTING\tNORTHING\tGCP\tELEVAT.\tDEM ELEVAT.\tDIFFERENCE\t15 :\t11.646799\t"
        "44.519965\t50.057\t49.000 ->\t1.057\n"
        "1 :\t17.073455\t52.276957\t124.366\t111.000 ->\t13.366\t16 :\t14.989779\t36.876079\t"
        "126.244\t152.000 ->\t-25.756\n")
    pts = read_points(listing)
    assert pts.number.tolist() == [1, 15, 16]
    assert pts.h.tolist() == [124.366, 50.057, 126.244]


@pytest.mark.parametrize(
    ("text", "word"),
    [("lon,lat\n1,2\n", "no h column"), ("x,y,z\n1,2,abc\n", "line 2"),
     ("lon,lat,h\n1,95,3\n", "invalid position"), ("", "no points")],
)
def test_read_points_errors(tmp_path, text, word):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(OptionsError, match=word):
        read_points(p)
    with pytest.raises(OptionsError, match="points file not found"):
        read_points(tmp_path / "absent.csv")


def test_bad_method_and_no_dem(tmp_path):
    pts = GroundControlPoints.from_arrays([1.0], [2.0], [3.0])
    with pytest.raises(OptionsError, match="method"):
        demcheck(pts, [tmp_path / "x.tif"], methods=("cubic-spline",))
    with pytest.raises(OptionsError, match="no DEM"):
        demcheck(pts, [])
    with pytest.raises(MerisOrthoError, match="not found"):
        demcheck(pts, [tmp_path / "x.tif"])

"""napari conventions of the plugin's layers and widgets: world units and labels, the
status bar, short layer names, reruns, legends, the N1 band axis and placement, settings."""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest
from pyproj import Transformer

from napari_meris_ortho.products.n1 import read_product, write_product

pytestmark = pytest.mark.slow

STAMP = "09-21 09:23"  # sensing start of the tiny product


def _ortho_widget(viewer):
    _, widget = viewer.window.add_plugin_dock_widget("napari-meris-ortho", "Orthorectify")
    return widget


def _run(widget, qtbot):
    assert widget.start() is not None, widget.status.value
    qtbot.waitUntil(lambda: not widget.running, timeout=120_000)
    assert widget.status.value.startswith("done"), widget.status.value


@pytest.fixture
def mapped(make_napari_viewer, qtbot, tiny_n1, tiny_dem):
    viewer = make_napari_viewer()
    widget = _ortho_widget(viewer)
    widget.products.value = [tiny_n1]
    widget.add_dem(tiny_dem)
    widget.bands.value = "7,5,2"
    _run(widget, qtbot)
    return viewer, widget


def test_units_axis_labels_and_scale_bar(mapped):
    import pint

    viewer, _ = mapped
    layer = viewer.layers[f"ortho b7 · {STAMP}"]
    metre = pint.get_application_registry()("metre").units
    assert tuple(layer.units) == (metre, metre)
    assert tuple(layer.axis_labels) == ("-northing", "easting")
    for other in viewer.layers:  # every layer of the run shares the world units
        assert tuple(other.units) == (metre, metre), other.name
    assert tuple(viewer.layers.units) == (metre, metre)
    elevation = viewer.layers[f"elevation · {STAMP}"]
    assert elevation.metadata["units"] == "m"


def test_status_bar_shows_positive_northing_and_crs(mapped):
    viewer, widget = mapped
    layer = viewer.layers[f"ortho b7 · {STAMP}"]
    grid = widget.last_run.items[0]["grid"]
    x, y = grid.xy(10, 20)  # centre of pixel (10, 20)
    status = layer.get_status((-y, x), world=True)
    coords = status["coords"]
    assert f"N {y:.0f} m" in coords and f"E {x:.0f} m" in coords, coords
    assert "EPSG:32632" in coords
    assert "-" not in coords.split("EPSG")[0]


def _parallax(viewer):
    """The run's parallax layer ("parallax ×<the exaggeration drawn> · ...")."""
    layer, = [x for x in viewer.layers if x.name.startswith("parallax ×")]
    return layer


def test_short_names_full_product_in_metadata_and_reruns_replace(mapped, qtbot, tiny_n1):
    viewer, widget = mapped
    names = [layer.name for layer in viewer.layers]
    for name in (f"ortho RGB 7-5-2 · {STAMP}", f"ortho b7 · {STAMP}", f"ortho b5 · {STAMP}",
                 f"footprint · {STAMP}", f"facets · {STAMP}", _parallax(viewer).name,
                 f"iterations · {STAMP}", f"elevation · {STAMP}",
                 f"elevation source · {STAMP}"):
        assert name in names, (name, names)
    product = read_product(tiny_n1)
    layer = viewer.layers[f"ortho b7 · {STAMP}"]
    assert layer.metadata["product"] == product.mph["PRODUCT"]
    assert layer.metadata["path"] == str(tiny_n1)
    assert viewer.layers[f"facets · {STAMP}"].visible
    before = [(x.name, id(x)) for x in viewer.layers]
    _run(widget, qtbot)  # the same run again: replaces, no "[1]" copies
    assert [x.name for x in viewer.layers] == [n for n, _ in before]
    assert not any("[" in x.name for x in viewer.layers)


def test_parallax_vectors_legend(mapped):
    viewer, _ = mapped
    vectors = _parallax(viewer)
    exaggeration = vectors.metadata["exaggeration"]
    assert vectors.name == f"parallax ×{exaggeration:g} · {STAMP}" and 0 < exaggeration <= 10
    legend = vectors.metadata["legend"]
    lo, hi = vectors.edge_contrast_limits
    assert legend == f"colour: height {lo:.0f}–{hi:.0f} m (viridis)"
    assert vectors.edge_colormap.name == "viridis"
    # the vectors stay readable: an edge a fraction of their spacing wide
    spacing = vectors.metadata["step"] * vectors.metadata["pixel_size"]
    assert 0 < vectors.edge_width <= spacing / 4


def test_parallax_vector_spacing_is_automatic_unless_chosen(mapped):
    """The widget's default spacing (0: automatic) puts about 60 vectors across the larger side of
    the output grid (one every 8 px at least): one every 16 px drew 22k overlapping arrows on
    fr-alps, which napari sliced and drew at every change (0.10-0.16 s a turn)."""
    from napari_meris_ortho._napari.geometry_layers import geometry_layers, vector_step_for
    from napari_meris_ortho.geometry.grid import OutputGrid

    viewer, widget = mapped
    assert widget.vector_step.value == 0
    assert widget.vector_step.label == "vector every (px, 0 = auto)"
    vectors = _parallax(viewer)
    rgb = viewer.layers[f"ortho RGB 7-5-2 · {STAMP}"]
    shape = (rgb.data[0] if rgb.multiscale else rgb.data).shape[:2]
    step = vectors.metadata["step"]
    assert max(8, max(shape) // 60) <= step <= max(8, max(shape) // 10)
    # no arrow reaches the next tail: the longest under half the spacing
    longest = float(np.hypot(*np.asarray(vectors.data)[:, 1].T).max())
    assert longest <= 0.45 * step * vectors.metadata["pixel_size"] * (1 + 1e-9)

    fr_alps = OutputGrid("EPSG:32632", 300_000.0, 5_200_000.0, 300.0, 300.0, 2950, 2720)
    assert vector_step_for(fr_alps) == 49
    assert vector_step_for(OutputGrid("EPSG:32632", 0.0, 0.0, 300.0, 300.0, 300, 200)) == 8
    n = 12
    lat, lon = np.mgrid[46.0:45.0:n * 1j, 7.0:9.0:n * 1j]
    shift = np.full((fr_alps.height, fr_alps.width), 100.0)
    for step, expected in ((0, 49), (16, 16)):
        layers = geometry_layers({"latitude": lat, "longitude": lon}, fr_alps,
                                 diagnostics={"shift_east_m": shift, "shift_north_m": shift},
                                 step=step)
        parallax = layers[-1]
        assert parallax[1]["metadata"]["step"] == expected
        assert len(parallax[0]) == len(range(expected // 2, 2950, expected)) * len(
            range(expected // 2, 2720, expected))


def test_elevation_source_legend(mapped, tiny_dem):
    viewer, _ = mapped
    source = viewer.layers[f"elevation source · {STAMP}"]
    table = source.features
    names = dict(zip(table["index"], table["source"], strict=True))
    assert names[1] == tiny_dem.name and names[2] == "tie points" and names[0] == "none"
    source.visible = True  # napari reports values of visible layers only
    value = int(source.data[source.data.shape[0] // 2, source.data.shape[1] // 2])
    assert value == 1
    status = source.get_status(source.data_to_world((source.data.shape[0] // 2,
                                                     source.data.shape[1] // 2)), world=True)
    assert tiny_dem.name in status["value"], status


def _n1_with_flags(path):
    h, w = 129, 257
    product_tp = None
    i, k = np.mgrid[0:3, 0:5].astype(np.float64)
    product_tp = {"latitude": 45.9 - 0.17 * i - 0.01 * k, "longitude": 8.0 - 0.215 * k + 0.03 * i,
                  "view_zenith": np.linspace(2.0, 22.0, 5) + 0 * i, "view_azimuth": 100.0 + 0 * i}
    rows, cols = np.mgrid[0:h, 0:w]
    flags = np.where(cols < 100, 16, 0) | np.where(rows < 10, 128, 0)
    write_product(path, product_type="MER_FR__1P", tie_points=product_tp,
                  counts=[(1000 + cols + b).astype(np.uint16) for b in range(15)],
                  flags=flags.astype(np.uint8), detector_index=(cols % 740).astype(np.int16),
                  first_line_time=dt.datetime(2003, 9, 21, 9, 23, 41))
    return path


def test_n1_band_axis_and_flag_legend(make_napari_viewer, tmp_path):
    path = _n1_with_flags(tmp_path / "MER_FR__1PFLAGS.N1")
    viewer = make_napari_viewer()
    layers = viewer.open(str(path), plugin="napari-meris-ortho")
    radiance = next(x for x in layers if x.name.startswith("radiance"))
    # the band slider reads MERIS band numbers 1..15
    assert radiance.axis_labels[0].startswith("MERIS band")
    assert radiance.data_to_world((0, 0, 0))[0] == 1.0
    assert radiance.data_to_world((14, 0, 0))[0] == 15.0
    assert radiance.metadata["band_names"][6] == "band 7 (665 nm)"
    flags = next(x for x in layers if x.name.startswith("flags"))
    table = flags.features
    names = dict(zip(table["index"], table["flags"], strict=True))
    assert names[16] == "LAND_OCEAN" and names[144] == "LAND_OCEAN|INVALID"
    assert names[0] == "none"
    flags.visible = True
    status = flags.get_status(flags.data_to_world((50, 20)), world=True)
    assert "LAND_OCEAN" in status["value"], status


def test_n1_opened_over_a_map_is_placed_by_its_geolocation(make_napari_viewer, qtbot, tiny_n1,
                                                           tiny_dem):
    viewer = make_napari_viewer()
    widget = _ortho_widget(viewer)
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"
    widget.geometry.value = False
    widget.bands.value = "7"
    _run(widget, qtbot)
    layers = viewer.open(str(tiny_n1), plugin="napari-meris-ortho")
    radiance = next(x for x in layers if x.name.startswith("radiance"))
    tp = read_product(tiny_n1).tie_points
    to_utm = Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True)
    x, y = to_utm.transform(tp["longitude"], tp["latitude"])
    for i, k in ((0, 0), (1, 2), (2, 4)):
        world = radiance.data_to_world((6, i * 64, k * 64))
        # an affine fit of the tie points: within 2 km of their map position (260 m pixels)
        assert np.hypot(world[2] - x[i, k], world[1] + y[i, k]) < 2000.0


def test_widgets_have_tooltips_progress_bar_and_remember_settings(make_napari_viewer, qtbot,
                                                                  tiny_n1):
    viewer = make_napari_viewer()
    widget = _ortho_widget(viewer)
    for child in widget.settings_widgets:
        assert child.tooltip, child.label
    widget.products.value = [tiny_n1]
    widget.elevation.value = "tiepoints"
    widget.bands.value = "7"
    widget.pixel_size.value = 520.0
    widget.geometry.value = False
    _run(widget, qtbot)
    assert widget.progress_bar.value == widget.progress_bar.max
    viewer2 = make_napari_viewer()  # same session, same settings files
    again = _ortho_widget(viewer2)
    assert again.elevation.value == "tiepoints"
    assert again.bands.value == "7" and again.pixel_size.value == 520.0
    assert again.geometry.value is False
    _, flicker = viewer2.window.add_plugin_dock_widget("napari-meris-ortho", "Flicker")
    for child in flicker.settings_widgets:
        assert child.tooltip, child.label

"""Plan-view map (``chirplidar.viz.planmap``) and ``chirplidar view --plan`` on small synthetic
inputs (no simulation run).

Reference values:
* true north in a polar stereographic projection (Snyder 1987, *Map Projections: A Working
  Manual*, USGS Professional Paper 1395, ch. 21, polar aspect): with central meridian lon0 the
  north-polar projection has x = rho sin(lon - lon0), y = -rho cos(lon - lon0); meridians are
  straight lines through the pole, so true north at (x, y) points at the origin, along
  (-sin(lon - lon0), cos(lon - lon0)): clockwise from grid north (+y) by -(lon - lon0), minus the
  grid convergence lon - lon0. EPSG:3413 has lon0 = 45 W (its definition: "Longitude of origin
  -45"), so at 50 W true north is 5 deg clockwise of grid north. The south-polar aspect
  (EPSG:3031, lon0 = 0) has x = rho sin(lon), y = rho cos(lon) and north points away from the
  pole: clockwise by lon, 100 deg at 100 E. Also checked against PROJ's meridian convergence
  (pyproj ``Proj.get_factors``), computed by PROJ from the projection's derivatives.
* hillshade: the shade is the cosine of the angle between the surface normal and the direction
  to the sun; a plane tilted 45 deg towards the north-west faces a sun at azimuth 315 deg,
  elevation 45 deg squarely (shade 1), the plane tilted 45 deg the other way is edge-on (0), a
  flat surface gets sin(45 deg).
"""

from __future__ import annotations

import math

import matplotlib.image as mpimg
import numpy as np
import pytest
import shapely
import trimesh
import xarray as xr
from conftest import write_scene
from pyproj import CRS, Proj, Transformer

from chirplidar.cli import main
from chirplidar.geometry.synthetic_terrain import flat_plane, sloped_plane
from chirplidar.geometry.terrain import Terrain
from chirplidar.mission.results import build_dataset, write_netcdf
from chirplidar.viz import plan_basemap, plan_layers, planmap
from chirplidar.viz._mpl import plt
from chirplidar.viz.plan_basemap import hillshade, scale_bar_length_m, true_north_bearing_deg
from chirplidar.viz.planmap import plan_map_figure, plot_plan_map

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
TO_3413 = Transformer.from_crs(4326, 3413, always_xy=True)
X0, Y0 = TO_3413.transform(-50.0, 67.0)      # 67 N 50 W, EPSG:3413 metres
CELL_M = 100.0


def _grid(nx=30, ny=20, x0=X0 - 1500.0, y0=Y0 - 1000.0):
    """A coverage grid of the documented shape: cells 100 m, the first column outside the
    region, one NaN precision cell."""
    x = x0 + CELL_M * (np.arange(nx) + 0.5)
    y = y0 + CELL_M * (np.arange(ny) + 0.5)
    yy, xx = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    in_region = np.ones((ny, nx), np.int8)
    in_region[:, 0] = 0
    shots = (5 * (xx % 4)).astype(np.int32)
    detected = (shots * 0.8).astype(np.int32)
    covered = (detected > 0).astype(np.int8)
    precision = np.where(detected > 0, 0.05 / np.sqrt(np.maximum(detected, 1)), np.nan)
    gap = np.where(covered == 1, 0.0, 50.0 + 5.0 * yy)

    def var(a, units, long_name):
        return (("y", "x"), a, {"units": units, "long_name": long_name, "grid_mapping": "crs"})

    coord = {"units": "m", "axis": "X", "standard_name": "projection_x_coordinate"}
    return xr.Dataset(
        {"in_region": var(in_region, "1", "cell inside the survey region"),
         "shots": var(shots, "1", "shots in the cell"),
         "detected_shots": var(detected, "1", "detected shots in the cell"),
         "detection_fraction": var(np.where(shots > 0, 0.8, np.nan), "1", "detected fraction"),
         "tracks": var(np.minimum(shots, 1).astype(np.int32), "1", "tracks through the cell"),
         "median_snr_db": var(10.0 + 0.3 * xx, "dB", "median SNR of the detected shots"),
         "height_precision_measured": var(precision, "m", "measured height precision"),
         "gap": var(gap, "m", "distance to the nearest detected footprint"),
         "covered": var(covered, "1", "cell covered"),
         "crs": ((), np.int32(0), CRS.from_epsg(3413).to_cf())},
        coords={"x": ("x", x, coord),
                "y": ("y", y, {**coord, "axis": "Y",
                               "standard_name": "projection_y_coordinate"})},
        attrs={"cell_size_m": CELL_M, "epsg_code": "EPSG:3413"})


def _terrain():
    # 4 km x 3 km plane rising 2 % towards +x around 67 N 50 W
    return sloped_plane(math.atan(0.02), 0.0, 500.0, (X0 - 2000, X0 + 2000, Y0 - 1500, Y0 + 1500),
                        50.0, origin_m=(X0, Y0))


def _track():
    t = np.linspace(0.0, 1.0, 500)
    return X0 - 1400.0 + 2800.0 * t, Y0 - 300.0 + 600.0 * t


def _colorbar_labels(fig):
    return [a.get_ylabel() for a in fig.axes[1:]]


# ------------------------------------------------------------------------------ north and scale
def test_true_north_at_67n_50w_in_epsg3413():
    bearing = true_north_bearing_deg(X0, Y0, 3413)
    assert bearing == pytest.approx(-(-50.0 - (-45.0)), abs=1e-6)        # +5 deg
    assert bearing == pytest.approx(-Proj("EPSG:3413").get_factors(-50.0, 67.0)
                                    .meridian_convergence, abs=1e-6)
    assert true_north_bearing_deg(X0, Y0, "EPSG:3413") == bearing
    # on the central meridian grid north is true north
    assert true_north_bearing_deg(*TO_3413.transform(-45.0, 72.0), 3413) == \
        pytest.approx(0.0, abs=1e-9)


def test_true_north_in_epsg3031_points_away_from_the_pole():
    x, y = Transformer.from_crs(4326, 3031, always_xy=True).transform(100.0, -75.0)
    assert true_north_bearing_deg(x, y, 3031) == pytest.approx(100.0, abs=1e-6)


def test_north_arrow_follows_true_north():
    fig = plan_map_figure(tracks=[_track()], epsg=3413)
    try:
        (arrow,) = [c for c in fig.axes[0].texts if c.get_gid() == "north_arrow"]
        (label,) = [c for c in fig.axes[0].texts if c.get_gid() == "north_label"]
        (hx, hy), (tx, ty) = arrow.xy, arrow.xyann        # head and tail, points from anchor
        drawn = math.degrees(math.atan2(hx - tx, hy - ty))
        xmin, xmax = fig.axes[0].get_xlim()
        ymin, ymax = fig.axes[0].get_ylim()
        expected = true_north_bearing_deg(0.5 * (xmin + xmax), 0.5 * (ymin + ymax), 3413)
        assert drawn == pytest.approx(expected, abs=1e-9)
        assert 4.9 < drawn < 5.1 and label.get_text() == "N"
    finally:
        plt.close(fig)
    fig = plan_map_figure(tracks=[_track()])          # no CRS: grid north, said so
    try:
        (label,) = [c for c in fig.axes[0].texts if c.get_gid() == "north_label"]
        assert label.get_text() == "N (grid)"
    finally:
        plt.close(fig)


@pytest.mark.parametrize(("width_m", "length_m"), [
    (6000.0, 1000.0), (3000.0, 500.0), (80_000.0, 10_000.0), (4999.0, 500.0), (5000.0, 1000.0),
    (1.2e6, 200_000.0), (37.0, 5.0), (12.0, 2.0)])
def test_scale_bar_length_is_round(width_m, length_m):
    got = scale_bar_length_m(width_m)
    assert got == length_m
    mantissa = got / 10 ** math.floor(math.log10(got))
    assert mantissa in (1.0, 2.0, 5.0) and got <= width_m / 5


def test_scale_bar_drawn_with_its_label():
    fig = plan_map_figure(tracks=[_track()], bounds=(X0 - 3000, Y0 - 2000, X0 + 3000, Y0 + 2000),
                          epsg=3413)
    try:
        (bar,) = [a for a in fig.axes[0].artists if a.get_gid() == "scale_bar"]
        assert bar.txt_label.get_text() == "1 km"
        assert bar.size_bar.get_children()[0].get_width() == 1000.0     # data units: metres
    finally:
        plt.close(fig)


# ------------------------------------------------------------------------------ the map
def test_png_written_at_the_expected_size(tmp_path):
    out = plot_plan_map(tmp_path / "sub" / "map.png", terrain=_terrain(), tracks=[_track()],
                        grid=_grid(), var="detected_shots",
                        region=shapely.box(X0 - 1400, Y0 - 900, X0 + 1400, Y0 + 900),
                        crossovers=xr.Dataset({"x": ("crossover", [X0]),
                                               "y": ("crossover", [Y0])}),
                        summary={"fraction_covered": 0.5}, figsize_in=(8.0, 6.0))
    assert out == tmp_path / "sub" / "map.png"
    assert out.read_bytes()[:8] == PNG_MAGIC
    img = mpimg.imread(out)
    assert img.shape[:2] == (720, 960)                                # 8 x 6 in at 120 dpi
    colours = np.unique((img[..., :3] * 255).round().astype(np.uint8).reshape(-1, 3), axis=0)
    assert len(colours) > 200                                         # hillshade + colour map


def test_default_size_follows_the_view_aspect(tmp_path):
    out = plot_plan_map(tmp_path / "map.png", tracks=[_track()], epsg=3413,
                        bounds=(X0 - 3000, Y0 - 1000, X0 + 3000, Y0 + 1000))
    assert mpimg.imread(out).shape[1] == 1200                        # 10 in
    fig = plan_map_figure(tracks=[_track()], epsg=3413,
                          bounds=(X0 - 3000, Y0 - 1000, X0 + 3000, Y0 + 1000))
    try:
        fig.canvas.draw()
        bbox = fig.axes[0].get_window_extent()
        assert bbox.height / bbox.width == pytest.approx(2000 / 6000, rel=0.01)   # equal scales
        assert fig.axes[0].get_xlim() == (X0 - 3000, X0 + 3000)
    finally:
        plt.close(fig)


def test_axes_in_km_of_the_projection():
    fig = plan_map_figure(grid=_grid(), var="gap")
    try:
        ax = fig.axes[0]
        assert ax.get_xlabel() == "x (km, EPSG:3413)" and ax.get_ylabel() == "y (km, EPSG:3413)"
        assert ax.xaxis.get_major_formatter()(-222500.0, 0) == "-222.5"
        assert ax.yaxis.get_major_formatter()(-2504000.0, 0) == "-2504"
        assert ax.get_aspect() == 1.0
    finally:
        plt.close(fig)


@pytest.mark.parametrize(("var", "label"), [
    ("gap", "distance to the nearest detected footprint (m)"),
    ("median_snr_db", "median SNR of the detected shots (dB)"),
    ("height_precision_measured", "measured height precision (mm)"),   # 5-50 mm: shown in mm
    ("detection_fraction", "detected fraction"),                       # units "1": no brackets
])
def test_colour_bar_label_has_long_name_and_units(var, label):
    fig = plan_map_figure(grid=_grid(), var=var)
    try:
        assert _colorbar_labels(fig) == [label]
        if var == "height_precision_measured":   # ticks in mm, the data still in m
            cbar_ax = fig.axes[1]
            assert cbar_ax.yaxis.get_major_formatter()(0.025, 0) == "25"
    finally:
        plt.close(fig)


def _mesh(fig):
    from matplotlib.collections import QuadMesh

    (mesh,) = [c for c in fig.axes[0].collections if isinstance(c, QuadMesh)]
    return mesh


def test_sparse_count_grid_gets_its_min_max_not_a_diverging_scale():
    """The trial's case (a satellite second over a 20 km scene: 0.6 % of the cells hold
    detections): the 1st-99th percentile of a grid of mostly zeros is 0..0; the colour range
    falls back to the data's min-max, 0..160 here, sequential (viridis), never -1..1 RdBu."""
    grid = _grid()
    counts = np.zeros(grid["detected_shots"].shape, np.int32)
    counts[3, 5], counts[4, 6], counts[5, 7], counts[6, 8] = 40, 80, 120, 160   # 4 of 580 cells
    grid["detected_shots"] = grid["detected_shots"].copy(data=counts)
    inside = counts[:, 1:]                                   # column 0 is outside the region
    assert np.percentile(inside, [1, 99]).tolist() == [0.0, 0.0]
    fig = plan_map_figure(grid=grid, var="detected_shots")
    try:
        mesh = _mesh(fig)
        assert mesh.get_cmap().name.startswith("viridis")
        assert (mesh.norm.vmin, mesh.norm.vmax) == (0.0, 160.0)
        cbar_ticks = fig.axes[1].get_yticks()
        assert cbar_ticks.min() >= 0.0                        # no negative counts on the bar
    finally:
        plt.close(fig)


@pytest.mark.parametrize(("value", "lo", "hi"), [(37.5, 35.625, 39.375), (0.0, 0.0, 1.0),
                                                 (-2.0, -2.1, -1.9)])
def test_all_equal_field_gets_a_small_range_holding_its_value(value, lo, hi):
    """An all-equal field: +-5 % around its value (0..1 for zeros), sequential."""
    grid = _grid()
    grid["gap"] = grid["gap"].copy(data=np.full(grid["gap"].shape, value))
    fig = plan_map_figure(grid=grid, var="gap")
    try:
        mesh = _mesh(fig)
        assert mesh.get_cmap().name.startswith("viridis")
        assert (mesh.norm.vmin, mesh.norm.vmax) == pytest.approx((lo, hi), rel=1e-12)
        assert mesh.norm.vmin <= value <= mesh.norm.vmax
    finally:
        plt.close(fig)


def test_shots_mostly_zero_get_min_max_and_signed_ones_stay_diverging():
    """Footprints coloured by a value (``view --plan``'s path): 500 shots, 496 of them 0 and 4
    between 0.4 and 0.7 (the 1st-99th percentile is 0..0), get 0..0.7 sequential; signed
    values (mostly 0, one -0.1, one +0.3) get the diverging map symmetric about 0
    (-0.3..0.3)."""
    x, y = _track()
    values = np.zeros(x.size)
    values[100:104] = [0.4, 0.5, 0.6, 0.7]
    assert np.percentile(values, [1, 99]).tolist() == [0.0, 0.0]
    fig = plan_map_figure(shots=(x, y, values), shot_var={"name": "v", "units": "m"},
                          epsg=3413)
    try:
        (pts,) = fig.axes[0].collections
        assert pts.get_cmap().name.startswith("viridis")
        assert (pts.norm.vmin, pts.norm.vmax) == (0.0, 0.7)
    finally:
        plt.close(fig)
    values = np.zeros(x.size)
    values[100], values[200] = -0.1, 0.3
    fig = plan_map_figure(shots=(x, y, values), shot_var={"name": "v", "units": "m"},
                          epsg=3413)
    try:
        (pts,) = fig.axes[0].collections
        assert pts.get_cmap().name.startswith("RdBu_r")
        assert (pts.norm.vmin, pts.norm.vmax) == (-0.3, 0.3)
    finally:
        plt.close(fig)


@pytest.mark.parametrize("label", [None, "survey polygon", "scene extent", "GeoJSON polygon"])
def test_region_legend_entry_says_what_the_region_is(label, tmp_path):
    kwargs = {} if label is None else {"region_label": label}
    fig = plan_map_figure(tracks=[_track()], epsg=3413,
                          region=shapely.box(X0 - 1400, Y0 - 900, X0 + 1400, Y0 + 900), **kwargs)
    try:
        texts = [t.get_text() for t in fig.legends[0].get_texts()]
        assert (label or "region") in texts and "survey region" not in texts
    finally:
        plt.close(fig)
    if label is not None:   # plot_plan_map passes it on
        import inspect

        assert inspect.signature(plot_plan_map).parameters["region_label"].default == "region"
        out = plot_plan_map(tmp_path / "r.png", tracks=[_track()], region_label=label,
                            region=shapely.box(X0 - 1400, Y0 - 900, X0 + 1400, Y0 + 900))
        assert out.read_bytes()[:8] == PNG_MAGIC


def test_flag_variable_gets_a_legend_not_a_colour_bar():
    fig = plan_map_figure(grid=_grid(), var="covered", tracks=[_track()])
    try:
        assert len(fig.axes) == 1                                      # no colour bar
        texts = [t.get_text() for t in fig.legends[0].get_texts()]
        assert "covered: no" in texts and "covered: yes" in texts
    finally:
        plt.close(fig)


def test_cells_outside_the_region_and_nan_cells_are_transparent():
    grid = _grid()
    fig = plan_map_figure(grid=grid, var="height_precision_measured", figsize_in=(8.0, 6.0))
    try:
        fig.canvas.draw()
        rgba = np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(float) / 255
        height = rgba.shape[0]

        def pixel(ix, iy):
            px, py = fig.axes[0].transData.transform((float(grid.x[ix]), float(grid.y[iy])))
            return rgba[height - round(py), round(px)]

        assert np.allclose(pixel(0, 5), 1.0)            # in_region == 0: white background
        assert np.allclose(pixel(4, 5), 1.0)            # shots 0 there: precision NaN
        assert not np.allclose(pixel(5, 5), 1.0)        # in region with a value: coloured
    finally:
        plt.close(fig)


def test_shots_coloured_with_their_units_and_nan_counted():
    x, y = _track()
    values = np.linspace(-0.2, 0.2, x.size)
    values[::10] = np.nan
    fig = plan_map_figure(shots=(x, y, values), epsg=3413,
                          shot_var={"name": "range_error", "long_name": "range error",
                                    "units": "m"})
    try:
        assert _colorbar_labels(fig) == ["range error (cm)"]          # +-20 cm: in cm
        texts = [t.get_text() for t in fig.legends[0].get_texts()]
        assert "no range_error value (50 shots)" in texts
    finally:
        plt.close(fig)


def test_many_shots_and_long_tracks_are_decimated():
    n = 450_000
    x = X0 + np.linspace(-2000.0, 2000.0, n)
    y = np.full(n, Y0)
    y[200_000] = np.nan                                                # a break in the track
    fig = plan_map_figure(tracks=[(x, y)], shots=(x, y, np.ones(n)), shot_var="v", epsg=3413)
    try:
        ax = fig.axes[0]
        line_x = ax.lines[0].get_xdata()
        assert line_x.size <= plan_layers.MAX_TRACK_VERTICES + 4
        assert np.isnan(ax.lines[0].get_ydata()).sum() == 1            # the break survives
        drawn = sum(len(c.get_offsets()) for c in ax.collections)
        assert 0 < drawn <= plan_layers.MAX_SHOTS_DRAWN
        texts = [t.get_text() for t in fig.legends[0].get_texts()]
        assert any(t.startswith("footprints: 1 in 3 of 449,999") for t in texts)
    finally:
        plt.close(fig)


def test_hillshade_lit_from_the_north_west():
    x = np.linspace(0.0, 100.0, 11)
    y = np.linspace(0.0, 100.0, 11)
    xx, yy = np.meshgrid(x, y)                  # rows increase in y, as HeightGrid
    slope = math.tan(math.radians(45.0)) / math.sqrt(2.0)  # 45 deg of tilt, along the diagonal
    facing_nw = slope * (xx - yy)               # rises to the south-east: faces north-west
    assert np.allclose(hillshade(facing_nw, x, y), 1.0)
    assert np.allclose(hillshade(-facing_nw, x, y), 0.0, atol=1e-12)
    assert np.allclose(hillshade(np.zeros_like(xx), x, y), math.sin(math.radians(45.0)))


def test_heightfield_terrain_shaded_and_decimated():
    # the sloped plane: uniform shade of the closed form; a 3001 x 2001 grid decimated
    terrain = _terrain()
    fig = plan_map_figure(terrain=terrain, epsg=3413)
    try:
        (image,) = fig.axes[0].images
        normal = np.array([-0.02, 0.0, 1.0]) / math.hypot(0.02, 1.0)
        sun = np.array([-0.5, 0.5, math.sqrt(0.5)])
        assert np.allclose(image.get_array().compressed(), normal @ sun)
    finally:
        plt.close(fig)
    big = flat_plane(100.0, (X0 - 3000, X0 + 3000, Y0 - 2000, Y0 + 2000), 2.0)
    fig = plan_map_figure(terrain=big, epsg=3413)
    try:
        (image,) = fig.axes[0].images
        assert max(image.get_array().shape) <= plan_basemap.MAX_SHADE_PX
    finally:
        plt.close(fig)


def test_mesh_terrain_is_interpolated_and_shaded():
    # two triangles of a plane tilted 45 deg towards the north-west: shade 1 inside
    s = 1.0 / math.sqrt(2.0)
    corners = np.array([[0.0, 0.0], [1000.0, 0.0], [1000.0, 1000.0], [0.0, 1000.0]])
    z = s * (corners[:, 0] - corners[:, 1])
    mesh = trimesh.Trimesh(vertices=np.column_stack([corners + (X0, Y0), z]),
                           faces=[[0, 1, 2], [0, 2, 3]], process=False)
    terrain = Terrain(mesh=mesh, face_materials=np.zeros(2, np.int32))
    assert terrain.grid is None
    fig = plan_map_figure(terrain=terrain, epsg=3413)
    try:
        (image,) = fig.axes[0].images
        shade = image.get_array().compressed()
        assert shade.size > 1000 and np.allclose(shade, 1.0)
    finally:
        plt.close(fig)


def test_summary_box_formats_numbers():
    text = planmap._summary_text({
        "fraction_covered": 0.8734, "largest_gap_m": 1250.0, "cells_covered": 12345,
        "cells_in_region": 14000, "median_height_precision_m": 0.0462, "median_snr_db": 17.56,
        "crossovers": 3, "missing": None, "undefined_m": float("nan"),
        "region": {"kind": "survey"}, "files": ["a.nc"], "tier": "link"})
    assert text.splitlines() == [
        "fraction covered: 87.3 %", "largest gap: 1.25 km", "cells covered: 12,345",
        "cells in region: 14,000", "median height precision: 4.62 cm", "median SNR: 17.6 dB",
        "crossovers: 3", "tier: link"]
    fig = plan_map_figure(tracks=[_track()], summary={"fraction_covered": 0.5})
    try:
        assert _summary_columns(fig) == [["fraction covered: 50.0 %"]]
    finally:
        plt.close(fig)


def _summary_columns(fig):
    """The summary box's lines, column by column."""
    from matplotlib.offsetbox import VPacker

    (box,) = [a for a in fig.artists if a.get_gid() == "summary"]
    columns = [c for c in box.findobj(VPacker)]
    return [[t.get_text() for t in col.findobj(plt.Text)] for col in columns]


SUMMARY = {"fraction_covered": 0.873, "cells_covered": 12345, "cells_in_region": 14000,
           "largest_gap_m": 1250.0, "median_height_precision_m": 0.0462,
           "along_track_spacing_m": 0.2, "across_track_spacing_m": 97.5, "crossovers": 60,
           "crossover_rms_m": 0.0613}


@pytest.mark.parametrize("figsize_in", [None, (8.0, 6.0)])
def test_summary_box_hides_nothing(figsize_in):
    """The summary box lies outside the map (a grid covering the whole view is not hidden),
    clear of the legend and inside the figure; its lines read down each column in the dict's
    order; the scale bar and north arrow stay in the map's corners."""
    fig = plan_map_figure(grid=_grid(), var="median_snr_db", tracks=[_track()],
                          region=shapely.box(X0 - 1400, Y0 - 900, X0 + 1400, Y0 + 900),
                          summary=SUMMARY, figsize_in=figsize_in)
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        ax = fig.axes[0]
        (box,) = [a for a in fig.artists if a.get_gid() == "summary"]
        b = box.get_window_extent(renderer)
        axes_box = ax.get_window_extent(renderer)
        legend_box = fig.legends[0].get_window_extent(renderer)
        assert not b.overlaps(axes_box) and not b.overlaps(legend_box)
        assert b.y1 < legend_box.y0 < axes_box.y0                     # map, legend, summary
        assert 0 <= b.x0 and b.x1 <= fig.bbox.width and 0 <= b.y0
        xlabel = ax.xaxis.label.get_window_extent(renderer)
        assert not b.overlaps(xlabel)
        columns = _summary_columns(fig)
        assert len(columns) > 1                                       # 9 lines side by side
        assert [line for col in columns for line in col] == \
            planmap._summary_text(SUMMARY).splitlines()
        (bar,) = [a for a in ax.artists if a.get_gid() == "scale_bar"]
        assert axes_box.contains(*bar.get_window_extent(renderer).p0)
    finally:
        plt.close(fig)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"grid": "GRID", "var": "nope"}, r"^var: 'nope' is not a variable of grid"),
    ({"grid": "GRID"}, r"^var: name the grid variable"),
    ({"var": "gap"}, r"^var: 'gap' names a grid variable but no grid"),
    ({"tracks": "TRACK", "bounds": (10.0, 0.0, 5.0, 1.0)}, r"^bounds: need XMIN < XMAX"),
    ({"tracks": "TRACK", "bounds": (0.0, 0.0, float("inf"), 1.0)}, r"^bounds: .*finite"),
    ({"tracks": "TRACK", "bounds": (0.0, 0.0, 1.0)}, r"^bounds: expected four numbers"),
    ({"shots": (np.zeros(3), np.zeros(3), np.zeros(2))}, r"^shots: x, y and values differ"),
    ({"tracks": [(np.zeros(3), np.zeros(4))]}, r"^tracks\[0\]: x and y differ"),
    ({"tracks": "TRACK", "region": "polygon"}, r"^region: expected a shapely Polygon"),
    ({"tracks": "TRACK", "epsg": 4326}, r"^epsg: 4326 must be a projected CRS"),
    ({"tracks": "TRACK", "summary": [("fraction_covered", 0.5)]}, r"^summary: expected a dict"),
    ({"tracks": "TRACK", "region_label": ""}, r"^region_label: expected a non-empty string"),
    ({}, r"^nothing to draw"),
])
def test_bad_input_names_the_argument(tmp_path, kwargs, match):
    made = {"GRID": _grid, "TRACK": lambda: [_track()]}     # built here, not at collection
    kwargs = {k: made[v]() if isinstance(v, str) and v in made else v
              for k, v in kwargs.items()}
    with pytest.raises(ValueError, match=match):
        plot_plan_map(tmp_path / "x.png", **kwargs)
    assert not (tmp_path / "x.png").exists()
    with pytest.raises(ValueError, match=r"^png: must name a \.png file"):
        plot_plan_map(tmp_path / "x.jpg", tracks=[_track()])


# ------------------------------------------------------------------------------ chirplidar view
SCENE_LAT, SCENE_LON = 69.0, -49.0


@pytest.fixture
def results_file(tmp_path, monkeypatch):
    """A tiny results file over a flat 4 km scene (EPSG:3413): 2 beams x 150 shots along grid x,
    with the survey polygon attribute; a function making variants (polygon off, no scene)."""
    monkeypatch.setenv("CHIRPLIDAR_CACHE", str(tmp_path / "cache"))
    scene = write_scene(tmp_path, "flat", 'flat height_m = 100.0\nmaterial = "snow"',
                        lat=SCENE_LAT, lon=SCENE_LON)
    cx, cy = Transformer.from_crs(4326, 3413, always_xy=True).transform(SCENE_LON, SCENE_LAT)

    def make(name="r.nc", polygon=True, scene_file=scene):
        n = 150
        x = cx + np.linspace(-1200.0, 1200.0, n)[None, :] + np.zeros((2, 1))
        y = cy + np.array([[-60.0], [60.0]]) + np.zeros((1, n))
        err = np.random.default_rng(0).normal(0.0, 0.03, (2, n))
        det = np.ones((2, n), np.int8)
        det[:, ::9] = 0
        err[det != 1] = np.nan
        ds = build_dataset({"delta_time": np.tile(np.arange(n) * 0.05, (2, 1)), "x": x, "y": y,
                            "h_li_true": np.full((2, n), 100.0), "range_error": err,
                            "snr_db": np.full((2, n), 15.0), "detected": det},
                           epsg=3413, epoch_iso="2026-01-01T00:00:00Z", config_toml="a = 1",
                           seed=1, software_version="test", date_created="2026-01-01T00:00:00Z")
        ds.attrs["scene_file"] = str(scene_file)
        if polygon:
            ds.attrs["survey_polygon_wkt"] = shapely.box(cx - 1500, cy - 800, cx + 1500,
                                                         cy + 800).wkt
        return write_netcdf(ds, tmp_path / name)

    make.centre = (cx, cy)
    return make


def _magenta_pixels(png) -> int:
    rgb = mpimg.imread(png)[..., :3]
    target = np.array([0xc5, 0x1b, 0x7d]) / 255.0      # REGION_COLOR
    return int(np.count_nonzero(np.all(np.abs(rgb - target) < 0.08, axis=-1)))


def test_view_plan_writes_the_map(results_file, tmp_path, capsys):
    nc = results_file()
    png = tmp_path / "plan.png"
    assert main(["view", str(nc), "--plan", "--png", str(png)]) == 0
    assert "wrote" in capsys.readouterr().err
    img = mpimg.imread(png)
    assert img.shape[1] == 1200
    assert _magenta_pixels(png) > 500                        # the survey polygon's outline
    grey = np.all(np.abs(img[..., :3] - img[..., :1]) < 0.01, axis=-1) & (img[..., 0] < 0.95) \
        & (img[..., 0] > 0.5)
    assert grey.mean() > 0.2                                  # the flat terrain's hillshade


def test_view_plan_without_polygon_and_with_bounds(results_file, tmp_path):
    nc = results_file("nopoly.nc", polygon=False)
    png = tmp_path / "zoom.png"
    cx, cy = results_file.centre
    # a negative XMIN written after --bounds (not --bounds=...) is a value, not an option
    bounds = f"{cx - 300:.0f},{cy - 200:.0f},{cx + 300:.0f},{cy + 200:.0f}"
    assert main(["view", str(nc), "--plan", "--png", str(png), "--var", "snr_db",
                 "--bounds", bounds]) == 0
    assert _magenta_pixels(png) == 0


@pytest.mark.parametrize(("args", "match"), [
    (["--bounds", "1,2,3"], "--bounds: expected XMIN,YMIN,XMAX,YMAX"),
    (["--bounds", "a,b,c,d"], "--bounds: expected XMIN,YMIN,XMAX,YMAX"),
    (["--bounds", "0,0,nan,1"], "--bounds: XMIN, YMIN, XMAX, YMAX must be finite"),
    (["--bounds", "5,0,1,1"], "--bounds: need XMIN < XMAX"),
    (["--bounds", "0,0,1000,1000"], "no footprint of"),        # far from Greenland's grid
    (["--camera-azimuth", "10"], "--camera-azimuth: only for the 3-D view"),
    (["--var", "nope"], "--var nope"),
])
def test_view_plan_bad_input_is_one_line(results_file, tmp_path, capsys, args, match):
    nc = results_file()
    png = tmp_path / "bad.png"
    assert main(["view", str(nc), "--plan", "--png", str(png), *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("chirplidar view: error: ")
    assert match in err
    assert "--bounds" in err or args[0] != "--bounds"
    assert not png.exists()


def test_view_plan_needs_png(results_file, capsys):
    assert main(["view", str(results_file()), "--plan"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--png" in err


def test_view_3d_bounds_outside_the_footprints_is_an_error(results_file, tmp_path, capsys):
    # refused before any rendering (no pyvista needed)
    png = tmp_path / "v.png"
    assert main(["view", str(results_file()), "--png", str(png), "--bounds",
                 "0,0,1000,1000"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--bounds 0,0,1000,1000: no footprint" in err
    assert not png.exists()

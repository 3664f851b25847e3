"""3-D view (pyvista, off-screen) of a results dataset over terrain at EPSG:3413 coordinates."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from chirplidar.geometry.synthetic_terrain import sloped_plane
from chirplidar.mission.results import build_dataset
from chirplidar.viz import scene3d
from chirplidar.viz.scene3d import render_track
from chirplidar.viz.scene3d_geometry import auto_vertical_exaggeration

pytest.importorskip("pyvista")
mpimg = pytest.importorskip("matplotlib.image")

X0, Y0 = -200_000.0, -2_200_000.0   # Greenland, EPSG:3413 metres
H0 = 1500.0
SIZE = (480, 360)                   # small window: fast software rendering
MATERIALS = {0: "snow", 1: "blue_ice"}


def _terrain():
    # 4 km x 3 km plane rising 2 % toward +x: relief 80 m, auto exaggeration x5
    return sloped_plane(np.arctan(0.02), 0.0, H0, (X0 - 2000, X0 + 2000, Y0 - 1500, Y0 + 1500),
                        250.0, origin_m=(X0, Y0))


def _dataset(*, n_beams=3, n_shots=60, altitude_above_m=800.0, all_nan=False, seed=0):
    rng = np.random.default_rng(seed)
    shape = (n_beams, n_shots)
    px = np.broadcast_to(X0 + np.linspace(-1500, 1500, n_shots), shape).copy()
    py = np.broadcast_to(Y0 + np.linspace(-600, 600, n_shots), shape).copy()
    x = px + 150.0 * (np.arange(n_beams)[:, None] - 1)
    y = py - 150.0 * (np.arange(n_beams)[:, None] - 1)
    h = H0 + 0.02 * (x - X0)                     # on the sloped plane
    det = np.ones(shape, dtype=int)
    det[:, ::7] = 0                              # some shots below threshold
    err = np.linspace(-0.2, 0.2, n_shots)[None, :] + rng.normal(0, 0.01, shape)
    err[det != 1] = np.nan
    if all_nan:
        err[:] = np.nan
    per_shot = {
        "delta_time": np.broadcast_to(np.arange(n_shots) * 0.01, shape).copy(),
        "x": x, "y": y, "platform_x": px, "platform_y": py,
        "platform_altitude": np.full(shape, H0 + altitude_above_m),
        "h_li_true": h, "h_li": np.where(det == 1, h + err, np.nan), "range_error": err,
        "snr_db": rng.normal(20.0, 3.0, shape), "detected": det,
        "surface_type": rng.integers(0, 2, shape),
    }
    return build_dataset(per_shot, epsg=3413, epoch_iso="2026-01-01T00:00:00Z",
                         config_toml="a = 1", seed=1, software_version="test",
                         materials=MATERIALS, date_created="2026-01-01T00:00:00Z")


def _image(path) -> np.ndarray:
    img = mpimg.imread(str(path))
    assert img.ndim == 3 and img.shape[:2] == (SIZE[1], SIZE[0])
    return img[..., :3].astype(float)


def _non_background_fraction(rgb: np.ndarray) -> float:
    background = rgb[0, 0]
    return float(np.mean(np.any(np.abs(rgb - background) > 0.02, axis=-1)))


def _scene_region(rgb: np.ndarray) -> np.ndarray:
    # Rows 15 %-80 %: below the title, above the scalar bar and the text legend.
    h = rgb.shape[0]
    return rgb[int(0.15 * h):int(0.80 * h)]


def _red(rgb):   # dark-red end of RdYlBu_r; nothing else in the scene is red
    return (rgb[..., 0] > 0.55) & (rgb[..., 1] < 0.3) & (rgb[..., 2] < 0.3)


def _blue(rgb):  # dark-blue end of RdYlBu_r (terrain and beam lines are lighter / greyer)
    return (rgb[..., 2] > 0.45) & (rgb[..., 0] < 0.35) & (rgb[..., 1] < 0.35)


def test_png_has_terrain_and_coloured_footprints(tmp_path):
    out = render_track(_dataset(), _terrain(), png=tmp_path / "scene.png", show=False,
                       window_size=SIZE)
    assert out == tmp_path / "scene.png" and out.is_file()
    rgb = _image(out)
    assert np.ptp(rgb.reshape(-1, 3), axis=0).max() > 0.5         # not one colour
    assert np.allclose(rgb[0, 0], 1.0, atol=0.02)                  # white background
    assert _non_background_fraction(rgb) > 0.15                    # terrain fills the view
    scene = _scene_region(rgb)
    colours = np.unique((scene * 255).round().astype(np.uint8).reshape(-1, 3), axis=0)
    assert len(colours) > 200                                      # shading + colormap
    # both ends of the diverging colormap appear on the footprints, not only in the bar
    assert np.count_nonzero(_red(scene)) > 10
    assert np.count_nonzero(_blue(scene)) > 10


def test_categorical_flag_variable(tmp_path):
    out = render_track(_dataset(), _terrain(), var="detected", png=tmp_path / "det.png",
                       show=False, window_size=SIZE)
    scene = _scene_region(_image(out))
    green = (scene[..., 1] > 0.45) & (scene[..., 0] < 0.3) & (scene[..., 2] < 0.4)  # detected
    orange = (scene[..., 0] > 0.75) & (scene[..., 1] > 0.25) & (scene[..., 1] < 0.55) \
        & (scene[..., 2] < 0.2)                                                     # below thr.
    assert np.count_nonzero(green) > 10
    assert np.count_nonzero(orange) > 3


def test_without_terrain(tmp_path):
    out = render_track(_dataset(), None, png=tmp_path / "noterrain.png", show=False,
                       window_size=SIZE)
    rgb = _image(out)
    assert 0.01 < _non_background_fraction(rgb) < 0.9
    scene = _scene_region(rgb)
    assert np.count_nonzero(_red(scene)) > 10 and np.count_nonzero(_blue(scene)) > 10


def test_satellite_platform_draws_short_beams(tmp_path):
    ds = _dataset(altitude_above_m=500e3)
    out = render_track(ds, _terrain(), png=tmp_path / "sat.png", show=False, window_size=SIZE)
    rgb = _image(out)
    # Drawn at 500 km the track would shrink the terrain to a few pixels.
    assert _non_background_fraction(rgb) > 0.15
    assert np.count_nonzero(_red(_scene_region(rgb))) > 10
    scene = scene3d._Scene(ds, _terrain(), "range_error", None, None)
    assert scene.track is None and scene.satellite_km == pytest.approx(501.5, abs=0.1)
    assert "platform at 502 km" in scene.title
    starts, ends = scene.rays
    assert np.allclose(np.linalg.norm(ends - starts, axis=1), 0.2 * scene.extent)


def test_aircraft_track_is_drawn_at_height():
    scene = scene3d._Scene(_dataset(), _terrain(), "range_error", None, None)
    assert scene.satellite_km is None and scene.track.shape == (60, 3)
    assert scene.ve == 5.0                        # 80 m relief over 4 km
    assert np.allclose(scene.track[:, 2], (H0 + 800.0 - H0) * 5.0)   # origin z: mean height
    # local origin removed before VTK: coordinates of order of the scene, not 1e6 m
    assert np.abs(scene.fp_xyz[:, :2]).max() < 2100.0
    assert np.abs(scene.terrain["points"][:, :2]).max() <= 2000.0 + 1e-6


def test_unknown_var_names_the_choices(tmp_path):
    with pytest.raises(ValueError, match=r"'nope'.*range_error.*snr_db"):
        render_track(_dataset(), None, var="nope", png=tmp_path / "x.png", show=False)
    assert not (tmp_path / "x.png").exists()


def _grey_pixels(rgb) -> int:
    return int(np.count_nonzero((np.ptp(rgb, axis=-1) < 0.04) & (rgb[..., 0] > 0.3)
                                & (rgb[..., 0] < 0.6)))


def test_all_nan_variable_renders_grey(tmp_path):
    # reference: snr_db has no NaN, so no grey footprints (greys only from text and lines)
    ref = render_track(_dataset(), _terrain(), var="snr_db", png=tmp_path / "ref.png",
                       show=False, window_size=SIZE)
    out = render_track(_dataset(all_nan=True), _terrain(), png=tmp_path / "nan.png",
                       show=False, window_size=SIZE)
    scene = _scene_region(_image(out))
    assert np.count_nonzero(_red(scene)) == 0 and np.count_nonzero(_blue(scene)) == 0
    assert _grey_pixels(scene) > _grey_pixels(_scene_region(_image(ref))) + 300


def test_invalid_arguments(tmp_path):
    ds = _dataset()
    with pytest.raises(ValueError, match="directory"):
        render_track(ds, None, png=tmp_path / "missing" / "x.png", show=False)
    with pytest.raises(ValueError, match=r"\.png"):
        render_track(ds, None, png=tmp_path / "x.jpg", show=False)
    with pytest.raises(ValueError, match="'x'"):
        render_track(ds.drop_vars(["x", "y"]), None, png=tmp_path / "x.png", show=False)
    with pytest.raises(ValueError, match="png"):
        render_track(ds, None, show=False)
    with pytest.raises(ValueError, match="window_size"):
        render_track(ds, None, png=tmp_path / "x.png", show=False, window_size=(0, 10))
    with pytest.raises(ValueError, match="vertical_exaggeration"):
        render_track(ds, None, png=tmp_path / "x.png", show=False, vertical_exaggeration=-1)
    with pytest.raises(ValueError, match="ds must be an xarray.Dataset"):
        render_track({"x": 1}, None, png=tmp_path / "x.png", show=False)


def test_show_without_display(tmp_path, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(ValueError, match="display"):
        render_track(_dataset(), None, show=True)
    with pytest.raises(ValueError, match="png"):
        render_track(_dataset(), None)          # show=None, nowhere to draw


@pytest.mark.parametrize(("relief", "extent", "expected"), [
    (0.0, 4000.0, 1.0),          # flat plane
    (800.0, 4000.0, 1.0),        # relief already 20 % of the extent
    (80.0, 4000.0, 5.0),         # 0.1 * 4000 / 80 = 5
    (30.0, 4000.0, 10.0),        # 13.3 rounded down to 10
    (1.0, 40_000.0, 100.0),      # capped
])
def test_auto_vertical_exaggeration(relief, extent, expected):
    assert auto_vertical_exaggeration(relief, extent) == expected


def test_import_does_not_import_pyvista():
    code = ("import sys, chirplidar.viz.scene3d; "
            "bad = [m for m in ('pyvista', 'vtk', 'vtkmodules') if m in sys.modules]; "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


# ------------------------------------------------------------------------------ framing (bounds)
BOX = (X0 - 500.0, Y0 - 400.0, X0 + 500.0, Y0 + 400.0)


def _inside(x, y, box):
    return (x >= box[0]) & (x <= box[2]) & (y >= box[1]) & (y <= box[3])


def test_bounds_crop_the_scene_and_frame_the_camera():
    ds = _dataset()
    scene = scene3d._Scene(ds, _terrain(), "range_error", None, None, bounds=BOX)
    x0, y0, _ = scene.origin
    assert (x0, y0) == (X0, Y0)                                   # centre of the box
    assert scene.extent == 1000.0
    assert scene.fit_xy == ((-500.0, 500.0), (-400.0, 400.0))
    fx, fy = scene.fp_xyz[:, 0] + x0, scene.fp_xyz[:, 1] + y0
    assert np.all(_inside(fx, fy, BOX))
    n_in = int(np.count_nonzero(_inside(ds.x.values, ds.y.values, BOX)))
    assert 0 < n_in < ds.x.size and len(fx) == n_in
    assert scene.n_outside == ds.x.size - n_in
    # terrain: the 250 m cells that overlap the box, no more
    tx, ty = scene.terrain["points"][:, 0] + x0, scene.terrain["points"][:, 1] + y0
    assert tx.min() <= BOX[0] and tx.max() >= BOX[2] and ty.min() <= BOX[1] and ty.max() >= BOX[3]
    assert tx.min() > BOX[0] - 250.0 - 1e-6 and tx.max() < BOX[2] + 250.0 + 1e-6
    assert len(scene.terrain["codes"]) == len(scene.terrain["faces"])
    assert scene.ve == auto_vertical_exaggeration(float(np.ptp(scene.terrain["z"])), 1000.0)
    assert len(scene.track_runs) == 1                             # one pass through the box
    assert "shots outside not drawn" in scene.legend_text


def test_track_breaks_where_it_leaves_the_box():
    # a lawnmower: east along y0 - 100 m, a turn outside the box, west along y0 + 100 m
    n = 100
    leg = np.linspace(-1500.0, 1500.0, n)
    px = X0 + np.concatenate([leg, leg[::-1]])[None, :]
    py = Y0 + np.concatenate([np.full(n, -100.0), np.full(n, 100.0)])[None, :]
    shape = px.shape
    ds = build_dataset({"delta_time": np.arange(2 * n)[None, :] * 0.1, "x": px, "y": py,
                        "platform_x": px, "platform_y": py,
                        "platform_altitude": np.full(shape, H0 + 500.0),
                        "h_li_true": H0 + 0.02 * (px - X0), "range_error": np.zeros(shape)},
                       epsg=3413, epoch_iso="2026-01-01T00:00:00Z", config_toml="a = 1",
                       seed=1, software_version="test", date_created="2026-01-01T00:00:00Z")
    scene = scene3d._Scene(ds, None, "range_error", None, None, bounds=BOX)
    assert len(scene.track_runs) == 2
    for a, b in scene.track_runs:                                 # each run: one straight leg
        assert np.ptp(scene.track[a:b, 1]) == 0.0
    whole = scene3d._Scene(ds, None, "range_error", None, None)
    assert whole.track_runs == [(0, 2 * n)]


def test_bounds_without_footprints_and_bad_camera_are_refused(tmp_path):
    ds = _dataset()
    far = (X0 + 10_000.0, Y0, X0 + 11_000.0, Y0 + 1000.0)
    with pytest.raises(ValueError, match=r"^bounds: no footprint lies inside"):
        render_track(ds, _terrain(), bounds=far, png=tmp_path / "x.png", show=False)
    with pytest.raises(ValueError, match=r"^bounds: need XMIN < XMAX"):
        render_track(ds, None, bounds=(1.0, 0.0, 0.0, 1.0), png=tmp_path / "x.png", show=False)
    with pytest.raises(ValueError, match=r"^camera_elevation_deg \(--camera-elevation\)"):
        render_track(ds, None, camera_elevation_deg=95.0, png=tmp_path / "x.png", show=False)
    with pytest.raises(ValueError, match=r"^camera_azimuth_deg \(--camera-azimuth\)"):
        render_track(ds, None, camera_azimuth_deg=float("nan"), png=tmp_path / "x.png",
                     show=False)
    with pytest.raises(ValueError, match=r"^zoom \(--zoom\) must be > 0"):
        render_track(ds, None, zoom=0.0, png=tmp_path / "x.png", show=False)
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize(("azimuth", "elevation"), [(None, None), (200.0, 60.0), (180.0, 90.0)])
def test_camera_is_fitted_to_the_box(azimuth, elevation):
    # the box's ground corners (with the heights drawn in it) project inside the window and
    # span most of it in one direction: fitted to the box, not to the whole scene
    import pyvista as pv

    scene = scene3d._Scene(_dataset(), _terrain(), "range_error", None, None, bounds=BOX)
    camera = scene3d._check_camera(azimuth, elevation, None)
    pl = pv.Plotter(off_screen=True, window_size=SIZE)
    try:
        scene3d._populate(pv, pl, scene, SIZE, camera)
        corners = np.array(np.meshgrid(*scene.fit_box, indexing="ij")).reshape(3, -1).T
        ren = pl.renderer
        display = []
        for c in corners:
            ren.SetWorldPoint(*c, 1.0)
            ren.WorldToDisplay()
            display.append(ren.GetDisplayPoint()[:2])
        display = np.array(display)
    finally:
        pl.close()
    w, h = SIZE
    assert np.all((display >= -1.0) & (display <= np.array([w, h]) + 1.0))
    span = np.ptp(display, axis=0) / np.array([w, h])
    assert span.max() > 0.85


def test_bounds_and_camera_render_the_box(tmp_path):
    size = (800, 600)      # footprints a few pixels wide: both colour-map ends countable
    out = render_track(_dataset(), _terrain(), png=tmp_path / "box.png", show=False,
                       window_size=size, bounds=BOX, camera_azimuth_deg=150.0,
                       camera_elevation_deg=40.0, zoom=1.1)
    rgb = mpimg.imread(str(out))[..., :3].astype(float)
    assert rgb.shape[:2] == (size[1], size[0])
    scene = _scene_region(rgb)
    assert _non_background_fraction(scene) > 0.6                 # the cropped terrain fills it
    # the colour range is that of the footprints in the box (min-max below 100 shots): both
    # ends drawn (the blue end is a single footprint of the 50 with a value)
    assert np.count_nonzero(_red(scene)) > 5 and np.count_nonzero(_blue(scene)) > 5


def test_cli_view_with_bounds_and_camera(tmp_path, capsys):
    from chirplidar.cli import main
    from chirplidar.mission.results import write_netcdf

    nc = write_netcdf(_dataset(), tmp_path / "r.nc")          # no scene file: track only
    png = tmp_path / "v.png"
    bounds = ",".join(f"{v:.0f}" for v in BOX)                 # starts with "-200500"
    assert main(["view", str(nc), "--png", str(png), "--bounds", bounds,
                 "--camera-azimuth", "200", "--camera-elevation", "60", "--zoom", "1.5"]) == 0
    assert png.is_file()
    assert main(["view", str(nc), "--png", str(png), "--zoom", "-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == ("chirplidar view: error: zoom (--zoom) must be > 0 (2: twice as "
                       "close), got -1")

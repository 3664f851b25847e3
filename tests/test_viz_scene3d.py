"""3-D view (pyvista, off-screen) of a results dataset over terrain at EPSG:3413 coordinates."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from chirplidar.geometry.terrain import sloped_plane
from chirplidar.mission.results import build_dataset
from chirplidar.viz import scene3d
from chirplidar.viz.scene3d import auto_vertical_exaggeration, render_track

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

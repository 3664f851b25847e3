"""The actors of the 3-D view (:mod:`chirplidar.viz.scene3d`): the shaded terrain, the
footprints coloured by a variable, the beam lines and platform track, the title, the legend and
the camera, added to a pyvista plotter. pyvista comes in as an argument and VTK and matplotlib
are imported inside the functions: importing this module pulls in no renderer."""

from __future__ import annotations

import math

import numpy as np

CAMERA_AZIMUTH_DEG = 135.0      # clockwise from grid north (+y): south-east
CAMERA_ELEVATION_DEG = 35.0
NAN_COLOR = "#707070"
TRACK_COLOR = "#202020"
RAY_COLOR = "#8c6bb1"           # lavender: not in viridis / RdYlBu_r ends, nor grey
BACKGROUND = "white"

# Ice-like height colormap for single-material terrain: grey-blue lows to near-white highs.
_ICE_COLORS = ("#7f98ad", "#a9bfcf", "#d3e0e9", "#f4f7f9")
# Face colours for material-coloured terrain (names of chirplidar.geometry.terrain.MATERIAL_NAMES).
MATERIAL_COLORS = {
    "snow": "#eef2f5", "snow_fresh": "#ffffff", "firn": "#e3dccb", "blue_ice": "#9cc8e0",
    "open_water": "#2c6ea3", "rock": "#7b6a58", "thesis_target": "#d9a441",
}
_OTHER_MATERIAL_COLORS = ("#c7b8d6", "#b9d6b2", "#e0c0b0", "#b0c4de")


def _terrain_polydata(pv, t: dict):
    faces = np.column_stack([np.full(len(t["faces"]), 3, np.int64), t["faces"]]).ravel()
    poly = pv.PolyData(t["points"], faces)
    poly.point_data["height"] = t["z"]
    return poly.compute_normals(cell_normals=False, point_normals=True, split_vertices=False,
                                auto_orient_normals=False)


def _material_color(name: str, i: int) -> str:
    return MATERIAL_COLORS.get(name, _OTHER_MATERIAL_COLORS[i % len(_OTHER_MATERIAL_COLORS)])


def add_terrain(pv, pl, t: dict, legend_entries: list) -> None:
    """The terrain ``t`` (a scene's ``terrain`` dict), shaded: by material when it has more than
    one, else by height with an ice colormap; its legend entries appended."""
    from matplotlib.colors import LinearSegmentedColormap, to_rgb

    poly = _terrain_polydata(pv, t)
    if t["used"].size > 1:
        # Several materials: colour faces by material (water, rock, ice stand out).
        rgb = np.array([to_rgb(_material_color(n, i)) for i, n in enumerate(t["names"])])
        # Darken low faces a little so the relief reads through the flat material colours.
        zf = t["z"][t["faces"]].mean(axis=1)
        span = float(np.ptp(zf))
        shade = 0.75 + 0.25 * (zf - zf.min()) / span if span > 0 else np.ones_like(zf)
        poly.cell_data["material_rgb"] = np.clip(
            rgb[t["codes"]] * shade[:, None] * 255, 0, 255).astype(np.uint8)
        pl.add_mesh(poly, scalars="material_rgb", rgb=True, smooth_shading=True,
                    show_scalar_bar=False, ambient=0.3, diffuse=0.8)
        for c in t["used"]:
            legend_entries.append([t["names"][c], _material_color(t["names"][c], int(c))])
    else:
        z = t["z"]
        clim = (float(z.min()), float(z.max()))
        if clim[1] <= clim[0]:
            pl.add_mesh(poly, color=_ICE_COLORS[2], smooth_shading=True, ambient=0.3,
                        diffuse=0.8)
        else:
            ice = LinearSegmentedColormap.from_list("ice", _ICE_COLORS)
            pl.add_mesh(poly, scalars="height", cmap=ice, clim=clim, smooth_shading=True,
                        show_scalar_bar=False, ambient=0.3, diffuse=0.8)
        legend_entries.append([f"terrain ({t['names'][int(t['used'][0])]})",
                               _ICE_COLORS[2]])


def _footprint_lift(s) -> np.ndarray:
    """Footprints sit on the surface; lift them a little so the surface does not hide them."""
    return np.array([0.0, 0.0, 0.002 * s.extent])


def add_footprints(pv, pl, s, window_size, font: int, legend_entries: list) -> None:
    """The footprints of scene ``s`` coloured by its variable (categories with annotations, or
    a colour bar), the shots without a value in grey."""
    from matplotlib.colors import ListedColormap

    lift = _footprint_lift(s)
    # pixels: ~10 at a 1000-px window, smaller for many shots so tracks stay readable
    point_size = float(np.clip(min(window_size) / 100, 4, 12))
    if s.fp_xyz.shape[0] > 2000:
        point_size = max(3.0, 0.6 * point_size)
    ok = np.isfinite(s.fp_scalars)
    if ok.any():
        cloud = pv.PolyData(s.fp_xyz[ok] + lift)
        cloud.point_data[s.var] = s.fp_scalars[ok]
        bar = {"title": s.label, "vertical": False, "position_x": 0.45, "position_y": 0.02,
               "width": 0.5, "height": 0.1, "title_font_size": font,
               "label_font_size": max(6, font - 6), "color": "black", "fmt": "%.3g"}
        if s.categories is not None:
            n = len(s.categories["meanings"])
            bar.update(n_labels=0, fmt="%.0f")
            pl.add_mesh(cloud, scalars=s.var, cmap=ListedColormap(s.categories["colors"]),
                        clim=s.clim, n_colors=n, render_points_as_spheres=True,
                        point_size=point_size, scalar_bar_args=bar,
                        annotations={float(i): m for i, m in
                                     enumerate(s.categories["meanings"])})
        else:
            pl.add_mesh(cloud, scalars=s.var, cmap=s.cmap, clim=s.clim,
                        render_points_as_spheres=True, point_size=point_size,
                        scalar_bar_args=bar)
        for actor in pl.scalar_bars.values():
            actor.SetTextPositionToPrecedeScalarBar()
    if (~ok).any():
        grey = pv.PolyData(s.fp_xyz[~ok] + lift)
        pl.add_mesh(grey, color=NAN_COLOR, render_points_as_spheres=True,
                    point_size=0.75 * point_size)
        legend_entries.append([f"no {s.var} value", NAN_COLOR])


def add_track_and_beams(pv, pl, s, legend_entries: list) -> None:
    """The beam lines (footprint towards platform) and the platform track of scene ``s``."""
    lift = _footprint_lift(s)
    if s.rays is not None and s.rays[0].shape[0]:
        starts, ends = s.rays
        pts = np.empty((2 * starts.shape[0], 3))
        pts[0::2], pts[1::2] = starts + lift, ends
        pl.add_mesh(pv.line_segments_from_points(pts), color=RAY_COLOR, opacity=0.5,
                    line_width=1.0)
        legend_entries.append(["beam to platform" if s.satellite_km is None
                               else "beam (toward platform)", RAY_COLOR])
    runs = [(a, b) for a, b in s.track_runs if b - a >= 2] if s.track is not None else []
    if runs:
        lines = np.concatenate([np.concatenate([[b - a], np.arange(a, b)]) for a, b in runs])
        pl.add_mesh(pv.PolyData(s.track, lines=lines), color=TRACK_COLOR, line_width=3.0)
        legend_entries.append(["platform track", TRACK_COLOR])
    elif s.track is not None:
        pl.add_mesh(pv.PolyData(s.track), color=TRACK_COLOR, point_size=8.0,
                    render_points_as_spheres=True)
        legend_entries.append(["platform", TRACK_COLOR])


def add_texts(pl, s, window_size, font: int, legend_entries: list) -> None:
    """Title, information lines and the legend box, sized to fit the window."""
    width_px, height_px = window_size
    # Text sized to fit the window (Arial is ~0.5 px wide per character and point).
    title_lines = s.title.splitlines()
    title_font = min(font + 4, int(0.95 * width_px / (0.55 * max(map(len, title_lines)))))
    pl.add_actor(_text_actor(s.title, (0.5, 0.985), max(title_font, 6), "center", "top"))
    info_lines = s.legend_text.splitlines()
    info_font = min(font, int(0.42 * width_px / (0.55 * max(map(len, info_lines)))),
                    int(0.3 * height_px / (1.2 * len(info_lines))))
    info_font_size = max(info_font, 6)
    pl.add_actor(_text_actor(s.legend_text, (0.01, 0.015), info_font_size, "left", "bottom"))
    if legend_entries:
        pl.add_actor(_legend_box(legend_entries, window_size, info_font_size))


def place_camera(pl, s, camera, window_size) -> None:
    """Camera ``camera`` = (azimuth_deg, elevation_deg, zoom), default the CAMERA_* constants and
    zoom 1: from grid south-east at 35 deg elevation (or as asked), fitted to the scene, or to
    the bounds' box (with the height range of what is drawn) when they are given."""
    width_px, height_px = window_size
    az_deg, el_deg, zoom = camera if camera is not None else (
        CAMERA_AZIMUTH_DEG, CAMERA_ELEVATION_DEG, 1.0)
    az, el = math.radians(az_deg), math.radians(el_deg)
    direction = np.array([math.cos(el) * math.sin(az), math.cos(el) * math.cos(az),
                          math.sin(el)])
    # Looking straight down (or up) the vertical is no "up": the far side of the azimuth is.
    view_up = (0.0, 0.0, 1.0) if abs(el_deg) < 89.5 else (-math.sin(az), -math.cos(az), 0.0)
    if s.fit_box is None:
        b = np.array(pl.bounds, dtype=float).reshape(3, 2)
        focal = b.mean(axis=1)
        pl.camera_position = [tuple(focal + direction * max(s.extent, 1.0)), tuple(focal),
                              view_up]
        pl.reset_camera()
        pl.camera.zoom(1.05 * zoom)   # 5 % margin around the fitted scene
    else:
        _fit_box(pl, s.fit_box, direction, view_up, width_px / height_px)
        pl.camera.zoom(zoom)


def _fit_box(pl, box: np.ndarray, direction: np.ndarray, view_up, aspect: float,
             margin: float = 1.05) -> None:
    """Place the perspective camera looking along -direction at the centre of ``box`` (3, 2)
    (local coordinates), just far enough for its 8 corners to fit the view (VTK's reset_camera
    fits the bounding sphere instead, which leaves a flat box small from above). aspect: window
    width / height; margin: 5 % of room around the box."""
    focal = box.mean(axis=1)
    d = direction / np.linalg.norm(direction)
    up = np.asarray(view_up, dtype=float)
    right = np.cross(d, up)          # screen axes of a camera looking along -d
    right /= np.linalg.norm(right)
    up = np.cross(right, d)
    tan_v = math.tan(math.radians(pl.camera.view_angle) / 2.0) / margin
    tan_h = tan_v * aspect
    corners = np.array(np.meshgrid(*box, indexing="ij")).reshape(3, -1).T - focal
    toward = corners @ d             # corner's distance from the focal plane towards the camera
    distance = float(np.max(toward + np.maximum(np.abs(corners @ right) / tan_h,
                                                np.abs(corners @ up) / tan_v)))
    distance = max(distance, 1e-3 * float(np.ptp(box[:2], axis=1).max()), 1.0)
    pl.camera_position = [tuple(focal + d * distance), tuple(focal), tuple(up)]
    pl.reset_camera_clipping_range()


def _text_actor(text: str, position, font_size: int, halign: str, valign: str):
    """Black 2-D text at a normalized-viewport position, fixed size in points (pixels)."""
    from vtkmodules.vtkRenderingCore import vtkTextActor

    actor = vtkTextActor()
    actor.SetInput(text)
    actor.SetTextScaleModeToNone()
    prop = actor.GetTextProperty()
    prop.SetFontFamilyToArial()
    prop.SetFontSize(int(font_size))
    prop.SetColor(0.0, 0.0, 0.0)
    {"left": prop.SetJustificationToLeft, "center": prop.SetJustificationToCentered}[halign]()
    {"top": prop.SetVerticalJustificationToTop,
     "bottom": prop.SetVerticalJustificationToBottom}[valign]()
    actor.GetPositionCoordinate().SetCoordinateSystemToNormalizedViewport()
    actor.GetPositionCoordinate().SetValue(*position)
    return actor


def _legend_box(entries, window_size, font_size: int):
    """VTK legend with a colour swatch per entry and black text (pyvista's add_legend colours
    the text like the entry, unreadable for light colours), upper left below the title."""
    from matplotlib.colors import to_rgb
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonDataModel import vtkImageData
    from vtkmodules.vtkRenderingAnnotation import vtkLegendBoxActor

    leg = vtkLegendBoxActor()
    leg.SetNumberOfEntries(len(entries))
    for i, (label, color) in enumerate(entries):
        img = vtkImageData()
        img.SetDimensions(16, 16, 1)
        rgb = np.tile((np.array(to_rgb(color)) * 255).astype(np.uint8), (256, 1))
        arr = numpy_to_vtk(rgb, deep=True)
        arr.SetNumberOfComponents(3)
        img.GetPointData().SetScalars(arr)
        leg.SetEntry(i, img, str(label), [-1.0, -1.0, -1.0])  # negative: text keeps its colour
    leg.GetEntryTextProperty().SetColor(0.0, 0.0, 0.0)
    leg.BorderOn()
    leg.GetBoxProperty().SetColor(0.6, 0.6, 0.6)
    leg.UseBackgroundOn()
    leg.SetBackgroundColor(1.0, 1.0, 1.0)
    # The actor scales text to fit its box: size the box for the wanted font.
    n_chars = max(len(str(label)) for label, _ in entries)
    height = min(0.5, len(entries) * 1.4 * font_size / window_size[1])
    width = min(0.3, (0.55 * font_size * n_chars + 2.0 * font_size) / window_size[0])
    leg.GetPositionCoordinate().SetCoordinateSystemToNormalizedViewport()
    leg.GetPositionCoordinate().SetValue(0.01, 0.88 - height)
    leg.GetPosition2Coordinate().SetCoordinateSystemToNormalizedViewport()
    leg.GetPosition2Coordinate().SetValue(width, height)
    return leg

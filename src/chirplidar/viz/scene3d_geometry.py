"""What the 3-D view (:mod:`chirplidar.viz.scene3d`) draws, as arrays: the footprints' per-shot
values, the terrain mesh (cropped to a box), the local frame and vertical exaggeration, the
footprints' colouring, and the platform track with its beam lines, in local display
coordinates (float64, origin removed, heights scaled). No renderer is imported here."""

from __future__ import annotations

import itertools
import math

import numpy as np

from .conventions import DETECTED_COLORS, FLAG_COLORS, colour_range, units_label

TRAJECTORY_DIM = "trajectory"
OBS_DIM = "obs"

SATELLITE_RATIO = 3.0           # platform height / scene extent above which beams are cut short
SEGMENT_FRACTION = 0.2          # length of the cut-short beams, fraction of the scene extent
MAX_SEGMENTS_PER_BEAM = 80      # satellite beam segments per beam (every k-th shot beyond;
                                # more would hide the footprints behind a curtain)
MAX_RAYS_PER_BEAM = 40          # aircraft: faint footprint-platform lines per beam (context only)
VE_RELIEF_FRACTION = 0.1        # auto exaggeration: relief appears as >= 10 % of the extent
VE_MAX = 100.0


def is_shot_variable(var) -> bool:
    """A per-shot numeric variable: dims ``(trajectory, obs)``, float or integer."""
    return (set(var.dims) == {TRAJECTORY_DIM, OBS_DIM}
            and (np.issubdtype(var.dtype, np.floating) or np.issubdtype(var.dtype, np.integer)))



def shot_array(ds, name: str) -> np.ndarray:
    """(n_beams, n_shots) float64 values of a per-shot variable."""
    v = ds[name]
    if set(v.dims) != {TRAJECTORY_DIM, OBS_DIM}:
        raise ValueError(f"ds: variable {name!r} must have dims ({TRAJECTORY_DIM!r}, {OBS_DIM!r}),"
                         f" got {v.dims}")
    return np.asarray(v.transpose(TRAJECTORY_DIM, OBS_DIM).values, dtype=np.float64)


def flag_table(var) -> tuple[np.ndarray, list[str]] | None:
    """(flag_values, flag_meanings) of a CF flag variable, or None if it is not one."""
    values = var.attrs.get("flag_values")
    meanings = var.attrs.get("flag_meanings")
    if values is None or meanings is None or not np.issubdtype(var.dtype, np.integer):
        return None
    values = np.atleast_1d(np.asarray(values)).astype(np.int64)
    names = str(meanings).split()
    if len(names) != values.size:
        raise ValueError(f"ds: variable {var.name!r} has {values.size} flag_values but "
                         f"{len(names)} flag_meanings")
    return values, names


def _nice_floor(v: float) -> float:
    """Largest of 1, 2, 5 x 10^k not above v (v >= 1)."""
    k = math.floor(math.log10(v))
    for m in (5.0, 2.0, 1.0):
        if m * 10 ** k <= v:
            return m * 10 ** k
    return 10.0 ** k  # pragma: no cover - unreachable for v >= 1


def auto_vertical_exaggeration(relief_m: float, extent_m: float) -> float:
    """Vertical exaggeration that makes the relief visible.

    relief_m: height range of the terrain (else of the footprints), m. extent_m: horizontal extent
    of the scene, m. Rule: the factor that makes the relief ``VE_RELIEF_FRACTION`` (10 %) of the
    extent, rounded down to 1, 2 or 5 x 10^k and clipped to [1, ``VE_MAX``] (100). Flat-ish
    scenes (relief already >= 10 % of the extent, or no relief at all) get 1.
    """
    if not (np.isfinite(relief_m) and np.isfinite(extent_m)) or relief_m <= 0 or extent_m <= 0:
        return 1.0
    raw = VE_RELIEF_FRACTION * extent_m / relief_m
    if raw <= 1.0:
        return 1.0
    return _nice_floor(min(raw, VE_MAX))

def _is_decibel(var) -> bool:
    return str(var.attrs.get("units", "")).strip().lower() == "db"


def _label(var) -> str:
    return units_label(str(var.attrs.get("long_name", var.name)), var.attrs.get("units", ""))


def _first_finite_per_obs(*arrays: np.ndarray) -> np.ndarray:
    """(n_obs, k) values from the first beam where all k arrays are finite; rows of NaN where no
    beam has them (the platform is the same for every beam, so any finite beam will do)."""
    stack = np.stack(arrays, axis=-1)                # (n_beams, n_obs, k)
    if stack.shape[0] == 0:
        return np.empty((0, stack.shape[2]))
    ok = np.all(np.isfinite(stack), axis=-1)         # (n_beams, n_obs)
    first = np.argmax(ok, axis=0)
    out = stack[first, np.arange(stack.shape[1])]
    out[~ok.any(axis=0)] = np.nan
    return out


def _every_kth(n: int, n_max: int) -> np.ndarray:
    return np.arange(0, n, max(1, math.ceil(n / n_max)))


def _crop_terrain(terrain, bounds):
    """(vertices (n, 3) float64, faces (m, 3) int64, material codes (m,)) of the terrain's faces
    that overlap ``bounds`` (whole faces: the box is covered to its edges), or None if none does.
    Heightfields are cropped on their grid without building the whole mesh."""
    xmin, ymin, xmax, ymax = bounds
    g = getattr(terrain, "grid", None)
    fm = np.asarray(terrain.face_materials)
    if g is not None:
        gx, gy = g.x_m, g.y_m
        # cell i spans gx[i]..gx[i+1]: it overlaps when gx[i] <= xmax and gx[i+1] >= xmin
        i0 = max(int(np.searchsorted(gx, xmin, side="right")) - 1, 0)
        i1 = min(int(np.searchsorted(gx, xmax, side="right")), gx.size - 1)
        j0 = max(int(np.searchsorted(gy, ymin, side="right")) - 1, 0)
        j1 = min(int(np.searchsorted(gy, ymax, side="right")), gy.size - 1)
        if i1 <= i0 or j1 <= j0:
            return None
        cf = g.cell_face[j0:j1, i0:i1]
        ok = (cf >= 0).ravel()
        if not ok.any():
            return None
        ny, nx = j1 - j0 + 1, i1 - i0 + 1
        idx = np.arange(ny * nx).reshape(ny, nx)
        v00, v10 = idx[:-1, :-1].ravel()[ok], idx[:-1, 1:].ravel()[ok]
        v01, v11 = idx[1:, :-1].ravel()[ok], idx[1:, 1:].ravel()[ok]
        faces = np.empty((2 * v00.size, 3), dtype=np.int64)   # as HeightGrid.build_mesh
        faces[0::2] = np.column_stack([v00, v10, v11])
        faces[1::2] = np.column_stack([v00, v11, v01])
        first = cf.ravel()[ok]
        codes = np.empty(2 * first.size, dtype=fm.dtype)
        codes[0::2], codes[1::2] = fm[first], fm[first + 1]
        xx, yy = np.meshgrid(gx[i0:i1 + 1], gy[j0:j1 + 1])
        verts = np.column_stack([xx.ravel(), yy.ravel(), g.z_m[j0:j1 + 1, i0:i1 + 1].ravel()])
    else:
        verts = np.asarray(terrain.mesh.vertices, dtype=np.float64)
        faces = np.asarray(terrain.mesh.faces, dtype=np.int64)
        fx, fy = verts[faces, 0], verts[faces, 1]
        keep = ((fx.min(axis=1) <= xmax) & (fx.max(axis=1) >= xmin)
                & (fy.min(axis=1) <= ymax) & (fy.max(axis=1) >= ymin))
        if not keep.any():
            return None
        faces, codes = faces[keep], fm[keep]
    used = np.zeros(len(verts), dtype=bool)
    used[faces.ravel()] = True
    remap = np.cumsum(used) - 1
    return verts[used], remap[faces], codes



def footprint_heights(ds, shape) -> np.ndarray:
    """(n_beams, n_shots) footprint heights [m]: the true surface (``h_li_true``), the measured
    height (``h_li``) where the truth is missing, NaN where neither is."""
    h = shot_array(ds, "h_li_true") if "h_li_true" in ds.variables \
        else np.full(shape, np.nan)
    if "h_li" in ds.variables:
        h = np.where(np.isfinite(h), h, shot_array(ds, "h_li"))
    return h


def terrain_arrays(terrain, bounds):
    """(vertices (n, 3), faces (m, 3), material codes (m,)) of the terrain in float64 projected
    metres, cropped to ``bounds`` when given; (None, None, None) without terrain or when none
    of it lies inside the bounds. ValueError for something that is not a Terrain."""
    if terrain is None:
        return None, None, None
    mesh = getattr(terrain, "mesh", None)
    if mesh is None or not hasattr(terrain, "face_materials"):
        raise ValueError("terrain must be a chirplidar.geometry.terrain.Terrain, got "
                         f"{type(terrain).__name__}")
    if bounds is not None:
        cropped = _crop_terrain(terrain, bounds)
        return cropped if cropped is not None else (None, None, None)
    return (np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64),
            np.asarray(terrain.face_materials))


def placed_footprints(x, y, bounds) -> tuple[np.ndarray, int, int]:
    """(mask of the footprints drawn, shots without finite x/y, shots outside ``bounds``);
    ValueError when bounds are given and no footprint lies inside them."""
    finite_xy = np.isfinite(x) & np.isfinite(y)
    n_unplaced = int(np.count_nonzero(~finite_xy))
    placed = finite_xy
    n_outside = 0
    if bounds is not None:
        xmin, ymin, xmax, ymax = bounds
        with np.errstate(invalid="ignore"):
            placed = finite_xy & (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)
        n_outside = int(np.count_nonzero(finite_xy & ~placed))
        if not placed.any():
            span = (f"footprints span x {x[finite_xy].min():.0f} .. {x[finite_xy].max():.0f}"
                    f", y {y[finite_xy].min():.0f} .. {y[finite_xy].max():.0f} m"
                    if finite_xy.any() else "no footprint has finite x and y")
            raise ValueError(f"bounds: no footprint lies inside x {xmin:.0f} .. {xmax:.0f}, "
                             f"y {ymin:.0f} .. {ymax:.0f} m ({span})")
    return placed, n_unplaced, n_outside


def filled_heights(h, placed, tv) -> tuple[np.ndarray, float, float, int]:
    """(heights with the missing ones of placed footprints filled, reference height z_ref [m],
    the fill height [m], footprints filled). A placed footprint without a height (e.g. no
    surface in the beam) is drawn at the median surface height, so the shot is still visible;
    z_ref is the terrain's mean vertex height (``tv``), else the footprints' median height."""
    finite_h = h[placed & np.isfinite(h)]
    if tv is not None:
        z_ref = float(tv[:, 2].mean())
    elif finite_h.size:
        z_ref = float(np.median(finite_h))
    else:
        raise ValueError("ds has no finite h_li_true/h_li and no terrain was given: "
                         "cannot place the footprints in height")
    fill_h = float(np.median(finite_h)) if finite_h.size else z_ref
    n_filled = int(np.count_nonzero(placed & ~np.isfinite(h)))
    return np.where(np.isfinite(h), h, fill_h), z_ref, fill_h, n_filled


def scene_extent(x, y, h, placed, tv, bounds) -> tuple[float, float, float, float, float]:
    """(x_lo, y_lo, x_hi, y_hi, relief) [m]: the box of the scene (the bounds when given, else
    the terrain and footprints) and the height range shown in it (terrain, else footprints)."""
    if bounds is not None:
        x_lo, y_lo, x_hi, y_hi = bounds
        relief = float(np.ptp(tv[:, 2])) if tv is not None else float(np.ptp(h[placed]))
    elif tv is not None:
        x_lo, y_lo = tv[:, 0].min(), tv[:, 1].min()
        x_hi, y_hi = tv[:, 0].max(), tv[:, 1].max()
        if placed.any():
            x_lo, x_hi = min(x_lo, x[placed].min()), max(x_hi, x[placed].max())
            y_lo, y_hi = min(y_lo, y[placed].min()), max(y_hi, y[placed].max())
        relief = float(np.ptp(tv[:, 2]))
    else:
        x_lo, x_hi, y_lo, y_hi = x[placed].min(), x[placed].max(), y[placed].min(), \
            y[placed].max()
        relief = float(np.ptp(h[placed]))
    return x_lo, y_lo, x_hi, y_hi, relief


def checked_exaggeration(vertical_exaggeration, relief_m: float, extent_m: float) -> float:
    """The vertical exaggeration: :func:`auto_vertical_exaggeration` for None, else the value,
    which must be a finite number > 0 (ValueError)."""
    if vertical_exaggeration is None:
        return auto_vertical_exaggeration(relief_m, extent_m)
    try:
        ve = math.nan if isinstance(vertical_exaggeration, (bool, np.bool_)) \
            else float(vertical_exaggeration)
    except (TypeError, ValueError):
        ve = math.nan
    if not (np.isfinite(ve) and ve > 0):
        raise ValueError("vertical_exaggeration must be a finite number > 0 or None, "
                         f"got {vertical_exaggeration!r}")
    return ve


def to_local(origin, ve: float, px, py, pz) -> np.ndarray:
    """(n, 3) local display coordinates of projected points: the origin (x0, y0, z0) removed,
    heights scaled by ``ve`` about z0."""
    x0, y0, z0 = origin
    return np.column_stack([np.ravel(px) - x0, np.ravel(py) - y0, (np.ravel(pz) - z0) * ve])


def footprint_colouring(dvar, var: str, fp_values: np.ndarray) -> dict:
    """How the footprints' values of variable ``dvar`` (named ``var``) are coloured: ``label``
    (colour-bar title), ``scalars`` (the values, or category indices for a flag variable),
    ``categories`` (meanings and colours, None for a continuous variable), ``clim`` and, for a
    continuous variable, ``cmap``."""
    out = {"label": _label(dvar), "categories": None}
    flags = flag_table(dvar)
    if flags is not None:
        fv, fm = flags
        idx = np.full(fp_values.shape, np.nan)
        for i, code in enumerate(fv):
            idx[fp_values == code] = i
        out["scalars"] = idx
        if var == "detected":
            colors = [DETECTED_COLORS.get(int(c), FLAG_COLORS[i % 10])
                      for i, c in enumerate(fv)]
        else:
            colors = [FLAG_COLORS[i % len(FLAG_COLORS)] for i in range(fv.size)]
        out["categories"] = {"meanings": fm, "colors": colors}
        out["clim"] = (-0.5, fv.size - 0.5)
    else:
        out["scalars"] = fp_values
        finite = fp_values[np.isfinite(fp_values)]
        symmetric = not _is_decibel(dvar)
        clim = colour_range(finite, symmetric) if finite.size else None
        out["clim"] = clim
        # Diverging map with a pale-yellow centre: stays distinct from the ice-blue terrain
        # and the grey of no-value shots (coolwarm's grey centre does not).
        out["cmap"] = "RdYlBu_r" if symmetric and clim is not None \
            and clim[0] < 0 < clim[1] else "viridis"
    return out


def platform_geometry(ds, placed, bounds, h, origin, ve: float, extent: float,
                      xyz: np.ndarray) -> dict | None:
    """The platform's track and beam lines in local coordinates, or None when ``ds`` has no
    platform position: ``track`` ((n, 3), None for a satellite, whose track is not drawn),
    ``track_runs`` ((start, stop) rows of the track drawn as one line each), ``rays``
    ((starts, ends), footprint towards platform, a subsample) and ``satellite_km`` (the
    platform's median altitude [km] when it is a satellite, else None). ``xyz``: the
    footprints' local coordinates (n_beams, n_obs, 3)."""
    names = ("platform_x", "platform_y", "platform_altitude")
    if not all(n in ds.variables for n in names):
        return None
    out = {"track": None, "track_runs": [], "rays": None, "satellite_km": None}
    n_beams, n_obs = xyz.shape[:2]
    px, py, pz = (shot_array(ds, n) for n in names)
    track = _first_finite_per_obs(px, py, pz)
    # With bounds: the shots with a footprint inside. The line breaks where the crop
    # removed shots (a lawnmower leaving and re-entering the box), not at NaN fixes.
    shown = placed.any(axis=0) if bounds is not None else np.ones(n_obs, bool)
    rows = np.flatnonzero(np.all(np.isfinite(track), axis=1) & shown)
    track = track[rows]
    cropped_before = np.cumsum(~shown)[rows]
    breaks = np.flatnonzero(np.diff(cropped_before) != 0) + 1
    edges = [0, *breaks.tolist(), rows.size]
    out["track_runs"] = [(a, b) for a, b in itertools.pairwise(edges) if b > a]
    if not track.shape[0]:
        return out
    height_above = float(np.median(track[:, 2])) - float(np.median(h[placed])) \
        if placed.any() else float(np.median(track[:, 2])) - origin[2]
    track_local = to_local(origin, ve, track[:, 0], track[:, 1], track[:, 2])
    # Visibility is decided on the drawn (exaggerated) height.
    satellite = height_above * ve > SATELLITE_RATIO * extent
    # beam lines: footprint -> platform of the same shot, for a subsample
    ray_ok = placed & np.all(np.isfinite(np.stack([px, py, pz], -1)), axis=-1)
    starts, ends = [], []
    for b in range(n_beams):
        obs = np.flatnonzero(ray_ok[b])
        obs = obs[_every_kth(obs.size, MAX_SEGMENTS_PER_BEAM if satellite
                             else MAX_RAYS_PER_BEAM)]
        starts.append(xyz[b, obs])
        ends.append(to_local(origin, ve, px[b, obs], py[b, obs], pz[b, obs]))
    starts, ends = np.concatenate(starts), np.concatenate(ends)
    if satellite:
        out["satellite_km"] = float(np.median(track[:, 2])) / 1e3
        d = ends - starts
        norm = np.linalg.norm(d, axis=1, keepdims=True)
        norm[norm == 0] = 1.0
        ends = starts + d / norm * (SEGMENT_FRACTION * extent)
    else:
        out["track"] = track_local
    out["rays"] = (starts, ends)
    return out

"""A loaded scene: the terrain in its projection, surface materials, atmosphere and effects.

:func:`load_scene` reads a scene file (its schema, validation and messages are in
:mod:`chirplidar.config.scene`), builds its terrain (:mod:`chirplidar.mission.scene_terrain`:
generated and cached, or read from a mesh or DEM file) and returns a :class:`Scene`, which answers
the survey's questions: ground heights, material reflectivities and slopes, the atmosphere's
transmission and Fried parameter. Heights everywhere are ellipsoidal (WGS-84) heights in metres,
the scene frame's z.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..atmosphere import turbulence as _turbulence
from ..config.loader import ConfigError
from ..config.models_effects import EFFECT_NAMES
from ..config.scene import SceneConfig, read_scene_config, scene_error
from ..geometry.frames import geodetic_to_projected, projected_to_geodetic
from ..geometry.raycast import cast_rays
from ..geometry.terrain import Terrain
from ..target.materials import MATERIALS
from .scene_terrain import build_terrain

__all__ = ["Scene", "load_scene", "scene_from_text"]


# ---------------------------------------------------------------------- the scene
@dataclass(frozen=True, eq=False)
class Scene:
    """A loaded scene: terrain mesh in the EPSG frame (metres, z = ellipsoidal height), material
    table, atmosphere and effects.

    path: the scene file (None if built from text); text: the file's text (stored in result
    files); overrides: dotted-key overrides applied on top of it; center_xy_m: the scene centre
    in the EPSG frame (the given centre, or the middle of a file terrain's bounds);
    cache_file / cache_hit: where a generated heightfield was cached and whether it was read
    from there; build_s: wall time of building the terrain (s).
    """

    path: Path | None
    name: str
    epsg: int
    terrain: Terrain
    effects: tuple[str, ...]
    config: SceneConfig
    text: str
    center_xy_m: tuple[float, float]
    overrides: tuple[tuple[str, Any], ...] = ()
    cache_file: Path | None = None
    cache_hit: bool = False
    build_s: float = 0.0
    input_files: tuple[Path, ...] = ()   # files the terrain was read from (mesh, DEM)

    # -- geometry
    @property
    def bounds_xy(self) -> tuple[float, float, float, float]:
        """(x0, x1, y0, y1) of the terrain mesh in the EPSG frame (m)."""
        lo, hi = self.terrain.bounds
        return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])

    @property
    def height_range_m(self) -> tuple[float, float]:
        """(z_min, z_max): ellipsoidal height range of the terrain (m)."""
        lo, hi = self.terrain.bounds
        return float(lo[2]), float(hi[2])

    @property
    def center_lat_lon_deg(self) -> tuple[float, float]:
        """Geodetic latitude and longitude of the scene centre (deg)."""
        lat, lon, _ = projected_to_geodetic(*self.center_xy_m, 0.0, self.epsg)
        return float(lat), float(lon)

    @property
    def material_names(self) -> tuple[str, ...]:
        return self.terrain.material_names

    def has_effect(self, name: str) -> bool:
        """Whether the scene enables ``name`` (one of EFFECT_NAMES; ValueError otherwise)."""
        if name not in EFFECT_NAMES:
            raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}")
        return name in self.effects

    def ground_height_m(self, x_m, y_m) -> np.ndarray:
        """Terrain height (ellipsoidal, m) below grid points (x_m, y_m) (EPSG metres).

        Vectorised over broadcast x_m, y_m; NaN off the terrain, in no-data holes and where x/y
        is not finite. Heightfield terrains (generated, DEM) evaluate the plane of the grid
        triangle under each point directly (``HeightGrid.surface_height_m``); mesh files cast a
        vertical ray down from above the highest terrain point, and on overhangs the highest
        surface is returned.
        """
        if self.terrain.grid is not None:
            return self.terrain.grid.surface_height_m(x_m, y_m)
        x, y = np.broadcast_arrays(np.asarray(x_m, dtype=np.float64),
                                   np.asarray(y_m, dtype=np.float64))
        out = np.full(x.shape, np.nan)
        ok = np.isfinite(x) & np.isfinite(y)
        if not ok.any():
            return out
        top = self.height_range_m[1] + 1.0
        xo, yo = x[ok], y[ok]
        o = np.column_stack([xo, yo, np.full(xo.size, top)])
        d = np.broadcast_to([0.0, 0.0, -1.0], o.shape)
        hits = cast_rays(self.terrain, o, d)
        z = np.where(hits.hit, top - hits.ranges_m, np.nan)
        # Rays exactly on the mesh's outer edge (e.g. x = bounds_xy[1]) can miss: retry those
        # inside the closed bounds a hair towards the centre, then evaluate the plane of the
        # face found at the original (x, y), so edge heights stay exact.
        x0, x1, y0, y1 = self.bounds_xy
        retry = np.flatnonzero(~hits.hit & (xo >= x0) & (xo <= x1) & (yo >= y0) & (yo <= y1))
        if retry.size:
            eps = 1e-6 * max(x1 - x0, y1 - y0)
            cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
            on = o[retry].copy()
            on[:, 0] += np.sign(cx - on[:, 0]) * eps
            on[:, 1] += np.sign(cy - on[:, 1]) * eps
            h2 = cast_rays(self.terrain, on, d[: retry.size])
            got = h2.hit
            if got.any():
                tri = self.terrain.face_vertices(h2.face_index[got])
                n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
                px, py = xo[retry[got]], yo[retry[got]]
                z[retry[got]] = tri[:, 0, 2] - (n[:, 0] * (px - tri[:, 0, 0])
                                                + n[:, 1] * (py - tri[:, 0, 1])) / n[:, 2]
        out[ok] = z
        return out

    # -- materials
    def material_reflectivity(self, wavelength_m) -> np.ndarray:
        """Reflectivity (W/W) of every material code of ``terrain.material_names`` at
        ``wavelength_m`` (m, scalar): the table of :mod:`chirplidar.target.materials` with the
        scene's ``[materials.<name>] reflectivity`` overrides.

        A material the terrain does not use and that has no value at this wavelength is NaN;
        one that the terrain uses raises ValueError naming it.
        """
        wl = float(wavelength_m)
        if not (np.isfinite(wl) and wl > 0):
            raise ValueError(f"wavelength_m must be a finite positive scalar, got {wavelength_m!r}")
        out = np.full(len(self.material_names), np.nan)
        for code, name in enumerate(self.material_names):
            over = self.config.materials.get(name)
            if over is not None and over.reflectivity is not None:
                out[code] = over.reflectivity
                continue
            try:
                out[code] = float(MATERIALS[name].reflectivity_at(wl))
            except ValueError as exc:
                if np.any(self.terrain.face_materials == code):
                    raise ValueError(f"scene {self.name!r}: terrain material {name!r}: {exc}; "
                                     f"override it with [materials.{name}] reflectivity") from None
        return out

    def material_specular(self) -> np.ndarray:
        """(n_materials,) bool: True where a material scatters specularly (overrides applied)."""
        out = np.zeros(len(self.material_names), dtype=bool)
        for code, name in enumerate(self.material_names):
            over = self.config.materials.get(name)
            kind = (over.scattering if over is not None and over.scattering is not None
                    else MATERIALS[name].scattering)
            out[code] = kind == "specular"
        return out

    def material_mss(self) -> np.ndarray:
        """(n_materials,) mean-square facet slope of the specular materials (``[materials.<name>]
        wind_speed_mps`` via Cox-Munk, or ``mean_square_slope``); NaN where not given (Lambertian
        materials, and specular ones the terrain does not use: loading checks the used ones)."""
        out = np.full(len(self.material_names), np.nan)
        for code, name in enumerate(self.material_names):
            over = self.config.materials.get(name)
            if over is not None and over.mss() is not None:
                out[code] = over.mss()
        return out

    def water_mss(self) -> float:
        """Mean-square facet slope of ``open_water`` (see ``material_mss``); ValueError if the
        scene does not give one."""
        v = float(self.material_mss()[self.material_names.index("open_water")])
        if np.isnan(v):
            raise ValueError(f"scene {self.name!r} gives no slopes for open_water: set "
                             "[materials.open_water] wind_speed_mps or mean_square_slope")
        return v

    # -- atmosphere
    def one_way_power_transmission(self, h_low_m, h_high_m, zenith_rad) -> np.ndarray:
        """One-way power transmission (W/W) between ellipsoidal heights h_low_m and h_high_m (m)
        along a straight path at zenith angle zenith_rad (rad, [0, pi/2)), flat Earth.

        Exponential atmosphere alpha(h) = alpha0 exp(-h/H):
        tau = alpha0 H (exp(-h_low/H) - exp(-h_high/H)) / cos(zenith), T = exp(-tau)
        (the difference computed with expm1, so short paths reach Beer-Lambert
        exp(-alpha0 exp(-h/H) L) exactly; H = inf is the uniform atmosphere alpha0 L).
        The two heights may come in either order. Vectorised (broadcast); float64 array.
        """
        a = self.config.atmosphere
        lo, hi, zen = np.broadcast_arrays(np.asarray(h_low_m, dtype=np.float64),
                                          np.asarray(h_high_m, dtype=np.float64),
                                          np.asarray(zenith_rad, dtype=np.float64))
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError("h_low_m and h_high_m must be finite heights (m)")
        if not np.all((zen >= 0) & (zen < np.pi / 2)):
            raise ValueError("zenith_rad must lie in [0, pi/2) rad")
        lo, hi = np.minimum(lo, hi), np.maximum(lo, hi)
        alpha0, big_h = a.extinction_per_m, a.scale_height_m
        if np.isinf(big_h):
            column = hi - lo
        else:   # H (e^{-lo/H} - e^{-hi/H}) = H e^{-lo/H} (-expm1(-(hi-lo)/H))
            column = big_h * np.exp(-lo / big_h) * -np.expm1(-(hi - lo) / big_h)
        return np.exp(-alpha0 * column / np.cos(zen))

    def cn2_profile(self):
        """The Cn^2 profile as a callable altitude-above-ground (m) -> m^-2/3, or None."""
        a = self.config.atmosphere
        if a.cn2_profile == "hufnagel_valley":
            return _turbulence.hufnagel_valley_profile(a.ground_cn2_m_minus_2_3, a.rms_wind_mps)
        if a.cn2_profile == "constant":
            return _turbulence.constant_profile(a.cn2_m_minus_2_3)
        return None

    def fried_parameter_m(self, wavelength_m, h_low_m, h_high_m, zenith_rad,
                          wave: str = "spherical", source: str = "low") -> np.ndarray:
        """Fried parameter r0 (m) of the slant path between ellipsoidal heights h_low_m and
        h_high_m (m) at zenith angle zenith_rad (rad, at the lower end), wavelength_m (m).

        The Cn^2 profile's "altitude above ground" is measured from the lower end (the lit spot
        on the terrain); the path integral is :func:`chirplidar.atmosphere.turbulence.
        fried_parameter_profile` (spherical Earth). ``wave``: "spherical" (a point source, e.g.
        the lit spot seen by the receiver) or "plane"; ``source``: "low" (the wave starts at the
        lower end: the return) or "high" (the platform: the downlink). cn2_profile = "none": inf.
        Vectorised by broadcasting; each distinct (h_high - h_low, zenith) is one quadrature
        (about a millisecond), so pass per-pass rather than per-shot arrays where possible.
        """
        if source not in ("low", "high"):
            raise ValueError(f"source must be 'low' or 'high', got {source!r}")
        lo, hi, zen = np.broadcast_arrays(np.asarray(h_low_m, dtype=np.float64),
                                          np.asarray(h_high_m, dtype=np.float64),
                                          np.asarray(zenith_rad, dtype=np.float64))
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError("h_low_m and h_high_m must be finite heights (m)")
        profile = self.cn2_profile()
        if profile is None:
            return np.full(lo.shape, np.inf)
        dh = hi - lo
        if np.any(dh <= 0):
            raise ValueError("h_high_m must be above h_low_m (a vertical extent is needed for a "
                             "path through the Cn^2 profile)")
        pairs = np.stack([dh.ravel(), zen.ravel()], axis=1)
        uniq, inverse = np.unique(pairs, axis=0, return_inverse=True)
        vals = np.empty(len(uniq))
        for i, (d, z) in enumerate(uniq):   # one quadrature per distinct geometry
            src, rcv = (0.0, d) if source == "low" else (d, 0.0)
            vals[i] = _turbulence.fried_parameter_profile(
                profile, wavelength_m, source_altitude_m=src, receiver_altitude_m=rcv,
                zenith_angle_rad=z, wave=wave)
        return vals[np.ravel(inverse)].reshape(lo.shape)

    def describe(self) -> str:
        """One paragraph: name, frame, centre, bounds, triangles, materials, effects."""
        x0, x1, y0, y1 = self.bounds_xy
        z0, z1 = self.height_range_m
        lat, lon = self.center_lat_lon_deg
        names = self.terrain.face_material_names()
        mats, counts = np.unique(names, return_counts=True)
        mat = ", ".join(f"{m} {c / names.size:.1%}" for m, c in zip(mats, counts))
        return (f"{self.name}: EPSG:{self.epsg}, centre {lat:.4f} {lon:.4f} deg, "
                f"x {x0:.0f}..{x1:.0f} m, y {y0:.0f}..{y1:.0f} m, z {z0:.1f}..{z1:.1f} m, "
                f"{self.terrain.n_faces} triangles ({mat}), holes {self.terrain.holes}, "
                f"effects {list(self.effects) or 'none'}")


# ---------------------------------------------------------------------- loading
def _check_specular_slopes(cfg: SceneConfig, terr: Terrain, source: str) -> None:
    """Every specular material on the terrain needs its facet slopes (no silent default)."""
    counts = np.bincount(terr.face_materials, minlength=len(terr.material_names))
    for code, name in enumerate(terr.material_names):
        over = cfg.materials.get(name)
        kind = (over.scattering if over is not None and over.scattering is not None
                else MATERIALS[name].scattering)
        if counts[code] and kind == "specular" and (over is None or over.mss() is None):
            raise scene_error(source, f"materials.{name}.wind_speed_mps",
                              f"missing: the terrain has {counts[code]} {name} faces (specular); "
                              "give wind_speed_mps (Cox-Munk slopes) or mean_square_slope")


def _centre(cfg: SceneConfig) -> tuple[float, float] | None:
    """The scene centre the file gives, in the EPSG frame (m); None if the terrain places it."""
    t = cfg.terrain
    if t.center_x_m is not None:
        return float(t.center_x_m), float(t.center_y_m)
    if t.center_lat_deg is not None:
        x, y, _ = geodetic_to_projected(t.center_lat_deg, t.center_lon_deg, 0.0, cfg.epsg)
        return float(x), float(y)
    return None


class _Progress:
    """Stage timings of building a scene on stderr (when on)."""

    def __init__(self, on: bool, label: str):
        self.on, self.label, self.t0 = on, label, time.perf_counter()

    def __call__(self, what: str):
        if self.on:
            print(f"[scene {self.label}] {time.perf_counter() - self.t0:7.2f} s  {what}",
                  file=sys.stderr, flush=True)


def scene_from_text(text: str, *, base_dir, source: str | None = None, path=None,
                    cache_dir=None, use_cache: bool = True, progress: bool = False,
                    overrides: Iterable[str] | Mapping[str, Any] = ()) -> Scene:
    """Build a :class:`Scene` from scene-file text (e.g. the copy stored in a result file).

    base_dir: directory that relative paths in the text are resolved against; source: the name
    used in error messages (default: ``path`` or "<scene text>"); overrides: ``--set`` style
    ``["terrain.resolution_m=20", ...]`` or a mapping of dotted keys to values, applied before
    validation; cache_dir / use_cache / progress as in :func:`load_scene`.
    """
    source = source or (str(path) if path is not None else "<scene text>")
    cfg, applied = read_scene_config(text, source, overrides)
    say = _Progress(progress, cfg.name)
    t0 = time.perf_counter()
    centre = _centre(cfg)
    built = build_terrain(cfg, Path(base_dir), source, centre, cache_dir=cache_dir,
                          use_cache=use_cache, say=say)
    terr = built.terrain
    _check_specular_slopes(cfg, terr, source)
    if centre is None:
        lo, hi = terr.bounds
        centre = (float(lo[0] + hi[0]) / 2, float(lo[1] + hi[1]) / 2)
    build_s = time.perf_counter() - t0
    say(f"terrain ready: {terr.n_faces} triangles")
    return Scene(path=Path(path) if path is not None else None, name=cfg.name, epsg=cfg.epsg,
                 terrain=terr, effects=tuple(cfg.effects), config=cfg, text=text,
                 center_xy_m=centre, overrides=applied, cache_file=built.cache_file,
                 cache_hit=built.cache_hit, build_s=build_s, input_files=built.input_files)


def load_scene(path, *, cache_dir=None, use_cache: bool = True, progress: bool = False,
               overrides: Iterable[str] | Mapping[str, Any] = ()) -> Scene:
    """Load and validate a scene file and build its terrain.

    path: the scene TOML file; relative paths inside it are relative to its directory.
    cache_dir: where generated heightfields are cached (default
    :func:`~chirplidar.mission.scene_terrain.default_cache_dir`);
    use_cache=False neither reads nor writes the cache. progress: stage timings on stderr.
    overrides: ``--set`` style changes applied before validation (e.g.
    ``["terrain.resolution_m=20"]``). Errors: :class:`ConfigError` naming the file and the key.
    """
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read scene file ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{p}: not a scene file (not UTF-8 text; a scene is a TOML "
                          "file)") from None
    return scene_from_text(text, base_dir=p.parent, path=p, cache_dir=cache_dir,
                           use_cache=use_cache, progress=progress, overrides=overrides)

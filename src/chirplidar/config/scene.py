"""Scene files: the schema of the terrain, its projection, surface materials, atmosphere and
enabled effects, and reading a scene file's text into a validated :class:`SceneConfig`.

A mission file references a scene file by path (``[scene] file = "../scenes/x.toml"``). The scene
file is TOML, validated by :class:`SceneConfig` (on :class:`~chirplidar.config.base.StrictModel`:
unknown keys are errors with close matches, inf and NaN are refused, SI units in key names, no
defaults for physical quantities). Paths inside a scene file are relative to the scene file. See
``scenes/README.md`` for the schema with an example; :mod:`chirplidar.mission.scene` builds the
terrain and the runtime :class:`~chirplidar.mission.scene.Scene`.

Top level: ``name``, ``description`` (optional), ``epsg`` (3413 Greenland / 3031 Antarctica),
``effects`` (names of :data:`chirplidar.config.models_effects.EFFECT_NAMES`), ``[terrain]``,
``[materials.<name>]`` (optional overrides), ``[atmosphere]``.

Terrain sources (``terrain.source``):

* ``synthetic``:
  :func:`~chirplidar.geometry.synthetic_terrain.synthetic_ice_sheet_heightfield` on a grid of
  ``size_x_m`` x ``size_y_m`` (projected-grid metres) centred on the scene centre, step
  ``resolution_m``, seeded by ``seed``; flow along grid x; divide and margin positions are given
  relative to the scene centre and feature bands as distances from the margin (metres);
* ``flat`` / ``sloped``: test planes on the same kind of grid;
* ``mesh``: an OBJ/STL/PLY/GLB file, vertices in ``"projected"`` EPSG metres or relative to the
  scene centre (``"scene_centre"``), z = ellipsoidal height;
* ``dem``: a projected raster (GeoTIFF ...) with heights above the ellipsoid, its no-data pixels
  an error (default), holes or filled from the nearest valid pixel.

Heights everywhere are ellipsoidal (WGS-84) heights in metres, the scene frame's z.
"""

from __future__ import annotations

import copy
import math
import sys
from collections.abc import Iterable, Mapping
from typing import Any, Literal

from pydantic import Field, ValidationError, field_validator, model_validator

from ..geometry.frames import SUPPORTED_EPSG
from ..geometry.synthetic_terrain import SYNTHETIC_FEATURES
from ..geometry.terrain import MATERIAL_NAMES
from ..target.materials import MATERIALS
from ..target.reflectance import COX_MUNK_MAX_WIND_MPS, cox_munk_mss
from .base import FieldError, StrictModel
from .keys import KeyIndex, model_keys
from .loader import ConfigError, parse_set
from .models_effects import EFFECT_NAMES

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

TERRAIN_SOURCES = ("synthetic", "mesh", "dem", "flat", "sloped")
#: The terrain sources generated on a grid (and cached), not read from a file.
GENERATED_SOURCES = ("synthetic", "flat", "sloped")

# Latitude bands the polar stereographic frames are meant for (EPSG areas of use are north of
# 60 N / south of 60 S; 40 deg leaves room for southern Greenland and sub-Antarctic margins).
_HEMISPHERE = {3413: ("north", 40.0), 3031: ("south", -40.0)}
_EPSG_NAMES = {3413: "NSIDC Sea Ice Polar Stereographic North (Greenland)",
               3031: "Antarctic Polar Stereographic"}

Pair = tuple[float, float]

#: Each pond or outcrop is one pass over the whole grid: the count is bounded so a typo
#: (n_ponds = 1e8) is an error, not hours of generation.
MAX_FEATURES = 1000
#: Grid nodes x features above which generation would take minutes (2e9: ~1000 features on
#: the 1e6-node demo grid).
MAX_FEATURE_WORK = 2e9
#: A projected coordinate (m) lies within half the Earth's circumference of the frame's origin.
MAX_PROJECTED_M = 2e7


def _check_material(name: str) -> str:
    if name not in MATERIAL_NAMES:
        raise FieldError("", f"unknown material {name!r}; known: {', '.join(MATERIAL_NAMES)}")
    return name


def _increasing(key: str, pair: Pair | None) -> None:
    if pair is not None and not pair[0] <= pair[1]:
        raise FieldError(key, f"must be [low, high] with low <= high, got {list(pair)}")


class SyntheticTerrain(StrictModel):
    """``[terrain.synthetic]``: a Vialov ice-sheet margin with crevasses, sastrugi, ponds, rock.

    Positions along grid x are relative to the scene centre; the ice flows along grid x from the
    divide to the margin. Bands are distances from the margin (m) and are converted to the
    generator's fractions of L = |margin_x_m - divide_x_m|. Optional keys fall back to the
    documented defaults of ``synthetic_ice_sheet_heightfield``.
    """

    divide_height_m: float = Field(gt=0, description="ice surface at the divide above the "
                                   "ice-free ground, H of the Vialov profile")
    base_height_m: float = Field(description="ellipsoidal height of the ice-free ground (the "
                                 "profile's zero, at the margin)")
    divide_x_m: float = Field(description="divide position along grid x from the scene centre")
    margin_x_m: float = Field(description="margin position along grid x from the scene centre")
    features: tuple[str, ...] = Field(SYNTHETIC_FEATURES, description="features to generate")
    snow_line_from_margin_m: float | None = Field(
        None, gt=0, description="snow (up-glacier) / blue ice boundary; generator default "
        "0.4 L from the margin (ela_fraction 0.6)")
    crevasse_band_from_margin_m: Pair | None = None
    crevasse_spacing_m: float | None = Field(None, gt=0)
    crevasse_depth_m: float | None = Field(None, ge=0)
    sastrugi_rms_m: float | None = Field(None, ge=0)
    sastrugi_length_m: Pair | None = Field(None, description="(along wind, across wind)")
    sastrugi_azimuth_deg: float | None = Field(
        None, description="wind direction the sastrugi are aligned with, clockwise from grid "
        "north (+y)")
    pond_band_from_margin_m: Pair | None = None
    n_ponds: int | None = Field(None, ge=0, le=MAX_FEATURES)
    pond_radius_m: Pair | None = None
    pond_depth_m: float | None = Field(None, ge=0)
    pond_max_basin_m: float | None = Field(None, ge=0)
    outcrop_band_from_margin_m: Pair | None = None
    n_outcrops: int | None = Field(None, ge=0, le=MAX_FEATURES)
    outcrop_height_m: Pair | None = None
    outcrop_radius_m: Pair | None = None

    @field_validator("features")
    @classmethod
    def _features(cls, v):
        unknown = [f for f in v if f not in SYNTHETIC_FEATURES]
        if unknown:
            raise FieldError("", f"unknown feature(s) {unknown}; "
                             f"known: {', '.join(SYNTHETIC_FEATURES)}")
        if len(set(v)) != len(v):
            raise FieldError("", f"features listed twice: {list(v)}")
        return v

    @model_validator(mode="after")
    def _geometry(self):
        length = abs(self.margin_x_m - self.divide_x_m)
        if length == 0:
            raise FieldError("margin_x_m", "must differ from divide_x_m")
        for key in ("crevasse_band_from_margin_m", "pond_band_from_margin_m",
                    "outcrop_band_from_margin_m"):
            band = getattr(self, key)
            _increasing(key, band)
            if band is not None and not (0 <= band[0] and band[1] <= length):
                raise FieldError(key, f"must lie within 0..{length:g} m (the margin-divide "
                                 f"distance), got {list(band)}")
        if self.snow_line_from_margin_m is not None and self.snow_line_from_margin_m >= length:
            raise FieldError("snow_line_from_margin_m", f"must be below the margin-divide "
                             f"distance {length:g} m, got {self.snow_line_from_margin_m:g}")
        for key in ("pond_radius_m", "outcrop_height_m", "outcrop_radius_m"):
            pair = getattr(self, key)
            _increasing(key, pair)
            if pair is not None and pair[0] <= 0:
                raise FieldError(key, f"must be > 0, got {list(pair)}")
        if self.sastrugi_length_m is not None and min(self.sastrugi_length_m) <= 0:
            raise FieldError("sastrugi_length_m", "correlation lengths must be > 0")
        return self

    @property
    def flow_length_m(self) -> float:
        """L: distance from the divide to the margin (m)."""
        return abs(self.margin_x_m - self.divide_x_m)

    def generator_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of ``synthetic_ice_sheet_heightfield`` (grid centred on 0)."""
        length = self.flow_length_m

        def frac(band):   # distances from the margin -> fractions of L from the divide
            return (1.0 - band[1] / length, 1.0 - band[0] / length)

        kw: dict[str, Any] = {"divide_height_m": self.divide_height_m,
                              "margin_x_m": self.margin_x_m, "divide_x_m": self.divide_x_m,
                              "features": tuple(self.features)}
        if self.snow_line_from_margin_m is not None:
            kw["ela_fraction"] = 1.0 - self.snow_line_from_margin_m / length
        for key, gen in (("crevasse_band_from_margin_m", "crevasse_band"),
                         ("pond_band_from_margin_m", "pond_band"),
                         ("outcrop_band_from_margin_m", "outcrop_band")):
            if getattr(self, key) is not None:
                kw[gen] = frac(getattr(self, key))
        for key in ("crevasse_spacing_m", "crevasse_depth_m", "sastrugi_rms_m",
                    "sastrugi_length_m", "n_ponds", "pond_radius_m", "pond_depth_m",
                    "pond_max_basin_m", "n_outcrops", "outcrop_height_m", "outcrop_radius_m"):
            if getattr(self, key) is not None:
                kw[key] = getattr(self, key)
        if self.sastrugi_azimuth_deg is not None:   # compass-like -> from +x towards +y
            kw["sastrugi_azimuth_rad"] = math.radians(90.0 - self.sastrugi_azimuth_deg)
        return kw


class _MaterialSection(StrictModel):
    material: str = Field(description=f"surface material, one of {MATERIAL_NAMES}")

    @field_validator("material")
    @classmethod
    def _material(cls, v):
        return _check_material(v)


class MeshTerrain(_MaterialSection):
    """``[terrain.mesh]``: a triangle mesh file (OBJ/STL/PLY/GLB), one material for all faces."""

    path: str = Field(min_length=1, description="relative to the scene file")
    coordinates: Literal["projected", "scene_centre"] = Field(
        description="'projected': vertices in the scene's EPSG metres; 'scene_centre': x, y "
        "relative to the scene centre (terrain.center_*); z is the ellipsoidal height in both")


class DemTerrain(_MaterialSection):
    """``[terrain.dem]``: a projected DEM raster of ellipsoidal heights (rasterio)."""

    path: str = Field(min_length=1, description="relative to the scene file")
    band: int = Field(1, ge=1, description="raster band holding the heights")
    nodata: Literal["error", "holes", "fill"] = Field(
        "error", description="no-data pixels: 'error' (refuse the file), 'holes' (cells left "
        "out; rays there miss), 'fill' (nearest valid pixel's height)")


class FlatTerrain(_MaterialSection):
    """``[terrain.flat]``: a horizontal plane."""

    height_m: float = Field(description="ellipsoidal height of the plane")


class SlopedTerrain(_MaterialSection):
    """``[terrain.sloped]``: a plane through the scene centre at ``height_m``."""

    slope_deg: float = Field(ge=0, lt=90)
    azimuth_deg: float = Field(description="uphill direction, clockwise from grid north (+y)")
    height_m: float = Field(description="ellipsoidal height at the scene centre")



class TerrainConfig(StrictModel):
    """``[terrain]``: where the scene sits and which terrain source builds it."""

    source: Literal["synthetic", "mesh", "dem", "flat", "sloped"]
    center_lat_deg: float | None = Field(None, ge=-90, le=90)
    center_lon_deg: float | None = Field(None, ge=-180, le=360)
    center_x_m: float | None = Field(None, ge=-MAX_PROJECTED_M, le=MAX_PROJECTED_M)
    center_y_m: float | None = Field(None, ge=-MAX_PROJECTED_M, le=MAX_PROJECTED_M)
    size_x_m: float | None = Field(None, gt=0, description="grid extent along x (projected m)")
    size_y_m: float | None = Field(None, gt=0, description="grid extent along y (projected m)")
    resolution_m: float | None = Field(None, gt=0, description="grid step (projected m)")
    seed: int | None = Field(None, ge=0, description="seed of the synthetic terrain's Generator")
    synthetic: SyntheticTerrain | None = None
    mesh: MeshTerrain | None = None
    dem: DemTerrain | None = None
    flat: FlatTerrain | None = None
    sloped: SlopedTerrain | None = None

    @model_validator(mode="after")
    def _consistent(self):
        src = self.source
        if getattr(self, src) is None:
            raise FieldError(src, f"missing section [terrain.{src}] (terrain.source = '{src}')")
        for other in TERRAIN_SOURCES:
            if other != src and getattr(self, other) is not None:
                raise FieldError(other, f"section given but terrain.source = '{src}'; "
                                 f"remove [terrain.{other}] or change terrain.source")
        geo = (self.center_lat_deg, self.center_lon_deg)
        xy = (self.center_x_m, self.center_y_m)
        for pair, names in ((geo, ("center_lat_deg", "center_lon_deg")),
                            (xy, ("center_x_m", "center_y_m"))):
            if (pair[0] is None) != (pair[1] is None):
                missing = names[0] if pair[0] is None else names[1]
                raise FieldError(missing, f"missing: {names[0]} and {names[1]} go together")
        has_geo, has_xy = geo[0] is not None, xy[0] is not None
        if has_geo and has_xy:
            raise FieldError("center_x_m", "give the centre either as center_lat_deg/"
                             "center_lon_deg or as center_x_m/center_y_m, not both")
        needs_centre = src in GENERATED_SOURCES or (src == "mesh" and self.mesh.coordinates ==
                                             "scene_centre")
        if needs_centre and not (has_geo or has_xy):
            raise FieldError("center_lat_deg", f"missing: terrain.source = '{src}' needs the "
                             "scene centre (center_lat_deg/center_lon_deg or "
                             "center_x_m/center_y_m)")
        if not needs_centre and (has_geo or has_xy):
            why = ("the DEM's own coordinates place it" if src == "dem" else
                   "terrain.mesh.coordinates = 'projected' places the mesh")
            raise FieldError("center_lat_deg" if has_geo else "center_x_m",
                             f"not used: {why} (the centre is the middle of its bounds)")
        grid = ("size_x_m", "size_y_m", "resolution_m")
        if src in GENERATED_SOURCES:
            for k in grid:
                if getattr(self, k) is None:
                    raise FieldError(k, f"missing: terrain.source = '{src}' is generated on "
                                     "a grid (size_x_m, size_y_m, resolution_m)")
            if self.resolution_m > min(self.size_x_m, self.size_y_m):
                raise FieldError("resolution_m", f"{self.resolution_m:g} m is larger than "
                                 "the grid's size")
            nodes = (self.size_x_m / self.resolution_m + 2) * (self.size_y_m /
                                                               self.resolution_m + 2)
            if nodes > 5e7:
                raise FieldError("resolution_m", f"{self.resolution_m:g} m gives ~{nodes:.3g} "
                                 "grid nodes (> 5e7); coarsen it")
            if src == "synthetic":
                syn = self.synthetic
                n_features = (syn.n_ponds or 0) * ("ponds" in syn.features) + \
                    (syn.n_outcrops or 0) * ("outcrops" in syn.features)
                if n_features * nodes > MAX_FEATURE_WORK:
                    raise FieldError("synthetic", f"{n_features} ponds and outcrops on "
                                     f"~{nodes:.3g} grid nodes would take minutes to generate "
                                     f"(each is a pass over the grid; keep features x nodes "
                                     f"<= {MAX_FEATURE_WORK:.0e}): fewer features or a coarser "
                                     "resolution_m")
        else:
            for k in grid:
                if getattr(self, k) is not None:
                    raise FieldError(k, f"not used: terrain.source = '{src}' takes its extent "
                                     "and resolution from the file")
        if src == "synthetic" and self.seed is None:
            raise FieldError("seed", "missing: the synthetic terrain is random (seeded)")
        if src != "synthetic" and self.seed is not None:
            raise FieldError("seed", f"not used: terrain.source = '{src}' draws no random "
                             "numbers")
        return self

    @property
    def section(self):
        """The model of the chosen source's section."""
        return getattr(self, self.source)


class MaterialOverride(StrictModel):
    """``[materials.<name>]``: overrides of the material table, and the facet slopes of a
    specular surface (open water), which the table does not carry.

    reflectivity replaces the tabulated value at every wavelength. A specular material used by
    the terrain needs its slope distribution: ``wind_speed_mps`` (Cox & Munk 1954 clean-surface
    fit, mss = 0.003 + 5.12e-3 U) or ``mean_square_slope`` directly (0: a mirror).
    """

    reflectivity: float | None = Field(None, ge=0, le=1, description="W/W, meaning as in "
                                       "chirplidar.target.materials (Lambertian rho or facet "
                                       "Fresnel reflectance)")
    scattering: Literal["lambertian", "specular"] | None = None
    wind_speed_mps: float | None = Field(
        None, ge=0, le=COX_MUNK_MAX_WIND_MPS, description="specular: wind speed at 12.5 m "
        "over the surface (Cox-Munk fit, 0-14 m/s)")
    mean_square_slope: float | None = Field(
        None, ge=0, description="specular: total mean-square facet slope (0: mirror)")

    @model_validator(mode="after")
    def _something(self):
        if all(getattr(self, k) is None for k in type(self).model_fields):
            raise FieldError("", "give reflectivity, scattering, wind_speed_mps or "
                             "mean_square_slope (or drop the section)")
        if self.wind_speed_mps is not None and self.mean_square_slope is not None:
            raise FieldError("mean_square_slope", "give either wind_speed_mps or "
                             "mean_square_slope, not both")
        return self

    def mss(self) -> float | None:
        """Mean-square facet slope, or None if neither key is given."""
        if self.mean_square_slope is not None:
            return self.mean_square_slope
        if self.wind_speed_mps is not None:
            return float(cox_munk_mss(self.wind_speed_mps))
        return None


class AtmosphereConfig(StrictModel):
    """``[atmosphere]``: turbulence profile and an exponential extinction profile.

    alpha(h) = extinction_per_m * exp(-h / scale_height_m), h the ellipsoidal height (taken as
    the height above sea level: geoid undulations of tens of metres are small against H).
    """

    cn2_profile: Literal["hufnagel_valley", "constant", "none"]
    ground_cn2_m_minus_2_3: float | None = Field(
        None, ge=0, description="hufnagel_valley: ground-layer coefficient A (HV-5/7: 1.7e-14)")
    rms_wind_mps: float | None = Field(
        None, ge=0, description="hufnagel_valley: rms 5-20 km wind speed (HV-5/7: 21)")
    cn2_m_minus_2_3: float | None = Field(None, ge=0, description="constant: Cn^2")
    extinction_per_m: float = Field(ge=0, description="extinction coefficient at h = 0 at the "
                                    "instrument wavelength (power, Beer-Lambert)")
    scale_height_m: float = Field(gt=0, allow_inf_nan=True,
                                  description="H of the exponential profile (inf: uniform)")

    @model_validator(mode="after")
    def _profile_keys(self):
        need = {"hufnagel_valley": ("ground_cn2_m_minus_2_3", "rms_wind_mps"),
                "constant": ("cn2_m_minus_2_3",), "none": ()}[self.cn2_profile]
        for k in ("ground_cn2_m_minus_2_3", "rms_wind_mps", "cn2_m_minus_2_3"):
            given = getattr(self, k) is not None
            if k in need and not given:
                raise FieldError(k, f"missing: cn2_profile = '{self.cn2_profile}' needs it")
            if k not in need and given:
                raise FieldError(k, f"not used with cn2_profile = '{self.cn2_profile}'")
        if math.isnan(self.scale_height_m):
            raise FieldError("scale_height_m", "must be a number > 0 (inf: uniform)")
        return self


class SceneConfig(StrictModel):
    """A whole scene file."""

    name: str = Field(min_length=1)
    description: str = ""
    epsg: int
    effects: tuple[str, ...] = Field(description=f"enabled effects, of {EFFECT_NAMES}")
    terrain: TerrainConfig
    materials: dict[str, MaterialOverride] = Field(default_factory=dict)
    atmosphere: AtmosphereConfig

    @field_validator("epsg")
    @classmethod
    def _epsg(cls, v):
        if v not in SUPPORTED_EPSG:
            known = ", ".join(f"{c} ({_EPSG_NAMES[c]})" for c in SUPPORTED_EPSG)
            raise FieldError("", f"must be one of {known}; got {v}")
        return v

    @field_validator("effects")
    @classmethod
    def _effects(cls, v):
        unknown = [e for e in v if e not in EFFECT_NAMES]
        if unknown:
            raise FieldError("", f"unknown effect(s) {unknown}; known: {', '.join(EFFECT_NAMES)}")
        if len(set(v)) != len(v):
            raise FieldError("", f"effects listed twice: {list(v)}")
        return v

    @field_validator("materials")
    @classmethod
    def _materials(cls, v):
        for name, over in v.items():
            if name not in MATERIAL_NAMES:
                raise FieldError(name, f"unknown material; known: {', '.join(MATERIAL_NAMES)}")
            kind = over.scattering or MATERIALS[name].scattering
            for k in ("wind_speed_mps", "mean_square_slope"):
                if getattr(over, k) is not None and kind != "specular":
                    raise FieldError(f"{name}.{k}", f"only for specular materials; {name} "
                                     f"scatters as {kind!r}")
        return v

    @model_validator(mode="after")
    def _hemisphere(self):
        lat = self.terrain.center_lat_deg
        side, limit = _HEMISPHERE[self.epsg]
        if lat is not None and ((side == "north" and lat < limit) or
                                (side == "south" and lat > limit)):
            raise FieldError("terrain.center_lat_deg",
                             f"{lat:g} deg is outside EPSG:{self.epsg} "
                             f"({_EPSG_NAMES[self.epsg]}): it needs latitudes "
                             f"{'>=' if side == 'north' else '<='} {limit:g} deg")
        return self


#: The scene's keys; messages lead with the key (``terrain.flat.height_m: ...``).
SCENE_KEYS = KeyIndex(model_keys(SceneConfig, {"materials": MATERIAL_NAMES}), "label")


def scene_error(source: str, key: str, text: str) -> ConfigError:
    """A problem with one key of a scene file, found after validation (e.g. a terrain file)."""
    return ConfigError(f"{source}: {key}: {text}")


def apply_scene_overrides(tree: dict, overrides: Iterable[str] | Mapping[str, Any],
                          source: str) -> tuple[dict, tuple[tuple[str, Any], ...]]:
    """A copy of the scene file's tables with ``--set`` style overrides (``["KEY=VALUE"]`` or a
    mapping of dotted key to value) written in, and the overrides applied as (key, value)."""
    if not overrides:
        return tree, ()
    items = (list(overrides.items()) if isinstance(overrides, Mapping)
             else [parse_set(s) for s in overrides])
    tree = copy.deepcopy(tree)
    for key, value in items:
        node = tree
        *parents, leaf = str(key).split(".")
        for p in parents:
            nxt = node.setdefault(p, {})
            if not isinstance(nxt, dict):
                raise ConfigError(f"{source}: --set {key}: '{p}' is not a section")
            node = nxt
        node[leaf] = value
    return tree, tuple((str(k), v) for k, v in items)


def read_scene_config(text: str, source: str,
                      overrides: Iterable[str] | Mapping[str, Any] = ()
                      ) -> tuple[SceneConfig, tuple[tuple[str, Any], ...]]:
    """Validate a scene file's text with overrides: (the configuration, the overrides applied).
    Errors: :class:`ConfigError`, one line naming ``source`` and the keys."""
    try:
        tree = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML: {exc}") from None
    tree, applied = apply_scene_overrides(tree, overrides, source)
    try:
        return SceneConfig.model_validate(tree), applied
    except ValidationError as err:
        raise ConfigError(SCENE_KEYS.message(err, source)) from None

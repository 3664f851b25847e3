"""Scene files: the terrain, its projection, surface materials, atmosphere and enabled effects.

A mission file references a scene file by path (``[scene] file = "../scenes/x.toml"``). The scene
file is TOML, validated by :class:`SceneConfig` (unknown keys are errors with close matches, SI
units in key names, no defaults for physical quantities). Paths inside a scene file are relative
to the scene file. See ``scenes/README.md`` for the schema with an example.

Top level: ``name``, ``description`` (optional), ``epsg`` (3413 Greenland / 3031 Antarctica),
``effects`` (names of :data:`chirplidar.config.models.EFFECT_NAMES`), ``[terrain]``,
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

Generated terrain (synthetic, flat, sloped) is cached as a compressed ``.npz`` heightfield keyed by
a hash of the terrain section, the scene centre, the EPSG code and a fingerprint of the generator
(its version and source), in ``cache_dir`` (default: ``$CHIRPLIDAR_CACHE``, else
``~/.cache/chirplidar/terrain``); writes are atomic, a corrupt file is regenerated with a
:class:`TerrainCacheWarning`.

Heights everywhere are ellipsoidal (WGS-84) heights in metres, the scene frame's z.
"""

from __future__ import annotations

import difflib
import hashlib
import inspect
import json
import math
import os
import sys
import tempfile
import time
import typing
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import trimesh
from pydantic import (
    BaseModel,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from ..atmosphere import turbulence as _turbulence
from ..config.loader import ConfigError, one_line_message, parse_set
from ..config.models import EFFECT_NAMES, StrictModel
from ..geometry import synthetic_terrain
from ..geometry.frames import (
    SUPPORTED_EPSG,
    geodetic_to_projected,
    projected_to_geodetic,
)
from ..geometry.raycast import cast_rays
from ..geometry.synthetic_terrain import SYNTHETIC_FEATURES
from ..geometry.terrain import MATERIAL_NAMES, Terrain
from ..target.materials import MATERIALS
from ..target.reflectance import COX_MUNK_MAX_WIND_MPS, cox_munk_mss

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = [
    "GENERATOR_VERSION",
    "TERRAIN_SOURCES",
    "AtmosphereConfig",
    "DemTerrain",
    "FlatTerrain",
    "MaterialOverride",
    "MeshTerrain",
    "Scene",
    "SceneConfig",
    "SlopedTerrain",
    "SyntheticTerrain",
    "TerrainCacheWarning",
    "TerrainConfig",
    "default_cache_dir",
    "load_scene",
    "scene_from_text",
]

#: Bump when the meaning of a cached heightfield changes in a way the source fingerprint misses
#: (e.g. a dependency's random stream); part of every cache key.
GENERATOR_VERSION = "terrain-heightfield-1"

TERRAIN_SOURCES = ("synthetic", "mesh", "dem", "flat", "sloped")
_GENERATED = ("synthetic", "flat", "sloped")

# Latitude bands the polar stereographic frames are meant for (EPSG areas of use are north of
# 60 N / south of 60 S; 40 deg leaves room for southern Greenland and sub-Antarctic margins).
_HEMISPHERE = {3413: ("north", 40.0), 3031: ("south", -40.0)}
_EPSG_NAMES = {3413: "NSIDC Sea Ice Polar Stereographic North (Greenland)",
               3031: "Antarctic Polar Stereographic"}


class TerrainCacheWarning(UserWarning):
    """The terrain cache could not be read (regenerated) or written (run continues uncached)."""


# ---------------------------------------------------------------------- schema
class _FieldError(ValueError):
    """A validation error of a named sub-key of the model being validated (dotted, relative)."""

    def __init__(self, key: str, text: str):
        super().__init__(f"{key}: {text}")
        self.key = key
        self.text = text


_Model = StrictModel


Pair = tuple[float, float]

#: Each pond or outcrop is one pass over the whole grid: the count is bounded so a typo
#: (n_ponds = 1e8) is an error, not hours of generation.
MAX_FEATURES = 1000
#: Grid nodes x features above which generation would take minutes (2e9: ~1000 features on
#: the 1e6-node demo grid).
MAX_FEATURE_WORK = 2e9


def _check_material(name: str) -> str:
    if name not in MATERIAL_NAMES:
        raise ValueError(f"unknown material {name!r}; known: {', '.join(MATERIAL_NAMES)}")
    return name


def _increasing(key: str, pair: Pair | None) -> None:
    if pair is not None and not pair[0] <= pair[1]:
        raise _FieldError(key, f"must be [low, high] with low <= high, got {list(pair)}")


class SyntheticTerrain(_Model):
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
            raise ValueError(f"unknown feature(s) {unknown}; "
                             f"known: {', '.join(SYNTHETIC_FEATURES)}")
        if len(set(v)) != len(v):
            raise ValueError(f"features listed twice: {list(v)}")
        return v

    @model_validator(mode="after")
    def _geometry(self):
        length = abs(self.margin_x_m - self.divide_x_m)
        if length == 0:
            raise _FieldError("margin_x_m", "must differ from divide_x_m")
        for key in ("crevasse_band_from_margin_m", "pond_band_from_margin_m",
                    "outcrop_band_from_margin_m"):
            band = getattr(self, key)
            _increasing(key, band)
            if band is not None and not (0 <= band[0] and band[1] <= length):
                raise _FieldError(key, f"must lie within 0..{length:g} m (the margin-divide "
                                  f"distance), got {list(band)}")
        if self.snow_line_from_margin_m is not None and self.snow_line_from_margin_m >= length:
            raise _FieldError("snow_line_from_margin_m", f"must be below the margin-divide "
                              f"distance {length:g} m, got {self.snow_line_from_margin_m:g}")
        for key in ("pond_radius_m", "outcrop_height_m", "outcrop_radius_m"):
            pair = getattr(self, key)
            _increasing(key, pair)
            if pair is not None and pair[0] <= 0:
                raise _FieldError(key, f"must be > 0, got {list(pair)}")
        if self.sastrugi_length_m is not None and min(self.sastrugi_length_m) <= 0:
            raise _FieldError("sastrugi_length_m", "correlation lengths must be > 0")
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


class _MaterialSection(_Model):
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


_SECTIONS = {"synthetic": SyntheticTerrain, "mesh": MeshTerrain, "dem": DemTerrain,
             "flat": FlatTerrain, "sloped": SlopedTerrain}


class TerrainConfig(_Model):
    """``[terrain]``: where the scene sits and which terrain source builds it."""

    source: Literal["synthetic", "mesh", "dem", "flat", "sloped"]
    center_lat_deg: float | None = Field(None, ge=-90, le=90)
    center_lon_deg: float | None = Field(None, ge=-180, le=360)
    center_x_m: float | None = None
    center_y_m: float | None = None
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
            raise _FieldError(src, f"missing section [terrain.{src}] (terrain.source = '{src}')")
        for other in TERRAIN_SOURCES:
            if other != src and getattr(self, other) is not None:
                raise _FieldError(other, f"section given but terrain.source = '{src}'; "
                                  f"remove [terrain.{other}] or change terrain.source")
        geo = (self.center_lat_deg, self.center_lon_deg)
        xy = (self.center_x_m, self.center_y_m)
        for pair, names in ((geo, ("center_lat_deg", "center_lon_deg")),
                            (xy, ("center_x_m", "center_y_m"))):
            if (pair[0] is None) != (pair[1] is None):
                missing = names[0] if pair[0] is None else names[1]
                raise _FieldError(missing, f"missing: {names[0]} and {names[1]} go together")
        has_geo, has_xy = geo[0] is not None, xy[0] is not None
        if has_geo and has_xy:
            raise _FieldError("center_x_m", "give the centre either as center_lat_deg/"
                              "center_lon_deg or as center_x_m/center_y_m, not both")
        needs_centre = src in _GENERATED or (src == "mesh" and self.mesh.coordinates ==
                                             "scene_centre")
        if needs_centre and not (has_geo or has_xy):
            raise _FieldError("center_lat_deg", f"missing: terrain.source = '{src}' needs the "
                              "scene centre (center_lat_deg/center_lon_deg or "
                              "center_x_m/center_y_m)")
        if not needs_centre and (has_geo or has_xy):
            why = ("the DEM's own coordinates place it" if src == "dem" else
                   "terrain.mesh.coordinates = 'projected' places the mesh")
            raise _FieldError("center_lat_deg" if has_geo else "center_x_m",
                              f"not used: {why} (the centre is the middle of its bounds)")
        grid = ("size_x_m", "size_y_m", "resolution_m")
        if src in _GENERATED:
            for k in grid:
                if getattr(self, k) is None:
                    raise _FieldError(k, f"missing: terrain.source = '{src}' is generated on "
                                      "a grid (size_x_m, size_y_m, resolution_m)")
            if self.resolution_m > min(self.size_x_m, self.size_y_m):
                raise _FieldError("resolution_m", f"{self.resolution_m:g} m is larger than "
                                  "the grid's size")
            nodes = (self.size_x_m / self.resolution_m + 2) * (self.size_y_m /
                                                               self.resolution_m + 2)
            if nodes > 5e7:
                raise _FieldError("resolution_m", f"{self.resolution_m:g} m gives ~{nodes:.3g} "
                                  "grid nodes (> 5e7); coarsen it")
            if src == "synthetic":
                syn = self.synthetic
                n_features = (syn.n_ponds or 0) * ("ponds" in syn.features) + \
                    (syn.n_outcrops or 0) * ("outcrops" in syn.features)
                if n_features * nodes > MAX_FEATURE_WORK:
                    raise _FieldError("synthetic", f"{n_features} ponds and outcrops on "
                                      f"~{nodes:.3g} grid nodes would take minutes to generate "
                                      f"(each is a pass over the grid; keep features x nodes "
                                      f"<= {MAX_FEATURE_WORK:.0e}): fewer features or a coarser "
                                      "resolution_m")
        else:
            for k in grid:
                if getattr(self, k) is not None:
                    raise _FieldError(k, f"not used: terrain.source = '{src}' takes its extent "
                                      "and resolution from the file")
        if src == "synthetic" and self.seed is None:
            raise _FieldError("seed", "missing: the synthetic terrain is random (seeded)")
        if src != "synthetic" and self.seed is not None:
            raise _FieldError("seed", f"not used: terrain.source = '{src}' draws no random "
                              "numbers")
        return self

    @property
    def section(self):
        """The model of the chosen source's section."""
        return getattr(self, self.source)


class MaterialOverride(_Model):
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
            raise ValueError("give reflectivity, scattering, wind_speed_mps or "
                             "mean_square_slope (or drop the section)")
        if self.wind_speed_mps is not None and self.mean_square_slope is not None:
            raise _FieldError("mean_square_slope", "give either wind_speed_mps or "
                              "mean_square_slope, not both")
        return self

    def mss(self) -> float | None:
        """Mean-square facet slope, or None if neither key is given."""
        if self.mean_square_slope is not None:
            return self.mean_square_slope
        if self.wind_speed_mps is not None:
            return float(cox_munk_mss(self.wind_speed_mps))
        return None


class AtmosphereConfig(_Model):
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
                raise _FieldError(k, f"missing: cn2_profile = '{self.cn2_profile}' needs it")
            if k not in need and given:
                raise _FieldError(k, f"not used with cn2_profile = '{self.cn2_profile}'")
        if math.isnan(self.scale_height_m):
            raise _FieldError("scale_height_m", "must be a number > 0 (inf: uniform)")
        return self


class SceneConfig(_Model):
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
            raise ValueError(f"must be one of {known}; got {v}")
        return v

    @field_validator("effects")
    @classmethod
    def _effects(cls, v):
        unknown = [e for e in v if e not in EFFECT_NAMES]
        if unknown:
            raise ValueError(f"unknown effect(s) {unknown}; known: {', '.join(EFFECT_NAMES)}")
        if len(set(v)) != len(v):
            raise ValueError(f"effects listed twice: {list(v)}")
        return v

    @field_validator("materials")
    @classmethod
    def _materials(cls, v):
        for name, over in v.items():
            if name not in MATERIAL_NAMES:
                raise _FieldError(name, f"unknown material; known: {', '.join(MATERIAL_NAMES)}")
            kind = over.scattering or MATERIALS[name].scattering
            for k in ("wind_speed_mps", "mean_square_slope"):
                if getattr(over, k) is not None and kind != "specular":
                    raise _FieldError(f"{name}.{k}", f"only for specular materials; {name} "
                                      f"scatters as {kind!r}")
        return v

    @model_validator(mode="after")
    def _hemisphere(self):
        lat = self.terrain.center_lat_deg
        side, limit = _HEMISPHERE[self.epsg]
        if lat is not None and ((side == "north" and lat < limit) or
                                (side == "south" and lat > limit)):
            raise _FieldError("terrain.center_lat_deg",
                              f"{lat:g} deg is outside EPSG:{self.epsg} "
                              f"({_EPSG_NAMES[self.epsg]}): it needs latitudes "
                              f"{'>=' if side == 'north' else '<='} {limit:g} deg")
        return self


# ---------------------------------------------------------------------- error messages
def _section_models(annotation) -> tuple[str, type[BaseModel]] | None:
    """('model', M) for M or M | None; ('dict', M) for dict[str, M]."""
    if typing.get_origin(annotation) is dict:
        val = typing.get_args(annotation)[1]
        if isinstance(val, type) and issubclass(val, BaseModel):
            return "dict", val
    for ann in (annotation, *typing.get_args(annotation)):
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            return "model", ann
    return None


def _scene_keys(model: type[BaseModel] = SceneConfig, prefix: str = "") -> list[str]:
    keys = []
    for name, f in model.model_fields.items():
        sub = _section_models(f.annotation)
        if sub is None:
            keys.append(prefix + name)
        elif sub[0] == "model":
            keys.extend(_scene_keys(sub[1], f"{prefix}{name}."))
        else:   # materials: one set of keys per known material
            for mat in MATERIAL_NAMES:
                keys.extend(_scene_keys(sub[1], f"{prefix}{name}.{mat}."))
    return keys


SCENE_KEYS: tuple[str, ...] = tuple(_scene_keys())


def _unknown_key(key: str) -> str:
    close = difflib.get_close_matches(key, SCENE_KEYS, n=5, cutoff=0.6)
    if not close:
        leaf = key.rsplit(".", 1)[-1].lower()
        close = [k for k in SCENE_KEYS if k.rsplit(".", 1)[-1].lower() == leaf][:5]
    return "unknown key" + (f" (did you mean: {', '.join(close)}?)" if close else "")


def _format_errors(err: ValidationError, source: str) -> str:
    """One line: the source, then each problem (missing keys together), ``; ``-separated."""
    missing, problems = [], []
    for e in err.errors():
        loc = [str(p) for p in e["loc"]]
        cause = (e.get("ctx") or {}).get("error")
        msg = e["msg"]
        if isinstance(cause, _FieldError):
            loc += cause.key.split(".")
            msg = cause.text
        elif e["type"] == "value_error":
            msg = msg.removeprefix("Value error, ")
        elif e["type"] not in ("missing", "extra_forbidden"):
            got = e.get("input")
            if not isinstance(got, Mapping):
                msg = f"{msg} (got {got!r})"
        key = ".".join(loc) or "(top level)"
        if e["type"] == "missing":
            missing.append(key)
            continue
        if e["type"] == "extra_forbidden":
            msg = _unknown_key(key)
        problems.append(f"{key}: {msg}")
    return one_line_message(source, missing, problems)


def _error(source: str, key: str, text: str) -> ConfigError:
    return ConfigError(f"{source}: {key}: {text}")


# ---------------------------------------------------------------------- cache
def default_cache_dir() -> Path:
    """``$CHIRPLIDAR_CACHE`` if set, else ``$XDG_CACHE_HOME`` (or ``~/.cache``)
    /chirplidar/terrain."""
    env = os.environ.get("CHIRPLIDAR_CACHE")
    if env:
        return Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "chirplidar" / "terrain"


_FINGERPRINT: list[str] = []


def _generator_fingerprint() -> str:
    """GENERATOR_VERSION plus a hash of the generators' source: edits invalidate old entries."""
    if not _FINGERPRINT:
        h = hashlib.sha256(GENERATOR_VERSION.encode())
        for fn in (*synthetic_terrain.HEIGHTFIELD_GENERATORS, _generate_heightfield):
            try:
                h.update(inspect.getsource(fn).encode())
            except (OSError, TypeError):   # no source (frozen app): the version alone
                h.update(fn.__qualname__.encode())
        h.update(np.__version__.split(".")[0].encode())   # Generator streams per major version
        _FINGERPRINT.append(f"{GENERATOR_VERSION}:{h.hexdigest()[:16]}")
    return _FINGERPRINT[0]


def _cache_key(cfg: SceneConfig, centre_xy: tuple[float, float]) -> str:
    payload = {"terrain": cfg.terrain.model_dump(mode="json"), "epsg": cfg.epsg,
               "centre_xy_m": [float(c).hex() for c in centre_xy],
               "generator": _generator_fingerprint()}
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def _read_cache(path: Path, key: str):
    """(x, y, z, codes) from a cache file, or None if absent; a bad file warns and gives None."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as d:
            if str(d["key"]) != key:
                raise ValueError("key mismatch")
            x, y, z = (np.asarray(d[k], dtype=np.float64) for k in ("x", "y", "z"))
            codes = np.asarray(d["codes"]).astype(np.int32)
        if (x.ndim != 1 or y.ndim != 1 or z.shape != (y.size, x.size)
                or codes.shape != z.shape):
            raise ValueError("inconsistent array shapes")
    except Exception as exc:  # noqa: BLE001 (zip, npy, key or shape damage: all mean "regenerate")
        warnings.warn(f"terrain cache file {path} is unreadable ({type(exc).__name__}: {exc}); "
                      "regenerating it", TerrainCacheWarning, stacklevel=4)
        return None
    return x, y, z, codes


def _write_cache(path: Path, key: str, hf) -> bool:
    """Atomic write (temporary file in the same directory, then os.replace)."""
    x, y, z, codes = hf
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-", suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, "wb") as f:
            small = codes.astype(np.int8) if len(MATERIAL_NAMES) < 128 else codes
            np.savez_compressed(f, key=np.array(key), x=x, y=y, z=z, codes=small)
        os.chmod(tmp, 0o644)   # mkstemp makes 0600; a shared cache should be readable
        os.replace(tmp, path)
        return True
    except OSError as exc:
        warnings.warn(f"cannot write terrain cache file {path} ({exc}); continuing without "
                      "the cache", TerrainCacheWarning, stacklevel=4)
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
        return False


# ---------------------------------------------------------------------- terrain building
def _generate_heightfield(cfg: TerrainConfig, centre_xy):
    """(x, y, z, codes) of a generated source, in the scene's EPSG metres."""
    sx, sy, res = cfg.size_x_m, cfg.size_y_m, cfg.resolution_m
    extent = (-sx / 2, sx / 2, -sy / 2, sy / 2)   # generated around 0: same terrain anywhere
    sec = cfg.section
    if cfg.source == "synthetic":
        rng = np.random.default_rng(cfg.seed)
        x, y, z, codes = synthetic_terrain.synthetic_ice_sheet_heightfield(
            extent, res, rng, **sec.generator_kwargs())
        z = z + sec.base_height_m
    elif cfg.source == "flat":
        x, y, z, codes = synthetic_terrain.flat_plane_heightfield(sec.height_m, extent, res,
                                                                  sec.material)
    else:   # sloped: compass azimuth -> generator's angle from +x towards +y
        x, y, z, codes = synthetic_terrain.sloped_plane_heightfield(
            math.radians(sec.slope_deg), math.radians(90.0 - sec.azimuth_deg), sec.height_m,
            extent, res, sec.material)
    return x + centre_xy[0], y + centre_xy[1], z, codes


class _Progress:
    def __init__(self, on: bool, label: str):
        self.on, self.label, self.t0 = on, label, time.perf_counter()

    def __call__(self, what: str):
        if self.on:
            print(f"[scene {self.label}] {time.perf_counter() - self.t0:7.2f} s  {what}",
                  file=sys.stderr, flush=True)


def _resolve(base_dir: Path, rel: str) -> Path:
    p = Path(rel).expanduser()
    return p if p.is_absolute() else base_dir / p


def _mesh_terrain(cfg: TerrainConfig, base_dir: Path, source: str, centre_xy):
    sec = cfg.mesh
    path = _resolve(base_dir, sec.path)
    if not path.is_file():
        raise _error(source, "terrain.mesh.path", f"file {sec.path} does not exist "
                     f"(looked for {path})")
    try:
        terr = Terrain.from_mesh_file(path, sec.material)
    except (ValueError, FileNotFoundError) as exc:
        raise _error(source, "terrain.mesh.path", str(exc)) from None
    if sec.coordinates == "scene_centre":
        v = np.asarray(terr.mesh.vertices, dtype=np.float64) + [centre_xy[0], centre_xy[1], 0.0]
        terr = Terrain(trimesh.Trimesh(vertices=v, faces=terr.mesh.faces, process=False),
                       terr.face_materials, terr.material_names)
    return terr


def _dem_terrain(cfg: TerrainConfig, base_dir: Path, source: str, epsg: int):
    sec = cfg.dem
    path = _resolve(base_dir, sec.path)
    if not path.is_file():
        raise _error(source, "terrain.dem.path", f"file {sec.path} does not exist "
                     f"(looked for {path})")
    try:
        import rasterio
    except ImportError as exc:
        raise ImportError("terrain.source = 'dem' needs rasterio: "
                          "pip install chirplidar[dem]") from exc
    try:
        with rasterio.open(path) as src:
            crs = src.crs
    except Exception as exc:  # noqa: BLE001 (rasterio raises many kinds for bad files)
        raise _error(source, "terrain.dem.path", f"cannot read DEM {sec.path}: {exc}") from None
    if crs is None:
        warnings.warn(f"{source}: DEM {sec.path} has no CRS; taking it as EPSG:{epsg}",
                      UserWarning, stacklevel=3)
    else:
        code = crs.to_epsg()
        if code is not None and code != epsg:
            raise _error(source, "terrain.dem.path", f"DEM {sec.path} is in EPSG:{code}, the "
                         f"scene in EPSG:{epsg}; reproject it (gdalwarp -t_srs EPSG:{epsg})")
    try:
        return Terrain.from_dem(path, sec.material, sec.band, nodata=sec.nodata)
    except (ValueError, FileNotFoundError) as exc:
        key = "terrain.dem.nodata" if "no-data" in str(exc) else "terrain.dem.path"
        raise _error(source, key, str(exc)) from None


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
        used = set(np.unique(self.terrain.face_materials).tolist())
        out = np.full(len(self.material_names), np.nan)
        for code, name in enumerate(self.material_names):
            over = self.config.materials.get(name)
            if over is not None and over.reflectivity is not None:
                out[code] = over.reflectivity
                continue
            try:
                out[code] = float(MATERIALS[name].reflectivity_at(wl))
            except ValueError as exc:
                if code in used:
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
def _apply_overrides(tree: dict, overrides, source: str) -> tuple[dict, tuple]:
    if not overrides:
        return tree, ()
    items = (list(overrides.items()) if isinstance(overrides, Mapping)
             else [parse_set(s) for s in overrides])
    tree = json.loads(json.dumps(tree))   # deep copy of plain TOML data
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


def _check_specular_slopes(cfg: SceneConfig, terr: Terrain, source: str) -> None:
    """Every specular material on the terrain needs its facet slopes (no silent default)."""
    counts = np.bincount(terr.face_materials, minlength=len(terr.material_names))
    for code, name in enumerate(terr.material_names):
        over = cfg.materials.get(name)
        kind = (over.scattering if over is not None and over.scattering is not None
                else MATERIALS[name].scattering)
        if counts[code] and kind == "specular" and (over is None or over.mss() is None):
            raise _error(source, f"materials.{name}.wind_speed_mps",
                         f"missing: the terrain has {counts[code]} {name} faces (specular); "
                         "give wind_speed_mps (Cox-Munk slopes) or mean_square_slope")


def _centre(cfg: SceneConfig) -> tuple[float, float] | None:
    t = cfg.terrain
    if t.center_x_m is not None:
        return float(t.center_x_m), float(t.center_y_m)
    if t.center_lat_deg is not None:
        x, y, _ = geodetic_to_projected(t.center_lat_deg, t.center_lon_deg, 0.0, cfg.epsg)
        return float(x), float(y)
    return None


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
    base_dir = Path(base_dir)
    try:
        tree = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML: {exc}") from None
    tree, applied = _apply_overrides(tree, overrides, source)
    try:
        cfg = SceneConfig.model_validate(tree)
    except ValidationError as err:
        raise ConfigError(_format_errors(err, source)) from None

    say = _Progress(progress, cfg.name)
    t0 = time.perf_counter()
    centre = _centre(cfg)
    tc = cfg.terrain
    cache_file, hit, stored = None, False, False
    if tc.source in _GENERATED:
        key = _cache_key(cfg, centre)
        hf = None
        if use_cache:
            cache_file = Path(cache_dir) if cache_dir is not None else default_cache_dir()
            cache_file = cache_file / f"{tc.source}-{key[:32]}.npz"
            hf = _read_cache(cache_file, key)
            hit = hf is not None
            say(f"heightfield read from cache {cache_file}" if hit else
                f"no usable cache entry ({cache_file.name})")
        if hf is None:
            try:
                hf = _generate_heightfield(tc, centre)
            except ValueError as exc:
                raise _error(source, f"terrain.{tc.source}", str(exc)) from None
            say(f"heightfield generated ({hf[2].shape[1]} x {hf[2].shape[0]} nodes)")
            stored = use_cache and _write_cache(cache_file, key, hf)
            if stored:
                say("heightfield cached")
        terr = Terrain.from_heightfield(*hf)
    elif tc.source == "mesh":
        terr = _mesh_terrain(tc, base_dir, source, centre)
    else:
        terr = _dem_terrain(tc, base_dir, source, cfg.epsg)
    read_from = getattr(tc, tc.source) if tc.source in ("mesh", "dem") else None
    files = (_resolve(base_dir, read_from.path).resolve(),) if read_from is not None else ()
    _check_specular_slopes(cfg, terr, source)
    if centre is None:
        lo, hi = terr.bounds
        centre = (float(lo[0] + hi[0]) / 2, float(lo[1] + hi[1]) / 2)
    build_s = time.perf_counter() - t0
    say(f"terrain ready: {terr.n_faces} triangles")
    return Scene(path=Path(path) if path is not None else None, name=cfg.name, epsg=cfg.epsg,
                 terrain=terr, effects=tuple(cfg.effects), config=cfg, text=text,
                 center_xy_m=centre, overrides=applied,
                 cache_file=cache_file if (hit or stored) else None, cache_hit=hit,
                 build_s=build_s, input_files=files)


def load_scene(path, *, cache_dir=None, use_cache: bool = True, progress: bool = False,
               overrides: Iterable[str] | Mapping[str, Any] = ()) -> Scene:
    """Load and validate a scene file and build its terrain.

    path: the scene TOML file; relative paths inside it are relative to its directory.
    cache_dir: where generated heightfields are cached (default :func:`default_cache_dir`);
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

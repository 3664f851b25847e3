"""Terrain of a scene: generated heightfields and their cache, mesh files and DEM rasters.

Generated terrain (synthetic, flat, sloped) is cached as a compressed ``.npz`` heightfield keyed by
a hash of the terrain section, the scene centre, the EPSG code and a fingerprint of the generator
(its version and source), in ``cache_dir`` (default: ``$CHIRPLIDAR_CACHE``, else
``~/.cache/chirplidar/terrain``); writes are atomic, a corrupt file is regenerated with a
:class:`TerrainCacheWarning`. Mesh files and DEM rasters are read each time.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import math
import os
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import trimesh

from ..config.scene import GENERATED_SOURCES, SceneConfig, TerrainConfig, scene_error
from ..geometry import synthetic_terrain
from ..geometry.terrain import MATERIAL_NAMES, Terrain

#: Bump when the meaning of a cached heightfield changes in a way the source fingerprint misses
#: (e.g. a dependency's random stream); part of every cache key.
GENERATOR_VERSION = "terrain-heightfield-1"


class TerrainCacheWarning(UserWarning):
    """The terrain cache could not be read (regenerated) or written (run continues uncached)."""


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
                      "regenerating it", TerrainCacheWarning, stacklevel=6)
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
                      "the cache", TerrainCacheWarning, stacklevel=6)
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
        return False


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


def resolve_path(base_dir: Path, rel: str) -> Path:
    """A path of a scene file (``~`` expanded), relative to ``base_dir`` unless absolute."""
    p = Path(rel).expanduser()
    return p if p.is_absolute() else base_dir / p


def _mesh_terrain(cfg: TerrainConfig, base_dir: Path, source: str, centre_xy):
    sec = cfg.mesh
    path = resolve_path(base_dir, sec.path)
    if not path.is_file():
        raise scene_error(source, "terrain.mesh.path", f"file {sec.path} does not exist "
                          f"(looked for {path})")
    try:
        terr = Terrain.from_mesh_file(path, sec.material)
    except (ValueError, FileNotFoundError) as exc:
        raise scene_error(source, "terrain.mesh.path", str(exc)) from None
    if sec.coordinates == "scene_centre":
        v = np.asarray(terr.mesh.vertices, dtype=np.float64) + [centre_xy[0], centre_xy[1], 0.0]
        terr = Terrain(trimesh.Trimesh(vertices=v, faces=terr.mesh.faces, process=False),
                       terr.face_materials, terr.material_names)
    return terr


def _dem_terrain(cfg: TerrainConfig, base_dir: Path, source: str, epsg: int):
    sec = cfg.dem
    path = resolve_path(base_dir, sec.path)
    if not path.is_file():
        raise scene_error(source, "terrain.dem.path", f"file {sec.path} does not exist "
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
        raise scene_error(source, "terrain.dem.path",
                          f"cannot read DEM {sec.path}: {exc}") from None
    if crs is None:
        warnings.warn(f"{source}: DEM {sec.path} has no CRS; taking it as EPSG:{epsg}",
                      UserWarning, stacklevel=4)
    else:
        code = crs.to_epsg()
        if code is not None and code != epsg:
            raise scene_error(source, "terrain.dem.path", f"DEM {sec.path} is in EPSG:{code}, the "
                              f"scene in EPSG:{epsg}; reproject it (gdalwarp -t_srs EPSG:{epsg})")
    try:
        return Terrain.from_dem(path, sec.material, sec.band, nodata=sec.nodata)
    except (ValueError, FileNotFoundError) as exc:
        key = "terrain.dem.nodata" if "no-data" in str(exc) else "terrain.dem.path"
        raise scene_error(source, key, str(exc)) from None


@dataclass(frozen=True)
class BuiltTerrain:
    """A scene's terrain and where it came from.

    cache_file / cache_hit: the cache entry of a generated heightfield (None: not cached) and
    whether it was read from there; input_files: the mesh or DEM file the terrain was read from.
    """

    terrain: Terrain
    cache_file: Path | None = None
    cache_hit: bool = False
    input_files: tuple[Path, ...] = ()


def build_terrain(cfg: SceneConfig, base_dir: Path, source: str, centre_xy, *, cache_dir=None,
                  use_cache: bool = True,
                  say: Callable[[str], None] = lambda what: None) -> BuiltTerrain:
    """The terrain of a validated scene: generated (through the cache), or read from its mesh or
    DEM file (paths relative to ``base_dir``). centre_xy: the scene centre in the EPSG frame (m;
    None for a file that places itself); say: reports each stage. Errors: ConfigError naming
    ``source`` and the key."""
    tc = cfg.terrain
    if tc.source in GENERATED_SOURCES:
        return _generated_terrain(cfg, source, centre_xy, cache_dir, use_cache, say)
    if tc.source == "mesh":
        terr = _mesh_terrain(tc, base_dir, source, centre_xy)
    else:
        terr = _dem_terrain(tc, base_dir, source, cfg.epsg)
    return BuiltTerrain(terr, input_files=(resolve_path(base_dir, tc.section.path).resolve(),))


def _generated_terrain(cfg: SceneConfig, source: str, centre_xy, cache_dir, use_cache: bool,
                       say: Callable[[str], None]) -> BuiltTerrain:
    tc = cfg.terrain
    key = _cache_key(cfg, centre_xy)
    cache_file, hf = None, None
    if use_cache:
        cache_file = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        cache_file = cache_file / f"{tc.source}-{key[:32]}.npz"
        hf = _read_cache(cache_file, key)
        say(f"heightfield read from cache {cache_file}" if hf is not None else
            f"no usable cache entry ({cache_file.name})")
    hit, stored = hf is not None, False
    if hf is None:
        try:
            hf = _generate_heightfield(tc, centre_xy)
        except ValueError as exc:
            raise scene_error(source, f"terrain.{tc.source}", str(exc)) from None
        say(f"heightfield generated ({hf[2].shape[1]} x {hf[2].shape[0]} nodes)")
        stored = use_cache and _write_cache(cache_file, key, hf)
        if stored:
            say("heightfield cached")
    return BuiltTerrain(Terrain.from_heightfield(*hf),
                        cache_file=cache_file if (hit or stored) else None, cache_hit=hit)

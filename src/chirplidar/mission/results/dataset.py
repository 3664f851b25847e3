"""Build the results dataset of a mission (CF-1.8 trajectories, see :mod:`.schema`) from
per-shot arrays, checking every value against the schema."""

from __future__ import annotations

import datetime as _dt
import sys

import numpy as np
import xarray as xr

from .schema import (
    CONVENTIONS,
    DERIVED_VARIABLES,
    DETECTED_FLAG_MEANINGS,
    DETECTED_FLAG_VALUES,
    FEATURE_TYPE,
    GRID_MAPPING_NAME,
    OBS_DIM,
    SCHEMA,
    SCHEMA_BY_NAME,
    TRAJECTORY_DIM,
    VarSpec,
    check_dataset,
    crs_attributes,
    flag_meaning,
    variable_attributes,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def _utc_now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat().replace(
        "+00:00", "Z")


def _check_epoch(epoch_iso: str) -> str:
    if not isinstance(epoch_iso, str) or not epoch_iso.strip():
        raise ValueError(f"epoch_iso must be an ISO 8601 string, got {epoch_iso!r}")
    try:
        _dt.datetime.fromisoformat(epoch_iso.replace("Z", "+00:00"))
    except ValueError:
        raise ValueError(f"epoch_iso is not an ISO 8601 date-time: {epoch_iso!r}") from None
    return epoch_iso


def _as_array(name: str, value, spec: VarSpec, materials: dict[int, str] | None) -> np.ndarray:
    """``value`` as an array of ``spec``'s dtype; ValueError for values the schema refuses."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric array: {exc}") from None
    if spec.dtype.startswith("float"):
        if arr.dtype == bool or not (np.issubdtype(arr.dtype, np.integer)
                                     or np.issubdtype(arr.dtype, np.floating)):
            raise ValueError(f"{name} must be real-valued, got dtype {arr.dtype}")
        arr = arr.astype(np.float64)
        if np.any(np.isinf(arr)):
            raise ValueError(f"{name} must not contain infinity")
        if not spec.nan_allowed and np.any(np.isnan(arr)):
            raise ValueError(f"{name} must not contain NaN")
        return arr
    # integer / flag variables
    if arr.dtype == bool:
        arr = arr.astype(np.int64)
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        if np.issubdtype(arr.dtype, np.floating) and np.all(np.isfinite(arr)) \
                and np.all(arr == np.round(arr)):
            arr = arr.astype(np.int64)
        else:
            raise ValueError(f"{name} must be integer-valued, got dtype {arr.dtype}")
    arr = arr.astype(np.int64)
    info = np.iinfo(spec.dtype)
    if arr.size and (arr.min() < info.min or arr.max() > info.max):
        raise ValueError(f"{name} values must fit in {spec.dtype}")
    if name == "detected":
        bad = ~np.isin(arr, DETECTED_FLAG_VALUES)
        if np.any(bad):
            raise ValueError(f"detected must be one of {DETECTED_FLAG_VALUES.tolist()} "
                             f"({DETECTED_FLAG_MEANINGS}), got {np.unique(arr[bad]).tolist()}")
    if name == "surface_type":
        if not materials:
            raise ValueError("surface_type given but materials is empty")
        bad = ~np.isin(arr, list(materials))
        if np.any(bad):
            raise ValueError(f"surface_type values {np.unique(arr[bad]).tolist()} are not keys "
                             f"of materials {sorted(materials)}")
    return arr.astype(spec.dtype)


def _check_materials(materials) -> dict[int, str]:
    if materials is None:
        return {}
    if not isinstance(materials, dict):
        raise ValueError(f"materials must be a dict[int, str], got {type(materials).__name__}")
    out: dict[int, str] = {}
    for k, v in materials.items():
        if isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)):
            raise ValueError(f"materials keys must be integers, got {k!r}")
        if not isinstance(v, str) or not v.strip():
            raise ValueError(f"materials[{k}] must be a non-empty string, got {v!r}")
        if not np.iinfo(np.int16).min <= int(k) <= np.iinfo(np.int16).max:
            raise ValueError(f"materials key {k} does not fit in int16")
        out[int(k)] = v
    meanings = [flag_meaning(v) for v in out.values()]
    if len(set(meanings)) != len(meanings):
        raise ValueError(f"materials names must be distinct, got {list(out.values())}")
    return out


def _to_2d(per_shot: dict) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """(beam ids, arrays shaped (n_beams, n_shots)) from either accepted input layout."""
    if not isinstance(per_shot, dict):
        raise ValueError(f"per_shot must be a dict of arrays, got {type(per_shot).__name__}")
    arrays = {k: np.asarray(v) for k, v in per_shot.items() if k != "beam"}
    beam = per_shot.get("beam")
    ndims = {k: a.ndim for k, a in arrays.items()}
    if arrays and all(n == 1 for n in ndims.values()):
        # flat layout: a leading shot axis plus a beam index per shot
        if beam is None:
            raise ValueError("beam: 1-D per-shot arrays need a per-shot 'beam' index")
        beam = np.asarray(beam)
        n = beam.shape[0] if beam.ndim == 1 else -1
        for k, a in arrays.items():
            if a.shape != (n,):
                raise ValueError(f"{k} has shape {a.shape}, expected ({n},) like beam")
        if beam.ndim != 1 or (beam.size and not np.issubdtype(beam.dtype, np.integer)):
            raise ValueError(f"beam must be a 1-D integer array, got {beam.dtype} {beam.shape}")
        ids, counts = np.unique(beam, return_counts=True)
        if ids.size and np.any(counts != counts[0]):
            raise ValueError("beam: every beam must have the same number of shots, got "
                             f"{dict(zip(ids.tolist(), counts.tolist()))}")
        order = np.argsort(beam, kind="stable")  # shot order within a beam is kept
        m = int(counts[0]) if ids.size else 0
        out = {k: a[order].reshape(ids.size, m) for k, a in arrays.items()}
        return out, ids
    shapes = {k: a.shape for k, a in arrays.items()}
    first = next(iter(shapes.values()), None)
    for k, s in shapes.items():
        if len(s) != 2:
            raise ValueError(f"{k} must have shape (n_beams, n_shots), got {s}")
        if s != first:
            raise ValueError(f"{k} has shape {s}, expected {first} like the other variables")
    n_beams = first[0] if first else 0
    if beam is None:
        ids = np.arange(n_beams)
    else:
        ids = np.asarray(beam)
        if ids.shape != (n_beams,) or (ids.size and not np.issubdtype(ids.dtype, np.integer)):
            raise ValueError(f"beam must be {n_beams} integer ids, got {ids.dtype} {ids.shape}")
    if np.unique(ids).size != ids.size:
        raise ValueError(f"beam ids must be distinct, got {ids.tolist()}")
    return arrays, ids


def build_dataset(per_shot: dict, *, epsg: int, epoch_iso: str, config_toml: str, seed: int,
                  software_version: str, materials: dict[int, str] | None = None,
                  title: str = "chirplidar simulated FM-chirped lidar altimeter shots",
                  date_created: str | None = None) -> xr.Dataset:
    """CF-1.8 trajectory dataset (dims ``(trajectory, obs)``) from per-shot arrays.

    ``per_shot`` maps schema names (see :data:`.schema.SCHEMA`) to arrays of shape
    ``(n_beams, n_shots)`` with optional ``beam`` ids of shape ``(n_beams,)`` (default
    ``0..n_beams-1``), or to 1-D arrays over all shots with a per-shot ``beam`` index (grouped by
    beam, shot order kept; every beam needs the same number of shots). ``delta_time`` is required;
    ``time`` is derived from it. Give ``latitude``/``longitude`` or ``x``/``y`` (or both): the
    missing pair is computed with pyproj. Other schema variables are optional; unknown names
    raise ValueError. ``date_created`` (ISO 8601) defaults to now (UTC); pass it for
    reproducible output.
    """
    epoch_iso = _check_epoch(epoch_iso)
    crs_attrs = crs_attributes(epsg)
    _check_provenance(config_toml, seed, software_version)
    materials = _check_materials(materials)
    if date_created is None:
        date_created = _utc_now_iso()
    _check_names(per_shot)

    arrays, beam_ids = _to_2d(per_shot)
    data = {k: _as_array(k, v, SCHEMA_BY_NAME[k], materials) for k, v in arrays.items()}
    beam_ids = _as_array("beam", beam_ids, SCHEMA_BY_NAME["beam"], None)
    shape = data["delta_time"].shape
    _fill_positions(data, epsg)
    data["time"] = data["delta_time"].copy()

    coords, data_vars = _variables(data, beam_ids, shape, epoch_iso, materials)
    data_vars[GRID_MAPPING_NAME] = ((), np.int32(0), crs_attrs)
    attrs = _global_attributes(title=title, date_created=date_created, epoch_iso=epoch_iso,
                               epsg=epsg, seed=seed, software_version=software_version,
                               config_toml=config_toml)
    ds = xr.Dataset(data_vars, coords=coords, attrs=attrs)
    check_dataset(ds)
    return ds


def _check_provenance(config_toml, seed, software_version) -> None:
    """ValueError unless the configuration is TOML text, the seed an integer and the software
    version a non-empty string."""
    if not isinstance(config_toml, str):
        raise ValueError(f"config_toml must be a string, got {type(config_toml).__name__}")
    try:
        tomllib.loads(config_toml)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"config_toml is not valid TOML: {exc}") from None
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"seed must be an integer, got {seed!r}")
    if not isinstance(software_version, str) or not software_version:
        raise ValueError(f"software_version must be a non-empty string, got {software_version!r}")


def _check_names(per_shot) -> None:
    """ValueError unless ``per_shot`` is a dict of schema variables (not derived ones) with
    ``delta_time``."""
    if not isinstance(per_shot, dict):
        raise ValueError(f"per_shot must be a dict of arrays, got {type(per_shot).__name__}")
    for k in per_shot:
        if k not in SCHEMA_BY_NAME:
            raise ValueError(f"per_shot: unknown variable {k!r} (not in the results schema)")
        if k in DERIVED_VARIABLES:
            raise ValueError(f"per_shot: {k!r} is derived from delta_time; do not pass it")
    if "delta_time" not in per_shot:
        raise ValueError("per_shot: delta_time is required")


def _fill_positions(data: dict, epsg) -> None:
    """Add the missing pair of positions (``latitude``/``longitude`` or ``x``/``y`` in
    ``epsg``) to ``data``, with pyproj."""
    have_ll = "latitude" in data and "longitude" in data
    have_xy = "x" in data and "y" in data
    for a, b in (("latitude", "longitude"), ("x", "y")):
        if (a in data) != (b in data):
            raise ValueError(f"{a} and {b} must be given together")
    if not (have_ll or have_xy):
        raise ValueError("per_shot: latitude/longitude or x/y is required")
    if have_ll and have_xy:
        return
    from pyproj import Transformer
    if have_ll:
        tr = Transformer.from_crs(4326, int(epsg), always_xy=True)
        x, y = tr.transform(data["longitude"], data["latitude"])
        data["x"], data["y"] = np.asarray(x, float), np.asarray(y, float)
    else:
        tr = Transformer.from_crs(int(epsg), 4326, always_xy=True)
        lon, lat = tr.transform(data["x"], data["y"])
        data["longitude"], data["latitude"] = np.asarray(lon, float), np.asarray(lat, float)


def _variables(data: dict, beam_ids, shape, epoch_iso: str, materials) -> tuple[dict, dict]:
    """(coordinates, data variables) of the dataset, in schema order (the file's order)."""
    dims2 = (TRAJECTORY_DIM, OBS_DIM)
    coords: dict = {}
    data_vars: dict = {}
    for spec in SCHEMA:
        if spec.name == "beam":
            coords["beam"] = ((TRAJECTORY_DIM,), beam_ids,
                              variable_attributes(spec, epoch_iso, materials))
            continue
        if spec.name not in data:
            continue
        arr = data[spec.name].reshape(shape)
        attrs = variable_attributes(spec, epoch_iso, materials)
        if spec.coordinate:
            coords[spec.name] = (dims2, arr, attrs)
        else:
            attrs["grid_mapping"] = GRID_MAPPING_NAME
            data_vars[spec.name] = (dims2, arr, attrs)
    return coords, data_vars


def _global_attributes(*, title: str, date_created: str, epoch_iso: str, epsg, seed,
                       software_version: str, config_toml: str) -> dict:
    """The dataset's global attributes (CF and provenance), in the file's order."""
    source = f"chirplidar {software_version}"
    return {
        "Conventions": CONVENTIONS,
        "featureType": FEATURE_TYPE,
        "title": title,
        "institution": source,
        "source": source,
        "history": f"{date_created} {source}: simulated mission run (seed {int(seed)})",
        "date_created": date_created,
        "mission_epoch": epoch_iso,
        "epsg_code": f"EPSG:{int(epsg)}",
        "seed": np.int64(seed),
        "software_version": software_version,
        "configuration": config_toml,
    }

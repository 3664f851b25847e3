"""Public Python API: one shot, and the thesis's parametric sweep (Table 4.11).

``simulate_shot`` and ``sweep`` evaluate a configuration's own channel (the lab bench of the
thesis missions). A survey mission (a file with ``[scene]``, ``[platform]``, ``[attitude]``,
``[beams]`` and ``[survey]``) is evaluated at its own geometry by ``simulate_mission_shot`` and
``sweep_mission``, which take the mission file (the scene path in it is relative to the file):
one shot of the survey, as ``chirplidar run`` computes it (:mod:`chirplidar.mission.shot`).
"""

from __future__ import annotations

import os
import warnings

import numpy as np
import xarray as xr

from .channel.lab import simulate_lab
from .config import MissionConfig, config_with, resolve_key
from .tiers.common import OUTPUT_NAMES, OUTPUT_UNITS
from .tiers.registry import get_tier

__all__ = ["simulate_shot", "simulate_lab", "sweep", "simulate_mission_shot", "sweep_mission",
           "OUTPUT_NAMES", "OUTPUT_UNITS"]


def _rng(config: MissionConfig, seed: int | None) -> np.random.Generator:
    return np.random.default_rng(config.seed if seed is None else seed)


def _config(config) -> MissionConfig:
    """A configuration, or the mission file it names (loaded without overrides)."""
    if isinstance(config, MissionConfig):
        return config
    if isinstance(config, (str, os.PathLike)):
        from .config import load_mission

        return load_mission(config)
    raise TypeError(f"expected a MissionConfig or a mission file path, got "
                    f"{type(config).__name__}")


def simulate_shot(config: MissionConfig | str | os.PathLike, seed: int | None = None,
                  tier: str = "rf", return_spectrum: bool = False) -> dict:
    """Run one shot; returns the thesis Table 4.10 outputs as floats plus ``flags``, ``tier`` and
    ``f_beat_hz`` (and ``spectrum`` when asked, from a tier that draws one: rf, baseband).

    Units are those of ``OUTPUT_UNITS`` (dBm, dBm/Hz, m, dB). Zero power reads -inf dB, never NaN.
    The seed defaults to the configuration's ``seed``. The shot sees the configuration's own
    channel (``channel.distance_m``, the target); for a survey mission that is not the mission's
    geometry: :func:`simulate_mission_shot` evaluates a shot of the survey (a UserWarning says so).
    ``config`` may also be a mission file's path.
    """
    config = _config(config)
    _warn_if_survey(config, "simulate_shot", "simulate_mission_shot")
    raw = simulate_lab(config, tier, _rng(config, seed), keep_spectrum=return_spectrum)
    return _shot_floats(raw)


def _warn_if_survey(config: MissionConfig, name: str, instead: str) -> None:
    if config.survey is not None:
        warnings.warn(f"{name}: this configuration is a survey mission, evaluated here on its "
                      f"lab channel (channel.distance_m = {config.channel.distance_m:g} m), not "
                      f"at the mission's geometry; {instead}(mission_path, ...) flies it",
                      UserWarning, stacklevel=3)


def _shot_floats(raw: dict) -> dict:
    """A tier's batch-of-one outputs as floats (the spectrum's arrays flattened)."""
    out = {}
    for key, value in raw.items():
        if key == "spectrum":
            out[key] = {k: (float(np.ravel(v)[0]) if np.size(v) == 1 else np.asarray(v).reshape(-1))
                        for k, v in value.items()}
        elif isinstance(value, np.ndarray):
            out[key] = float(value[0])
        else:
            out[key] = value
    return out


def simulate_mission_shot(mission, overrides=(), seed: int | None = None, tier: str = "rf",
                          at_s: float | None = None, beam: int = 0,
                          return_spectrum: bool = False) -> dict:
    """One shot of the survey mission file ``mission`` at the mission's geometry.

    The mission is prepared as ``chirplidar run`` prepares it (``overrides``: ``--set`` style
    strings or a mapping; ``seed``: the run's seed, default the mission's); the shot is the first
    of the survey span whose beam ``beam`` hits the terrain, or the one nearest to ``at_s``
    seconds of the mission clock; the tier (any of ``chirplidar.tiers.TIERS``) takes the returns a
    survey run builds for that shot (:mod:`chirplidar.mission.shot`). Returns :func:`simulate_shot`'s
    dict (Table 4.10 names of that shot) plus its geometry (``t_s``, ``beam``, ``shot_index``,
    ``range_m``, ``footprint_range_m``, ``x_m``, ``y_m``, ``surface_height_m``, ``surface``,
    ``incidence_deg``, ``off_nadir_deg``, ``platform_height_m``) and ``mission_geometry =
    True``. Bad input (time outside the span, beam out of range, no surface) raises ConfigError.
    """
    from .mission.shot import simulate_mission_shot as _mission_shot

    if not isinstance(mission, (str, os.PathLike)):
        raise TypeError(f"simulate_mission_shot takes the mission file's path (its scene path is "
                        f"relative to it), not a {type(mission).__name__}")
    raw = _mission_shot(mission, tier=tier, at_s=at_s, beam=beam, overrides=overrides,
                        seed=seed, batch=1, keep_spectrum=return_spectrum)
    geometry = raw.pop("geometry")
    out = _shot_floats(raw)
    out.update(geometry)
    return out


def _sweep_values(start: float, stop: float, n: int, scale: str) -> np.ndarray:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n (points) must be an integer >= 1, got {n!r}")
    if scale == "log":
        if start <= 0 or stop <= 0:
            raise ValueError("a log sweep needs positive start and stop")
        return np.geomspace(start, stop, n)
    if scale == "lin":
        return np.linspace(start, stop, n)
    raise ValueError("scale must be 'lin' or 'log'")


def _sweep_dataset(rows: list, xs: np.ndarray, key: str, vary: str, repeat: int, tier: str,
                   seed: int, extra: dict | None = None, attrs: dict | None = None) -> xr.Dataset:
    """The sweep Dataset (dims x, repeat) of the tiers' raw outputs ``rows``, one per x."""
    from .tiers.registry import tier_outputs

    units, long_names = tier_outputs(tier)
    data = {name: (("x", "repeat"), np.stack([np.asarray(r[name], float) for r in rows]),
                   {"units": units[name], "long_name": long_names[name]})
            for name in units}
    if "f_beat_hz" in rows[0]:
        data["f_beat_hz"] = (("x", "repeat"), np.stack([r["f_beat_hz"] for r in rows]),
                             {"units": "Hz", "long_name": "measured beat frequency"})
    data["flags"] = (("x",), np.array([",".join(r["flags"]) for r in rows], dtype=object),
                     {"long_name": "comma-separated flags"})
    data.update(extra or {})
    return xr.Dataset(
        data, coords={"x": ("x", xs, {"long_name": key, "thesis_name": vary}),
                      "repeat": np.arange(repeat)},
        attrs={"vary": key, "tier": tier, "seed": int(seed), **(attrs or {})})


def _progress(iterator, vary: str, progress: bool, **kwargs):
    if not progress:
        return iterator
    from tqdm import tqdm

    return tqdm(iterator, desc=f"sweep {vary}", unit="pt", **kwargs)


def sweep(config: MissionConfig | str | os.PathLike, vary: str, start: float, stop: float,
          n: int, repeat: int = 1, scale: str = "lin", seed: int | None = None, tier: str = "rf",
          progress: bool = False) -> xr.Dataset:
    """Vary one parameter (thesis or project name) over ``n`` points, ``repeat`` shots each.

    Each point draws from its own child of the run's SeedSequence, so a point's result does not
    depend on how many points the sweep has before it. Like :func:`simulate_shot`, on the
    configuration's own channel: :func:`sweep_mission` sweeps a survey mission at its geometry.
    ``config`` may also be a mission file's path.
    """
    config = _config(config)
    _warn_if_survey(config, "sweep", "sweep_mission")
    key = resolve_key(vary)
    xs = _sweep_values(start, stop, n, scale)
    get_tier(tier)   # an unknown tier is refused before the first point
    children = np.random.SeedSequence(config.seed if seed is None else seed).spawn(n)
    rows = []
    for i in _progress(range(n), vary, progress):
        cfg = config_with(config, {key: float(xs[i])})
        rows.append(simulate_lab(cfg, tier, np.random.default_rng(children[i]), batch=repeat))
    return _sweep_dataset(rows, xs, key, vary, repeat, tier,
                          config.seed if seed is None else seed)


def sweep_mission(mission, vary: str, start: float, stop: float, n: int, overrides=(),
                  repeat: int = 1, scale: str = "lin", seed: int | None = None,
                  tier: str = "rf", at_s: float | None = None, beam: int = 0,
                  progress: bool = False) -> xr.Dataset:
    """:func:`sweep` of a survey mission file at the mission's geometry.

    Each point applies ``vary`` = x to the mission (after ``overrides``; any key, e.g.
    ``platform.uav.altitude_m`` or a beam or attitude key), prepares and plans it again (the
    geometry changes with the key) and evaluates the shot :func:`simulate_mission_shot` picks
    (``at_s``, ``beam``), ``repeat`` records of that footprint. The survey's own draws are the
    run's with ``seed`` at every point (pointing jitter, speckle and the other effects: the same
    survey, so the outputs follow the geometry, not a new speckle draw per point); the tier
    draws point i's records from child i of ``SeedSequence(seed)``, as :func:`sweep` does. The
    Dataset is
    :func:`sweep`'s plus the per-point geometry (dim x): ``t_s``, ``beam``, ``shot_index``,
    ``range_m``, ``footprint_range_m``, ``x_m``, ``y_m``, ``surface_height_m``, ``surface``,
    ``incidence_deg``, ``off_nadir_deg``, ``platform_height_m``; attribute ``mission_geometry``.
    """
    from .config.loader import load_mission, parse_set
    from .mission.shot import GEOMETRY_KEYS, GEOMETRY_UNITS, prepare_mission
    from .mission.shot import simulate_mission_shot as _mission_shot

    key = resolve_key(vary)
    xs = _sweep_values(start, stop, n, scale)
    items = (list(overrides.items()) if hasattr(overrides, "items")
             else [parse_set(s) for s in overrides])
    if seed is None:
        seed = load_mission(mission, dict(items)).seed
    children = np.random.SeedSequence(seed).spawn(n)
    rows, geometry = [], []

    def point(i):
        over = dict(items)
        over[key] = float(xs[i])  # after the overrides: the varied key wins
        prep = prepare_mission(mission, overrides=over, seed=seed)
        raw = _mission_shot(prep, tier=tier, at_s=at_s, beam=beam,
                            rng=np.random.default_rng(children[i]), batch=repeat)
        geometry.append(raw.pop("geometry"))
        rows.append(raw)

    point(0)  # before the progress bar: a bad --at-s or --beam is one error line
    for i in _progress(range(1, n), vary, progress, initial=1, total=n):
        point(i)
    extra = {}
    for name in GEOMETRY_KEYS:
        values = [g[name] for g in geometry]
        arr = np.array(values, dtype=object if name == "surface" else None)
        attrs = {"long_name": f"evaluated survey shot: {name}"}
        if name in GEOMETRY_UNITS:
            attrs["units"] = GEOMETRY_UNITS[name]
        extra[name] = (("x",), arr, attrs)
    return _sweep_dataset(rows, xs, key, vary, repeat, tier, seed, extra,
                          {"mission_geometry": 1})

"""Public Python API: one shot, and the thesis's parametric sweep (Table 4.11)."""

from __future__ import annotations

import numpy as np
import xarray as xr

from .config import MissionConfig, config_with, resolve_key
from .tiers import TIERS
from .tiers.common import OUTPUT_LONG_NAMES, OUTPUT_NAMES, OUTPUT_UNITS

__all__ = ["simulate_shot", "sweep", "OUTPUT_NAMES", "OUTPUT_UNITS"]


def _rng(config: MissionConfig, seed: int | None) -> np.random.Generator:
    return np.random.default_rng(config.seed if seed is None else seed)


def _tier(name: str):
    try:
        return TIERS[name]
    except KeyError:
        raise ValueError(f"unknown tier '{name}'; choose one of {', '.join(TIERS)}") from None


def simulate_shot(config: MissionConfig, seed: int | None = None, tier: str = "rf",
                  return_spectrum: bool = False) -> dict:
    """Run one shot; returns the thesis Table 4.10 outputs as floats plus ``flags``, ``tier`` and
    ``f_beat_hz`` (and ``spectrum`` for the rf tier when asked).

    Units are those of ``OUTPUT_UNITS`` (dBm, dBm/Hz, m, dB). Zero power reads -inf dB, never NaN.
    The seed defaults to the configuration's ``seed``.
    """
    raw = _tier(tier)(config, _rng(config, seed), batch=1, keep_spectrum=return_spectrum)
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


def sweep(config: MissionConfig, vary: str, start: float, stop: float, n: int, repeat: int = 1,
          scale: str = "lin", seed: int | None = None, tier: str = "rf",
          progress: bool = False) -> xr.Dataset:
    """Vary one parameter (thesis or project name) over ``n`` points, ``repeat`` shots each.

    Each point draws from its own child of the run's SeedSequence, so a point's result does not
    depend on how many points the sweep has before it.
    """
    key = resolve_key(vary)
    if scale == "log":
        if start <= 0 or stop <= 0:
            raise ValueError("a log sweep needs positive start and stop")
        xs = np.geomspace(start, stop, n)
    elif scale == "lin":
        xs = np.linspace(start, stop, n)
    else:
        raise ValueError("scale must be 'lin' or 'log'")
    run = _tier(tier)
    children = np.random.SeedSequence(config.seed if seed is None else seed).spawn(n)
    rows = []
    iterator = range(n)
    if progress:
        from tqdm import tqdm
        iterator = tqdm(iterator, desc=f"sweep {vary}", unit="pt")
    flags = []
    for i in iterator:
        cfg = config_with(config, {key: float(xs[i])})
        raw = run(cfg, np.random.default_rng(children[i]), batch=repeat)
        rows.append(raw)
        flags.append(",".join(raw["flags"]))
    data = {name: (("x", "repeat"), np.stack([r[name] for r in rows]),
                   {"units": OUTPUT_UNITS[name], "long_name": OUTPUT_LONG_NAMES[name]})
            for name in OUTPUT_NAMES}
    data["f_beat_hz"] = (("x", "repeat"), np.stack([r["f_beat_hz"] for r in rows]),
                         {"units": "Hz", "long_name": "measured beat frequency"})
    data["flags"] = (("x",), np.array(flags, dtype=object), {"long_name": "comma-separated flags"})
    return xr.Dataset(
        data, coords={"x": ("x", xs, {"long_name": key, "thesis_name": vary}),
                      "repeat": np.arange(repeat)},
        attrs={"vary": key, "tier": tier, "seed": int(config.seed if seed is None else seed)})

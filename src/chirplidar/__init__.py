"""chirplidar: simulator for FM-chirped lidar altimeters with self-chirped homodyne detection.

The public names below are imported on first use (PEP 562): ``import chirplidar.units`` or
``chirplidar --help`` does not pay for numpy-heavy modules (scipy, xarray, pydantic) it does
not use.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

#: Public name -> the module that defines it.
_LAZY = {
    "simulate_shot": ".api", "sweep": ".api", "simulate_mission_shot": ".api",
    "sweep_mission": ".api", "OUTPUT_NAMES": ".api", "OUTPUT_UNITS": ".api",
    "load_mission": ".config", "ConfigError": ".config", "MissionConfig": ".config",
    "doppler_shift_hz": ".doppler",
}

__all__ = ["simulate_shot", "sweep", "simulate_mission_shot", "sweep_mission", "load_mission",
           "ConfigError", "MissionConfig", "OUTPUT_NAMES", "OUTPUT_UNITS", "doppler_shift_hz",
           "__version__"]


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'chirplidar' has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value   # the next access is a plain lookup
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))

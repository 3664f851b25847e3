"""chirplidar: simulator for FM-chirped lidar altimeters with self-chirped homodyne detection.

The public names below are imported on first use (PEP 562): ``import chirplidar.units`` or
``chirplidar --help`` does not pay for the numpy-heavy modules (scipy, xarray, pydantic) it does
not use.
"""

from .lazy import lazy_exports

__version__ = "0.1.0"
__all__ = ["simulate_shot", "sweep", "simulate_mission_shot", "sweep_mission", "load_mission",
           "ConfigError", "MissionConfig", "OUTPUT_NAMES", "OUTPUT_UNITS", "doppler_shift_hz",
           "__version__"]

__getattr__, __dir__ = lazy_exports(__name__, {
    "api": ("OUTPUT_NAMES", "OUTPUT_UNITS", "simulate_mission_shot", "simulate_shot", "sweep",
            "sweep_mission"),
    "config": ("ConfigError", "MissionConfig", "load_mission"),
    "doppler": ("doppler_shift_hz",),
})
del lazy_exports

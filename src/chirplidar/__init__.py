"""chirplidar: simulator for FM-chirped lidar altimeters with self-chirped homodyne detection."""

from .api import (OUTPUT_NAMES, OUTPUT_UNITS, simulate_mission_shot, simulate_shot, sweep,
                  sweep_mission)
from .config import ConfigError, MissionConfig, load_mission
from .doppler import doppler_shift_hz

__version__ = "0.1.0"
__all__ = ["simulate_shot", "sweep", "simulate_mission_shot", "sweep_mission", "load_mission", "ConfigError", "MissionConfig",
           "OUTPUT_NAMES", "OUTPUT_UNITS", "doppler_shift_hz", "__version__"]

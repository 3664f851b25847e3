"""Mission configuration: TOML files validated by pydantic models, thesis names as aliases."""

from .aliases import THESIS_TABLE, THESIS_TO_KEY, resolve_key, resolve_output
from .instrument import instrument_from_config
from .loader import (ConfigError, PROJECT_KEYS, config_flat, config_with, load_mission, parse_set,
                     read_mission_flat)
from .models import MissionConfig

__all__ = ["THESIS_TABLE", "THESIS_TO_KEY", "resolve_key", "resolve_output", "ConfigError",
           "PROJECT_KEYS", "config_flat", "config_with", "load_mission", "parse_set",
           "read_mission_flat", "MissionConfig", "instrument_from_config"]

"""Channel: turns geometry and scene into per-shot returns (bench channel for now)."""

from .bench import power_transmission, round_trip_delay_s

__all__ = ["power_transmission", "round_trip_delay_s"]

"""Channel: turns the configuration (the lab bench) or a survey's geometry into the returns the
tiers take (:class:`chirplidar.tiers.model.Returns`)."""

from .lab import lab_returns, power_transmission, round_trip_delay_s, simulate_lab

__all__ = ["lab_returns", "simulate_lab", "power_transmission", "round_trip_delay_s"]

"""Fidelity tiers: one interface ``(config, rng, *, batch, keep_spectrum) -> dict``, three costs."""

from .baseband import simulate_baseband
from .link import simulate_link
from .rf import simulate_rf

TIERS = {"rf": simulate_rf, "baseband": simulate_baseband, "link": simulate_link}

__all__ = ["TIERS", "simulate_rf", "simulate_baseband", "simulate_link"]

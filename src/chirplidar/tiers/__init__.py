"""Fidelity tiers: one interface, ``simulate(instrument, returns, rng) -> Measurements``, three
costs for the chirped instruments (:data:`TIERS`: rf, baseband, link) and the pulsed tier for
short-pulse altimeters. See :mod:`chirplidar.tiers.model`."""

from __future__ import annotations

from ..lazy import lazy_exports
from .model import Instrument, Measurements, Returns, Supports, Tier, UnsupportedError
from .registry import TIER_NAMES, TIERS, get_tier

__all__ = [
    "TIERS",
    "TIER_NAMES",
    "get_tier",
    "Instrument",
    "Returns",
    "Measurements",
    "Tier",
    "Supports",
    "UnsupportedError",
    "simulate_rf",
    "simulate_baseband",
    "simulate_link",
    "simulate_pulsed",
]

# The tier modules load scipy: imported on first use (PEP 562).
__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "rf": ("simulate_rf",),
        "baseband": ("simulate_baseband",),
        "link": ("simulate_link",),
        "pulsed": ("simulate_pulsed",),
    },
)
del lazy_exports

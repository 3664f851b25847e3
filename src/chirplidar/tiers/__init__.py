"""Fidelity tiers: one interface, ``simulate(instrument, returns, rng) -> Measurements``, three
costs (:data:`TIERS`: rf, baseband, link). See :mod:`chirplidar.tiers.model`."""

from __future__ import annotations

import importlib

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
]

_LAZY = {"simulate_rf": "rf", "simulate_baseband": "baseband", "simulate_link": "link"}


def __getattr__(name: str):
    if name in _LAZY:  # the tier modules load scipy: imported on first use
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

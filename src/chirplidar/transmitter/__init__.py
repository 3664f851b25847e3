"""Transmitter (thesis TX_model.m): laser, Mach-Zehnder modulator, splitter, optical amplifier."""

from .laser import wiener_phase
from .mzm import (
    mzm_field,
    mzm_fundamental_field,
    mzm_mean_power_transmission,
    mzm_power_fundamental,
)

__all__ = [
    "wiener_phase",
    "mzm_field",
    "mzm_fundamental_field",
    "mzm_mean_power_transmission",
    "mzm_power_fundamental",
]

"""Receivers (thesis RX_model.m): couplers, photodetectors and their noise.

Noise PSDs are one-sided current densities (A^2/Hz) referred to the photodiode (thesis Sec. 2.5):
shot 2 q I (APD: 2 q I M^2 F), thermal 4 k T / R, amplifier (NEP * R)^2. Table 4.7-4.9's Isol, Ibgd,
Ilkg are listed in A/rtHz but enter as DC currents whose shot noise is 2 q I (eqs. 2.5.2-2.5.3): read
as densities, PIN.Ibgd = 4 uA/rtHz would exceed every other noise source by 60 dB.
"""

from functools import lru_cache

import numpy as np

from ..units import BOLTZMANN_J_K, ELEMENTARY_CHARGE_C

# 3 dB coupler, eq. 3.3.1; inputs ordered (LO, signal).
COUPLER_3DB = np.array([[1.0, 1.0j], [1.0j, 1.0]]) / np.sqrt(2.0)

# The two ports of the 3x3 90-degree hybrid used in Ch. 5 (eq. 5.5, Appendix C).
_P = np.exp(0.75j * np.pi)
HYBRID_90 = np.array([[np.sqrt(0.2), np.sqrt(0.4) * _P], [np.sqrt(0.4) * _P, np.sqrt(0.2)]])


def shot_psd(current_a):
    return 2.0 * ELEMENTARY_CHARGE_C * np.asarray(current_a)


def thermal_psd(temperature_k: float, resistance_ohm: float) -> float:
    return 4.0 * BOLTZMANN_J_K * temperature_k / resistance_ohm


class single_pole:
    """First-order low-pass H(f) = 1 / (1 + j f / B).

    Evaluated on an rfft grid (``n``, ``fs``) it is cached, since every shot of a run reuses it.
    """

    def __init__(self, bandwidth_hz: float):
        self.bandwidth_hz = bandwidth_hz

    def __call__(self, f):
        return 1.0 / (1.0 + 1j * np.asarray(f) / self.bandwidth_hz)

    def on_grid(self, n_fft: int, fs_hz: float) -> np.ndarray:
        return _single_pole_grid(self.bandwidth_hz, n_fft, fs_hz)


@lru_cache(maxsize=8)
def _single_pole_grid(bandwidth_hz: float, n_fft: int, fs_hz: float) -> np.ndarray:
    f = np.arange(n_fft // 2 + 1) * (fs_hz / n_fft)
    h = 1.0 / (1.0 + 1j * f / bandwidth_hz)
    h.setflags(write=False)
    return h

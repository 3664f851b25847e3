"""Optical fields at the receiver as complex envelopes E = A exp(j phi) + n.

A is the real MZM field amplitude (sqrt(W), may be negative), phi the optical phase (a per-record
constant or a time series when the laser has a linewidth), n optional additive noise (ASE). Keeping
A and phi apart lets a coupler output be computed in real arithmetic when phi is a constant:
|s0 E_LO + s1 E_s|^2 = |s0|^2 |E_LO|^2 + |s1|^2 |E_s|^2 + 2 Re(s0 s1* E_LO E_s*).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Field:
    amp: np.ndarray
    phase: np.ndarray
    noise: np.ndarray | None = None

    def complex(self) -> np.ndarray:
        e = self.amp * np.exp(1j * self.phase)
        return e if self.noise is None else e + self.noise

    def power(self) -> np.ndarray:
        if self.noise is None:
            return np.broadcast_to(
                self.amp * self.amp, np.broadcast_shapes(np.shape(self.amp), np.shape(self.phase))
            )
        return np.abs(self.complex()) ** 2


def port_power(s_lo: complex, s_sig: complex, lo: Field, sig: Field) -> np.ndarray:
    """Optical power (W) at a coupler port with field coefficients ``s_lo`` and ``s_sig``."""
    c = s_lo * np.conj(s_sig)
    if lo.noise is None and sig.noise is None:
        cross = (2.0 * abs(c)) * lo.amp * sig.amp * np.cos(lo.phase - sig.phase + np.angle(c))
    else:
        cross = 2.0 * np.real(c * lo.complex() * np.conj(sig.complex()))
    return abs(s_lo) ** 2 * lo.power() + abs(s_sig) ** 2 * sig.power() + cross


def port_coefficients(
    s_lo: complex, s_sig: complex, lo_scale: float, sig_scale: float, dphase
) -> tuple[float, float, np.ndarray]:
    """(cL, cS, cX) with port power = cL a_lo^2 + cS a_sig^2 + cX a_lo a_sig.

    For unit MZM amplitudes a (the field is sqrt(scale) a exp(j phi)) whose phase difference
    ``dphase`` = phi_LO - phi_sig is constant over the record (shape (..., 1)): the fast path of
    :func:`port_power`, with the three arrays shared by every shot.
    """
    c = s_lo * np.conj(s_sig)
    cross = 2.0 * abs(c) * np.sqrt(lo_scale * sig_scale) * np.cos(dphase + np.angle(c))
    return abs(s_lo) ** 2 * lo_scale, abs(s_sig) ** 2 * sig_scale, cross


def combine(coefs, arrays):
    """sum_i coef_i * array_i, skipping zero coefficients (a balanced pair cancels its LO term)."""
    out = None
    for c, a in zip(coefs, arrays, strict=True):
        if np.all(np.asarray(c) == 0):
            continue
        term = c * a
        out = term if out is None else out + term
    return np.zeros_like(arrays[0]) if out is None else out

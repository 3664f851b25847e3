"""Doppler shift and what it does to the self-chirped homodyne beat (thesis eq. 2.2.5, App. D).

Sign convention: a positive line-of-sight velocity is **closing** (the range decreasing); it
gives a positive Doppler shift f_d = 2 v / lambda (eq. 2.2.5), the return arriving at a higher
optical frequency. The line-of-sight velocity is the negative of the range rate.

The real homodyne output with Doppler is y = cos(2 pi f_d t + theta) cos(2 pi f_R t) (App. D):
two lines of equal amplitude 1/2 at f_R - f_d and f_R + f_d, and no line at the range beat f_R
itself. Appendix D requires |f_d| < f_R "to avoid ambiguity from negative frequency components":
for |f_d| > f_R the lower line folds through zero and the pair {|f_d| - f_R, |f_d| + f_R} is the
same as a beat at |f_d| with Doppler f_R — range and Doppler swap. The sign of f_d is never
recoverable from a real record (y is even in f_d). Squaring the record (App. D) puts a
Doppler-free line at 2 f_R.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ._checks import out, real_array
from .units import OMEGA_EARTH_RAD_S, WGS84_A_M  # noqa: F401  (re-exported)


def _vectors(name: str, value) -> np.ndarray:
    arr = real_array(name, value)
    if arr.ndim == 0 or arr.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (3,) or (n_shots, 3), got {arr.shape}")
    return arr


def doppler_shift_hz(velocity_mps, wavelength_m):
    """Doppler shift f_d = 2 v / lambda (Hz), thesis eq. 2.2.5.

    velocity_mps: line-of-sight velocity (m/s), positive closing (range decreasing);
    wavelength_m: vacuum wavelength (m, > 0). Broadcast; float64 (float for scalars). Zero
    velocity gives exactly 0. 1 m/s at 1310 nm is 1.5267 MHz.
    """
    v = real_array("velocity_mps", velocity_mps)
    lam = real_array("wavelength_m", wavelength_m)
    if np.any(lam <= 0.0):
        raise ValueError("wavelength_m must be > 0")
    return out(2.0 * v / lam)


def earth_rotation_velocity_mps(position_m):
    """Velocity (m/s) of a point fixed on the Earth, omega_E x r, in axes aligned with ECEF.

    position_m: ECEF position (m), shape (3,) or (n, 3). Returns the same shape. At the equator
    on the WGS 84 ellipsoid the speed is omega_E a = 465.10 m/s eastward.
    """
    r = _vectors("position_m", position_m)
    omega = np.array([0.0, 0.0, OMEGA_EARTH_RAD_S])
    return np.cross(omega, r)


def line_of_sight_velocity_mps(
    platform_velocity_mps,
    pointing_unit,
    target_velocity_mps=None,
    earth_rotation=False,
    position_m=None,
):
    """Closing velocity along the beam, (v_platform - v_target) . u (m/s) = -(range rate).

    platform_velocity_mps: (3,) or (n_shots, 3), m/s; pointing_unit: unit vector from the
    platform towards the target, (3,) or (n_shots, 3) (norm 1 within 1e-6); target_velocity_mps:
    the target's own velocity (ice flow, a moving vehicle), same frame, default none;
    earth_rotation: True when the platform velocity is inertial (e.g. an orbit propagator's ECI
    velocity, axes aligned with ECEF at the shot time) and the target rides on the rotating Earth:
    its velocity omega_E x r is subtracted as well, with r = position_m, the target's (footprint's)
    ECEF position, (3,) or (n_shots, 3). position_m without earth_rotation is an error (it would
    be silently unused). All vectors in one frame. Returns float or (n_shots,) float64.

    Positive = closing, the sign of ``doppler_shift_hz``. Nadir pointing with a horizontal velocity
    gives 0; a beam tilted forward by phi from nadir gives v sin(phi).
    """
    vp = _vectors("platform_velocity_mps", platform_velocity_mps)
    u = _vectors("pointing_unit", pointing_unit)
    norm = np.linalg.norm(u, axis=-1)
    if np.any(np.abs(norm - 1.0) > 1e-6):
        raise ValueError("pointing_unit must have unit norm (within 1e-6)")
    rel = vp
    if target_velocity_mps is not None:
        rel = rel - _vectors("target_velocity_mps", target_velocity_mps)
    if earth_rotation:
        if position_m is None:
            raise ValueError("earth_rotation=True needs position_m (the target's ECEF position)")
        rel = rel - earth_rotation_velocity_mps(position_m)
    elif position_m is not None:
        raise ValueError("position_m is only used with earth_rotation=True")
    try:
        v_los = np.sum(rel * u, axis=-1)
    except ValueError:
        raise ValueError(
            f"velocity and pointing shapes do not broadcast: {rel.shape}, {u.shape}"
        ) from None
    return out(v_los)


class DopplerLines(NamedTuple):
    """Line frequencies of the real homodyne output with Doppler (Hz) and the ambiguity flag."""

    lower_hz: np.ndarray | float
    upper_hz: np.ndarray | float
    ambiguous: np.ndarray | bool


def homodyne_doppler_spectrum_lines(f_beat_hz, f_doppler_hz) -> DopplerLines:
    """Where y = cos(2 pi f_d t + theta) cos(2 pi f_R t) has its lines (thesis Appendix D).

    f_beat_hz: range beat f_R (Hz, >= 0); f_doppler_hz: Doppler shift f_d (Hz, either sign).
    Broadcast. Returns ``DopplerLines(lower_hz=|f_R - |f_d||, upper_hz=f_R + |f_d|, ambiguous)``;
    each line has amplitude 1/2 (power 1/8 of a unit product; at f_d = 0 the two merge into
    cos(theta) cos(2 pi f_R t): fading instead of splitting). ``ambiguous`` is True where
    |f_d| >= f_R: the lower line has folded through (or sits at) zero frequency and the line pair
    no longer tells the range beat (the mean of the two lines is max(f_R, |f_d|)). The sign of f_d
    is never observable in the real output.
    """
    fr = real_array("f_beat_hz", f_beat_hz)
    fd = real_array("f_doppler_hz", f_doppler_hz)
    if np.any(fr < 0.0):
        raise ValueError("f_beat_hz must be >= 0")
    fr, fd = np.broadcast_arrays(fr, fd)
    ad = np.abs(fd)
    amb = ad >= fr
    return DopplerLines(out(np.abs(fr - ad)), out(fr + ad), bool(amb) if amb.ndim == 0 else amb)


@dataclass(frozen=True)
class SquaredRecord:
    """The squared beat record and its one-sided spectrum (``squaring_recovery``).

    squared: y^2, same shape as the record; freqs_hz: (n_samples // 2 + 1,) rfft frequencies;
    power: (..., n_samples // 2 + 1) one-sided mean-square per bin in record units^2 (a tone
    A cos(2 pi f t) on a bin reads A^2/2, DC reads mean^2), rectangular window.
    """

    squared: np.ndarray
    freqs_hz: np.ndarray
    power: np.ndarray


def squaring_recovery(record, fs_hz) -> SquaredRecord:
    """Appendix D's Doppler-free recovery: square the real beat record, look at 2 f_R.

    With y = cos(w_d t) cos(w_B t),
    y^2 = 1/4 [1 + cos(2 w_d t) + cos(2 w_B t) + 1/2 cos(2 (w_B - w_d) t) + 1/2 cos(2 (w_B + w_d) t)]
    (direct expansion; App. D prints the prefactor as 1/2, the line positions are the same). The
    term (1/4) cos(2 w_B t) does not depend on the Doppler shift, even when f_d wanders from block
    to block, so the peak of the squared record's spectrum sits at 2 f_R; the Doppler moves to
    baseband (2 f_d) and to sidebands at 2 (f_R +- f_d). The caller finds the peak above the
    baseband terms (e.g. in ``chirplidar.processing``) and halves it.

    The noise level rises (App. D: "on par with the envelope detection" of heterodyne detection):
    for y = s + n, y^2 = s^2 + 2 s n + n^2 — the signal-noise cross term spreads the noise over
    twice the bandwidth and the noise-noise term adds noise that does not fall with the signal, so
    the SNR at 2 f_R is below the SNR a Doppler-free record has at f_R, increasingly so at low SNR.
    Squaring also needs twice the sampling bandwidth: 2 f_R must stay below fs_hz / 2.

    record: real array (..., n_samples), n_samples >= 2 (batch over leading axes); fs_hz: sample
    rate (Hz, > 0). Returns ``SquaredRecord``.
    """
    y = np.asarray(record)
    if np.iscomplexobj(y):
        raise ValueError("record must be real-valued (the real photocurrent / voltage of App. D)")
    y = real_array("record", y)
    if y.ndim == 0 or y.shape[-1] < 2:
        raise ValueError("record must have at least 2 samples along its last axis")
    fs = real_array("fs_hz", fs_hz)
    if fs.ndim != 0 or fs <= 0.0:
        raise ValueError("fs_hz must be a scalar > 0")
    n = y.shape[-1]
    sq = y * y
    spec = np.fft.rfft(sq, axis=-1)
    power = (spec.real**2 + spec.imag**2) / n**2
    # One-sided: double every bin that has a negative-frequency twin (not DC, not Nyquist).
    last = n // 2 + 1 if n % 2 else n // 2
    power[..., 1:last] *= 2.0
    return SquaredRecord(squared=sq, freqs_hz=np.fft.rfftfreq(n, d=1.0 / float(fs)), power=power)

"""Linear FM chirp train (thesis Table 4.3, Figs. 4.4-4.5, eq. 3.2.3).

Each period ``Tchp`` has a rising ramp of duration ``rdcyc * Tchp`` from F1+F0 to F2+F0, during which
the amplitude rises, holds for ``adcyc`` of the ramp, and falls (raised-cosine transitions); the
falling ramp that completes the period carries no amplitude. The instrument runs in steady state, so
the train is periodic for all times: a return delayed by more than a period meets a later chirp of
the reference, exactly as the bench's 106 us reference delay does (eq. 5.2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def drive_levels(config) -> tuple[float, float]:
    """(amplitude, dc) in volts at the modulator for a drive of ``chrp.Vpp`` and ``chrp.Vdc``.

    Vpp is set for a matched load (signal-generator convention); the modulator's input impedance Ri
    then sees 2 Ri / (Ro + Ri) of it.
    """
    wf, mzm = config.waveform, config.modulator
    divider = 2.0 * mzm.input_impedance_ohm / (wf.output_impedance_ohm + mzm.input_impedance_ohm)
    return 0.5 * wf.vpp_v * divider, wf.vdc_v * divider


class PeriodicTrain:
    """What every periodic drive shares: the record gate and a grid over one period."""

    period_s: float
    amplitude_v: float
    dc_v: float

    def unit(self, t_s: np.ndarray) -> np.ndarray:
        """The waveform in units of the amplitude at times ``t_s`` (s); each drive defines it."""
        raise NotImplementedError

    def envelope(self, t_s: np.ndarray) -> np.ndarray:
        """The amplitude envelope (0..1) at times ``t_s`` (s); each drive defines it."""
        raise NotImplementedError

    def voltage(self, t_s: np.ndarray) -> np.ndarray:
        """Drive voltage at the modulator (V): dc + amplitude x the unit waveform."""
        return self.dc_v + self.amplitude_v * self.unit(t_s)

    def record_gate(self, t_s: np.ndarray, duration_s: float) -> np.ndarray:
        """True where a whole chirp of the record lies: chirps start at multiples of the period
        and one that would not finish inside ``duration_s`` is not generated (Table 4.3, Tchp)."""
        n_chirps = int(np.floor(duration_s / self.period_s + 1e-9))
        return np.asarray(t_s) < n_chirps * self.period_s * (1.0 - 1e-12)

    def envelope_samples(self, n: int = 4096) -> np.ndarray:
        """Envelope on a uniform grid over one period (for averages of slow functions of w)."""
        tc = (np.arange(n) + 0.5) * (self.period_s / n)
        return self.envelope(tc)


@dataclass(frozen=True)
class ChirpTrain(PeriodicTrain):
    """Chirp timing and levels. Frequencies in Hz, times in s, voltages in V at the modulator."""

    period_s: float
    rise_s: float
    f_start_hz: float
    f_stop_hz: float
    amplitude_duty_cycle: float
    hold_time_s: float
    amplitude_v: float
    dc_v: float

    @classmethod
    def from_config(cls, config) -> ChirpTrain:
        wf = config.waveform
        amplitude_v, dc_v = drive_levels(config)
        return cls(
            period_s=wf.chirp_period_s,
            rise_s=wf.ramp_duty_cycle * wf.chirp_period_s,
            f_start_hz=wf.f_start_hz + wf.f_offset_hz,
            f_stop_hz=wf.f_stop_hz + wf.f_offset_hz,
            amplitude_duty_cycle=wf.amplitude_duty_cycle,
            hold_time_s=wf.hold_time_s,
            amplitude_v=amplitude_v,
            dc_v=dc_v,
        )

    @property
    def bandwidth_hz(self) -> float:
        return self.f_stop_hz - self.f_start_hz

    @property
    def rate_hz_per_s(self) -> float:
        """Chirp rate kappa = (F2 - F1) / tau; the beat is f_R = kappa * delay (eq. 2.3.1)."""
        return self.bandwidth_hz / self.rise_s

    def time_in_chirp(self, t_s: np.ndarray) -> np.ndarray:
        """Time since the start of the current chirp, in [0, period)."""
        t = np.asarray(t_s, dtype=float)
        return t - self.period_s * np.floor(t / self.period_s)

    def envelope(self, tc_s: np.ndarray) -> np.ndarray:
        """Amplitude window in [0, 1] at time-in-chirp ``tc_s``: rise, hold, fall (Tukey)."""
        tc = np.asarray(tc_s, dtype=float)
        edge = 0.5 * (1.0 - self.amplitude_duty_cycle) * self.rise_s
        w = np.zeros_like(tc)
        inside = (tc >= 0) & (tc < self.rise_s)
        w[inside] = 1.0
        if edge > 0:
            up = inside & (tc < edge)
            w[up] = 0.5 * (1.0 - np.cos(np.pi * tc[up] / edge))
            down = inside & (tc > self.rise_s - edge)
            w[down] = 0.5 * (1.0 - np.cos(np.pi * (self.rise_s - tc[down]) / edge))
        return w

    def phase(self, tc_s: np.ndarray) -> np.ndarray:
        """Chirp phase (rad) at time-in-chirp ``tc_s``, from the chirp's own start.

        With a sample-and-hold of the frequency (``hold_time_s`` = q > 0) the instantaneous
        frequency is f(m q) on [m q, (m+1) q) and the phase is its exact integral.
        """
        tc = np.asarray(tc_s, dtype=float)
        f1, k = self.f_start_hz, self.rate_hz_per_s
        q = self.hold_time_s
        if q <= 0:
            cycles = f1 * tc + 0.5 * k * tc * tc
        else:
            m = np.floor(tc / q)
            held = f1 + k * m * q
            cycles = q * (m * f1 + 0.5 * k * q * m * (m - 1.0)) + held * (tc - m * q)
        # A ramp holds at most (F2 + F0) * tau cycles; below 1e6 cycles sin() of the unreduced
        # phase errs by < 1e-9 rad, so the reduction to [0, 1) is only paid for longer ramps.
        if self.f_stop_hz * self.rise_s >= 1e6:
            cycles = cycles - np.floor(cycles)
        return 2.0 * np.pi * cycles

    def unit(self, t_s: np.ndarray) -> np.ndarray:
        """Normalised drive w(t) sin(phi(t)) in [-1, 1]: also the RF dechirp reference."""
        tc = self.time_in_chirp(t_s)
        return self.envelope(tc) * np.sin(self.phase(tc))

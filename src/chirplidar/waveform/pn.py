"""Maximal-length (PN) code modulation, the pulse-compression alternative of thesis Sec. 2.3.

The code's +-1 chips drive the modulator during the same on-window as the chirp (``rdcyc`` of the
period); the range is found by cross-correlating the detected code with the reference.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .chirp import PeriodicTrain, drive_levels

# Feedback taps of primitive polynomials (Fibonacci LFSR), one per register length.
# Source: Xilinx XAPP052 "Efficient Shift Registers, LFSR Counters, and Long Pseudo-Random
# Sequence Generators", Table 3.
_TAPS = {
    3: (3, 2),
    4: (4, 3),
    5: (5, 3),
    6: (6, 5),
    7: (7, 6),
    8: (8, 6, 5, 4),
    9: (9, 5),
    10: (10, 7),
    11: (11, 9),
    12: (12, 6, 4, 1),
    13: (13, 4, 3, 1),
    14: (14, 5, 3, 1),
    15: (15, 14),
    16: (16, 15, 13, 4),
    17: (17, 14),
    18: (18, 11),
    19: (19, 6, 2, 1),
    20: (20, 17),
    21: (21, 19),
    22: (22, 21),
    23: (23, 18),
    24: (24, 23, 22, 17),
}


@lru_cache(maxsize=32)
def mls(order: int) -> np.ndarray:
    """One period (2**order - 1 chips) of an m-sequence as +-1 (int8)."""
    if order not in _TAPS:
        raise ValueError(f"PN order {order} not supported (3..24)")
    taps = _TAPS[order]
    state = [1] * order
    n = 2**order - 1
    out = np.empty(n, dtype=np.int8)
    for i in range(n):
        bit = state[-1]
        out[i] = 1 - 2 * bit
        fb = 0
        for t in taps:
            fb ^= state[t - 1]
        state = [fb] + state[:-1]
    return out


@dataclass(frozen=True)
class PNTrain(PeriodicTrain):
    period_s: float
    rise_s: float
    chip_rate_hz: float
    order: int
    amplitude_v: float
    dc_v: float

    @classmethod
    def from_config(cls, config) -> PNTrain:
        wf = config.waveform
        amplitude_v, dc_v = drive_levels(config)
        return cls(
            period_s=wf.chirp_period_s,
            rise_s=wf.ramp_duty_cycle * wf.chirp_period_s,
            chip_rate_hz=wf.pn_chip_rate_hz,
            order=wf.pn_order,
            amplitude_v=amplitude_v,
            dc_v=dc_v,
        )

    @property
    def bandwidth_hz(self) -> float:
        return self.chip_rate_hz

    def envelope(self, tc_s: np.ndarray) -> np.ndarray:
        tc = np.asarray(tc_s, dtype=float)
        return ((tc >= 0) & (tc < self.rise_s)).astype(float)

    def unit(self, t_s: np.ndarray) -> np.ndarray:
        """+-1 chips during the on-window, 0 elsewhere."""
        code = mls(self.order)
        tc = np.mod(t_s, self.period_s)
        idx = np.floor(tc * self.chip_rate_hz).astype(np.int64) % code.size
        return self.envelope(tc) * code[idx]

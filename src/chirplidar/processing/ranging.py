"""Range resolution and accuracy of a ranging signal (thesis Sec. 2.2).

* eq. 2.1.1: a pulse of duration tau resolves two targets at least c tau / 2 apart (in a medium of
  group index n: c tau / 2n);
* eq. 2.2.2: the accuracy of one target's range at signal bandwidth B and SNR,
  dR ~ c / (2 n B sqrt(2 SNR)).

Example (thesis Table 2.1, GLAS: 5 ns pulses resolve 75 cm)::

    >>> round(float(pulse_range_resolution_m(5e-9)), 4)
    0.7495
"""

from __future__ import annotations

import numpy as np

from .._checks import positive, positive_array
from ..units import SPEED_OF_LIGHT_M_S


def two_way_delay_s(range_m, group_index: float):
    """2 n R / c [s]: the round-trip delay of a return from ``range_m`` (m) through a path of
    group index ``group_index`` (arrays broadcast)."""
    return 2.0 * np.asarray(range_m, float) * group_index / SPEED_OF_LIGHT_M_S


def pulse_range_resolution_m(pulse_duration_s, group_index: float = 1.0):
    """c tau / (2 n) [m] (eq. 2.1.1): the closest two targets a pulse of duration
    ``pulse_duration_s`` (s, > 0) separates, in a medium of group index ``group_index``."""
    tau = positive_array("pulse_duration_s", pulse_duration_s)
    positive("group_index", group_index)
    return (SPEED_OF_LIGHT_M_S * tau / (2.0 * group_index))[()]


def range_accuracy_m(bandwidth_hz, snr, group_index: float = 1.0):
    """c / (2 n B sqrt(2 SNR)) [m] (eq. 2.2.2) for a signal of bandwidth ``bandwidth_hz`` (Hz, > 0)
    at the linear ``snr`` (array, >= 0; inf reads 0 m); inf where the SNR is zero or not a
    number (nothing to range on)."""
    bandwidth = positive_array("bandwidth_hz", bandwidth_hz)
    positive("group_index", group_index)
    snr = np.asarray(snr, dtype=float)
    if np.any(snr < 0):
        raise ValueError("snr must be >= 0 (a linear power ratio)")
    with np.errstate(divide="ignore"):
        return np.where(
            snr > 0,
            SPEED_OF_LIGHT_M_S
            / (2 * group_index * bandwidth * np.sqrt(2 * np.maximum(snr, 1e-300))),
            np.inf,
        )[()]

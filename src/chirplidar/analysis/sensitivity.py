"""Receiver sensitivity from an SNR-against-received-power curve (thesis Fig. 5.7, Tables 5.2-5.4)."""

from __future__ import annotations

from typing import Sequence

import numpy as np


def sensitivity_at(psig_dbm: Sequence[float], snr_db: Sequence[float], level_db: float = 10.0,
                   fit_range_db: tuple[float, float] = (12.0, 40.0)) -> tuple[float, float, int]:
    """(Psig at ``level_db`` SNR in dBm, slope in dB/dB, points used).

    A straight line is fitted to the points whose SNR lies in ``fit_range_db`` and read at
    ``level_db``. Fitting above the level keeps out the floor a peak search reads from noise alone
    (about 5-8 dB for a 30 kHz RBW record), which would bend a curve read point by point; the
    thesis's own figures (Table 5.4 spans 10-41 dB) are read the same way. Returns nan for the
    power and slope when fewer than three points lie in the range.
    """
    p = np.asarray(psig_dbm, dtype=float).ravel()
    s = np.asarray(snr_db, dtype=float).ravel()
    keep = np.isfinite(p) & np.isfinite(s) & (s >= fit_range_db[0]) & (s <= fit_range_db[1])
    if np.count_nonzero(keep) < 3:
        return float("nan"), float("nan"), int(np.count_nonzero(keep))
    slope, intercept = np.polyfit(p[keep], s[keep], 1)
    return float((level_db - intercept) / slope), float(slope), int(np.count_nonzero(keep))

"""Physical constants (CODATA 2018 exact SI values) and dB conversions.

dB of zero is exactly -inf, computed without a warning and never NaN (docs/architecture.md numerical rules).
"""

from __future__ import annotations

import numpy as np

SPEED_OF_LIGHT_M_S = 299_792_458.0
PLANCK_J_S = 6.626_070_15e-34
ELEMENTARY_CHARGE_C = 1.602_176_634e-19
BOLTZMANN_J_K = 1.380_649e-23

# The Earth: WGS-84 defining parameters (NGA.STND.0036 / NIMA TR8350.2). The IERS mean sidereal
# rate 7.2921158553e-5 rad/s differs from the WGS-84 rotation rate by 1e-7 relative.
WGS84_A_M = 6_378_137.0  # semi-major (equatorial) axis
WGS84_F = 1.0 / 298.257_223_563  # flattening
OMEGA_EARTH_RAD_S = 7.292_115e-5  # angular velocity


def db_to_ratio(db):
    return 10.0 ** (np.asarray(db, dtype=float) / 10.0)


def ratio_db(ratio):
    """10 log10 of a power ratio; -inf for zero, NaN never produced for ratio >= 0."""
    r = np.asarray(ratio, dtype=float)
    out = np.full(r.shape, -np.inf)
    pos = r > 0
    out[pos] = 10.0 * np.log10(r[pos])
    return out if out.ndim else float(out)


def power_dbm(power_w):
    """dBm of a power in watts; -inf for zero power."""
    out = ratio_db(power_w)
    return out + 30.0


def responsivity_a_per_w(quantum_efficiency: float, wavelength_m: float) -> float:
    """R = eta q / (h nu), thesis eq. 2.4.17."""
    return (
        quantum_efficiency * ELEMENTARY_CHARGE_C * wavelength_m / (PLANCK_J_S * SPEED_OF_LIGHT_M_S)
    )

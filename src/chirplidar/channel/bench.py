"""The bench / point-target channel of thesis Table 4.6 (TX_model.m propagation).

``atm.state = off`` is the lab bench: a fiber spool and an attenuator stand in for free space, so only
``atm.Pattn`` applies. ``atm.state = on`` adds the geometric range equation for a Lambertian target
(eq. 2.2.3: P_r = P_t rho A_r / (pi R^2)), the fraction of a Gaussian beam of radius
W(R) = W0 + div R that a disc target of radius Wr intercepts, and the transmissions T_atm (one way,
field) and T_opt (end to end, field) as power factors T_atm^4 and T_opt^2. Turbulence, speckle and
coupling belong to the effect modules.
"""

from __future__ import annotations

import numpy as np

from ..units import SPEED_OF_LIGHT_M_S, db_to_ratio


def round_trip_delay_s(config) -> float:
    ch = config.channel
    return 2.0 * ch.distance_m * ch.group_index / SPEED_OF_LIGHT_M_S


def power_transmission(config) -> float:
    """Received / transmitted optical power (W/W)."""
    ch = config.channel
    h = float(db_to_ratio(-ch.extra_attenuation_db))
    if not ch.free_space:
        return h
    r = ch.distance_m
    if r <= 0:
        raise ValueError("channel.distance_m (atm.dst) must be > 0 with channel.free_space = on")
    w_r = ch.beam_radius_m + ch.divergence_half_angle_rad * r
    intercept = 1.0 - np.exp(-2.0 * ch.target_radius_m**2 / w_r**2)
    area = 0.25 * np.pi * ch.telescope_diameter_m**2
    lambertian = ch.target_reflectivity * area / (np.pi * r * r)
    return float(h * intercept * lambertian * ch.atmospheric_transmission**4
                 * ch.optical_transmission**2)

"""The lab bench's point-target channel of thesis Table 4.6 (TX_model.m propagation).

``atm.state = off`` is the lab bench: a fiber spool and an attenuator stand in for free space, so only
``atm.Pattn`` applies. ``atm.state = on`` adds, each from the package that owns its physics:

* the fraction of the Gaussian transmit beam (atm.Wo, atm.div; optics.beam_radius_m) that a disc
  target of radius atm.Wr intercepts; with the 'turbulence' effect the weak-turbulence long-term
  spread is added in quadrature (atmosphere.long_term_beam_radius);
* the Lambertian range equation (eq. 2.2.3 in geometric form, target.lambertian_power_fraction),
  at normal incidence on the bench target;
* the transmissions T_atm (one way, field: T_atm^4 round trip) and T_opt (end to end, field: T_opt^2).

Coupling into the fiber, turbulence in the pupil and speckle are effects (channel.effects).
:func:`lab_returns` is what the tiers take from this channel.
"""

from __future__ import annotations

import numpy as np

from ..config.models import MissionConfig
from ..tiers.echoes import Echoes
from ..tiers.model import Returns
from ..processing.ranging import two_way_delay_s
from ..units import db_to_ratio
from .effects import channel_returns


def round_trip_delay_s(config) -> float:
    return float(two_way_delay_s(config.channel.distance_m, config.channel.group_index))


def footprint_radius_m(config) -> float:
    """1/e^2 radius (m) of the transmit beam at the target (atm.dst)."""
    from ..optics import beam_radius_m

    ch = config.channel
    w = beam_radius_m(ch.beam_radius_m, ch.divergence_half_angle_rad, ch.distance_m)
    if "turbulence" in config.effects.enabled and ch.cn2_m_minus_2_3 > 0:
        from ..atmosphere import gaussian_beam_parameters, long_term_beam_radius

        lam = config.wavelength_m
        w_lt = long_term_beam_radius(ch.beam_radius_m, lam, ch.distance_m, ch.cn2_m_minus_2_3)
        w_free = gaussian_beam_parameters(ch.beam_radius_m, lam, ch.distance_m)["w_m"]
        w = float(np.sqrt(w * w + w_lt * w_lt - w_free * w_free))  # the turbulent excess spread
    return w


def power_transmission(config) -> float:
    """Received / transmitted optical power (W/W)."""
    ch = config.channel
    h = float(db_to_ratio(-ch.extra_attenuation_db))
    if not ch.free_space:
        return h
    from ..atmosphere import round_trip_power_transmission
    from ..optics import beam_fraction_in_disc
    from ..target import lambertian_power_fraction

    if ch.distance_m <= 0:
        raise ValueError("channel.distance_m (atm.dst) must be > 0 with channel.free_space = on")
    intercept = beam_fraction_in_disc(footprint_radius_m(config), ch.target_radius_m)
    area = 0.25 * np.pi * ch.telescope_diameter_m**2
    lambertian = lambertian_power_fraction(ch.target_reflectivity, area, ch.distance_m, 0.0)
    transmission = (round_trip_power_transmission(t_atm_field=ch.atmospheric_transmission)
                    * ch.optical_transmission**2)
    return float(h * intercept * lambertian * transmission)


def lab_returns(config: MissionConfig, batch: int, rng: np.random.Generator,
                echoes: Echoes | None = None) -> Returns:
    """The returns of ``batch`` shots at the configuration's own channel: its point target at
    ``channel.distance_m`` (or ``echoes`` of a footprint around it), with the enabled effects
    drawn on their own children of ``rng`` (``rng`` itself is not consumed)."""
    effects = channel_returns(config, batch, rng)
    return _point_target_returns(config, batch, effects.power_factor, effects.phase_rad,
                                 effects.doppler_hz, echoes)


def _point_target_returns(config: MissionConfig, batch: int, power_factor, phase_rad, doppler_hz,
                          echoes: Echoes | None = None) -> Returns:
    """The configuration's point target with the given per-shot effects."""
    ch = config.channel
    return Returns(transmission=power_transmission(config), delay_s=round_trip_delay_s(config),
                   range_m=ch.distance_m, group_index=ch.group_index, power_factor=power_factor,
                   phase_rad=phase_rad, doppler_hz=doppler_hz, carrier_phase=ch.carrier_phase,
                   echoes=echoes, background_power_w=lab_background_power_w(config), batch=batch)


def lab_background_power_w(config: MissionConfig) -> float:
    """Background light a pulsed receiver collects on the bench (W): ``background.source =
    "radiance"`` through its filter and field of view; 0 for a chirped instrument or none. The
    sun needs a place and a time: a survey's (``mission``)."""
    bg = config.background
    if config.pulse is None or bg is None or bg.source == "none":
        return 0.0
    if bg.source == "sun":
        raise ValueError("background.source = 'sun' needs a survey (the sun's elevation at each "
                         "shot); on the bench give background.source = 'radiance'")
    return float(collected_background_w(config, bg.radiance_w_m2_sr_m))


def collected_background_w(config: MissionConfig, radiance_w_m2_sr_m):
    """Background power (W) a pulsed receiver collects from a spectral radiance at its
    telescope: through its filter, field of view, aperture and the end-to-end optics
    (``channel.optical_transmission`` is a field transmission: squared for power)."""
    from ..receiver.background import background_power_w

    rx = config.pulse_receiver
    return background_power_w(radiance_w_m2_sr_m, rx.filter_bandwidth_m,
                              config.channel.telescope_diameter_m, rx.field_of_view_rad,
                              config.channel.optical_transmission ** 2)


def simulate_lab(config: MissionConfig, tier: str, rng: np.random.Generator, *, batch: int = 1,
                 echoes: Echoes | None = None, keep_spectrum: bool = False):
    """``batch`` shots of the configuration's own channel (:func:`lab_returns`) through the tier
    called ``tier``: its :class:`~chirplidar.tiers.model.Measurements`."""
    from ..config.instrument import instrument_from_config
    from ..tiers.registry import get_tier

    chosen = get_tier(tier)
    return chosen.simulate(instrument_from_config(config), lab_returns(config, batch, rng, echoes),
                           rng, keep_spectrum=keep_spectrum)


def lab_budget(config: MissionConfig):
    """The tiers' :class:`~chirplidar.tiers.budget.Budget` of the configuration's own channel
    (its mean return: no effect is drawn)."""
    from ..config.instrument import instrument_from_config
    from ..tiers.budget import make_budget

    mean = _point_target_returns(config, 1, 1.0, 0.0, 0.0)
    return make_budget(instrument_from_config(config), mean)

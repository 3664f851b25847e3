"""A survey's footprint returns: what each shot-beam's footprint sends back to the receiver.

Each footprint sub-ray k (Gaussian beam weight w_k, true range R_k, incidence theta_k, material)
returns the power fraction

* Lambertian surfaces: (rho_k / pi) cos(theta_k) A / R_k^2 (``target.lambertian_power_fraction``),
* specular surfaces (open water): ``target.specular_return_fraction`` with the Cox-Munk slopes of
  the scene's wind,

and the shot receives P_tx sum_k w_k f_k, times the round-trip atmospheric transmission of the
scene (exponential atmosphere over the slant path), T_opt^2, ``channel.extra_attenuation_db`` and
the power factors of the scene's enabled effects (speckle, coupling, turbulence), each beam's
effects on its own random stream.

The tiers take these as :class:`~chirplidar.tiers.model.Returns`: the link tier through its
survey table (``tiers.link_survey``, nodes in attenuation relative to the ideal reference target
of :func:`reference_power_fraction`), the rf and baseband tiers with the sub-rays as echoes
(:func:`footprint_returns`, ``tiers.echoes.footprint_echoes``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config.loader import config_with
from ..doppler import doppler_shift_hz
from ..geometry.footprints import weighted_range_stats
from ..streams import stream
from ..target import (
    lambertian_power_fraction,
    receiver_cone_half_angle_rad,
    specular_return_fraction,
)
from ..units import db_to_ratio
from .effects import channel_returns, return_wave
from .lab import lab_budget


def reference_power_fraction(telescope_diameter_m: float, range_m):
    """Received / transmitted power from the ideal reference target at ``range_m`` (W/W)."""
    area = 0.25 * np.pi * telescope_diameter_m ** 2
    return np.asarray(lambertian_power_fraction(1.0, area, range_m, 0.0), float)


def reference_attenuation_db(telescope_diameter_m: float, range_m, fraction):
    """The attenuation [dB] that turns the reference target's received power fraction at
    ``range_m`` into ``fraction`` (received / transmitted power): 10 log10(f_ref(R) / fraction),
    the ``channel.extra_attenuation_db`` of a link-tier shot aimed at that range."""
    return 10.0 * np.log10(reference_power_fraction(telescope_diameter_m, range_m) / fraction)


def sub_ray_power_fractions(config, scene, geom):
    """(n, b, k) received / transmitted power of every footprint sub-ray (beam weight included),
    before atmospheric and optical losses; 0 for misses."""
    ch = config.channel
    area = 0.25 * np.pi * ch.telescope_diameter_m ** 2
    hit = np.isfinite(geom.sub_range_m)
    code = np.where(hit, geom.sub_material, 0)
    rho = scene.material_reflectivity(config.wavelength_m)[code]
    specular = scene.material_specular()[code] & hit
    r = np.where(hit, geom.sub_range_m, 1.0)
    inc = np.where(hit, geom.sub_incidence_rad, 0.0)
    frac = np.where(hit, lambertian_power_fraction(np.where(hit, rho, 0.0), area, r, inc), 0.0)
    if np.any(specular):
        mss = scene.water_mss()
        spec = specular_return_fraction(inc[specular], mss, rho[specular],
                                        receiver_cone_half_angle_rad(area, r[specular]),
                                        ch.divergence_half_angle_rad)
        frac[specular] = spec
    return frac * geom.sub_weight


def path_transmission(config, scene, geom):
    """(n, b) round-trip atmospheric x optical x attenuator power transmission, times each
    beam's share of the transmitter power (1 for equal beams)."""
    z_ground = geom.hit_xyz_m[..., 2]
    z_plat = np.broadcast_to(geom.platform_xyh[:, 2:3], z_ground.shape)
    ok = np.isfinite(z_ground)
    zen = geom.off_nadir_rad
    t1 = np.ones(z_ground.shape)
    if np.any(ok):
        t1[ok] = scene.one_way_power_transmission(z_ground[ok], z_plat[ok], zen[ok])
    ch = config.channel
    return (t1 ** 2 * ch.optical_transmission ** 2 * float(db_to_ratio(-ch.extra_attenuation_db))
            * geom.beam_power_share[None, :])


def effect_returns(config, scene, geom, seq, exclude=("doppler",)):
    """(n, b) power factor and (n, b) carrier phase [rad] (the speckle field's phase) of the
    enabled channel effects, each beam on its own streams."""
    names = [e for e in scene.effects if e not in exclude and e != "phase_noise"]
    if config.receiver is not None:  # the receiver's focal-plane field is the coupling
        names = [e for e in names if e != "coupling"]
    n, b = geom.range_true_m.shape
    if (not names and config.receiver is None) or n == 0:
        return np.ones((n, b)), np.zeros((n, b))
    cfg = effects_config(config, scene, geom, names)
    power, phase = np.empty((n, b)), np.empty((n, b))
    for j in range(b):  # a handful of beams; the shots are vectorised
        ret = channel_returns(cfg, n, stream(seq, "beam_effects", j))
        power[:, j], phase[:, j] = ret.power_factor, ret.phase_rad
    return power, phase


def effects_config(config, scene, geom, names):
    """The configuration the chunk's effects are drawn with: the chunk's median range."""
    hit = np.isfinite(geom.range_true_m)
    r_med = float(np.median(geom.range_true_m[hit])) if np.any(hit) else 1.0
    over = {"effects.enabled": list(names), "channel.distance_m": r_med,
            "channel.free_space": True}
    if "turbulence" in names:
        over["channel.cn2_m_minus_2_3"] = equivalent_cn2(config, scene, geom, r_med)
    return config_with(config, over)


def equivalent_cn2(config, scene, geom, r_med: float) -> float:
    """The constant Cn^2 over the chunk's median slant path that gives the Fried parameter of the
    scene's Cn^2 profile along it (r0 ~ (Cn^2)^(-3/5)): the turbulence effect then sees the
    scene's atmosphere, not the instrument file's bench value."""
    from ..atmosphere import fried_parameter

    hit = np.isfinite(geom.range_true_m)
    z_g = float(np.median(geom.hit_xyz_m[..., 2][hit]))
    z_p = float(np.median(geom.platform_xyh[:, 2]))
    zen = float(np.median(geom.off_nadir_rad[hit]))
    wave = return_wave(config, scene.effects)
    lam = config.wavelength_m
    r0 = float(scene.fried_parameter_m(lam, z_g, z_p, zen, wave=wave))
    if not np.isfinite(r0):
        return 0.0
    return float((fried_parameter(1.0, lam, r_med, wave=wave) / r0) ** (5.0 / 3.0))


def subray_speckle_fields(config, scene, geom, seq):
    """(n, b, k) complex speckle factor of every footprint sub-ray, E|z|^2 = 1, or None when the
    scene does not enable ``speckle``.

    Each sub-ray's patch of a diffuse surface holds many scatterers: its field is the speckle
    effect's draw (power gamma of ``effects.speckle.cells``, uniform phase: for M = 1, the coupled
    single-mode receiver, a circular complex Gaussian; Goodman 2007 Ch. 3), each (beam, sub-ray)
    on its own stream over the chunk's shots in time order (so ``shift_per_shot_m`` correlates
    successive shots of the same sub-ray, and the footprint's field keeps the effect's shot-to-shot
    correlation). The footprint field sum_k sqrt(w_k) z_k has mean power sum_k w_k. None with a
    ``[receiver]`` too: its pupil field holds the footprint's speckle.
    """
    if "speckle" not in scene.effects or config.receiver is not None:
        return None
    n, b, k = geom.sub_range_m.shape
    z = np.empty((n, b, k), complex)
    if n == 0:
        return z
    cfg = effects_config(config, scene, geom, ["speckle"])
    for j in range(b):
        for kk in range(k):  # k sub-rays per beam; the shots are vectorised
            ret = channel_returns(cfg, n, stream(seq, "subray_speckle", j, kk))
            z[:, j, kk] = np.sqrt(ret.power_factor) * np.exp(1j * ret.phase_rad)
    return z


def received_power(config, scene, geom, seq, *, exclude_effects=("doppler",)):
    """Per shot-beam: (P_sig [W], power-weighted mean range [m], range std [m], sub-ray power
    fractions (n, b, k) after transmission and effects)."""
    return received(config, scene, geom, seq, exclude_effects)[:4]


def received(config, scene, geom, seq, exclude_effects=("doppler",)):
    """:func:`received_power` and the effects' (n, b) carrier phase [rad] (speckle)."""
    tot, scale, mean, std, frac, phase = _footprint_terms(config, scene, geom, seq,
                                                          exclude_effects)
    return lab_budget(config).ptx_w * tot * scale, mean, std, frac, phase


def footprint_transmission(config, scene, geom, seq, exclude_effects=("doppler",)):
    """Per shot-beam: (received / transmitted power or energy (W/W), power-weighted mean range
    [m], range std [m], sub-ray fractions (n, b, k) after transmission and effects, the
    effects' carrier phase [rad])."""
    tot, scale, mean, std, frac, phase = _footprint_terms(config, scene, geom, seq,
                                                          exclude_effects)
    return tot * scale, mean, std, frac, phase


def _footprint_terms(config, scene, geom, seq, exclude_effects):
    """(the sub-rays' summed power fraction, the path's and effects' factor, mean range, range
    std, the sub-ray fractions after that factor, the effects' phase), each per shot-beam."""
    frac = sub_ray_power_fractions(config, scene, geom)
    power, phase = effect_returns(config, scene, geom, seq, exclude=exclude_effects)
    scale = path_transmission(config, scene, geom) * power
    mean, std, tot = weighted_range_stats(frac, geom.sub_range_m)
    return tot, scale, mean, std, frac * scale[..., None], phase


def shot_doppler_hz(config, scene, geom):
    """(n, b) carrier Doppler shift [Hz] of each shot-beam's return, 0 unless the scene enables
    ``doppler``: f_d = 2 v / lambda of the closing speed left after any compensation."""
    if "doppler" not in scene.effects:
        return np.zeros_like(geom.closing_speed_mps)
    return doppler_shift_hz(geom.doppler_speed_mps, config.wavelength_m)


@dataclass(frozen=True)
class FootprintReturns:
    """What the time-domain tiers (rf, baseband) start from, per shot-beam (n, b): received power
    ``psig_w`` and power-weighted mean range ``range_m`` without the Doppler and speckle effects
    (the sub-rays' own speckle draws replace speckle), the sub-rays' power shares ``frac``
    (n, b, k), their speckle ``fields`` (or None) and the shot-beams with a return ``ok``."""

    psig_w: np.ndarray
    range_m: np.ndarray
    frac: np.ndarray
    fields: np.ndarray | None
    ok: np.ndarray


def footprint_returns(config, scene, geom, seq) -> FootprintReturns:
    """The chunk's :class:`FootprintReturns`."""
    psig, r_mean, _, frac = received_power(config, scene, geom, seq,
                                           exclude_effects=("doppler", "speckle"))
    fields = subray_speckle_fields(config, scene, geom, seq)
    return FootprintReturns(psig, r_mean, frac, fields, np.isfinite(r_mean) & (psig > 0))

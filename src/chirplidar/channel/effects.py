"""Effect registry: each channel effect has a name; a configuration enables some by name.

Only enabled effects are called, and each draws from its own random stream, a child of the run's
SeedSequence keyed by the effect's name: enabling one effect leaves the draws of the others, and
of the detector noise, unchanged (docs/architecture.md "Effects").

An effect turns the per-shot returns into new per-shot returns (it never mutates them). The
tiers apply the returns: ``power_factor`` scales the received power, ``phase_rad`` adds to the
signal's carrier phase, ``doppler_hz`` shifts the signal's carrier frequency.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import lru_cache
from typing import Callable

import numpy as np

from ..config.models_effects import EFFECT_NAMES
from ..doppler import doppler_shift_hz
from ..streams import STREAMS, child_stream
from ..target import speckle_phase, speckle_power


@dataclass(frozen=True)
class ShotReturns:
    """What the channel's effects do to each shot (arrays of shape (batch,))."""

    power_factor: np.ndarray
    phase_rad: np.ndarray
    doppler_hz: np.ndarray

    @classmethod
    def unaffected(cls, batch: int) -> "ShotReturns":
        return cls(power_factor=np.ones(batch), phase_rad=np.zeros(batch),
                   doppler_hz=np.zeros(batch))


@dataclass(frozen=True)
class Effect:
    name: str
    summary: str
    # (config, returns, rng) -> returns; None for effects the transceiver applies itself.
    apply: Callable[..., ShotReturns] | None


def speckle_shot_correlation(config) -> float:
    """Lag-1 intensity correlation of successive shots' speckle (matched single-mode transceiver):
    the footprint radius and wavefront curvature at atm.dst of the beam of waist atm.Wo."""
    from ..optics import beam_radius_m
    from ..target import speckle_decorrelation

    ch = config.channel
    w = beam_radius_m(ch.beam_radius_m, ch.divergence_half_angle_rad, ch.distance_m)
    return float(speckle_decorrelation(config.effects.speckle.shift_per_shot_m, w,
                                       config.wavelength_m, ch.distance_m))


def _speckle(config, returns: ShotReturns, rng: np.random.Generator) -> ShotReturns:
    n = returns.power_factor.size
    sp = config.effects.speckle
    if sp.shift_per_shot_m is None:
        power, phase = speckle_power(n, sp.cells, rng), speckle_phase(n, rng)
    else:
        # Successive shots of the batch over a moving footprint: a correlated field sequence;
        # the homodyne receiver sees the first cell's phase (M = 1 for a single-mode fiber).
        from ..target import correlated_speckle_field

        z = correlated_speckle_field(n, speckle_shot_correlation(config), int(sp.cells), rng)
        power, phase = np.sum(z.real**2 + z.imag**2, axis=1), np.angle(z[:, 0])
    return dataclasses.replace(returns, power_factor=returns.power_factor * power,
                               phase_rad=returns.phase_rad + phase)


def _doppler(config, returns: ShotReturns, rng: np.random.Generator) -> ShotReturns:
    f_d = doppler_shift_hz(config.effects.doppler.radial_velocity_mps, config.wavelength_m)
    return dataclasses.replace(returns, doppler_hz=returns.doppler_hz + f_d)


def coupling_factor(config) -> float:
    """Mean telescope-to-fiber coupling for the configured telescope, fiber and target kind."""
    c = config.effects.coupling
    return _coupling_for(_coupling_beta(config), c.obstruction_ratio, c.target)


@lru_cache(maxsize=64)
def _coupling_for(beta: float, obstruction: float, target: str) -> float:
    """Cached: the diffuse (Winzer & Leeb) integral costs ~20 ms and every shot of a run reuses it."""
    from ..optics import coupling_efficiency, monostatic_diffuse_coupling

    if target == "diffuse":
        return monostatic_diffuse_coupling(beta, obstruction)
    return coupling_efficiency(beta, obstruction)


def _coupling(config, returns: ShotReturns, rng: np.random.Generator) -> ShotReturns:
    return dataclasses.replace(returns, power_factor=returns.power_factor * coupling_factor(config))


def turbulence_d_over_r0(config) -> float:
    """D / r0 of the return path: spherical wave from a diffuse target, plane wave from a specular
    one, constant Cn^2 (atm.Cn2) over the one-way distance (atm.dst)."""
    from ..atmosphere import fried_parameter

    r0 = fried_parameter(config.channel.cn2_m_minus_2_3, config.wavelength_m,
                         config.channel.distance_m,
                         wave=return_wave(config, config.effects.enabled))
    return config.channel.telescope_diameter_m / r0


def return_wave(config, enabled) -> str:
    """The return's wave for turbulence: spherical from a diffuse target (the ``coupling``
    effect's target kind; with a ``[receiver]``, a target with ``speckle`` among the ``enabled``
    effects), plane from a specular one."""
    if config.receiver is not None:
        return "spherical" if "speckle" in enabled else "plane"
    return "spherical" if config.effects.coupling.target == "diffuse" else "plane"


def _coupling_beta(config) -> float:
    from ..optics import coupling_beta

    c = config.effects.coupling
    return coupling_beta(config.channel.telescope_diameter_m, c.focal_length_m,
                         c.mode_field_radius_m, config.wavelength_m)


def _turbulence(config, returns: ShotReturns, rng: np.random.Generator) -> ShotReturns:
    """Coupling through turbulence relative to the plane-wave coupling without it.

    For a specular return this is exact (the coupling effect then holds the plane-wave value); for a
    diffuse one it scales Winzer & Leeb's mean by the same ratio, an approximation (turbulence
    and target speckle together are not modelled jointly).
    """
    from ..atmosphere import MovingScreen, turbulent_coupling_mean
    from ..optics import coupling_efficiency, pupil_field_coupling

    t = config.effects.turbulence
    c = config.effects.coupling
    if config.channel.cn2_m_minus_2_3 == 0:
        return returns
    beta, alpha = _coupling_beta(config), c.obstruction_ratio
    d_over_r0 = turbulence_d_over_r0(config)
    plane = coupling_efficiency(beta, alpha)
    d_tel = config.channel.telescope_diameter_m
    if t.fading == "mean":
        factor = float(turbulent_coupling_mean(d_over_r0, beta, alpha,
                                               outer_scale_over_d=t.outer_scale_m / d_tel)) / plane
        return dataclasses.replace(returns, power_factor=returns.power_factor * factor)
    if t.screen_pixels is None:
        n = max(64, int(np.ceil(4 * d_over_r0)))  # >= 4 pixels per r0 (see atmosphere.coupling)
    else:
        n = int(t.screen_pixels)
        if n < d_over_r0:
            raise ValueError(
                f"effects.turbulence.screen_pixels = {n} makes the screen's pixel D / {n} = "
                f"{d_tel / n:.3g} m coarser than r0 = {d_tel / d_over_r0:.3g} m (D / r0 = "
                f"{d_over_r0:.3g}): use at least {int(np.ceil(d_over_r0))} pixels, or leave it "
                "unset for the default max(64, ceil(4 D / r0))")
    screen = MovingScreen(n, d_tel / n, d_tel / d_over_r0, t.outer_scale_m, rng=rng)
    shifts = np.full(returns.power_factor.size, t.transverse_speed_mps * t.shot_interval_s)
    phases = screen.next_apertures(shifts)
    eta = np.atleast_1d(pupil_field_coupling(np.exp(1j * phases), beta, alpha))
    return dataclasses.replace(returns, power_factor=returns.power_factor * eta / plane)


EFFECTS: dict[str, Effect] = {
    "phase_noise": Effect("phase_noise", "laser linewidth as Wiener phase noise, exact at the "
                          "delayed times (applied by the transceiver tiers)", None),
    "speckle": Effect("speckle", "gamma-distributed power of order M and a random phase per shot "
                      "(Goodman)", _speckle),
    "doppler": Effect("doppler", "carrier shift f_d = 2 v / lambda: lines at f_R +- f_d in the real "
                      "homodyne output (thesis Appendix D)", _doppler),
    "coupling": Effect("coupling", "telescope-to-fiber coupling with the central obstruction "
                       "(Ruilier 1998; monostatic diffuse targets: Winzer & Leeb 1998)", _coupling),
    "turbulence": Effect("turbulence", "phase-only turbulence in the pupil: mean coupling loss "
                         "(mutual coherence) or frozen-flow fading from shot to shot", _turbulence),
}
# The config's list of names, the registry and the effects' random streams are one list.
if tuple(EFFECTS) != EFFECT_NAMES or any(f"effect.{n}" not in STREAMS for n in EFFECT_NAMES):
    raise ImportError("channel.effects.EFFECTS, config.models_effects.EFFECT_NAMES and the effect "
                      "streams of chirplidar.streams disagree")


def effect_rng(rng: np.random.Generator, name: str) -> np.random.Generator:
    """The named effect's own stream: a child of ``rng``'s SeedSequence keyed by the effect."""
    return child_stream(rng, f"effect.{name}")


#: Effects a ``[receiver]`` computes from its focal-plane field instead (channel.receiver).
RECEIVER_EFFECTS = ("speckle", "coupling", "turbulence")


def pipeline(config) -> list[Effect]:
    """The enabled effects, in the registry's order (so the order in the file does not matter);
    with a ``[receiver]``, without those its focal-plane field holds (:data:`RECEIVER_EFFECTS`)."""
    skip = RECEIVER_EFFECTS if config.receiver is not None else ()
    return [EFFECTS[name] for name in EFFECTS
            if name in config.effects.enabled and name not in skip]


def channel_returns(config, batch: int, rng: np.random.Generator) -> ShotReturns:
    """Per-shot returns after every enabled effect; ``rng`` is the run's generator (not consumed)."""
    returns = ShotReturns.unaffected(batch)
    for effect in pipeline(config):
        if effect.apply is not None:
            returns = effect.apply(config, returns, effect_rng(rng, effect.name))
    if config.receiver is not None:
        from .receiver import receiver_returns

        returns = receiver_returns(config, returns, rng)
    return returns

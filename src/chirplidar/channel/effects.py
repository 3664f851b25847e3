"""Effect registry: each channel effect has a name; a configuration enables some by name.

Only enabled effects are called, and each draws from its own random stream, a child of the run's
SeedSequence keyed by the effect's name: enabling one effect leaves the draws of the others, and
of the detector noise, unchanged (DESIGN.md "Effects").

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

from ..config.models import EFFECT_NAMES
from ..doppler import doppler_shift_hz
from ..target import speckle_power


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


def _speckle(config, returns: ShotReturns, rng: np.random.Generator) -> ShotReturns:
    n = returns.power_factor.size
    cells = config.effects.speckle.cells
    return dataclasses.replace(
        returns, power_factor=returns.power_factor * speckle_power(n, cells, rng),
        phase_rad=returns.phase_rad + rng.uniform(0.0, 2 * np.pi, n))


def _doppler(config, returns: ShotReturns, rng: np.random.Generator) -> ShotReturns:
    f_d = doppler_shift_hz(config.effects.doppler.radial_velocity_mps, config.laser.wavelength_m)
    return dataclasses.replace(returns, doppler_hz=returns.doppler_hz + f_d)


def coupling_factor(config) -> float:
    """Mean telescope-to-fiber coupling for the configured telescope, fiber and target kind."""
    from ..optics import coupling_beta

    c = config.effects.coupling
    beta = coupling_beta(config.channel.telescope_diameter_m, c.focal_length_m,
                         c.mode_field_radius_m, config.laser.wavelength_m)
    return _coupling_for(beta, c.obstruction_ratio, c.target)


@lru_cache(maxsize=64)
def _coupling_for(beta: float, obstruction: float, target: str) -> float:
    """Cached: the diffuse (Winzer & Leeb) integral costs ~20 ms and every shot of a run reuses it."""
    from ..optics import coupling_efficiency, monostatic_diffuse_coupling

    if target == "diffuse":
        return monostatic_diffuse_coupling(beta, obstruction)
    return coupling_efficiency(beta, obstruction)


def _coupling(config, returns: ShotReturns, rng: np.random.Generator) -> ShotReturns:
    return dataclasses.replace(returns, power_factor=returns.power_factor * coupling_factor(config))


EFFECTS: dict[str, Effect] = {
    "phase_noise": Effect("phase_noise", "laser linewidth as Wiener phase noise, exact at the "
                          "delayed times (applied by the transceiver tiers)", None),
    "speckle": Effect("speckle", "gamma-distributed power of order M and a random phase per shot "
                      "(Goodman)", _speckle),
    "doppler": Effect("doppler", "carrier shift f_d = 2 v / lambda: lines at f_R +- f_d in the real "
                      "homodyne output (thesis Appendix D)", _doppler),
    "coupling": Effect("coupling", "telescope-to-fiber coupling with the central obstruction "
                       "(Ruilier 1998; monostatic diffuse targets: Winzer & Leeb 1998)", _coupling),
}
if tuple(EFFECTS) != EFFECT_NAMES:  # the config's list of names and the registry are one list
    raise ImportError("channel.effects.EFFECTS and config.models.EFFECT_NAMES disagree")


def effect_rng(rng: np.random.Generator, name: str) -> np.random.Generator:
    """The named effect's own stream: a child of ``rng``'s SeedSequence keyed by the effect."""
    seq = rng.bit_generator.seed_seq
    child = np.random.SeedSequence(entropy=seq.entropy,
                                   spawn_key=tuple(seq.spawn_key) + (1000 + EFFECT_NAMES.index(name),))
    return np.random.default_rng(child)


def pipeline(config) -> list[Effect]:
    """The enabled effects, in the registry's order (so the order in the file does not matter)."""
    return [EFFECTS[name] for name in EFFECTS if name in config.effects.enabled]


def channel_returns(config, batch: int, rng: np.random.Generator) -> ShotReturns:
    """Per-shot returns after every enabled effect; ``rng`` is the run's generator (not consumed)."""
    returns = ShotReturns.unaffected(batch)
    for effect in pipeline(config):
        if effect.apply is not None:
            returns = effect.apply(config, returns, effect_rng(rng, effect.name))
    return returns

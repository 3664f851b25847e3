"""The tier registry: each tier's name, summary, what it supports and where its code lives.

Declarative and cheap to import (the command line lists the tiers without loading them); a
tier's module is imported on its first :meth:`RegisteredTier.simulate`.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass

import numpy as np

from .model import Instrument, Measurements, Returns, Supports

_ALL_RECEIVERS = frozenset({"homodyne", "phase_diversity", "heterodyne", "pin", "apd"})
_CHIRPED_TIER = "a pulsed instrument flies with --tier pulsed (survey.tier = 'pulsed')"
_DSP_HINT = (
    "dsp compensates the Doppler shift in the complex record of the phase-diversity (I/Q) "
    "receiver (thesis Appendices C and D): set system.coherent_mode = 'phase_diversity'"
)

RF_SUPPORTS = Supports(
    receivers=_ALL_RECEIVERS,
    modulations=frozenset({"fm_chirp", "pn_code"}),
    doppler_recovery=frozenset({"none", "squaring", "dsp"}),
    echoes=True,
    spectrum=True,
    recovery_receivers={
        "squaring": frozenset({"homodyne"}),
        "dsp": frozenset({"phase_diversity"}),
    },
    architectures=frozenset({"fiber", "large_detector"}),
    hint={
        "kind": _CHIRPED_TIER,
        "architecture": "an FPA's N x N pixel records fly with --tier baseband or link",
        "recovery_receiver": "squaring recovers the self-chirped homodyne beat (thesis Appendix "
        "D); " + _DSP_HINT,
    },
)
BASEBAND_SUPPORTS = Supports(
    receivers=frozenset({"homodyne", "phase_diversity"}),
    modulations=frozenset({"fm_chirp"}),
    doppler_recovery=frozenset({"none", "dsp"}),
    echoes=True,
    spectrum=True,
    architectures=frozenset({"fiber", "large_detector", "fpa"}),
    combining=frozenset({"incoherent", "mrc", "selection"}),
    recovery_receivers={"dsp": frozenset({"phase_diversity"})},
    hint={
        "kind": _CHIRPED_TIER,
        "combining": "gains estimated from the data (mrc_estimated) fly with --tier link",
        "modulation": "use --tier rf",
        "receiver": "use --tier rf or link (direct and heterodyne detection)",
        "recovery_receiver": _DSP_HINT,
        "doppler_recovery": "use --tier rf: squaring the full-rate record folds in products "
        "the baseband record does not hold",
    },
)
LINK_SUPPORTS = Supports(
    receivers=_ALL_RECEIVERS,
    modulations=frozenset({"fm_chirp"}),
    doppler_recovery=frozenset({"none", "dsp"}),
    echoes=False,
    spectrum=False,
    architectures=frozenset({"fiber", "large_detector", "fpa"}),
    combining=frozenset({"incoherent", "mrc", "mrc_estimated", "selection"}),
    recovery_receivers={"dsp": frozenset({"phase_diversity"})},
    hint={
        "kind": _CHIRPED_TIER,
        "modulation": "use --tier rf",
        "recovery_receiver": _DSP_HINT,
        "doppler_recovery": "use --tier rf: its noise penalty has no closed form here",
    },
)

PULSED_SUPPORTS = Supports(
    receivers=frozenset({"apd", "photon_counting"}),
    modulations=frozenset(),
    doppler_recovery=frozenset(),
    echoes=True,
    spectrum=False,
    kinds=frozenset({"pulsed"}),
    hint={"kind": "a chirped instrument flies with --tier link, baseband or rf"},
)


@dataclass(frozen=True)
class RegisteredTier:
    """A tier of the registry (implements :class:`~chirplidar.tiers.model.Tier`)."""

    name: str
    summary: str
    supports: Supports
    module: str  # chirplidar.tiers.<module>
    function: str  # its simulate(instrument, returns, rng, *, keep_spectrum) function

    def check(self, instrument: Instrument, returns: Returns | None = None) -> None:
        """Raise :class:`~chirplidar.tiers.model.UnsupportedError` for what it does not model."""
        self.supports.check(self.name, instrument, returns)

    def simulate(
        self,
        instrument: Instrument,
        returns: Returns,
        rng: np.random.Generator,
        *,
        keep_spectrum: bool = False,
    ) -> Measurements:
        self.check(instrument, returns)
        fn = getattr(importlib.import_module(f"chirplidar.tiers.{self.module}"), self.function)
        return fn(instrument, returns, rng, keep_spectrum=keep_spectrum)


TIERS: dict[str, RegisteredTier] = {
    "rf": RegisteredTier(
        "rf",
        "full-rate time-domain chain of thesis Ch. 4 (the reference)",
        RF_SUPPORTS,
        "rf",
        "simulate_rf",
    ),
    "baseband": RegisteredTier(
        "baseband",
        "the dechirped beat generated at the detector's "
        "output rate (self-chirped coherent receivers)",
        BASEBAND_SUPPORTS,
        "baseband",
        "simulate_baseband",
    ),
    "link": RegisteredTier(
        "link",
        "closed-form link budget with a Cramer-Rao range draw (campaigns)",
        LINK_SUPPORTS,
        "link",
        "simulate_link",
    ),
    "pulsed": RegisteredTier(
        "pulsed",
        "short-pulse direct detection: the footprint's waveform, photon statistics, digitizer "
        "and range estimators (GLAS, MOLA; thesis Ch. 2)",
        PULSED_SUPPORTS,
        "pulsed",
        "simulate_pulsed",
    ),
}
TIER_NAMES: tuple[str, ...] = tuple(TIERS)


def tier_outputs(name: str) -> tuple[dict[str, str], dict[str, str]]:
    """(units, long names) of what tier ``name`` reports per shot, in its order: the chirped
    tiers thesis Table 4.10's, the pulsed tier its own."""
    module = "pulsed" if "pulsed" in get_tier(name).supports.kinds else "common"
    mod = importlib.import_module(f"chirplidar.tiers.{module}")
    return mod.OUTPUT_UNITS, mod.OUTPUT_LONG_NAMES


def tiers_flying(kind: str) -> tuple[str, ...]:
    """Names of the tiers that fly a ``kind`` (``"chirped"`` or ``"pulsed"``) instrument."""
    return tuple(name for name, tier in TIERS.items() if kind in tier.supports.kinds)


def get_tier(name: str) -> RegisteredTier:
    """The tier called ``name``; ValueError naming the choices otherwise."""
    try:
        return TIERS[name]
    except KeyError:
        raise ValueError(f"unknown tier {name!r}; choose one of {', '.join(TIERS)}") from None

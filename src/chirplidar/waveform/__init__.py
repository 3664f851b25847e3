"""Modulation waveforms (thesis FM_chirp.m): linear FM chirp trains and maximal-length PN codes.

A waveform is evaluated analytically at any array of times, so delays are exact (t - tau), and the
chirp phase is always taken from the time since that chirp's start (docs/architecture.md, numerical
rules).
"""

from typing import TypeAlias

from .chirp import ChirpTrain
from .pn import PNTrain, mls

__all__ = ["ChirpTrain", "PNTrain", "Waveform", "mls", "waveform_from_config"]

#: A drive waveform: what :func:`waveform_from_config` builds.
Waveform: TypeAlias = ChirpTrain | PNTrain


def waveform_from_config(config) -> Waveform:
    """The drive waveform selected by ``system.modulation`` (thesis ``sys.MxMode``)."""
    if config.system.modulation == "pn_code":
        return PNTrain.from_config(config)
    return ChirpTrain.from_config(config)

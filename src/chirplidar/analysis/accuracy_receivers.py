"""The accuracy-versus-time study's receivers (issue 18): what each ``[receiver]``
architecture costs per shot in the baseband and link tiers, on the UAV receivers mission's
instrument at 370 m (the field trial's range) with the footprint's speckle.

The reference row is the fiber in the baseband tier; the other rows are each architecture in
each tier that models it. The SNR point is placed with the speckle off (a plane wave: one
deterministic gain per architecture), at the fiber's; the rows' own SNR then differs by what
each receiver collects. Range RMS and SNR are those of each receiver, not a fidelity error:
the column to read is the cost.
"""

from __future__ import annotations

from pathlib import Path

#: The study's knob family.
RECEIVER_FAMILIES = ("receiver",)
RECEIVER_MISSION = "greenland_uav_receivers.toml"
#: The instrument's channel for the study: lab shots at the trial's 370 m, one chirp per record.
RECEIVER_SETTINGS = {"channel.distance_m": 370.0, "processing.averages": 1}
#: (label, tier, receiver.architecture, FPA combining or None); the first is the reference.
RECEIVER_CASES = (
    ("bb fiber", "baseband", "fiber", None),
    ("link fiber", "link", "fiber", None),
    ("bb large detector", "baseband", "large_detector", None),
    ("link large detector", "link", "large_detector", None),
    ("bb FPA 4x4 mrc", "baseband", "fpa", "mrc"),
    ("link FPA 4x4 mrc", "link", "fpa", "mrc"),
    ("bb FPA 4x4 incoherent", "baseband", "fpa", "incoherent"),
    ("link FPA 4x4 incoherent", "link", "fpa", "incoherent"),
    ("link FPA 4x4 mrc_estimated", "link", "fpa", "mrc_estimated"),
)


def default_receiver_mission_path() -> Path:
    from ..mission_files import default_mission_path as find

    return find(RECEIVER_MISSION)


def receiver_base(mission=None):
    """(the study's configuration with the speckle on, the attenuation that puts the fiber's
    plane-wave SNR at 0 dB of extra attenuation's reference)."""
    from ..config import config_with, load_mission

    base = load_mission(mission if mission is not None else default_receiver_mission_path())
    return config_with(base, {**RECEIVER_SETTINGS, "receiver.architecture": "fiber"})


def case_overrides(architecture: str, combining: str | None) -> dict:
    """The overrides of one case."""
    over = {"receiver.architecture": architecture, "effects.enabled": ["speckle"]}
    if combining is not None:
        over["receiver.fpa.combining"] = combining
    return over

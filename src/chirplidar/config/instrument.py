"""The factory from a validated configuration to the domain object the tiers take."""

from __future__ import annotations

from ..tiers.model import FiberAcceptance, Instrument
from .models import CHIRPED_SECTIONS, PULSED_SECTIONS, MissionConfig


def instrument_from_config(config: MissionConfig) -> Instrument:
    """The configuration's transceiver as an :class:`~chirplidar.tiers.model.Instrument`: its
    instrument sections (chirped or pulsed), the receive telescope's diameter and, when the
    receiver couples into a single-mode fiber (the ``coupling`` effect or a fiber
    ``[receiver]``), the fiber's acceptance; the receiver's architecture."""
    fiber = None
    rx = config.receiver
    if rx is not None and rx.architecture == "fiber":
        fiber = FiberAcceptance(telescope_diameter_m=config.channel.telescope_diameter_m,
                                focal_length_m=rx.focal_length_m,
                                numerical_aperture=rx.fiber.numerical_aperture)
    elif "coupling" in config.effects.enabled:
        c = config.effects.coupling
        fiber = FiberAcceptance(telescope_diameter_m=config.channel.telescope_diameter_m,
                                focal_length_m=c.focal_length_m,
                                numerical_aperture=c.fiber_numerical_aperture)
    sections = {name: getattr(config, name) for name in CHIRPED_SECTIONS + PULSED_SECTIONS}
    return Instrument(telescope_diameter_m=config.channel.telescope_diameter_m, apd=config.apd,
                      receiver=rx, fiber=fiber, **sections)

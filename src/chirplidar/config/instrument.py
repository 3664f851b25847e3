"""The factory from a validated configuration to the domain object the tiers take."""

from __future__ import annotations

from ..tiers.model import FiberAcceptance, Instrument
from .models import MissionConfig


def instrument_from_config(config: MissionConfig) -> Instrument:
    """The configuration's transceiver as an :class:`~chirplidar.tiers.model.Instrument`: its
    instrument sections, the receive telescope's diameter and, when the receiver couples into a
    single-mode fiber (the ``coupling`` effect), the fiber's acceptance."""
    fiber = None
    if "coupling" in config.effects.enabled:
        c = config.effects.coupling
        fiber = FiberAcceptance(telescope_diameter_m=config.channel.telescope_diameter_m,
                                focal_length_m=c.focal_length_m,
                                numerical_aperture=c.fiber_numerical_aperture)
    return Instrument(simulation=config.simulation, system=config.system,
                      processing=config.processing, waveform=config.waveform,
                      laser=config.laser, modulator=config.modulator,
                      transmitter=config.transmitter, balanced=config.balanced, pin=config.pin,
                      apd=config.apd, heterodyne=config.heterodyne,
                      telescope_diameter_m=config.channel.telescope_diameter_m, fiber=fiber)

"""What every tier takes and gives: :class:`Instrument`, :class:`Returns`, :class:`Measurements`,
and the :class:`Tier` protocol with the :class:`Supports` each tier declares.

The data flow is one way: the configuration layer builds the instrument
(``chirplidar.config.instrument_from_config``), the channel builds the returns (the lab bench's
point target: ``chirplidar.channel.lab_returns``; a survey's footprints: ``chirplidar.mission``),
and a tier turns them into measurements::

    tier = TIERS["rf"]
    tier.check(instrument, returns)            # refuses what the tier does not model, before work
    out = tier.simulate(instrument, returns, rng)
    out["SNR"]                                 # (batch,) dB, thesis Table 4.10

Sign convention (one for every tier): a phase in :class:`Returns` or in
:class:`~chirplidar.tiers.echoes.Echoes` is the phase of the received signal's optical field,
``E_sig = |E_sig| exp(+j phase)``, relative to the local oscillator's.
"""

from __future__ import annotations

import typing
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Literal, Protocol

import numpy as np
from numpy.typing import ArrayLike

from ..waveform import Waveform, waveform_from_config
from .echoes import Echoes

CarrierPhase = Literal["optimal", "random", "propagation"]

#: Receiver kinds a tier may support: the coherent receiver's modes and the direct detectors.
RECEIVER_KINDS = ("homodyne", "phase_diversity", "heterodyne", "pin", "apd", "photon_counting")


@dataclass(frozen=True)
class FiberAcceptance:
    """The receiver's telescope focal cone against the single-mode fiber's acceptance (thesis
    Sec. 2.6: the marginal ray D / 2f beyond the fiber's numerical aperture is flagged)."""

    telescope_diameter_m: float
    focal_length_m: float
    numerical_aperture: float

    @property
    def exceeded(self) -> bool:
        half_angle = np.arctan(self.telescope_diameter_m / (2 * self.focal_length_m))
        return bool(np.sin(half_angle) > self.numerical_aperture)


@dataclass(frozen=True)
class Instrument:
    """The transceiver a tier simulates, independent of where it points (frozen, hashable).

    Its sections are the validated configuration sections of the same names. A chirped
    instrument (thesis Tables 4.1-4.9) has the waveform and its timing (``waveform``,
    ``simulation``), the transmitter (``laser``, ``modulator``, ``transmitter``), the receiver
    (``system`` chooses it; ``balanced``, ``pin``, ``apd``, ``heterodyne`` describe the
    detectors) and the processing (``processing``, with the reference-delay rule in ``system``).
    A pulsed instrument (thesis Tables 2.1-2.2) has ``pulse``, ``pulse_receiver``, ``digitizer``,
    ``pulse_ranging`` and, by its detector, ``apd`` or ``photon_counting``; its other sections
    are None. ``receiver`` is the coherent receiver's architecture (the ``[receiver]`` section:
    fiber, large detector or focal-plane array; None for the fiber of the closed-form
    ``coupling`` effect). ``fiber`` is the fiber coupling's acceptance check, when the receiver
    couples into a fiber; ``telescope_diameter_m`` the receive aperture. Build it with
    ``chirplidar.config.instrument_from_config``.
    """

    telescope_diameter_m: float
    simulation: Any = None
    system: Any = None
    processing: Any = None
    waveform: Any = None
    laser: Any = None
    modulator: Any = None
    transmitter: Any = None
    balanced: Any = None
    pin: Any = None
    apd: Any = None
    heterodyne: Any = None
    pulse: Any = None
    pulse_receiver: Any = None
    photon_counting: Any = None
    digitizer: Any = None
    pulse_ranging: Any = None
    receiver: Any = None
    fiber: FiberAcceptance | None = None

    @property
    def kind(self) -> str:
        """``"pulsed"`` (it has a ``pulse`` section) or ``"chirped"``."""
        return "pulsed" if self.pulse is not None else "chirped"

    @property
    def wavelength_m(self) -> float:
        """The carrier wavelength: the pulse's or the laser's."""
        return float((self.pulse if self.pulse is not None else self.laser).wavelength_m)

    @cached_property
    def train(self) -> Waveform:
        """The drive waveform (:class:`~chirplidar.waveform.ChirpTrain` or ``PNTrain``)."""
        return waveform_from_config(self)

    @property
    def n_samples(self) -> int:
        """Samples of one rf record: duration x sample rate."""
        return int(round(self.simulation.duration_s * self.simulation.sample_rate_hz))

    @property
    def receiver_kind(self) -> str:
        """One of :data:`RECEIVER_KINDS`."""
        if self.pulse is not None:
            return str(self.pulse_receiver.detector)
        if self.system.receiver == "coherent":
            return str(self.system.coherent_mode)
        return str(self.system.receiver)


def _per_shot(name: str, value: ArrayLike, batch: int) -> np.ndarray:
    arr = np.array(np.broadcast_to(np.asarray(value, dtype=np.float64), (batch,)))
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"returns.{name} must be finite (got NaN or inf)")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, init=False)
class Returns:
    """What reaches the receiver, for a batch of shots.

    transmission:  received / transmitted optical power of the mean return (W/W), before fading
    delay_s:       round-trip delay of the return (s); footprint echoes are offsets from it
    range_m:       the true one-way range (m), what ``d_error`` is measured against
    group_index:   group index of the path (ranges are read as c tau / 2n)
    power_factor:  (batch,) each shot's fading of the received power (speckle, coupling,
                   turbulence), 1 for none
    phase_rad:     (batch,) each shot's extra carrier phase of the signal field (speckle)
    doppler_hz:    (batch,) each shot's carrier Doppler shift
    carrier_phase: the static carrier phase: the receiver's optimum, uniform at random per record,
                   or the propagation phase -2 pi nu (tau - tau_ref)
    echoes:        the footprint as delayed sub-returns, or None for a point target
    reference_delay_s: the range gate a tracker set for these shots (s), or None for the
                   instrument's own rule (``system.reference_delay_s`` or ``sys.fmaxopt``; a
                   pulsed instrument's digitizer window is centred on ``delay_s``)
    background_power_w: (batch,) background light the receiver collects (W: sun or sky in
                   its field of view and filter band); direct detection counts it

    Per-shot fields accept a scalar (every shot alike) and are stored as read-only (batch,)
    float64 arrays; ``batch`` is their length.
    """

    transmission: float
    delay_s: float
    range_m: float
    group_index: float
    power_factor: np.ndarray
    phase_rad: np.ndarray
    doppler_hz: np.ndarray
    carrier_phase: CarrierPhase = "optimal"
    echoes: Echoes | None = None
    reference_delay_s: float | None = None
    background_power_w: np.ndarray = field(default_factory=lambda: np.zeros(1))
    batch: int = field(default=1)  # set by __init__: the per-shot arrays' length

    # Written out (not generated) so that the per-shot fields take any array-like and are
    # stored as arrays; dataclasses.replace calls it with every field.
    def __init__(
        self,
        transmission: float,
        delay_s: float,
        range_m: float,
        group_index: float,
        power_factor: ArrayLike,
        phase_rad: ArrayLike,
        doppler_hz: ArrayLike,
        carrier_phase: CarrierPhase = "optimal",
        echoes: Echoes | None = None,
        reference_delay_s: float | None = None,
        background_power_w: ArrayLike = 0.0,
        batch: int | None = None,
    ) -> None:
        batch = int(np.size(power_factor)) if batch is None else batch
        if isinstance(batch, bool) or not isinstance(batch, (int, np.integer)) or batch < 1:
            raise ValueError(f"returns: a batch needs at least one shot (got batch = {batch!r})")
        if carrier_phase not in typing.get_args(CarrierPhase):
            raise ValueError(
                f"returns.carrier_phase must be one of "
                f"{', '.join(typing.get_args(CarrierPhase))}; got {carrier_phase!r}"
            )
        if reference_delay_s is not None:
            reference_delay_s = float(reference_delay_s)
            if not np.isfinite(reference_delay_s):
                raise ValueError(
                    f"returns.reference_delay_s must be finite (got {reference_delay_s})"
                )
        per_shot = {
            "power_factor": power_factor,
            "phase_rad": phase_rad,
            "doppler_hz": doppler_hz,
            "background_power_w": background_power_w,
        }
        values: dict[str, Any] = {"batch": batch}
        for name, value in per_shot.items():
            values[name] = _per_shot(name, value, batch)
        scalars = {
            "transmission": transmission,
            "delay_s": delay_s,
            "range_m": range_m,
            "group_index": group_index,
        }
        for name, value in scalars.items():
            values[name] = float(value)
            if not np.isfinite(values[name]):
                raise ValueError(f"returns.{name} must be finite (got {values[name]})")
        if values["transmission"] < 0 or np.any(values["power_factor"] < 0):
            raise ValueError("returns.transmission and returns.power_factor must be >= 0")
        if np.any(values["background_power_w"] < 0):
            raise ValueError("returns.background_power_w must be >= 0")
        if echoes is not None and not isinstance(echoes, Echoes):
            raise ValueError(
                f"echoes must be a chirplidar.tiers.echoes.Echoes or None; "
                f"got {type(echoes).__name__}"
            )
        if echoes is not None:
            echoes.for_batch(batch)  # (batch, k) echoes must match the batch: checked now
        values.update(
            carrier_phase=carrier_phase, echoes=echoes, reference_delay_s=reference_delay_s
        )
        for name, value in values.items():
            object.__setattr__(self, name, value)

    def echo_arrays(self):
        """(delay_offset_s, normalised power weight, phase_rad), each (batch, k), or None."""
        return None if self.echoes is None else self.echoes.for_batch(self.batch)


class Measurements(Mapping):
    """A tier's outputs for a batch: the thesis Table 4.10 names (:data:`OUTPUT_UNITS`) and
    ``f_beat_hz`` as (batch,) arrays, tier-specific extras (e.g. the phase-diversity arms'
    ``arm1_Crx``), the batch's ``flags``, the ``tier`` name and, when asked, the ``spectrum``.
    ``flag_masks`` holds every flag as a (batch,) bool array: the shots it applies to (all of
    them for a flag of the whole batch, such as ``no_lo`` or ``saturation``).

    A read-only mapping: ``out["SNR"]``, ``out["flags"]`` (a list), ``out["tier"]``.
    """

    def __init__(
        self,
        tier: str,
        values: Mapping[str, np.ndarray],
        flags,
        spectrum=None,
        *,
        flag_masks: Mapping[str, np.ndarray] | None = None,
    ):
        self.tier = tier
        self.arrays = dict(values)
        self.flags = tuple(flags)
        self.spectrum = spectrum
        self.flag_masks = dict(flag_masks or {})

    def _items(self) -> dict:
        out: dict[str, Any] = dict(self.arrays)
        out["flags"] = list(self.flags)
        out["tier"] = self.tier
        if self.spectrum is not None:
            out["spectrum"] = self.spectrum
        return out

    def __getitem__(self, key: str):
        if key == "flags":
            return list(self.flags)
        if key == "tier":
            return self.tier
        if key == "spectrum" and self.spectrum is not None:
            return self.spectrum
        return self.arrays[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._items())

    def __len__(self) -> int:
        return len(self._items())

    def __repr__(self) -> str:
        return (
            f"Measurements(tier={self.tier!r}, keys={list(self.arrays)}, flags={list(self.flags)})"
        )


class UnsupportedError(ValueError):
    """A tier was asked for something it does not model (raised before any work)."""


@dataclass(frozen=True)
class Supports:
    """What a tier models: its receivers (:data:`RECEIVER_KINDS`), modulations, Doppler
    recoveries, whether it takes footprint echoes and whether it draws a spectrum (the rf and
    baseband tiers read their outputs off one; the link tier has none).
    ``recovery_receivers``: the receivers a Doppler recovery works with, where it does not work
    with all (squaring needs the self-chirped homodyne beat, thesis Appendix D). ``hint``: where
    else to go, by key. ``kinds``: the instruments it flies, ``"chirped"`` and/or ``"pulsed"``
    (a pulsed instrument is checked for its detector only). ``architectures``: the
    ``receiver.architecture`` values it models (an instrument without ``[receiver]`` is the
    closed-form fiber, which every chirped tier models); ``combining``: an FPA's combining
    rules it models."""

    receivers: frozenset[str]
    modulations: frozenset[str]
    doppler_recovery: frozenset[str]
    echoes: bool
    spectrum: bool
    recovery_receivers: Mapping[str, frozenset[str]] = field(default_factory=dict)
    hint: Mapping[str, str] = field(default_factory=dict)
    kinds: frozenset[str] = frozenset({"chirped"})
    architectures: frozenset[str] = frozenset()
    combining: frozenset[str] = frozenset()

    def check(self, tier: str, instrument: Instrument, returns: Returns | None = None) -> None:
        """Raise :class:`UnsupportedError` naming the setting this tier does not model."""
        if instrument.kind not in self.kinds:
            given = (
                "a pulsed instrument ([pulse] section)"
                if instrument.kind == "pulsed"
                else "a chirped instrument ([waveform], [system], [laser] sections)"
            )
            raise UnsupportedError(
                f"the {tier} tier does not model {given}"
                + (f"; {self.hint['kind']}" if "kind" in self.hint else "")
            )
        if instrument.kind == "pulsed":
            self._check_pulsed(tier, instrument)
            return
        sysc, proc = instrument.system, instrument.processing

        def refuse(setting: str, models: str, key: str) -> UnsupportedError:
            hint = self.hint.get(key, "")
            return UnsupportedError(
                f"the {tier} tier does not model {setting}: it models {models}"
                + (f"; {hint}" if hint else "")
            )

        if sysc.modulation not in self.modulations:
            pn = " (sys.MxMode = PN)" if sysc.modulation == "pn_code" else ""
            raise refuse(
                f"system.modulation = {sysc.modulation!r}{pn}",
                " and ".join(repr(m) for m in sorted(self.modulations)),
                "modulation",
            )
        kind = instrument.receiver_kind

        def setting_of(kind: str) -> str:
            if sysc.receiver == "coherent":
                return f"system.coherent_mode = {kind!r}"
            return f"system.receiver = {kind!r}"

        if kind not in self.receivers:
            raise refuse(
                setting_of(kind), "the receivers " + ", ".join(sorted(self.receivers)), "receiver"
            )
        if proc.doppler_recovery not in self.doppler_recovery:
            raise refuse(
                f"processing.doppler_recovery = {proc.doppler_recovery!r}",
                " and ".join(repr(m) for m in sorted(self.doppler_recovery)),
                "doppler_recovery",
            )
        needs = self.recovery_receivers.get(proc.doppler_recovery)
        if needs is not None and kind not in needs:
            raise refuse(
                f"processing.doppler_recovery = {proc.doppler_recovery!r} with {setting_of(kind)}",
                f"{proc.doppler_recovery} recovery with the receivers " + ", ".join(sorted(needs)),
                "recovery_receiver",
            )
        self._check_architecture(tier, instrument)
        if returns is not None and returns.echoes is not None and not self.echoes:
            raise UnsupportedError(
                f"the {tier} tier takes no footprint echoes (a survey "
                "broadens its line in closed form)"
            )

    def _check_architecture(self, tier: str, instrument: Instrument) -> None:
        rx = instrument.receiver
        if rx is None:
            return
        hint = self.hint.get("architecture", "")
        if rx.architecture not in self.architectures:
            models = ", ".join(sorted(self.architectures)) or "no receiver architecture"
            raise UnsupportedError(
                f"the {tier} tier does not model receiver.architecture = {rx.architecture!r}: "
                f"it models {models}" + (f"; {hint}" if hint else "")
            )
        if rx.architecture == "fpa" and rx.combining not in self.combining:
            raise UnsupportedError(
                f"the {tier} tier does not model receiver.combining = {rx.combining!r}: it "
                f"models {', '.join(sorted(self.combining))}"
                + (f"; {self.hint['combining']}" if "combining" in self.hint else "")
            )

    def _check_pulsed(self, tier: str, instrument: Instrument) -> None:
        kind = instrument.receiver_kind
        if kind not in self.receivers:
            raise UnsupportedError(
                f"the {tier} tier does not model pulse_receiver.detector = {kind!r}: it models "
                + ", ".join(sorted(self.receivers))
            )


class Tier(Protocol):
    """One fidelity tier: ``simulate(instrument, returns, rng) -> Measurements``.

    ``rng`` is the batch's generator; the effects' and the laser phase noise's streams are its
    children, so enabling one leaves the others' draws unchanged.
    """

    name: str
    summary: str
    supports: Supports

    def check(self, instrument: Instrument, returns: Returns | None = None) -> None: ...

    def simulate(
        self,
        instrument: Instrument,
        returns: Returns,
        rng: np.random.Generator,
        *,
        keep_spectrum: bool = False,
    ) -> Measurements: ...

"""The whole mission configuration: :class:`MissionConfig` and its checks across sections.

Unknown keys are errors, inf and NaN are refused (:class:`chirplidar.config.base.StrictModel`).
The sections are in :mod:`~chirplidar.config.models_instrument` (the transceiver, thesis Tables
4.1-4.9 and 4.11), :mod:`~chirplidar.config.models_effects` (channel effects) and
:mod:`~chirplidar.config.models_survey` (scene, platform, beams, run); the thesis names of the
transceiver keys are in :mod:`chirplidar.config.aliases`.
"""

from __future__ import annotations

from pydantic import Field, model_validator

from .base import StrictModel
from .models_effects import Effects
from .models_instrument import (APD, PIN, Balanced, Channel, Heterodyne, Laser, Modulator,
                                Processing, Simulation, Sweep, System, Transmitter, Waveform)
from .models_pulsed import Background, Digitizer, PhotonCounting, Pulse, PulseRanging, PulseReceiver
from .models_receiver import Receiver
from .models_survey import AttitudeConfig, Beams, Platform, SceneRef, SurveyRun

#: A chirp's frequency ramp must span at least this many samples to be a chirp at all.
MIN_RAMP_SAMPLES = 4
#: Seeds are stored as a signed 64-bit NetCDF attribute.
MAX_SEED = 2**63 - 1
# The heterodyne IF band (the tiers filter with it) must fit below Nyquist.
from ..tiers.budget import IF_HALF_WIDTH_FACTOR  # noqa: E402


#: The chirped transceiver's own sections (thesis Tables 4.1-4.9): all present, or none.
CHIRPED_SECTIONS = ("simulation", "system", "processing", "waveform", "laser", "modulator",
                    "transmitter", "balanced", "pin", "heterodyne")
#: A pulsed altimeter's own sections (thesis Tables 2.1-2.2; ``config.models_pulsed``).
PULSED_SECTIONS = ("pulse", "pulse_receiver", "photon_counting", "digitizer", "pulse_ranging")
#: What a pulsed instrument needs besides [pulse], by its detector.
PULSED_REQUIRED = ("pulse_receiver", "digitizer", "pulse_ranging")


class MissionConfig(StrictModel):
    """A whole transceiver configuration (the ``instrument`` of a mission) and, for a survey,
    where it flies. The instrument is chirped (the sections of :data:`CHIRPED_SECTIONS`, thesis
    Ch. 4) or pulsed (``[pulse]`` and the sections of :data:`PULSED_SECTIONS`, thesis Ch. 2);
    ``[channel]`` and ``[apd]`` serve both."""

    simulation: Simulation | None = None
    system: System | None = None
    processing: Processing | None = None
    waveform: Waveform | None = None
    laser: Laser | None = None
    modulator: Modulator | None = None
    transmitter: Transmitter | None = None
    channel: Channel
    apd: APD | None = None
    balanced: Balanced | None = None
    pin: PIN | None = None
    heterodyne: Heterodyne | None = None
    receiver: Receiver | None = None
    pulse: Pulse | None = None
    pulse_receiver: PulseReceiver | None = None
    photon_counting: PhotonCounting | None = None
    digitizer: Digitizer | None = None
    pulse_ranging: PulseRanging | None = None
    background: Background | None = None
    effects: Effects = Effects()
    sweep: Sweep = Sweep()
    seed: int = Field(ge=0, le=MAX_SEED, description="seed of the run's numpy Generator")
    # Survey (chirplidar run): optional for transceiver-only files.
    scene: SceneRef | None = None
    platform: Platform | None = None
    attitude: AttitudeConfig | None = None
    beams: Beams | None = None
    survey: SurveyRun | None = None

    @model_validator(mode="before")
    @classmethod
    def _one_kind_of_instrument(cls, data):
        """A chirped or a pulsed instrument, never a mixture; a survey's tier and shot rate
        default to the instrument's own (see :func:`instrument_survey_defaults`)."""
        if not isinstance(data, dict):
            return data
        pulsed = "pulse" in data
        if pulsed:
            mixed = [s for s in CHIRPED_SECTIONS if s in data]
            if mixed:
                raise ValueError(
                    f"a pulsed instrument ([pulse]) takes no chirped-transceiver sections; "
                    f"remove [{'], ['.join(mixed)}] (chirp keys), or remove [pulse] for a "
                    "chirped instrument")
            missing = [s for s in PULSED_REQUIRED if s not in data]
            rx = data.get("pulse_receiver")
            detector = rx.get("detector") if isinstance(rx, dict) else None
            if detector in ("apd", "photon_counting") and detector not in data:
                missing.append(detector)
            if "receiver" in data:
                raise ValueError("[receiver] chooses a coherent receiver's architecture; a "
                                 "pulsed instrument ([pulse]) detects directly: remove [receiver]")
        else:
            stray = [s for s in PULSED_SECTIONS if s in data]
            if stray:
                raise ValueError(
                    f"[{'], ['.join(stray)}] belong to a pulsed instrument, which has a [pulse] "
                    "section; this one has none (a chirped instrument takes none of them)")
            missing = [s for s in CHIRPED_SECTIONS + ("apd",) if s not in data]
        if missing:
            kind = "a pulsed" if pulsed else "a chirped"
            raise ValueError(f"{kind} instrument needs the section(s) [{'], ['.join(missing)}]")
        survey = data.get("survey")
        if isinstance(survey, dict):
            data = {**data, "survey": {**instrument_survey_defaults(data), **survey}}
        return data

    @model_validator(mode="after")
    def _pulsed(self):
        if self.pulse is None:
            return self
        from ..waveform.pulse import check_pulse_timing

        dig = self.digitizer
        check_pulse_timing(self.pulse.duration_s, self.pulse.prf_hz, dig.sample_rate_hz,
                           dig.record_samples)
        sv = self.survey
        if sv is not None and abs(sv.prf_hz - self.pulse.prf_hz) > 1e-9 * self.pulse.prf_hz:
            raise ValueError(
                f"survey.prf_hz = {sv.prf_hz:g} Hz differs from the pulsed laser's "
                f"pulse.prf_hz = {self.pulse.prf_hz:g} Hz: omit survey.prf_hz (a pulsed "
                "instrument shoots at its laser's rate)")
        return self

    @model_validator(mode="after")
    def _campaign(self):
        sv = self.survey
        if sv is None or sv.start_utc is None:
            return self
        kind = self.platform.kind if self.platform is not None else None
        if kind != "satellite":
            raise ValueError(f"survey.start_utc / stop_utc (a campaign window) are for "
                             f"satellites; a {kind or 'platform-less'} campaign is several "
                             "flights (one mission file each) combined by `chirplidar coverage`")
        if sv.start_s is not None or sv.stop_s is not None:
            raise ValueError("give either a campaign window (survey.start_utc, stop_utc) or a "
                             "span (survey.start_s, stop_s), not both")
        return self

    @model_validator(mode="after")
    def _receiver(self):
        en = self.effects.enabled
        if "turbulence" in en and "coupling" not in en and self.receiver is None:
            raise ValueError("effects 'turbulence' acts on the receiver's coupling: enable "
                             "'coupling' (the fiber's closed form) or give a [receiver]")
        rx = self.receiver
        if rx is None:
            return self
        sysc = self.system
        if sysc.receiver != "coherent" or sysc.coherent_mode == "heterodyne":
            raise ValueError(
                "[receiver] sets the self-chirped coherent receiver's architecture: it needs "
                "system.receiver = 'coherent' with coherent_mode 'homodyne' or 'phase_diversity'")
        if rx.architecture == "fpa" and sysc.coherent_mode != "phase_diversity":
            raise ValueError(
                "receiver.architecture = 'fpa' combines complex pixel records in its DSP: set "
                "system.coherent_mode = 'phase_diversity' (an I/Q hybrid per pixel, Appendix C)")
        if not self.channel.free_space:
            raise ValueError("[receiver] needs channel.free_space = on (atm.state): the bench's "
                             "fiber channel has no telescope or focal plane")
        if "coupling" in en:
            raise ValueError("[receiver] computes the coupling from the focal-plane field: "
                             "remove 'coupling' from effects.enabled (its closed form is the "
                             "fiber receiver's mean)")
        sp = self.effects.speckle
        if "speckle" in en and (sp.cells != 1 or sp.shift_per_shot_m is not None):
            raise ValueError("with [receiver], speckle is drawn across the pupil from the "
                             "footprint: effects.speckle.cells must be 1 and shift_per_shot_m "
                             "unset (the receiver sets how many cells it integrates)")
        if rx.architecture == "fpa":
            from ..optics import beam_radius_m
            from ..optics.focal_plane import return_spot_radius_m

            ch = self.channel
            if rx.footprint == "monostatic":  # the transmit mode's far field: w / R = w0 / f
                w = ch.distance_m * rx.transmit_mode_radius_m / rx.focal_length_m
            else:
                w = beam_radius_m(ch.beam_radius_m, ch.divergence_half_angle_rad, ch.distance_m)
            spot = return_spot_radius_m(rx.focal_length_m, self.wavelength_m,
                                        ch.telescope_diameter_m, float(w), ch.distance_m)
            if rx.fpa.pitch_m > 2.0 * spot:
                raise ValueError(
                    f"receiver.fpa.pitch_m = {rx.fpa.pitch_m:.3g} m is larger than the "
                    f"focal spot's field ({2 * spot:.3g} m across at channel.distance_m): one "
                    "pixel would hold the whole return; use a finer pitch or "
                    "receiver.architecture = 'large_detector'")
        return self

    @property
    def kind(self) -> str:
        """``"pulsed"`` or ``"chirped"``: the instrument's kind."""
        return "pulsed" if self.pulse is not None else "chirped"

    @property
    def wavelength_m(self) -> float:
        """The carrier wavelength: the pulse's or the laser's."""
        return (self.pulse if self.pulse is not None else self.laser).wavelength_m

    @model_validator(mode="after")
    def _weak_turbulence(self):
        ch = self.channel
        if "turbulence" in self.effects.enabled and ch.free_space and ch.cn2_m_minus_2_3 > 0:
            from ..atmosphere.turbulence import rytov_variance

            sigma2 = float(rytov_variance(ch.cn2_m_minus_2_3, self.wavelength_m,
                                          ch.distance_m, "plane"))
            if sigma2 >= 1.0:
                raise ValueError(
                    f"channel.cn2_m_minus_2_3 (atm.Cn2) = {ch.cn2_m_minus_2_3:g} over "
                    f"channel.distance_m (atm.dst) = {ch.distance_m:g} m gives a plane-wave "
                    f"Rytov variance of {sigma2:.3g} >= 1: strong fluctuations, outside the "
                    "weak-turbulence theory the turbulence effect uses; lower atm.Cn2 or atm.dst")
        return self

    @model_validator(mode="after")
    def _sampling(self):
        if self.pulse is not None:
            return self
        nyq = self.simulation.sample_rate_hz / 2
        f_top = self.waveform.f_stop_hz + self.waveform.f_offset_hz
        if f_top >= nyq:
            raise ValueError(
                f"waveform.f_stop_hz + f_offset_hz (chrp.F2 + chrp.F0 = {f_top:g} Hz) is at or above "
                f"the Nyquist frequency sample_rate_hz/2 (sims.Fs/2 = {nyq:g} Hz): the chirp cannot "
                "be represented; raise sims.Fs or lower chrp.F2")
        rise_s = self.waveform.ramp_duty_cycle * self.waveform.chirp_period_s
        if rise_s * self.simulation.sample_rate_hz < MIN_RAMP_SAMPLES:
            raise ValueError(
                f"the frequency ramp lasts waveform.ramp_duty_cycle x chirp_period_s (chrp.rdcyc "
                f"x chrp.Tchp) = {rise_s:.3g} s, less than {MIN_RAMP_SAMPLES} samples at "
                f"sims.Fs = {self.simulation.sample_rate_hz:g} Hz: no chirp to sample")
        if self.waveform.f_start_hz + self.waveform.f_offset_hz < 0:
            raise ValueError("waveform.f_start_hz + f_offset_hz (chrp.F1 + chrp.F0) is negative")
        if self.waveform.chirp_period_s > self.simulation.duration_s * (1 + 1e-9):
            raise ValueError(
                f"waveform.chirp_period_s (chrp.Tchp = {self.waveform.chirp_period_s:g} s) is longer "
                f"than simulation.duration_s (sims.T = {self.simulation.duration_s:g} s): no whole "
                "chirp fits in the record")
        if (self.system.receiver == "coherent" and self.system.coherent_mode == "heterodyne"):
            top = self.balanced.lo_offset_hz + IF_HALF_WIDTH_FACTOR * f_top
            if top >= nyq:
                raise ValueError(
                    f"heterodyne IF band: balanced.lo_offset_hz + 1.25*(F2+F0) = {top:g} Hz is at or above "
                    f"Nyquist ({nyq:g} Hz); lower COH.f_LO or raise sims.Fs")
        if self.system.modulation == "pn_code":
            if self.waveform.pn_chip_rate_hz is None or self.waveform.pn_order is None:
                raise ValueError("system.modulation = 'pn_code' needs waveform.pn_chip_rate_hz "
                                 "and waveform.pn_order")
            if self.waveform.pn_chip_rate_hz >= nyq:
                raise ValueError("waveform.pn_chip_rate_hz is at or above Nyquist (sims.Fs/2)")
            if self.system.receiver == "coherent":
                raise ValueError(
                    "system.modulation = 'pn_code' needs a receiver that recovers the code "
                    "(system.receiver = 'pin' or 'apd'): the self-chirped homodyne product of a "
                    "code with its delayed copy carries no correlation peak")
        if "coupling" in self.effects.enabled and not self.channel.free_space:
            raise ValueError("effects 'coupling' needs channel.free_space = on (atm.state): the "
                             "bench's fiber channel has no telescope")
        if self.processing.doppler_recovery == "squaring" and self.processing.doppler_max_hz is None:
            raise ValueError("processing.doppler_recovery = 'squaring' needs processing.doppler_max_hz")
        if self.processing.doppler_recovery == "dsp" and not (
                self.system.receiver == "coherent" and self.system.coherent_mode == "phase_diversity"):
            raise ValueError(
                "processing.doppler_recovery = 'dsp' needs the I/Q receiver's complex record: set "
                "system.receiver = 'coherent' and system.coherent_mode = 'phase_diversity' (got "
                f"receiver {self.system.receiver!r}, coherent_mode {self.system.coherent_mode!r})")
        lw_on = self.laser.linewidth_hz > 0
        if lw_on != ("phase_noise" in self.effects.enabled):
            raise ValueError(
                "laser.linewidth_hz (lsr.Lw) > 0 needs 'phase_noise' in effects.enabled, and "
                "'phase_noise' needs a linewidth > 0: the list is the one switch for each effect "
                f"(linewidth {self.laser.linewidth_hz:g} Hz, enabled {list(self.effects.enabled)})")
        if self.survey is not None:
            record_rate = record_rate_hz(self.processing.averages, self.waveform.chirp_period_s)
            if self.survey.prf_hz > record_rate * (1 + 1e-9):
                raise ValueError(
                    f"survey.prf_hz = {self.survey.prf_hz:g} Hz is faster than the record rate "
                    f"1 / (processing.averages x chrp.Tchp) = {record_rate:g} Hz: a record of "
                    f"{self.processing.averages} chirps takes longer than the shot interval")
        if self.processing.averages > 1 and self.waveform.chirp_period_s <= self.simulation.duration_s / 2:
            raise ValueError("processing.averages > 1 (sys.avg) needs one chirp per record: set "
                             "waveform.chirp_period_s (chrp.Tchp) > simulation.duration_s/2 "
                             "(thesis Table 4.2 note)")
        return self

    @property
    def n_samples(self) -> int:
        return int(round(self.simulation.duration_s * self.simulation.sample_rate_hz))


def record_rate_hz(averages, chirp_period_s) -> float:
    """A chirped instrument's records per second, one after another: 1 / (averages x chirp
    period) (each record averages ``processing.averages`` chirps, sys.avg)."""
    return 1.0 / (averages * chirp_period_s)


def instrument_survey_defaults(data: dict) -> dict:
    """A survey's tier and shot rate when the mission leaves them out: the instrument's own.
    A pulsed instrument flies the pulsed tier at its laser's PRF; a chirped one the link tier
    at its record rate 1 / (processing.averages x waveform.chirp_period_s), one record after
    another. ``chirplidar compare`` relies on these: one mission, each instrument at its own."""
    try:
        if "pulse" in data:
            return {"tier": "pulsed", "prf_hz": data["pulse"]["prf_hz"]}
        rate = record_rate_hz(data["processing"]["averages"], data["waveform"]["chirp_period_s"])
    except (KeyError, TypeError, ZeroDivisionError):
        return {}  # the sections' own validation names what is missing
    return {"tier": "link", "prf_hz": rate}

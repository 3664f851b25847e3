"""Transceiver sections of a mission: thesis Tables 4.1-4.9 and 4.11 plus Chapter 5's prototype.

Every key carries its SI unit in its name (``_s``, ``_hz``, ``_w``, ``_m``, ``_v``, ``_ohm``, ``_k``,
``_a``, ``_db``); dimensionless ratios say what they are a ratio of. Physical quantities have no
defaults: a mission file states them all. Only algorithm choices (peak interpolator,
noise-estimation span, ...) have defaults, each with its source. The thesis names map onto these
keys in :mod:`chirplidar.config.aliases`.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import Field, field_validator, model_validator

from .base import StrictModel

# Thesis string values accepted wherever the project's own value is expected (Table 4.2, 4.6, 4.11).
THESIS_VALUES: dict[str, dict[str, object]] = {
    "receiver": {"APD": "apd", "COH": "coherent", "PIN": "pin"},
    "coherent_mode": {"hom": "homodyne", "het": "heterodyne"},
    "modulation": {"FM": "fm_chirp", "PN": "pn_code"},
    "on_off": {"on": True, "off": False},
}


def thesis_value(value, table: str):
    """``value`` in the project's spelling if it is one of ``table``'s thesis spellings."""
    if isinstance(value, str):
        lookup = {k.lower(): v for k, v in THESIS_VALUES[table].items()}
        return lookup.get(value.lower(), value)
    return value


class Simulation(StrictModel):
    """Thesis Table 4.1 (``sims``)."""

    duration_s: float = Field(gt=0, description="record duration T (sims.T)")
    sample_rate_hz: float = Field(gt=0, description="sample rate Fs (sims.Fs)")
    upsample_factor: int = Field(ge=1, description="delay resampling factor (sims.upxn); "
                                 "only used with delay_method='resample'")
    delay_method: Literal["analytic", "resample"] = Field(
        "analytic",
        description="'analytic' evaluates the waveform at t - tau exactly; 'resample' rounds the "
        "delay to 1/(Fs*upxn) as the thesis's resampling does")
    baseband_rate_hz: float | None = Field(
        None, gt=0, description="baseband tier: sample rate of the dechirped beat record (the "
        "detector's output rate). Unset = twice the processed band's top "
        "(processing.peak_search_max_hz, else the chirp's start frequency F1 + F0, below which "
        "every self-chirped beat lies), raised to a fast FFT length")
    baseband_precision: Literal["single", "double"] = Field(
        "single", description="baseband tier: floating-point precision of the noisy records and "
        "their FFT (the signal's phases are always computed in double). 'single' halves the FFT "
        "and noise cost; tests/test_baseband.py shows it moves SNR and range by far less than "
        "their noise")


class System(StrictModel):
    """Thesis Table 4.2 (``sys``)."""

    receiver: Literal["apd", "coherent", "pin"]
    coherent_mode: Literal["homodyne", "heterodyne", "phase_diversity"]
    modulation: Literal["fm_chirp", "pn_code"]
    max_beat_frequency_hz: float = Field(gt=0, description="sys.fmaxopt: the reference chirp is "
                                         "delayed so that the beat does not exceed this")
    reference_delay_s: float | None = Field(
        None, ge=0, description="explicit reference (LO / dechirp) delay; overrides the "
        "max_beat_frequency_hz rule (the bench used the 106 us chirp period, eq. 5.2)")

    @field_validator("receiver", mode="before")
    @classmethod
    def _rsel(cls, v):
        return thesis_value(v, "receiver")

    @field_validator("coherent_mode", mode="before")
    @classmethod
    def _cx(cls, v):
        return thesis_value(v, "coherent_mode")

    @field_validator("modulation", mode="before")
    @classmethod
    def _mx(cls, v):
        return thesis_value(v, "modulation")


class Processing(StrictModel):
    """Spectrum processing (FFT_peak.m): thesis ``sys.smoothx``, ``sys.avg``, ``sys.f_highpass``,
    ``sys.BWres`` plus the project's choices of peak interpolator and noise-estimation window."""

    zero_pad_factor: int = Field(ge=1, description="FFT smoothing factor (sys.smoothx)")
    averages: int = Field(ge=1, description="number of chirps averaged (sys.avg)")
    averaging: Literal["coherent", "power"] = Field(
        "coherent", description="'coherent' averages the voltage records (the thesis's choice: "
        "SNR grows with the number of chirps while the phase is stable); 'power' averages spectra")
    highpass_hz: float = Field(ge=0, description="peak search minimum frequency (sys.f_highpass)")
    peak_search_max_hz: float | None = Field(
        None, gt=0, description="peak search maximum frequency; unset = Nyquist, except for phase "
        "diversity where it is F1 + F0: each unbalanced hybrid arm also detects the LO's own power, "
        "at DC and at or above the chirp's start frequency, which Appendix C band-passes out")
    rbw_hz: float = Field(gt=0, description="spectrum-analyzer resolution bandwidth (sys.BWres)")
    peak_method: Literal["bin", "parabolic", "dtft"] = Field(
        "dtft", description="'bin' = FFT argmax (thesis FFT_peak.m); 'parabolic' = 3-point "
        "Gaussian interpolation; 'dtft' = the exact DTFT near the peak, interpolated from the FFT "
        "bins with the Dirichlet kernel, maximised on a fine grid (no scalloping)")
    noise_span_hz: float = Field(
        4e6, gt=0, description="span around the peak over which the noise level is averaged; "
        "where the tone's own skirt is not flat there, the window (span / 2 - guard each side) "
        "is stepped outward, up to 16 steps, to the first one beyond the skirt")
    doppler_recovery: Literal["none", "squaring", "dsp"] = Field(
        "none", description="'squaring' squares the real beat record and reads the line at "
        "2 f_R, which Doppler does not move (thesis Appendix D; rf tier, homodyne receivers). "
        "'dsp' compensates it in the combining DSP of the phase-diversity (I/Q) receiver: the "
        "two arms form the complex record C(t) exp(j 2 pi f_d t), lines at f_d +- f_R; f_d is "
        "estimated per shot as their centre of symmetry, removed, and the folded spectrum read "
        "at f_R (no noise penalty; valid while both lines lie in the processed band; rf, "
        "baseband and link tiers, system.coherent_mode = 'phase_diversity')")
    doppler_max_hz: float | None = Field(
        None, gt=0, description="largest Doppler shift expected (squaring): the search for 2 f_R "
        "starts above 2 x this, clear of the squared Doppler line at 2 f_d (Appendix D assumes "
        "10 MHz, about 13 m/s at 1310 nm)")
    noise_guard_hz: float = Field(
        1e6, gt=0, description="half-width around the peak excluded from the noise average: keeps "
        "the tone's own sidelobes out of the noise reading (the thesis reads the noise over a "
        "'flat' region, Sec. 2.6); the least one: a strong tone's skirt moves the window out")


class Waveform(StrictModel):
    """Thesis Table 4.3 (``chrp``) plus the PN-code alternative."""

    chirp_period_s: float = Field(gt=0, description="chrp.Tchp")
    f_start_hz: float = Field(ge=0, description="chrp.F1")
    f_stop_hz: float = Field(gt=0, description="chrp.F2")
    f_offset_hz: float = Field(description="chrp.F0, added to F1 and F2")
    ramp_duty_cycle: float = Field(gt=0, le=1, description="chrp.rdcyc: rise time / period")
    amplitude_duty_cycle: float = Field(ge=0, le=1, description="chrp.adcyc: hold / rise time")
    hold_time_s: float = Field(ge=0, description="chrp.qnt: sample-and-hold of the frequency")
    vpp_v: float = Field(ge=0, description="chrp.Vpp into a matched load")
    vdc_v: float = Field(description="chrp.Vdc")
    output_impedance_ohm: float = Field(gt=0, description="chrp.Ro")
    pn_chip_rate_hz: float | None = Field(None, gt=0, description="PN chip rate (MxMode=PN)")
    pn_order: int | None = Field(None, ge=3, le=24, description="PN shift-register length")

    @model_validator(mode="after")
    def _check(self):
        if self.f_stop_hz <= self.f_start_hz:
            raise ValueError(f"f_stop_hz (chrp.F2={self.f_stop_hz:g}) must exceed "
                             f"f_start_hz (chrp.F1={self.f_start_hz:g})")
        return self


class Laser(StrictModel):
    """Thesis Table 4.4 (``lsr``)."""

    wavelength_m: float = Field(gt=0, description="lsr.Lo")
    power_w: float = Field(ge=0, description="lsr.Po")
    linewidth_hz: float = Field(ge=0, description="lsr.Lw, FWHM of the Lorentzian line")


class Modulator(StrictModel):
    """Thesis Table 4.5 (``mzm``): field transfer E = E0 cos(pi V / (2 Vpi)), eq. 2.4.16."""

    v_pi_v: float = Field(gt=0, description="mzm.Vpi")
    bias_v: float = Field(description="mzm.Vdc")
    input_impedance_ohm: float = Field(gt=0, description="mzm.Ri")


class Transmitter(StrictModel):
    """Splitter and optical amplifier after the modulator (thesis Fig. 3.1, Table 5.1)."""

    tx_split_loss_db: float = Field(ge=0, description="loss from modulator to the transmit arm")
    amplifier: bool = Field(description="optical amplifier in the transmit arm")
    amplifier_gain_db: float | None = Field(None, ge=0, description="amplifier gain")
    amplifier_noise_figure_db: float | None = Field(
        None, ge=3.0 - 1e-9, description="amplifier noise figure (>= 3 dB, the high-gain limit)")

    @model_validator(mode="after")
    def _amp(self):
        if self.amplifier and (self.amplifier_gain_db is None or self.amplifier_noise_figure_db is None):
            raise ValueError("transmitter.amplifier = true needs amplifier_gain_db and "
                             "amplifier_noise_figure_db")
        return self


class Channel(StrictModel):
    """Thesis Table 4.6 (``atm``) plus group index and carrier-phase handling."""

    extra_attenuation_db: float = Field(gt=-math.inf, allow_inf_nan=True, description="atm.Pattn "
                                        "(applies in both states; inf: no signal at all)")
    free_space: bool = Field(description="atm.state: off = lab-bench fiber channel")
    distance_m: float = Field(ge=0, description="atm.dst, one-way distance")
    group_index: float = Field(ge=1, description="group index of the path (fiber 1.46, air 1.0003)")
    cn2_m_minus_2_3: float = Field(ge=0, description="atm.Cn2")
    surface_correlation_length_m: float = Field(gt=0, description="atm.lc")
    beam_radius_m: float = Field(gt=0, description="atm.Wo")
    divergence_half_angle_rad: float = Field(ge=0, description="atm.div")
    target_radius_m: float = Field(gt=0, description="atm.Wr")
    target_reflectivity: float = Field(ge=0, le=1, description="atm.R_trg")
    telescope_diameter_m: float = Field(gt=0, description="atm.D_tel")
    atmospheric_transmission: float = Field(ge=0, le=1, description="atm.T_atm (field, one way)")
    optical_transmission: float = Field(ge=0, le=1, description="atm.T_opt (field, end to end)")
    carrier_phase: Literal["optimal", "random", "propagation"] = Field(
        description="signal/LO optical phase: 'optimal' = tuned for highest CNR as on the bench "
        "(Ch. 5), 'random' = uniform per chirp, 'propagation' = 2 pi nu tau from the path")

    @field_validator("free_space", mode="before")
    @classmethod
    def _state(cls, v):
        return thesis_value(v, "on_off")


class _Photodiode(StrictModel):
    solar_current_a: float = Field(ge=0, description="Isol")
    background_current_a: float = Field(ge=0, description="Ibgd")
    leakage_current_a: float = Field(ge=0, description="Ilkg")


class APD(_Photodiode):
    """Thesis Table 4.7 (``APD``): APD with a transimpedance amplifier."""

    feedback_temperature_k: float = Field(gt=0, description="APD.Tfb")
    detector_temperature_k: float = Field(gt=0, description="APD.Tdet")
    feedback_resistance_ohm: float = Field(gt=0, description="APD.Rfb")
    feedback_capacitance_f: float = Field(gt=0, description="APD.Cfb")
    amp_current_noise_a_per_rthz: float = Field(ge=0, description="APD.INin")
    amp_voltage_noise_v_per_rthz: float = Field(ge=0, description="APD.VNen")
    dynamic_resistance_ohm: float = Field(gt=0, description="APD.Ro")
    detector_capacitance_f: float = Field(ge=0, description="APD.Cdet")
    gain: float = Field(ge=1, description="APD.M")
    excess_noise_factor: float = Field(ge=1, description="APD.NF, F(M)")
    quantum_efficiency: float = Field(gt=0, le=1, description="APD.qe")
    center_frequency_hz: float = Field(gt=0, description="APD.fo: where the capacitive "
                                       "voltage-noise term is evaluated")


class Balanced(_Photodiode):
    """Thesis Table 4.8 (``COH``): balanced photodetector and local oscillator."""

    noise_temperature_k: float = Field(ge=0, description="COH.To (0 switches thermal noise off)")
    output_impedance_ohm: float = Field(gt=0, description="COH.Ro")
    lo_power_w: float = Field(ge=0, description="COH.P_LO, mean LO power into the coupler")
    lo_offset_hz: float = Field(ge=0, description="COH.f_LO, heterodyne LO offset")
    lo_linewidth_hz: float = Field(ge=0, description="COH.lw, heterodyne LO laser linewidth")
    nep_w_per_rthz: float = Field(ge=0, description="COH.Nep")
    quantum_efficiency_1: float = Field(gt=0, le=1, description="COH.qe1")
    quantum_efficiency_2: float = Field(gt=0, le=1, description="COH.qe2")
    transimpedance_ohm: float = Field(gt=0, description="COH.Ztia")
    bandwidth_hz: float = Field(gt=0, description="detector bandwidth (Table 5.1: 800 MHz)")
    saturation_power_w: float = Field(gt=0, description="saturation of the detector's RF "
                                      "amplifier, as optical power of the differential signal")
    coupler_excess_loss_db: float = Field(ge=0, description="3 dB coupler / hybrid loss beyond "
                                          "the ideal split (Table 5.1: max IL 3.6 dB -> 0.6 dB)")


class PIN(_Photodiode):
    """Thesis Table 4.9 (``PIN``)."""

    bandwidth_hz: float = Field(gt=0, description="PIN.B")
    noise_temperature_k: float = Field(ge=0, description="PIN.To")
    output_impedance_ohm: float = Field(gt=0, description="PIN.Ro")
    nep_w_per_rthz: float = Field(ge=0, description="PIN.Nep")
    quantum_efficiency: float = Field(gt=0, le=1, description="PIN.qe")
    transimpedance_ohm: float = Field(gt=0, description="PIN.Ztia")


class Heterodyne(StrictModel):
    """The heterodyne prototype of thesis Fig. 5.5 and the losses Chapter 5 names."""

    quantum_efficiency: float = Field(gt=0, le=1, description="high-speed photodiode "
                                      "(Ch. 5: 0.45 A/W against 0.95 A/W, -3.25 dB)")
    capped_arm: bool = Field(description="only one coupler output detected (Ch. 5: +3 dB loss)")
    demodulation: Literal["envelope", "synchronous"] = Field(
        description="'envelope' = RF envelope detector (prototype); 'synchronous' = ideal coherent "
        "IF demodulation that knows the LO phase")


class Sweep(StrictModel):
    """Thesis Table 4.11 (``test``)."""

    enabled: bool = False
    vary: str = "channel.extra_attenuation_db"
    start: float = 32.0
    stop: float = 102.0
    n: int = Field(10, ge=1)
    repeat: int = Field(1, ge=1)
    scale: Literal["lin", "log"] = "lin"
    x_output: str = "Psig"
    y_output: str = "SNR"
    x_axis_scale: Literal["lin", "log"] = "lin"
    y_axis_scale: Literal["lin", "log"] = "lin"

    @field_validator("enabled", mode="before")
    @classmethod
    def _state(cls, v):
        return thesis_value(v, "on_off")

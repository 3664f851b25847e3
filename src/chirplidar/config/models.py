"""Validated configuration models.

Every key carries its SI unit in its name (``_s``, ``_hz``, ``_w``, ``_m``, ``_v``, ``_ohm``, ``_k``,
``_a``, ``_db``); dimensionless ratios say what they are a ratio of. Unknown keys are errors
(``extra="forbid"``). Physical quantities have no defaults: a mission file states them all. Only
algorithm choices (peak interpolator, noise-estimation span, ...) have defaults, each with its source.

The thesis names of Tables 4.1-4.9 and 4.11 map onto these keys in :mod:`chirplidar.config.aliases`.
"""

from __future__ import annotations

import math
import typing
from typing import Literal

import numpy as np

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

# Thesis string values accepted wherever the project's own value is expected (Table 4.2, 4.6, 4.11).
THESIS_VALUES: dict[str, dict[str, object]] = {
    "receiver": {"APD": "apd", "COH": "coherent", "PIN": "pin"},
    "coherent_mode": {"hom": "homodyne", "het": "heterodyne"},
    "modulation": {"FM": "fm_chirp", "PN": "pn_code"},
    "on_off": {"on": True, "off": False},
}


def _translate(value, table: str):
    if isinstance(value, str):
        lookup = {k.lower(): v for k, v in THESIS_VALUES[table].items()}
        return lookup.get(value.lower(), value)
    return value


#: Any key in dB beyond +-this is refused: 10^30 is no gain, loss or SNR an instrument has,
#: and powers that far apart overflow the single-precision records.
MAX_DB = 300.0
#: Any non-zero number of a configuration lies within these magnitudes (SI units): the
#: smallest quantities the simulator sees (Cn^2 ~ 1e-17 m^-2/3, NEP ~ 1e-12 W/rtHz) and their
#: squares are far inside; 1e-300 (a typo) underflows to 0 when squared.
SMALLEST_SI = 1e-100
LARGEST_SI = 1e100
#: dB keys whose losses MAX_DB does not bound, only their gains: a path loss may be anything (a
#: survey shot over specular water far off its glint loses 500 dB: no signal, as inf is).
ANY_LOSS_DB = frozenset({"extra_attenuation_db"})
#: Beams of a custom pattern: every shot casts each beam's sub-rays (ICESat-2 has 6, a
#: multi-beam scanner a few dozen).
MAX_BEAMS = 64
#: A chirp's frequency ramp must span at least this many samples to be a chirp at all.
MIN_RAMP_SAMPLES = 4


def _accepts_bool(annotation) -> bool:
    if annotation is bool:
        return True
    return any(_accepts_bool(a) for a in typing.get_args(annotation))


def _only_numbers(annotation) -> bool:
    """Whether a field takes numbers only (int, float, optional or not): no text."""
    args = [a for a in (typing.get_args(annotation) or (annotation,)) if a is not type(None)]
    return bool(args) and all(a in (int, float) for a in args)


class StrictModel(BaseModel):
    """The base of every configuration model (missions and scenes): unknown keys are errors,
    inf and NaN are refused (a field that means something by inf says so), and a number is
    never read from ``true``/``false`` (pydantic would read ``speed_mps = true`` as 1)."""

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True,
                              allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _no_bool_for_a_number(cls, value, info):
        annotation = cls.model_fields[info.field_name].annotation \
            if info.field_name in cls.model_fields else None
        if isinstance(value, bool) and annotation is not None and not _accepts_bool(annotation):
            raise ValueError("expected a number or text, not true or false")
        if isinstance(value, str) and annotation is not None and _only_numbers(annotation):
            raise ValueError("expected a number, not text (no quotes around numbers)")
        if isinstance(value, (int, float)) and not isinstance(value, bool) and \
                math.isfinite(value):
            loss_only = info.field_name in ANY_LOSS_DB   # any loss, but not any gain
            if info.field_name.endswith("_db") and (-value if loss_only else abs(value)) > MAX_DB:
                raise ValueError(f"{value:g} dB is a power ratio beyond 1e{MAX_DB / 10:.0f}: "
                                 "not a physical gain, loss or SNR (is it in linear units?)")
            if value != 0 and not SMALLEST_SI <= abs(value) <= LARGEST_SI:
                raise ValueError(f"{value:g} is outside {SMALLEST_SI:g}..{LARGEST_SI:g} in "
                                 "magnitude: no quantity in SI units is that small or large "
                                 "(its square under- or overflows)")
        return value


_Model = StrictModel


#: Seeds are stored as a signed 64-bit NetCDF attribute.
MAX_SEED = 2**63 - 1
#: A chunk holds ~2 kB per shot and beam with 7 sub-rays (measured on the Greenland UAV demo:
#: 0.35 GB at 20 000 shots, 0.63 GB at 159 000), so a million shots is ~2 GB per beam.
MAX_CHUNK_SHOTS = 1_000_000

Positive = Field(gt=0)
NonNegative = Field(ge=0)


class Simulation(_Model):
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


class System(_Model):
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
        return _translate(v, "receiver")

    @field_validator("coherent_mode", mode="before")
    @classmethod
    def _cx(cls, v):
        return _translate(v, "coherent_mode")

    @field_validator("modulation", mode="before")
    @classmethod
    def _mx(cls, v):
        return _translate(v, "modulation")


class Processing(_Model):
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
    doppler_recovery: Literal["none", "squaring"] = Field(
        "none", description="'squaring' squares the real beat record and reads the line at "
        "2 f_R, which Doppler does not move (thesis Appendix D; rf tier, homodyne receivers)")
    doppler_max_hz: float | None = Field(
        None, gt=0, description="largest Doppler shift expected (squaring): the search for 2 f_R "
        "starts above 2 x this, clear of the squared Doppler line at 2 f_d (Appendix D assumes "
        "10 MHz, about 13 m/s at 1310 nm)")
    noise_guard_hz: float = Field(
        1e6, gt=0, description="half-width around the peak excluded from the noise average: keeps "
        "the tone's own sidelobes out of the noise reading (the thesis reads the noise over a "
        "'flat' region, Sec. 2.6); the least one: a strong tone's skirt moves the window out")


class Waveform(_Model):
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


class Laser(_Model):
    """Thesis Table 4.4 (``lsr``)."""

    wavelength_m: float = Field(gt=0, description="lsr.Lo")
    power_w: float = Field(ge=0, description="lsr.Po")
    linewidth_hz: float = Field(ge=0, description="lsr.Lw, FWHM of the Lorentzian line")


class Modulator(_Model):
    """Thesis Table 4.5 (``mzm``): field transfer E = E0 cos(pi V / (2 Vpi)), eq. 2.4.16."""

    v_pi_v: float = Field(gt=0, description="mzm.Vpi")
    bias_v: float = Field(description="mzm.Vdc")
    input_impedance_ohm: float = Field(gt=0, description="mzm.Ri")


class Transmitter(_Model):
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


class Channel(_Model):
    """Thesis Table 4.6 (``atm``) plus group index and carrier-phase handling."""

    extra_attenuation_db: float = Field(gt=-np.inf, allow_inf_nan=True, description="atm.Pattn "
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
        return _translate(v, "on_off")


class _Photodiode(_Model):
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


class Heterodyne(_Model):
    """The heterodyne prototype of thesis Fig. 5.5 and the losses Chapter 5 names."""

    quantum_efficiency: float = Field(gt=0, le=1, description="high-speed photodiode "
                                      "(Ch. 5: 0.45 A/W against 0.95 A/W, -3.25 dB)")
    capped_arm: bool = Field(description="only one coupler output detected (Ch. 5: +3 dB loss)")
    demodulation: Literal["envelope", "synchronous"] = Field(
        description="'envelope' = RF envelope detector (prototype); 'synchronous' = ideal coherent "
        "IF demodulation that knows the LO phase")


# The heterodyne IF band (the tiers filter with it) must fit below Nyquist.
from ..tiers.budget import IF_HALF_WIDTH_FACTOR  # noqa: E402

EFFECT_NAMES = ("phase_noise", "speckle", "doppler", "coupling", "turbulence")


class DopplerEffect(_Model):
    """Target motion along the beam (thesis eq. 2.2.5, Appendix D)."""

    radial_velocity_mps: float = Field(description="closing speed along the line of sight "
                                       "(positive: range decreasing)")


class SpeckleEffect(_Model):
    """Speckle of a rough target (Goodman): gamma-distributed power of order M, random phase."""

    cells: float = Field(ge=1, description="speckle cells the receiver integrates, M (1 for a "
                         "single-mode-fiber coherent receiver)")
    shift_per_shot_m: float | None = Field(
        None, ge=0, description="footprint displacement between successive shots; unset: "
        "independent speckle per shot; set: a correlated sequence (whole cells only)")

    @model_validator(mode="after")
    def _whole_cells(self):
        if self.shift_per_shot_m is not None and self.cells != int(self.cells):
            raise ValueError("effects.speckle.shift_per_shot_m needs a whole number of cells")
        return self


class CouplingEffect(_Model):
    """Telescope-to-fiber coupling with a central obstruction (free space only).

    diffuse targets: the monostatic mean of Winzer & Leeb (1998), 42 % at best unobstructed;
    specular targets (a plane wave back): the closed form of Ruilier (1998), 81 % at best.
    """

    obstruction_ratio: float = Field(ge=0, lt=1, description="secondary / primary diameter")
    focal_length_m: float = Field(gt=0, description="telescope focal length")
    mode_field_radius_m: float = Field(gt=0, description="fiber mode-field radius (MFD / 2)")
    fiber_numerical_aperture: float = Field(gt=0, lt=1, description="fiber NA: the focal cone "
                                            "D / (2 f) beyond it is flagged (thesis: about +-6 deg)")
    target: Literal["diffuse", "specular"] = Field(description="diffuse (Lambertian speckle) or "
                                                   "specular (plane wave) return")


class TurbulenceEffect(_Model):
    """Phase-only turbulence in the receive pupil, Cn^2 = atm.Cn2 over atm.dst (needs 'coupling').

    'mean': the mutual-coherence mean coupling (deterministic, draws nothing). 'frozen_flow':
    successive shots of a batch see one screen moving past the aperture by speed x interval, so
    the fading of coupled power is correlated from shot to shot.
    """

    fading: Literal["mean", "frozen_flow"]
    outer_scale_m: float = Field(gt=0, allow_inf_nan=True, description="von Karman outer scale "
                                 "(inf: Kolmogorov; finite for "
                                 "frozen flow; the phase covariance needs it)")
    transverse_speed_mps: float | None = Field(None, ge=0, description="screen speed across the "
                                               "beam (frozen_flow)")
    shot_interval_s: float | None = Field(None, gt=0, description="time between shots (frozen_flow)")
    screen_pixels: int | None = Field(
        None, ge=16, description="frozen_flow: phase-screen samples across the aperture (a "
        "fidelity knob: >= 16, the pupil-coupling grid's minimum, and the pixel D / screen_pixels "
        "must not exceed r0); unset = max(64, ceil(4 D / r0)), at least 4 pixels per r0")

    @model_validator(mode="after")
    def _frozen(self):
        if self.fading == "frozen_flow":
            if self.transverse_speed_mps is None or self.shot_interval_s is None:
                raise ValueError("turbulence fading = 'frozen_flow' needs transverse_speed_mps "
                                 "and shot_interval_s")
            if not np.isfinite(self.outer_scale_m):
                raise ValueError("turbulence fading = 'frozen_flow' needs a finite outer_scale_m")
        return self


class Effects(_Model):
    """Channel effects by name (DESIGN.md): only the enabled ones are computed or draw numbers."""

    enabled: tuple[Literal["phase_noise", "speckle", "doppler", "coupling", "turbulence"], ...] = Field(
        (), description="effects to simulate; the rest cost nothing and draw no random numbers")
    doppler: DopplerEffect | None = None
    speckle: SpeckleEffect | None = None
    coupling: CouplingEffect | None = None
    turbulence: TurbulenceEffect | None = None

    @model_validator(mode="after")
    def _sections(self):
        if len(set(self.enabled)) != len(self.enabled):
            raise ValueError(f"effects.enabled lists an effect twice: {list(self.enabled)}")
        for name in self.enabled:
            if name in ("doppler", "speckle", "coupling", "turbulence") and getattr(self, name) is None:
                raise ValueError(f"effects.enabled includes '{name}' but [effects.{name}] is missing")
        if "turbulence" in self.enabled and "coupling" not in self.enabled:
            raise ValueError("effects 'turbulence' degrades the fiber coupling: enable 'coupling' "
                             "too (it holds the telescope and fiber)")
        return self


class Sweep(_Model):
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
        return _translate(v, "on_off")


# ------------------------------------------------------------------------------------------
# Survey sections: where the instrument flies (scene, platform, beams, run). Optional in a
# transceiver-only mission file; ``chirplidar run`` needs them all (mission.survey checks).

XY = tuple[float, float]


class SceneRef(_Model):
    """The scene the mission flies over. Any other key of the section changes the scene file's
    key of that name for this mission (``[scene.atmosphere] ground_cn2_m_minus_2_3 = 1e-13``,
    ``--set scene.terrain.flat.material=blue_ice``); the scene loader validates them."""

    model_config = ConfigDict(extra="allow", frozen=True, validate_default=True)

    file: str = Field(description="scene TOML file, relative to the mission file (scenes/*.toml)")


def _check_polygon(points, key: str):
    from shapely import is_valid_reason
    from shapely.geometry import Polygon

    if len(points) < 3:
        raise ValueError(f"{key} needs at least 3 vertices, got {len(points)}")
    poly = Polygon(points)
    if not poly.is_valid:
        raise ValueError(f"{key} is not a simple polygon ({is_valid_reason(poly)}); "
                         "self-intersecting survey outlines are refused")
    if poly.area <= 0:
        raise ValueError(f"{key} has zero area")


class _Survey2D(_Model):
    """A path as waypoints, or a lawnmower pattern over a polygon (x, y in ``coordinates``)."""

    coordinates: Literal["scene_centre", "projected"] = Field(
        description="'scene_centre': x, y in metres east/north (grid) of the scene centre; "
        "'projected': absolute x, y of the scene's EPSG frame")
    waypoints_m: tuple[XY, ...] | None = Field(None, description="path vertices (x, y) [m]")
    survey_polygon_m: tuple[XY, ...] | None = Field(
        None, description="area to cover with a lawnmower pattern (x, y) [m]")
    line_spacing_m: float | None = Field(None, gt=0, description="lawnmower line spacing")
    heading_deg: float | None = Field(None, description="lawnmower line direction, clockwise "
                                      "from grid north")

    @model_validator(mode="after")
    def _one_path(self):
        kind = type(self).__name__.lower().replace("platform", "")
        if (self.waypoints_m is None) == (self.survey_polygon_m is None):
            raise ValueError(f"platform.{kind}: give exactly one of waypoints_m and "
                             "survey_polygon_m")
        if self.waypoints_m is not None and len(self.waypoints_m) < 2:
            raise ValueError(f"platform.{kind}.waypoints_m needs at least 2 points")
        if self.survey_polygon_m is not None:
            _check_polygon(self.survey_polygon_m, f"platform.{kind}.survey_polygon_m")
            if self.line_spacing_m is None or self.heading_deg is None:
                raise ValueError(f"platform.{kind}.survey_polygon_m needs line_spacing_m and "
                                 "heading_deg")
        return self


class UavPlatform(_Survey2D):
    speed_mps: float = Field(gt=0, description="ground speed along the path")
    altitude_m: float = Field(description="flight height: above the terrain or above the WGS-84 "
                              "ellipsoid, per altitude_mode")
    altitude_mode: Literal["above_ground", "absolute"]
    max_climb_mps: float | None = Field(None, gt=0, description="above_ground: largest climb "
                                        "rate; with max_descent_mps the UAV flies the lowest "
                                        "profile at least altitude_m above the ground that "
                                        "keeps within both (omitted: follows the ground "
                                        "exactly)")
    max_descent_mps: float | None = Field(None, gt=0, description="above_ground: largest "
                                          "descent rate")
    endurance_s: float | None = Field(None, gt=0, description="longest flight the platform can "
                                      "make (a run warns beyond it; plan keeps within it)")
    turn_radius_m: float | None = Field(None, gt=0, description="smallest turn radius: the "
                                        "path turns at its waypoints; plan refuses lines "
                                        "closer than twice it (no U-turn between them)")

    @model_validator(mode="after")
    def _climb_limits(self):
        if self.altitude_mode == "above_ground" and self.altitude_m <= 0:
            raise ValueError(f"platform.uav.altitude_m = {self.altitude_m:g} m with altitude_mode "
                             "= 'above_ground' is not above the ground: give a height > 0")
        if (self.max_climb_mps is None) != (self.max_descent_mps is None):
            raise ValueError("platform.uav.max_climb_mps and max_descent_mps go together")
        if self.max_climb_mps is not None and self.altitude_mode != "above_ground":
            raise ValueError("platform.uav.max_climb_mps / max_descent_mps shape an "
                             "above_ground profile (altitude_mode = 'above_ground')")
        return self


class AircraftPlatform(_Survey2D):
    speed_mps: float = Field(gt=0, description="ground speed")
    altitude_m: float = Field(description="flight height above the WGS-84 ellipsoid")
    turn_radius_m: float = Field(gt=0, description="radius of the turns joining the lines")
    endurance_s: float | None = Field(None, gt=0, description="longest flight the platform can "
                                      "make (a run warns beyond it; plan keeps within it)")


class OrbitPlatform(_Model):
    """Keplerian elements with J2 drift; the orbit is placed so its nadir point passes the scene
    centre at t = 0 (the RAAN and the anomaly are solved for, on the chosen pass)."""

    altitude_m: float = Field(gt=100e3, le=36_000e3, description="height of the satellite "
                              "above the WGS-84 ellipsoid where its nadir crosses the scene "
                              "centre (t = 0); low Earth orbit up to geostationary height")
    eccentricity: float = Field(ge=0, lt=0.1)
    inclination_deg: float = Field(gt=0, lt=180)
    pass_direction: Literal["ascending", "descending"]
    j2: bool = Field(True, description="secular J2 drift of the node and perigee")


class TlePlatform(_Model):
    """A two-line element set propagated with SGP4; the run's t = 0 is ``survey.epoch_utc``,
    which must lie within ``TLE_MAX_AGE_DAYS`` of the element set's epoch."""

    line1: str = Field(description="TLE line 1 (69 characters, with its checksum)")
    line2: str = Field(description="TLE line 2 (69 characters, with its checksum)")


class Platform(_Model):
    kind: Literal["uav", "aircraft", "satellite"]
    uav: UavPlatform | None = None
    aircraft: AircraftPlatform | None = None
    orbit: OrbitPlatform | None = None
    tle: TlePlatform | None = None

    @model_validator(mode="after")
    def _one_kind(self):
        given = [k for k in ("uav", "aircraft", "orbit", "tle") if getattr(self, k) is not None]
        wanted = {"uav": ["uav"], "aircraft": ["aircraft"],
                  "satellite": [["orbit"], ["tle"]]}[self.kind]
        ok = given in wanted if self.kind == "satellite" else given == wanted
        if not ok:
            need = "[platform.orbit] or [platform.tle]" if self.kind == "satellite" \
                else f"[platform.{self.kind}]"
            raise ValueError(f"platform.kind = '{self.kind}' needs exactly {need}; "
                             f"found {['platform.' + g for g in given] or 'none'}")
        return self


class AttitudeConfig(_Model):
    """Platform attitude (intrinsic Z-Y-X: yaw, pitch, roll) and pointing jitter."""

    roll_deg: float
    pitch_deg: float
    yaw_deg: float
    jitter_rad_rms: float = Field(ge=0, description="pointing jitter per axis (rms)")
    doppler_steering: bool = Field(False, description="pitch every shot so its beams are "
                                   "perpendicular to the velocity (zero Doppler shift, as "
                                   "ICESat-2 steers), on top of pitch_deg")


class Beams(_Model):
    """Beam pattern: nadir, three ICESat-2-like pairs, a conical scan, or a custom list."""

    pattern: Literal["nadir", "paired", "conical", "custom"]
    pair_spacing_deg: float | None = Field(None, gt=0, description="paired: across-track angle "
                                           "between pair centres")
    within_pair_deg: float | None = Field(None, gt=0, description="paired: angle between the "
                                          "two beams of a pair")
    stagger_deg: float = Field(0.0, ge=0, description="paired: along-track angle between the "
                               "two beams of a pair (the left one ahead)")
    pair_power_ratio: float = Field(1.0, gt=0, description="paired: transmitted power of each "
                                    "pair's left (strong) beam over its right (weak) one")
    cone_half_angle_deg: float | None = Field(None, gt=0, lt=60, description="conical: "
                                              "off-nadir angle")
    scan_rate_deg_s: float | None = Field(None, description="conical: azimuth rate")
    off_nadir_deg: tuple[float, ...] | None = Field(None, max_length=MAX_BEAMS,
                                                    description="custom: per beam")
    azimuth_deg: tuple[float, ...] | None = Field(None, max_length=MAX_BEAMS,
                                                  description="custom: per beam, from "
                                                  "the flight direction towards the right")

    @model_validator(mode="after")
    def _needs(self):
        need = {"nadir": (), "paired": ("pair_spacing_deg", "within_pair_deg"),
                "conical": ("cone_half_angle_deg", "scan_rate_deg_s"),
                "custom": ("off_nadir_deg", "azimuth_deg")}[self.pattern]
        missing = [k for k in need if getattr(self, k) is None]
        if missing:
            raise ValueError(f"beams.pattern = '{self.pattern}' needs "
                             f"{', '.join('beams.' + k for k in missing)}")
        if self.pattern == "paired":
            if self.within_pair_deg >= self.pair_spacing_deg:
                raise ValueError(f"beams.within_pair_deg ({self.within_pair_deg:g}) must be "
                                 f"smaller than beams.pair_spacing_deg ({self.pair_spacing_deg:g})"
                                 ": the pairs would overlap")
            widest = self.pair_spacing_deg + self.within_pair_deg / 2 + self.stagger_deg
            if widest >= 60:
                raise ValueError(f"beams.pair_spacing_deg + within_pair_deg / 2 + stagger_deg "
                                 f"= {widest:g} deg: the outer beams must stay within 60 deg of "
                                 "nadir (as custom and conical beams)")
        if self.pattern == "custom":
            if len(self.off_nadir_deg) != len(self.azimuth_deg) or not self.off_nadir_deg:
                raise ValueError("beams.off_nadir_deg and beams.azimuth_deg must be non-empty "
                                 "lists of equal length")
            if any(not 0 <= a < 60 for a in self.off_nadir_deg):
                raise ValueError("beams.off_nadir_deg must lie in [0, 60) degrees")
        return self


def _utc(text: str):
    import datetime as _dt

    return _dt.datetime.fromisoformat(text.replace("Z", "+00:00"))


class SurveyRun(_Model):
    """What to run: shot clock, time span, tier, detection, footprint sampling, chunking."""

    tier: Literal["link", "baseband", "rf"]
    prf_hz: float = Field(gt=0, description="record (shot) rate; each record averages "
                          "processing.averages chirps (sys.avg)")
    start_s: float | None = Field(None, description="first shot time, s after the path start "
                                  "(UAV, aircraft) or after epoch_utc (satellite: a design "
                                  "orbit's nadir crosses the scene centre then)")
    stop_s: float | None = Field(None, description="end of the span; omitted = the end of the "
                                 "path (UAV, aircraft only)")
    epoch_utc: str = Field(description="ISO 8601 UTC date-time of t = 0 (the results' time origin)")
    start_utc: str | None = Field(None, description="satellite campaign: window start (ISO 8601 "
                                  "UTC); the run flies every pass over the scene until stop_utc, "
                                  "instead of start_s..stop_s")
    stop_utc: str | None = Field(None, description="satellite campaign: window end (ISO 8601 "
                                 "UTC)")
    detection_threshold_db: float = Field(description="SNR in the RBW a return needs to count "
                                          "as detected (the thesis quotes sensitivity at 10 dB)")
    doppler_compensation: Literal["none", "lo_offset"] = Field(
        "none", description="'lo_offset': each beam's local oscillator is shifted by the Doppler "
        "shift predicted from the platform velocity and the beam's nominal pointing (an "
        "acousto-optic shifter per beam), leaving what pointing jitter adds; 'none': the "
        "shift acts (see also attitude.doppler_steering)")
    range_window_m: float | None = Field(None, gt=0, description="width of the range window: "
                                         "the reference delay follows each beam's range "
                                         "predicted to the scene's mid-height surface, as an "
                                         "altimeter's range gate does; returns outside it are "
                                         "flagged (omitted: system.reference_delay_s or its "
                                         "sys.fmaxopt rule)")
    subrays_per_beam: int = Field(ge=1, le=512, description="footprint samples per beam")
    chunk_shots: int = Field(20000, ge=1, le=MAX_CHUNK_SHOTS, description="shots per chunk "
                             "(memory bound and "
                             "resume granularity)")

    @field_validator("epoch_utc", "start_utc", "stop_utc", mode="before")
    @classmethod
    def _epoch(cls, v):
        import datetime as _dt

        if v is None:
            return v
        if isinstance(v, _dt.datetime):   # --set survey.epoch_utc=2026-08-15T12:00:00Z (TOML)
            if v.tzinfo is None:
                raise ValueError(f"give the time zone (a Z for UTC): {v.isoformat()}")
            v = v.astimezone(_dt.timezone.utc).isoformat().replace("+00:00", "Z")
        if not isinstance(v, str):
            raise ValueError(f"expected an ISO 8601 date-time string, got {v!r}")
        try:
            t = _dt.datetime.fromisoformat(v.replace("Z", "+00:00"))
        except ValueError:
            raise ValueError(f"not an ISO 8601 date-time: {v!r}") from None
        if t.tzinfo is None:
            raise ValueError(f"give the time zone (a Z for UTC): {v!r}")
        return v

    @model_validator(mode="after")
    def _span(self):
        if (self.start_utc is None) != (self.stop_utc is None):
            raise ValueError("survey.start_utc and survey.stop_utc go together (a campaign "
                             "window)")
        if self.start_utc is not None:
            if _utc(self.stop_utc) <= _utc(self.start_utc):
                raise ValueError(f"survey.stop_utc ({self.stop_utc}) is not after "
                                 f"survey.start_utc ({self.start_utc})")
            return self
        if self.start_s is None:
            raise ValueError("survey.start_s is required (or, for a satellite, a campaign "
                             "window: survey.start_utc and stop_utc)")
        if self.stop_s is not None and self.stop_s < self.start_s:
            raise ValueError(f"survey.stop_s ({self.stop_s}) is before survey.start_s "
                             f"({self.start_s})")
        return self


class MissionConfig(_Model):
    """A whole transceiver configuration (the ``instrument`` of a mission)."""

    simulation: Simulation
    system: System
    processing: Processing
    waveform: Waveform
    laser: Laser
    modulator: Modulator
    transmitter: Transmitter
    channel: Channel
    apd: APD
    balanced: Balanced
    pin: PIN
    heterodyne: Heterodyne
    effects: Effects = Effects()
    sweep: Sweep = Sweep()
    seed: int = Field(ge=0, le=MAX_SEED, description="seed of the run's numpy Generator")
    # Survey (chirplidar run): optional for transceiver-only files.
    scene: SceneRef | None = None
    platform: Platform | None = None
    attitude: AttitudeConfig | None = None
    beams: Beams | None = None
    survey: SurveyRun | None = None

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
    def _weak_turbulence(self):
        ch = self.channel
        if "turbulence" in self.effects.enabled and ch.free_space and ch.cn2_m_minus_2_3 > 0:
            from ..atmosphere.turbulence import rytov_variance

            sigma2 = float(rytov_variance(ch.cn2_m_minus_2_3, self.laser.wavelength_m,
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
        lw_on = self.laser.linewidth_hz > 0
        if lw_on != ("phase_noise" in self.effects.enabled):
            raise ValueError(
                "laser.linewidth_hz (lsr.Lw) > 0 needs 'phase_noise' in effects.enabled, and "
                "'phase_noise' needs a linewidth > 0: the list is the one switch for each effect "
                f"(linewidth {self.laser.linewidth_hz:g} Hz, enabled {list(self.effects.enabled)})")
        if self.survey is not None:
            record_rate = 1.0 / (self.processing.averages * self.waveform.chirp_period_s)
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

"""Deterministic quantities shared by every tier: powers, delays, beat frequency, scales.

Computed once per (instrument, returns), so the tiers cannot disagree on them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..receiver import COUPLER_3DB, HYBRID_90
from ..transmitter.mzm import mzm_mean_power_transmission
from ..units import PLANCK_J_S, SPEED_OF_LIGHT_M_S, db_to_ratio, responsivity_a_per_w
from ..waveform import ChirpTrain, Waveform
from .model import Instrument, Returns

#: The heterodyne IF band-pass half-width as a multiple of the chirp's top frequency.
IF_HALF_WIDTH_FACTOR = 1.25


@dataclass(frozen=True)
class Budget:
    train: Waveform
    nu_hz: float  # optical frequency c / lambda
    mzm_mean_transmission: float  # <cos^2(pi V / 2 V_pi)> over a period
    pchrp_w: float  # generator power into the modulator while chirping
    tx_gain: float  # transmit arm power gain after the modulator (split, amplifier)
    ptx_w: float  # mean transmitted optical power (signal)
    ase_psd_w_per_hz: float  # ASE PSD at the transmitter output (one polarisation), 0 if none
    h: float  # channel power transmission
    psig_w: float  # mean received optical power
    delay_s: float  # round-trip delay tau
    ref_delay_s: float  # reference (LO / dechirp) delay tau_ref
    lag_s: float  # tau - tau_ref reduced to [0, period)
    f_beat_hz: float  # kappa * lag (FM) ; 0 for PN
    rate_hz_per_s: float
    group_index: float
    quantized: bool

    def lo_power_scale(self, lo_power_w: float) -> float:
        """The LO power over the modulator's mean transmission: the power of the LO field
        whose modulated mean is ``lo_power_w`` (the LO is a tap of the modulated laser). Zero
        when the modulator transmits nothing (biased at null without a drive): no LO either."""
        t = self.mzm_mean_transmission
        return lo_power_w / t if t > 0 else 0.0

    @property
    def d_offset_m(self) -> float:
        return SPEED_OF_LIGHT_M_S * self.ref_delay_s / (2.0 * self.group_index)

    def range_from_lag_m(self, lag_s):
        return (
            SPEED_OF_LIGHT_M_S * (np.asarray(lag_s) + self.ref_delay_s) / (2.0 * self.group_index)
        )


def chirp_train(train: Waveform) -> ChirpTrain:
    """``train`` as a chirp, for what only a chirp has (its frequencies, rate and phase). The
    callers run for fm_chirp only: their tier's Supports or the configuration refuse a code."""
    if not isinstance(train, ChirpTrain):
        raise RuntimeError(f"a chirp train is needed here; got {type(train).__name__}")
    return train


def reference_delay_s(instrument: Instrument, delay_s, rate_hz_per_s: float):
    """Reference delay: explicit, or the ``sys.fmaxopt`` rule (delay the reference until the beat
    falls to ``max_beat_frequency_hz``; zero when it already does). ``delay_s`` may be an array
    (one per shot: the rule then tracks each shot's range, as a range-gate tracker would)."""
    config = instrument
    if config.system.reference_delay_s is not None:
        return np.full(np.shape(delay_s), config.system.reference_delay_s)[()]
    if config.system.modulation == "pn_code":
        return np.zeros(np.shape(delay_s))[()]
    f_max = config.system.max_beat_frequency_hz
    return np.maximum(0.0, np.asarray(delay_s, float) - f_max / rate_hz_per_s)[()]


def make_budget(instrument: Instrument, returns: Returns) -> Budget:
    """The budget of ``instrument`` on the mean return of ``returns`` (its transmission, delay
    and group index; the range gate ``returns.reference_delay_s`` when a tracker set one)."""
    config = instrument
    train = instrument.train
    nu = SPEED_OF_LIGHT_M_S / config.laser.wavelength_m
    m2 = mzm_mean_power_transmission(train, config.modulator.bias_v, config.modulator.v_pi_v)
    ri = config.modulator.input_impedance_ohm
    pchrp = train.amplitude_v**2 / (2.0 * ri) + train.dc_v**2 / ri
    tx = config.transmitter
    gain = float(db_to_ratio(-tx.tx_split_loss_db))
    ase = 0.0
    if tx.amplifier:
        g = float(db_to_ratio(tx.amplifier_gain_db))
        f_noise = float(db_to_ratio(tx.amplifier_noise_figure_db))
        # S_ASE = n_sp h nu (G - 1) with F = (2 n_sp (G - 1) + 1) / G  =>  S = (F G - 1) h nu / 2.
        ase = max(f_noise * g - 1.0, 0.0) * PLANCK_J_S * nu / 2.0
        gain *= g
    ptx = config.laser.power_w * m2 * gain
    h = returns.transmission
    delay = returns.delay_s
    rate = train.rate_hz_per_s if hasattr(train, "rate_hz_per_s") else 0.0
    ref = (
        float(returns.reference_delay_s)
        if returns.reference_delay_s is not None
        else float(reference_delay_s(instrument, delay, rate if rate else 1.0))
    )
    quantized = config.simulation.delay_method == "resample"
    if quantized:
        q = 1.0 / (config.simulation.sample_rate_hz * config.simulation.upsample_factor)
        delay, ref = round(delay / q) * q, round(ref / q) * q
    lag = float(np.mod(delay - ref, train.period_s))
    return Budget(
        train=train,
        nu_hz=nu,
        mzm_mean_transmission=m2,
        pchrp_w=pchrp,
        tx_gain=gain,
        ptx_w=ptx,
        ase_psd_w_per_hz=ase,
        h=h,
        psig_w=ptx * h,
        delay_s=delay,
        ref_delay_s=ref,
        lag_s=lag,
        f_beat_hz=rate * lag,
        rate_hz_per_s=rate,
        group_index=returns.group_index,
        quantized=quantized,
    )


def responsivities(config: Instrument, nu_hz: float) -> dict[str, float]:
    lam = SPEED_OF_LIGHT_M_S / nu_hz
    return {
        "balanced_1": responsivity_a_per_w(config.balanced.quantum_efficiency_1, lam),
        "balanced_2": responsivity_a_per_w(config.balanced.quantum_efficiency_2, lam),
        "pin": responsivity_a_per_w(config.pin.quantum_efficiency, lam),
        "apd": responsivity_a_per_w(config.apd.quantum_efficiency, lam),
        "heterodyne": responsivity_a_per_w(config.heterodyne.quantum_efficiency, lam),
    }


def coupler_field_transmission(config: Instrument) -> float:
    """Field factor of the receiver coupler's excess loss (applies to LO and signal alike)."""
    return float(np.sqrt(db_to_ratio(-config.balanced.coupler_excess_loss_db)))


def receiver_coupler(config: Instrument, mode: str) -> np.ndarray:
    """Field matrix S of the coherent receiver's coupler with its excess loss (S[j, 0]: the LO,
    S[j, 1]: the signal into arm j): the 3 dB coupler of the balanced homodyne pair, else the
    90-degree hybrid of phase diversity (thesis Appendix C)."""
    return (COUPLER_3DB if mode == "homodyne" else HYBRID_90) * coupler_field_transmission(config)


def arm_cross(S: np.ndarray, r) -> tuple[complex, complex]:
    """The arms' cross coefficients c_j = r_j S_j0 S_j1* (arm j's current holds
    2 Re(c_j E_LO E_s*), :func:`~chirplidar.receiver.fields.port_power`), ``r`` the arms'
    responsivities."""
    return (complex(r[0] * S[0, 0] * np.conj(S[0, 1])), complex(r[1] * S[1, 0] * np.conj(S[1, 1])))


def if_half_width_hz(config: Instrument, bud: Budget) -> float:
    """Half-width of the heterodyne IF band-pass around f_LO (the validated band)."""
    return IF_HALF_WIDTH_FACTOR * chirp_train(bud.train).f_stop_hz

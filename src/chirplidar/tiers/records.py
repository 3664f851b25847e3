"""A batch of records through the receiver's processing, shared by the rf and baseband tiers:
squaring (Appendix D) or the combining DSP's Doppler compensation, PN correlation (Fig. 2.3) or
the spectrum's peak, the phase-diversity arms; then the Table 4.10 outputs
(:func:`~chirplidar.tiers.common.finish_outputs`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.fft

from ..processing import analyze_records
from ..processing.spectrum import PeakResult, parabolic_vertex
from ..receiver.fpa import compensate, estimate_doppler_hz
from .common import finish_outputs
from .model import Instrument, Measurements, Returns, UnsupportedError


def pn_peak(v: np.ndarray, ref: np.ndarray, fs: float, load: float, proc):
    """Cross-correlation ranging for PN codes (thesis Fig. 2.3).

    Returns a PeakResult whose ``f_peak_hz`` holds the lag in seconds (the caller converts), the
    SNR as matched-filter peak power over the mean off-peak correlation power, and Crx as the
    detected code power.
    """
    v = np.asarray(v).mean(axis=1) if proc.averaging == "coherent" else np.asarray(v)[:, 0]
    n = v.shape[-1]
    C = scipy.fft.irfft(scipy.fft.rfft(v, axis=-1) * np.conj(scipy.fft.rfft(ref)), n=n, axis=-1)
    energy = float(np.sum(ref * ref))
    lags, lo, hi, peak_w, noise_w, snr = (np.empty(v.shape[0]) for _ in range(6))
    for b in range(v.shape[0]):
        c2 = C[b] ** 2
        k = int(np.argmax(c2))
        d = parabolic_vertex(*np.log(np.maximum(c2[[k - 1, k, (k + 1) % n]], 1e-300)))
        lags[b] = (k + d) / fs
        half = 0.5 * c2[k]
        left = k
        while c2[left - 1] >= half and k - left < n // 2:
            left -= 1
        right = k
        while c2[(right + 1) % n] >= half and right - k < n // 2:
            right += 1
        lo[b], hi[b] = (left - 0.5) / fs, (right + 0.5) / fs
        guard = np.ones(n, bool)
        guard[np.arange(k - 8, k + 9) % n] = False
        off = float(np.mean(c2[guard]))
        snr[b] = c2[k] / off
        amp = C[b, k] / energy
        peak_w[b] = amp**2 * energy / n / load
        noise_w[b] = peak_w[b] / snr[b] / proc.rbw_hz
    return PeakResult(
        f_peak_hz=lags,
        peak_power_w=peak_w,
        noise_psd_w_per_hz=noise_w,
        f_lo_hz=lo,
        f_hi_hz=hi,
        snr=snr,
    )


def _squared_records(config, records: dict, flags: list, kw: dict, fs_hz: float) -> dict:
    """Doppler recovery by squaring (thesis Appendix D): the records squared, their mean
    removed; y^2 holds (1/4) cos(2 w_B t), independent of the Doppler shift, so the search
    band in ``kw`` moves to 2 f_R. Adds the ``squaring_recovery`` flag."""
    proc, sysc = config.processing, config.system
    homodyne = sysc.receiver == "coherent" and sysc.coherent_mode == "homodyne"
    if "main" not in records or not homodyne or sysc.modulation != "fm_chirp":
        raise ValueError(
            "processing.doppler_recovery = 'squaring' applies to the self-chirped "
            "homodyne FM receiver (thesis Appendix D)"
        )
    y = records["main"]
    squared = {"main": y * y - np.mean(y * y, axis=-1, keepdims=True)}
    if "squaring_recovery" not in flags:
        flags.append("squaring_recovery")
    kw["highpass_hz"] = 2 * max(proc.highpass_hz, proc.doppler_max_hz)
    kw["search_max_hz"] = min(2 * kw["search_max_hz"], fs_hz / 2)
    return squared


#: FFT padding of the Doppler estimate's power spectrum: with the parabolic interpolation of its
#: self-convolution the estimate's grid error is a small fraction of fs / (2 N x 2) (2.4 kHz on
#: the Chapter 5 bench), against the 1 / T_ov (28 kHz there) that would split the folded line.
DSP_ZERO_PAD = 2


def arms_to_complex(x1, x2, arm_cross) -> np.ndarray:
    """The complex record Y of the phase-diversity arms x_j = 2 Re(c_j Y) (+ direct terms).

    c_j = r_j S_j0 S_j1* is arm j's cross coefficient (responsivity times the hybrid's field
    coefficients of the LO and the signal; thesis Appendix C, eq. 5.5) and Y = E_LO E_s* the
    optical product: (x1, x2) = 2 M (Re Y, Im Y), M = ((Re c1, -Im c1), (Re c2, -Im c2)),
    inverted.
    The system is singular for in-phase arms (a balanced 3 dB pair: c2 = -c1), which carry one
    quadrature only.
    """
    c = np.asarray(arm_cross, complex)
    m = 2.0 * np.array([[c[0].real, -c[0].imag], [c[1].real, -c[1].imag]])
    if abs(np.linalg.det(m)) <= 1e-9 * float(np.sum(m * m)):
        raise ValueError(
            "processing.doppler_recovery = 'dsp': the two arms read the same quadrature "
            "(no complex record); it needs the 90-degree hybrid of system.coherent_mode = "
            "'phase_diversity'"
        )
    inv = np.linalg.inv(m)
    return (inv[0, 0] * x1 + inv[0, 1] * x2) + 1j * (inv[1, 0] * x1 + inv[1, 1] * x2)


def dsp_compensated_arms(
    records: dict, arm_cross, fs_hz: float, band_hz: tuple[float, float], transfer
) -> tuple[dict, np.ndarray]:
    """Doppler compensation in the combining DSP of the phase-diversity (I/Q) receiver.

    Thesis Appendix D: with Doppler the optical product is Y(t) = C(t) exp(j (2 pi f_d t + phi)),
    C real holding the beat at f_R, so the complex record has two lines at f_d +- f_R. Steps:

    1. Y from the arms (:func:`arms_to_complex`), through the detector response ``transfer``
       (H(f) on signed frequencies: each real arm is filtered by it) and band-passed to the
       processed band f_lo <= |f| <= f_hi (``band_hz``): the arms' own LO and signal powers
       (DC, the chirp envelope, at and above the chirp's start frequency; Appendix C band-passes
       them out) would otherwise move into the band with the compensation.
    2. f_d per shot from all its records (``receiver.fpa.estimate_doppler_hz``, the centre of
       symmetry of their summed power spectra), removed: Y' = Y exp(-j 2 pi f_d t)
       (``receiver.fpa.compensate``).
    3. Split back into arms x_j' = 2 Re(c_j Y'). Their summed spectra are the folded spectrum
       2 (|X1'|^2 + |X2'|^2) ~ |Y'(f)|^2 + |Y'(-f)|^2 of the zero-Doppler record: one line at f_R.
       A residual error delta of the estimate splits it symmetrically into f_R +- delta: no
       first-order range bias.

    Valid while both lines f_d +- f_R lie in the processed band (else a line is filtered out
    and the estimate has no pair to centre on: ``tiers.common.dsp_doppler_unlocked``).
    ``records``: {"arm1", "arm2"} (batch, records, N) volts. Returns the compensated arms (in
    the records' dtype, with the detector response applied) and f_d [Hz] per shot (batch,).
    """
    x1, x2 = records["arm1"], records["arm2"]
    n = x1.shape[-1]
    y = scipy.fft.fft(arms_to_complex(x1, x2, arm_cross), axis=-1, workers=-1)
    f = scipy.fft.fftfreq(n, 1.0 / fs_hz)
    lo, hi = band_hz
    gain = np.where((np.abs(f) >= lo) & (np.abs(f) <= hi), 1.0, 0.0).astype(complex)
    if transfer is not None:
        gain *= transfer(f)  # H(-f) = H(f)*: a real filter on each arm
    y = scipy.fft.ifft(y * gain, axis=-1, workers=-1)
    f_d = estimate_doppler_hz(y, fs_hz, method="symmetry", zero_pad=DSP_ZERO_PAD)
    y = compensate(y, f_d, fs_hz)
    c = np.asarray(arm_cross, complex)
    arms = {k: (2.0 * np.real(c[j] * y)).astype(x1.dtype) for j, k in enumerate(("arm1", "arm2"))}
    return arms, f_d


def _analyze_arms(
    records: dict,
    fs_hz: float,
    load_ohm: float,
    averaging: str,
    keep_spectrum: bool,
    kw: dict,
    extra: dict,
) -> PeakResult:
    """The phase-diversity arms: each arm's peak (into ``extra``: ``arm1_Crx_w``, ``arm1_snr``,
    ...) and the peak of their summed spectra."""
    r1 = analyze_records(records["arm1"], fs_hz, load_ohm, averaging=averaging, **kw)
    r2 = analyze_records(records["arm2"], fs_hz, load_ohm, averaging=averaging, **kw)
    both = (
        np.concatenate([records["arm1"], records["arm2"]], axis=1)
        if averaging == "power"
        else np.stack([records["arm1"].mean(axis=1), records["arm2"].mean(axis=1)], axis=1)
    )
    result = analyze_records(
        both, fs_hz, load_ohm, averaging="power", keep_spectrum=keep_spectrum, **kw
    )
    # Power averaging halves the sum of the arms' spectra (thesis Fig. 5.13 sums them):
    # report the sums; the SNR is unchanged.
    extra.update(
        {
            "arm1_Crx_w": r1.peak_power_w,
            "arm2_Crx_w": r2.peak_power_w,
            "arm1_snr": r1.snr,
            "arm2_snr": r2.snr,
        }
    )
    return dataclasses.replace(
        result,
        peak_power_w=2 * result.peak_power_w,
        noise_psd_w_per_hz=2 * result.noise_psd_w_per_hz,
    )


def analyze_block(
    config,
    records: dict,
    load_ohm: float,
    flags: list,
    *,
    fs_hz: float,
    transfer,
    search_max_hz: float,
    keep_spectrum: bool,
    pn_reference=None,
    spectrum_analyzer=None,
    averaging: str | None = None,
    arm_cross=None,
) -> tuple[PeakResult, dict]:
    """The receiver's processing of a block of shots, shared by the rf and baseband tiers:
    optional squaring (Appendix D) or DSP Doppler compensation (:func:`dsp_compensated_arms`),
    PN correlation or spectrum peak analysis, the phase-diversity arms' summed spectra. Returns
    the peak result and the extra per-shot outputs (the arms').

    ``records``: {"main": (batch, averages, N)} volts, or {"arm1", "arm2"} for phase diversity.
    ``spectrum_analyzer`` (optional) replaces :func:`analyze_records` for "main" records with the
    same keyword interface (the baseband tier's direct draw of power-averaged spectra).
    ``averaging`` (optional) replaces ``processing.averaging`` (the baseband tier's FPA pixels
    summed in power).
    ``arm_cross``: the arms' cross coefficients (c_1, c_2), arm j = 2 Re(c_j E_LO E_s*) (A/W),
    needed by ``processing.doppler_recovery = "dsp"``.
    """
    proc, sysc = config.processing, config.system
    averaging = averaging or proc.averaging
    extra: dict[str, np.ndarray] = {}
    analyze_main = spectrum_analyzer or analyze_records
    kw = dict(
        rbw_hz=proc.rbw_hz,
        highpass_hz=proc.highpass_hz,
        zero_pad=proc.zero_pad_factor,
        peak_method=proc.peak_method,
        noise_span_hz=proc.noise_span_hz,
        noise_guard_hz=proc.noise_guard_hz,
        transfer=transfer,
        search_max_hz=search_max_hz,
    )
    squaring = proc.doppler_recovery == "squaring"
    if squaring:
        records = _squared_records(config, records, flags, kw, fs_hz)
    if proc.doppler_recovery == "dsp":
        if "arm1" not in records or arm_cross is None:
            raise ValueError(
                "processing.doppler_recovery = 'dsp' needs the phase-diversity arms and their "
                "cross coefficients (system.coherent_mode = 'phase_diversity')"
            )
        band = (kw["highpass_hz"], kw["search_max_hz"])
        records, _ = dsp_compensated_arms(records, arm_cross, fs_hz, band, kw["transfer"])
        kw["transfer"] = None  # applied to the arms before the compensation
    if sysc.modulation == "pn_code":
        # PN ranging: cross-correlate the detected code with the reference code (Fig. 2.3).
        return pn_peak(records["main"], pn_reference, fs_hz, load_ohm, proc), extra
    if "main" in records:
        result = analyze_main(
            records["main"],
            fs_hz,
            load_ohm,
            averaging=averaging,
            keep_spectrum=keep_spectrum,
            **kw,
        )
    else:
        result = _analyze_arms(records, fs_hz, load_ohm, averaging, keep_spectrum, kw, extra)
    if squaring:
        # The line found is 2 f_R; its power and SNR are those of the squared record.
        result = dataclasses.replace(
            result,
            f_peak_hz=result.f_peak_hz / 2,
            f_lo_hz=result.f_lo_hz / 2,
            f_hi_hz=result.f_hi_hz / 2,
        )
    return result, extra


def concatenate_blocks(blocks: list[tuple[PeakResult, dict]]) -> tuple[PeakResult, dict]:
    """The :func:`analyze_block` results of consecutive blocks as one batch."""
    if len(blocks) == 1:
        return blocks[0]
    results = [b[0] for b in blocks]
    fields = {}
    for f in dataclasses.fields(PeakResult):
        parts = [getattr(r, f.name) for r in results]
        if parts[0] is None or f.name == "spectrum_f_hz":
            fields[f.name] = parts[0]
        else:
            fields[f.name] = np.concatenate([np.atleast_1d(p) for p in parts], axis=0)
    extra = {k: np.concatenate([np.atleast_1d(b[1][k]) for b in blocks]) for k in blocks[0][1]}
    return PeakResult(**fields), extra


def process_records(
    config: Instrument,
    bud,
    records: dict,
    noise,
    load_ohm: float,
    flags: list,
    returns: Returns,
    *,
    fs_hz: float,
    transfer,
    search_max_hz: float,
    keep_spectrum: bool,
    tier: str,
    extra: dict | None = None,
    pn_reference=None,
    spectrum_analyzer=None,
    nyquist_hz=None,
    delay_offset_s=None,
    arm_cross=None,
) -> Measurements:
    """:func:`analyze_block` then :func:`finish_outputs` for one batch of records (``extra``:
    further per-shot outputs to report; ``arm_cross``: :func:`analyze_block`'s)."""
    result, arms = analyze_block(
        config,
        records,
        load_ohm,
        flags,
        fs_hz=fs_hz,
        transfer=transfer,
        search_max_hz=search_max_hz,
        keep_spectrum=keep_spectrum,
        pn_reference=pn_reference,
        spectrum_analyzer=spectrum_analyzer,
        arm_cross=arm_cross,
    )
    return finish_outputs(
        config,
        bud,
        result,
        {**(extra or {}), **arms},
        noise,
        flags,
        returns,
        tier=tier,
        nyquist_hz=nyquist_hz,
        delay_offset_s=delay_offset_s,
    )


def records_per_shot(config: Instrument) -> tuple[int, str]:
    """Records per shot and how their spectra combine: the ``processing.averages`` chirps, and
    an FPA combined incoherently sums its N^2 pixels' power spectra too. Each pixel is then a
    record at the combined SNR sum_k S_k / sum_k N_k (the channel's gain): the sum of K
    spectra sum_k |c_k s + n_k|^2 is noncentral chi-square with 2K degrees of freedom per bin,
    whose law depends on the total noncentrality sum_k |c_k|^2 / N only (pixels of equal noise
    N; an LO of unequal shares makes it an approximation)."""
    proc, rx = config.processing, config.receiver
    if rx is None or rx.architecture != "fpa" or rx.combining != "incoherent":
        return proc.averages, proc.averaging
    if proc.averaging == "coherent" and proc.averages > 1:
        raise UnsupportedError(
            "the baseband tier does not model an FPA combined incoherently after coherent "
            "averaging over chirps (processing.averaging = 'coherent', averages > 1): set "
            "processing.averaging = 'power', or fly --tier link"
        )
    return proc.averages * rx.pixel_count, "power"

"""The receiver stage: each shot's field across the pupil, focused and mixed with the LO of the
``[receiver]`` architecture (fiber, large detector, focal-plane array; thesis Ch. 6).

Per shot the pupil field is fully developed speckle of the footprint (``speckle`` enabled) or a
plane wave (a smooth target). The footprint is the far field of the transmit fiber's mode through
this telescope (``receiver.footprint = "monostatic"``, the field trial: Winzer & Leeb 1998,
``optics.focal_plane.monostatic_speckle_pupil_fields``) or the channel's Gaussian beam
(``"beam"``: the van Cittert-Zernike coherence radius rho = lambda R / (pi w) of the footprint
of radius w at range R, ``optics.focal_plane.speckle_pupil_fields``),
times a turbulence phase screen (``turbulence`` enabled: independent screens per shot, or one
screen moving past the aperture for ``fading = "frozen_flow"``), through the obstructed aperture.
It is normalised to the mean collected power (so the factor below keeps the speckle's power
fluctuation) and focused by the unitary Fraunhofer transform; the LO is normalised to unit
power over the whole focal plane (LO light beside the detector is lost).

Each detector k (one for the fiber and the large detector, N x N pixels for the FPA) reads the
beat a_k = int_k E_s E_LO* dA. Its SNR relative to the reference the tiers compute (the whole
mean collected power mixed perfectly with the whole LO on the configured balanced detector,
noise N_ref = shot + circuit) is

    g_k = |a_k|^2 N_ref / N_k,    N_k = shot_ref x P_LO,k + n_k,

P_LO,k the LO's share on detector k and n_k its own circuit noise and dark current (the
configured detector's for the fiber and the large detector; ``receiver.fpa.noise_a_per_rthz``
and ``dark_current_a`` for each FPA pixel; thesis Sec. 2.5). The FPA combines them: maximal ratio sum_k g_k (Brennan 1959; also for
``mrc_estimated``, whose estimation loss the link tier applies from the shot's SNR), selection
max_k g_k, incoherent sum_k |a_k|^2 N_ref / sum_k N_k. The result multiplies the shot's
``power_factor``; the beat's phase (one detector), relative to a plane wave's, adds to its
``phase_rad``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..optics import beam_radius_m, coupling_beta, pupil_grid
from ..optics.focal_plane import (
    fiber_mode_lo,
    flat_top_lo,
    focal_fields,
    gaussian_lo,
    monostatic_speckle_pupil_fields,
    speckle_coherence_radius_m,
    speckle_pupil_fields,
)
from ..receiver import COUPLER_3DB, HYBRID_90, fpa
from ..receiver.detectors import balanced_noise
from ..streams import child_stream
from ..tiers.budget import coupler_field_transmission, responsivities
from ..units import ELEMENTARY_CHARGE_C, SPEED_OF_LIGHT_M_S

_BLOCK_ELEMENTS = 1 << 22  # complex samples per block of shots (pupil + focal fields), 64 MiB
_FIBER_WINDOW_W0 = 4.5  # the fiber's focal window half-width in mode radii (the overlap's >= 4)
_DETAIL_SAMPLES = 4  # focal samples across a pixel's active side or the fiber's mode radius


@dataclass(frozen=True)
class ReceiverOptics:
    """A configuration's receiver geometry: pupil sampling, focal grid, the normalised LO, the
    detectors' layout and each detector's noise relative to the reference (``noise_ratio``)."""

    n_pupil: int
    aperture_m: float
    obstruction: float
    coherence_radius_m: float | None  # the beam footprint's rho; None for monostatic
    transmit_beta: float | None  # the monostatic transmit mode's beta (coupling_beta)
    u_m: np.ndarray
    lo: np.ndarray
    n_pixels: int
    pitch_m: float
    fill_factor: float
    shot_ratio: float  # shot_ref / N_ref: the LO's shot noise share of the reference noise
    circuit_ratio: float  # n_k / N_ref of each detector

    def noise_ratio(self, lo_share) -> np.ndarray:
        """N_k / N_ref for detectors holding ``lo_share`` of the LO's power."""
        return self.shot_ratio * np.asarray(lo_share, float) + self.circuit_ratio


def _reference_noise(config) -> tuple[float, float]:
    """(N_ref, its LO shot-noise part) [A^2/Hz] of the configured coherent receiver at its
    operating point, as the tiers read it: the balanced pair's difference current (homodyne),
    or the two unbalanced arms of the 90-degree hybrid summed (phase diversity, thesis
    Appendix C, whose spectra the tiers sum)."""
    nu = SPEED_OF_LIGHT_M_S / config.wavelength_m
    resp = responsivities(config, nu)
    r = (resp["balanced_1"], resp["balanced_2"])
    homodyne = config.system.coherent_mode == "homodyne"
    s = COUPLER_3DB if homodyne else HYBRID_90
    loss = coupler_field_transmission(config) ** 2
    p = [loss * abs(s[k, 0]) ** 2 * config.balanced.lo_power_w for k in (0, 1)]
    lo_shot = 2.0 * ELEMENTARY_CHARGE_C * (r[0] * p[0] + r[1] * p[1])
    if homodyne:
        return balanced_noise(config, *r, *p).total, lo_shot
    return sum(balanced_noise(config, *r, *p, arm=a).total for a in (0, 1)), lo_shot


def coherence_radius_m(config) -> float:
    """The beam footprint's speckle coherence radius in the pupil at ``channel.distance_m``."""
    ch = config.channel
    w = float(beam_radius_m(ch.beam_radius_m, ch.divergence_half_angle_rad, ch.distance_m))
    return float(speckle_coherence_radius_m(config.wavelength_m, ch.distance_m, w))


def receiver_optics(config) -> ReceiverOptics:
    """The receiver geometry of ``config`` (its ``[receiver]`` and channel)."""
    rx, ch = config.receiver, config.channel
    sub = rx.chosen
    d, lam, f = ch.telescope_diameter_m, config.wavelength_m, rx.focal_length_m
    monostatic = rx.footprint == "monostatic"
    rho = None if monostatic else coherence_radius_m(config)
    beta = coupling_beta(d, f, rx.transmit_mode_radius_m, lam) if monostatic else None
    if rx.architecture == "fiber":
        half, n_pix, fill = _FIBER_WINDOW_W0 * sub.mode_field_radius_m, 1, 1.0
        detail = sub.mode_field_radius_m
    elif rx.architecture == "large_detector":
        half, n_pix, fill, detail = 0.5 * sub.side_m, 1, 1.0, sub.side_m
    else:
        half, n_pix, fill = 0.5 * sub.pixels * sub.pitch_m, sub.pixels, sub.fill_factor
        detail = np.sqrt(fill) * sub.pitch_m
    # focal_sampling per lambda f / D, and at least _DETAIL_SAMPLES across the smallest
    # detector feature (a pixel's active side, the fiber mode radius).
    du = min(lam * f / (d * rx.focal_sampling), detail / _DETAIL_SAMPLES)
    m = int(np.ceil(half / du))
    u = (np.arange(2 * m + 1) - m) * du
    pitch = 2.0 * half / n_pix
    # The pupil samples resolve the speckle (3 per rho), the turbulence (2 per r0) and the
    # focal window (the focused field repeats every n lambda f / D).
    window_lfd = (2 * m + 1) * du * d / (lam * f)
    need = [32, 3.0 * d / rho if rho is not None and "speckle" in config.effects.enabled else 0.0,
            2.0 * window_lfd]
    if _turbulent(config):
        need.append(2.0 * _d_over_r0(config))
    n = int(rx.pupil_samples) if rx.pupil_samples is not None else int(np.ceil(max(need)))
    total, lo_shot = _reference_noise(config)
    if rx.architecture == "fpa":
        circuit = sub.noise_a_per_rthz**2 + 2.0 * ELEMENTARY_CHARGE_C * sub.dark_current_a
    else:
        circuit = total - lo_shot
    return ReceiverOptics(
        n_pupil=n, aperture_m=d, obstruction=rx.obstruction_ratio, coherence_radius_m=rho,
        transmit_beta=beta, u_m=u, lo=_lo_field(rx, u), n_pixels=n_pix, pitch_m=pitch,
        fill_factor=fill, shot_ratio=lo_shot / total, circuit_ratio=circuit / total)


def _lo_field(rx, u) -> np.ndarray:
    """The LO in the focal plane, normalised to unit power over the whole plane."""
    sub = rx.chosen
    if rx.architecture == "fiber":
        w0 = sub.mode_field_radius_m
        return fiber_mode_lo(u, w0) / np.sqrt(0.5 * np.pi * w0 * w0)
    r = sub.lo_radius_m
    if sub.lo_profile == "gaussian":
        return gaussian_lo(u, r) / np.sqrt(0.5 * np.pi * r * r)
    return flat_top_lo(u, r) / np.sqrt(np.pi * r * r)


def _turbulent(config) -> bool:
    return "turbulence" in config.effects.enabled and config.channel.cn2_m_minus_2_3 > 0


def _d_over_r0(config) -> float:
    from .effects import turbulence_d_over_r0

    return float(turbulence_d_over_r0(config))


def receiver_returns(config, returns, rng: np.random.Generator):
    """``returns`` (``effects.ShotReturns``) times each shot's receiver gain g (module
    docstring), plus the beat's phase for a single detector. ``rng``: the run's generator (its
    children ``effect.receiver_speckle`` and ``effect.receiver_turbulence`` are drawn)."""
    opt = receiver_optics(config)
    batch = returns.power_factor.size
    gain, phase = np.empty(batch), np.zeros(batch)
    screens = _screens(config, opt, child_stream(rng, "effect.receiver_turbulence"))
    speckle_rng = child_stream(rng, "effect.receiver_speckle")
    n, n_out = opt.n_pupil, opt.u_m.size
    step = max(1, _BLOCK_ELEMENTS // (2 * n * n + n * n_out + n_out * n_out))
    for s0 in range(0, batch, step):
        sl = slice(s0, min(batch, s0 + step))
        px = shot_pixels(config, opt, sl.stop - sl.start, speckle_rng,
                         None if screens is None else screens(sl))
        gain[sl], ph = _combine(config, opt, px)
        if ph is not None:
            phase[sl] = ph
    return dataclasses.replace(returns, power_factor=returns.power_factor * gain,
                               phase_rad=returns.phase_rad + phase)


def _screens(config, opt: ReceiverOptics, rng):
    """A function of a slice of shots giving their (k, n, n) phase screens, or None."""
    if not _turbulent(config):
        return None
    from ..atmosphere import MovingScreen, phase_screens

    t = config.effects.turbulence
    n, d = opt.n_pupil, opt.aperture_m
    r0 = d / _d_over_r0(config)
    if r0 < d / n:
        raise ValueError(f"turbulence: r0 = {r0:.3g} m is finer than the pupil sampling "
                         f"D / receiver.pupil_samples = {d / n:.3g} m; raise "
                         f"receiver.pupil_samples to at least {int(np.ceil(d / r0))}")
    if t.fading == "frozen_flow":
        screen = MovingScreen(n, d / n, r0, t.outer_scale_m, rng=rng)
        shift = t.transverse_speed_mps * t.shot_interval_s
        return lambda sl: screen.next_apertures(np.full(sl.stop - sl.start, shift))
    return lambda sl: phase_screens(sl.stop - sl.start, n, d / n, r0,
                                    outer_scale_m=t.outer_scale_m, rng=rng)


def _pupil_fields(config, opt: ReceiverOptics, k: int, rng, screen) -> np.ndarray:
    """(k, n, n) aperture-weighted pupil fields, mean collected power 1 (W)."""
    grid = pupil_grid(opt.n_pupil, opt.obstruction)
    if "speckle" in config.effects.enabled and opt.transmit_beta is not None:
        e = monostatic_speckle_pupil_fields(grid, opt.transmit_beta, rng, k,
                                            phase_screen_rad=screen)
    elif "speckle" in config.effects.enabled:
        e = speckle_pupil_fields(grid, opt.aperture_m, opt.coherence_radius_m, rng, k,
                                 phase_screen_rad=screen)
    else:
        e = np.broadcast_to(grid.weights.astype(complex), (k,) + grid.weights.shape)
        e = e * np.exp(1j * screen) if screen is not None else e.copy()
    return e / np.sqrt(grid.area * opt.aperture_m**2)


def shot_pixels(config, opt: ReceiverOptics, batch: int, rng: np.random.Generator,
                screen=None) -> fpa.PixelFields:
    """``batch`` shots' detectors: each one's beat a_k with the normalised LO, signal power
    (fraction of the mean collected power) and LO share (``receiver.fpa.PixelFields``,
    (batch, N, N)); ``screen``: their (batch, n, n) turbulence phases or None."""
    fields = _pupil_fields(config, opt, batch, rng, screen)
    ef, u = focal_fields(fields, opt.aperture_m / opt.n_pupil, config.wavelength_m,
                         config.receiver.focal_length_m, opt.u_m.size,
                         float(opt.u_m[1] - opt.u_m[0]))
    return fpa.pixelise(ef, opt.lo, u, opt.n_pixels, opt.pitch_m, opt.fill_factor)


def _combine(config, opt: ReceiverOptics, px) -> tuple[np.ndarray, np.ndarray | None]:
    """Each shot's gain g and, for one detector, the beat's phase (rad)."""
    rx = config.receiver
    k = opt.n_pixels**2
    beat = px.beat_w.reshape(-1, k)
    share = np.abs(beat) ** 2  # the pixels' tone over the ideal one
    noise = np.broadcast_to(opt.noise_ratio(px.lo_power_w.reshape(k)), share.shape)
    if rx.architecture != "fpa":
        # The phase relative to a plane wave's beat: focusing multiplies every field by -i
        # (focal_fields), a constant the receiver's tuning ("optimal" carrier phase) absorbs.
        return share[:, 0] / noise[:, 0], np.angle(1j * beat[:, 0])
    rule = {"incoherent": fpa.incoherent_snr, "selection": fpa.selection_snr}
    return rule.get(rx.combining, fpa.mrc_snr)(share, noise), None

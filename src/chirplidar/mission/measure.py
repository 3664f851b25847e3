"""Per-shot measurements of a survey chunk: the footprint's returns through the chosen tier.

Received power (every tier)
---------------------------
Each footprint sub-ray k (Gaussian beam weight w_k, true range R_k, incidence theta_k, material)
returns the power fraction

* Lambertian surfaces: (rho_k / pi) cos(theta_k) A / R_k^2 (``target.lambertian_power_fraction``),
* specular surfaces (open water): ``target.specular_return_fraction`` with the Cox-Munk slopes of
  the scene's wind,

and the shot receives P_tx sum_k w_k f_k, times the round-trip atmospheric transmission of the
scene (exponential atmosphere over the slant path), T_opt^2, ``channel.extra_attenuation_db`` and
the power factors of the scene's enabled effects (speckle, coupling, turbulence).

Link tier (whole campaigns)
---------------------------
The link tier's closed form (``tiers.link``) is evaluated on a grid of (range, extra attenuation)
nodes spanning the chunk, for an ideal reference target (rho = 1, normal incidence, fully
intercepted beam, no transmission losses); each shot's SNR is the bilinear interpolation in
(range, dB) at its own range and at the attenuation that turns the reference power into its own
received power. Node spacing: 1 % in range, 3 dB in attenuation (interpolation error < 0.05 dB:
the SNR in dB is smooth in both). The measured beat is drawn around the shot's beat with the
Cramer-Rao spread (Rife & Boorstyn 1974), as the link tier does.

Footprint spread: the power-weighted range spread sigma_R of the sub-rays spreads the beat over
sigma_f = kappa 2 n sigma_R / c. The link tier approximates the broadened line as a tone whose
width is the quadrature sum of the resolution width 0.886 / T_ov and the spread's FWHM
2.355 sigma_f: the peak SNR drops, and the effective duration shortens, by that width ratio g.
The measured range centres on the power-weighted mean range. (The baseband and rf tiers draw the
broadened line itself: see "Footprint echoes" below.)

Carrier phase. ``channel.carrier_phase = "random"`` (the field instrument's setting): the nodes
hold the mean over a uniform carrier phase; each shot's SNR takes its own fading factor
(``tiers.link.carrier_fading_factor``: 2 sin^2 psi for one homodyne record, averaged over the
record's K chirps in power), drawn on its own stream, as the rf and baseband tiers draw the phase
per chirp. Without it a K = 1 survey would detect shots near threshold by the mean SNR while the
other tiers fade (speckle x fading is chi-square of one degree of freedom, not exponential).
``"optimal"`` and ``"propagation"``: the nodes hold the optimum phase and each shot takes the
factor of its own static phase (``tiers.link.static_phase_factor``, sin^2 psi for the balanced
pair): the optimum, or -2 pi nu (tau - tau_ref) of the shot's own mean delay (a platform's range
moves by many wavelengths from shot to shot, so over a survey this is the arcsine law), plus the
speckle field's phase when that effect is on, as the other tiers add it: with speckle on, one
homodyne record then fades as chi-square of one degree of freedom whatever the setting (the
speckle field is circular: |z|^2 sin^2(psi + arg z) = (Im part)^2).

Footprint echoes (baseband and rf tiers)
----------------------------------------
The sub-rays sample the footprint; they are not scatterers, and their optical path differences
(2 k0 (R_k - R_l), thousands of wavelengths) must not interfere (summing them with amplitudes
sqrt(w_k) and their propagation phases gave up to (sum_k sqrt(w_k))^2 ~ 6.4 times the power on
flat snow with 7 sub-rays, or a fraction of it). ``footprint_echoes`` builds the echoes:

* speckle on: each sub-ray's patch returns its own speckle field sqrt(w_k) z_k
  (``subray_speckle_fields``: the speckle effect's draw per sub-ray, circular complex Gaussian
  for M = 1) at its own delay: mean power sum_k w_k, exponential for an unresolved footprint,
  the mean spectrum the power-weighted sum of the sub-rays' lines;
* speckle off: the mean return, deterministically: echoes on the chirp's resolution grid around
  the power-weighted mean delay, with the mean line's powers (``footprint_cells``) and one
  common phase, their record energy held at the mean power (``footprint_coherence``). An
  unresolved footprint is one echo of its whole power; a spread one draws the mean line.

Doppler (``doppler`` in the scene's effects): f_d = 2 v / lambda from each shot's closing speed
(platform velocity along the beam; the terrain is fixed in ECEF, so for satellites the ECEF
velocity already holds the Earth's rotation). A shift the record resolves (|f_d| >= 1 / T_ov)
splits the homodyne line (thesis Appendix D): the SNR takes the link tier's split factor and the
lines sit at |f_R + f_d| and |f_R - f_d| with equal power: the peak search takes one of those
inside the processed band (either, with equal chance, when both are), as the rf and baseband
tiers do through their noise. Such a range is off by f_d / kappa: unless
``processing.doppler_recovery`` recovers it (rf tier), the return is flagged
``doppler_displaced`` (``detected = 4``) whenever the record resolves it (|f_d| T_ov >= 1, T_ov
the chirps' overlap at the shot's lag).
``attitude.doppler_steering`` removes the shift at its source (beams in the body's across-track
plane perpendicular to the velocity); ``survey.doppler_compensation = "lo_offset"`` shifts each
beam's LO by its predicted Doppler (``ChunkGeometry.doppler_speed_mps`` is what is left).

Range window (``survey.range_window_m`` = W)
--------------------------------------------
As an altimeter's range gate, the reference delay follows each beam's range R_p predicted to the
scene's mid-height surface (:attr:`survey.ChunkGeometry.range_predicted_m`): returns with a mean
range in [R_p - W/2, R_p + W/2] beat between the high-pass corner f_hp and f_hp + kappa 2 n W / c,
which must lie in the processed band (:func:`check_range_window`):

    tau_ref = 2 n (R_p - W / 2) / c - f_hp / kappa

A return outside the window is flagged ``outside_range_gate`` (``detected = 3``): the
instrument does not look there, and its beat would alias or leave the band.

Without a window the reference delay is the configuration's (``system.reference_delay_s``, or
the ``sys.fmaxopt`` rule). A return whose delay lies outside [tau_ref, tau_ref + T) (T the chirp
period) beats like one whole periods away: its range would be off by a multiple of c T / 2n. It
is flagged ``range_ambiguous`` (``detected = 5``, whatever its SNR) and has no measured range.
A link-tier node whose chirps do not overlap has no tone (SNR 0): the shots it would be
interpolated into are evaluated on nodes at a lag with overlap, scaled by their own overlap
(:func:`_unread_nodes`); a shot with no tone has no SNR (the fill value), never a sentinel.
"""

from __future__ import annotations

import numpy as np

from ..channel.effects import channel_returns
from ..config.loader import config_with
from ..doppler import doppler_shift_hz
from ..geometry.footprints import weighted_range_stats
from ..target import (
    lambertian_power_fraction,
    receiver_cone_half_angle_rad,
    specular_return_fraction,
)
from ..tiers.budget import make_budget, reference_delay_s
from ..tiers.common import beat_flags, doppler_line_hz, optimal_phase
from ..tiers.common import range_ambiguous as _range_ambiguous
from ..tiers.link import (
    carrier_fading_factor,
    crb_sigma_f_hz,
    overlap_duration_s,
    simulate_link,
    static_phase_factor,
)
from ..units import SPEED_OF_LIGHT_M_S, db_to_ratio
from .survey import stream

STREAM_EFFECTS = 100      # + beam index: each beam's effect draws
STREAM_NOISE = 200        # measurement noise of the link tier
STREAM_RF = 1_000_000     # + flat shot index: each rf shot's own stream
STREAM_BASEBAND = 300     # + batch index: each baseband batch's stream
STREAM_SUBRAY_SPECKLE = 400  # (key, beam, sub-ray): the sub-rays' speckle fields (baseband, rf)
STREAM_FADING = 900_000   # carrier-phase fading of the link tier (below STREAM_RF, above the
                          # baseband batches of any practical chunk)
STREAM_SIDEBAND = 900_001  # which Doppler sideband the link tier's peak search takes
BASEBAND_BATCH = 256      # shots per baseband call (sorted by range: one range gate per batch)

_RANGE_STEP = 0.01        # relative node spacing in range
_ATT_STEP_DB = 3.0        # node spacing in attenuation
_ATT_SPAN_DB = 90.0       # below the strongest shot by more than this: SNR extrapolated


def _node_config(config, enabled):
    """The instrument aimed at the ideal reference target: rho = 1 at normal incidence, a beam
    fully intercepted, no transmission losses (the shots' own losses go into the attenuation)."""
    return config_with(config, {
        "channel.free_space": True, "channel.target_radius_m": 1e9,
        "channel.target_reflectivity": 1.0, "channel.atmospheric_transmission": 1.0,
        "channel.optical_transmission": 1.0, "channel.extra_attenuation_db": 0.0,
        "effects.enabled": list(enabled)})


def reference_power_fraction(config, range_m):
    """Received / transmitted power from the ideal reference target at ``range_m`` (W/W)."""
    area = 0.25 * np.pi * config.channel.telescope_diameter_m ** 2
    return np.asarray(lambertian_power_fraction(1.0, area, range_m, 0.0), float)


def reference_attenuation_db(config, range_m, fraction):
    """The attenuation [dB] that turns the reference target's received power fraction at
    ``range_m`` into ``fraction`` (received / transmitted power): 10 log10(f_ref(R) / fraction),
    the ``channel.extra_attenuation_db`` of a link-tier shot aimed at that range."""
    return 10.0 * np.log10(reference_power_fraction(config, range_m) / fraction)


def sub_ray_power_fractions(config, scene, geom):
    """(n, b, k) received / transmitted power of every footprint sub-ray (beam weight included),
    before atmospheric and optical losses; 0 for misses."""
    ch = config.channel
    area = 0.25 * np.pi * ch.telescope_diameter_m ** 2
    hit = np.isfinite(geom.sub_range_m)
    code = np.where(hit, geom.sub_material, 0)
    rho = scene.material_reflectivity(config.laser.wavelength_m)[code]
    specular = scene.material_specular()[code] & hit
    r = np.where(hit, geom.sub_range_m, 1.0)
    inc = np.where(hit, geom.sub_incidence_rad, 0.0)
    frac = np.where(hit, lambertian_power_fraction(np.where(hit, rho, 0.0), area, r, inc), 0.0)
    if np.any(specular):
        mss = scene.water_mss()
        spec = specular_return_fraction(inc[specular], mss, rho[specular],
                                        receiver_cone_half_angle_rad(area, r[specular]),
                                        ch.divergence_half_angle_rad)
        frac[specular] = spec
    return frac * geom.sub_weight


def _transmission(config, scene, geom):
    """(n, b) round-trip atmospheric x optical x attenuator power transmission, times each
    beam's share of the transmitter power (1 for equal beams)."""
    z_ground = geom.hit_xyz_m[..., 2]
    z_plat = np.broadcast_to(geom.platform_xyh[:, 2:3], z_ground.shape)
    ok = np.isfinite(z_ground)
    zen = geom.off_nadir_rad
    t1 = np.ones(z_ground.shape)
    if np.any(ok):
        t1[ok] = scene.one_way_power_transmission(z_ground[ok], z_plat[ok], zen[ok])
    ch = config.channel
    return (t1 ** 2 * ch.optical_transmission ** 2 * float(db_to_ratio(-ch.extra_attenuation_db))
            * geom.beam_power_share[None, :])


def _effects(config, scene, geom, seq, exclude=("doppler",)):
    """(n, b) power factor of the enabled channel effects, each beam on its own streams."""
    return _effect_returns(config, scene, geom, seq, exclude)[0]


def _effect_returns(config, scene, geom, seq, exclude=("doppler",)):
    """(n, b) power factor and (n, b) carrier phase [rad] (the speckle field's phase) of the
    enabled channel effects, each beam on its own streams."""
    names = [e for e in scene.effects if e not in exclude and e != "phase_noise"]
    n, b = geom.range_true_m.shape
    if not names or n == 0:
        return np.ones((n, b)), np.zeros((n, b))
    cfg = _effects_config(config, scene, geom, names)
    power, phase = np.empty((n, b)), np.empty((n, b))
    for j in range(b):  # a handful of beams; the shots are vectorised
        ret = channel_returns(cfg, n, stream(seq, STREAM_EFFECTS + j))
        power[:, j], phase[:, j] = ret.power_factor, ret.phase_rad
    return power, phase


def _effects_config(config, scene, geom, names):
    """The configuration the chunk's effects are drawn with: the chunk's median range."""
    hit = np.isfinite(geom.range_true_m)
    r_med = float(np.median(geom.range_true_m[hit])) if np.any(hit) else 1.0
    over = {"effects.enabled": list(names), "channel.distance_m": r_med,
            "channel.free_space": True}
    if "turbulence" in names:
        over["channel.cn2_m_minus_2_3"] = _equivalent_cn2(config, scene, geom, r_med)
    return config_with(config, over)


def subray_speckle_fields(config, scene, geom, seq):
    """(n, b, k) complex speckle factor of every footprint sub-ray, E|z|^2 = 1, or None when the
    scene does not enable ``speckle``.

    Each sub-ray's patch of a diffuse surface holds many scatterers: its field is the speckle
    effect's draw (power gamma of ``effects.speckle.cells``, uniform phase: for M = 1, the coupled
    single-mode receiver, a circular complex Gaussian; Goodman 2007 Ch. 3), each (beam, sub-ray)
    on its own stream over the chunk's shots in time order (so ``shift_per_shot_m`` correlates
    successive shots of the same sub-ray, and the footprint's field keeps the effect's shot-to-shot
    correlation). The footprint field sum_k sqrt(w_k) z_k has mean power sum_k w_k.
    """
    if "speckle" not in scene.effects:
        return None
    n, b, k = geom.sub_range_m.shape
    z = np.empty((n, b, k), complex)
    if n == 0:
        return z
    cfg = _effects_config(config, scene, geom, ["speckle"])
    for j in range(b):
        for kk in range(k):  # k sub-rays per beam; the shots are vectorised
            child = np.random.SeedSequence(
                entropy=seq.entropy,
                spawn_key=tuple(seq.spawn_key) + (STREAM_SUBRAY_SPECKLE, j, kk))
            ret = channel_returns(cfg, n, np.random.default_rng(child))
            z[:, j, kk] = np.sqrt(ret.power_factor) * np.exp(1j * ret.phase_rad)
    return z


_GRAM_POINTS = 2048       # time grid of the footprint's coherence factor (over one record)
_GRAM_BLOCK = 1 << 21     # shots x sub-rays x points per block


def _overlap(config, bud):
    """The record's overlap of the two chirps on a grid: (instantaneous frequency of the return
    f(t) [Hz], beat amplitude envelope A(t) >= 0, duration of one chirp's overlap [s]: the
    equivalent rectangular duration (sum A)^2 / sum A^2 per chirp), where A > 0."""
    train = bud.train
    dur = config.simulation.duration_s
    dt = dur / _GRAM_POINTS
    t = (np.arange(_GRAM_POINTS) + 0.5) * dt
    tc_sig = train.time_in_chirp(t - bud.delay_s)
    env = (train.envelope(train.time_in_chirp(t - bud.ref_delay_s)) * train.envelope(tc_sig)
           * train.record_gate(t, dur))
    keep = env > 0
    if not np.any(keep):
        return np.zeros(0), np.zeros(0), 0.0
    a = env[keep]
    chirps = max(1, int(np.floor(dur / train.period_s + 1e-9)))
    t_eq = float(a.sum() ** 2 / np.sum(a * a)) * dt / chirps
    return train.f_start_hz + train.rate_hz_per_s * tc_sig[keep], a, t_eq


def footprint_coherence(config, bud, amplitude, dtau_s) -> np.ndarray:
    """(m,) record energy of the common-phase beat sum_k a_k b_k(t) relative to one sub-ray's:
    <A^2(t) |sum_k a_k exp(j 2 pi f(t) dtau_k)|^2> / <A^2(t)>, for amplitudes with sum_k a_k = 1.

    b_k is the beat of a sub-ray delayed by dtau_k: the same tone as at dtau = 0 with the extra
    phase 2 pi f(t) dtau_k, f(t) the instantaneous chirp frequency of the return (f_start +
    kappa t_c), under the overlap envelope A(t) of the two chirps in the record (``bud``: the
    instrument at the shots' range). Two sub-rays' beats correlate as <A^2 cos(2 pi f dtau_kl)> /
    <A^2> = cos(2 pi f_c dtau_kl) sinc(B dtau_kl) for a linear chirp over the band B about f_c:
    1 for an unresolved footprint (the factor is then 1), -> 0 once the range spread is resolved
    (the factor -> sum_k a_k^2). ``amplitude`` (m, k) >= 0, summing to 1 per shot; ``dtau_s``
    (m, k) delay offsets (a common offset cancels). The beat's harmonics are left out.
    """
    a = np.asarray(amplitude, float)
    d = np.asarray(dtau_s, float)
    m, k = a.shape
    f, env, _ = _overlap(config, bud)
    if f.size == 0 or m == 0:
        return np.ones(m)
    a2 = env * env / np.sum(env * env)
    out = np.empty(m)
    rows = max(1, _GRAM_BLOCK // (k * f.size))
    for s0 in range(0, m, rows):
        sl = slice(s0, min(m, s0 + rows))
        ph = 2 * np.pi * (d[sl, :, None] - d[sl, :1, None]) * f[None, None, :]   # (r, k, p)
        re = np.einsum("rk,rkp->rp", a[sl], np.cos(ph))
        im = np.einsum("rk,rkp->rp", a[sl], np.sin(ph))
        out[sl] = (re * re + im * im) @ a2
    return out


_CELL_MARGIN = 3          # resolution cells beyond the footprint's extreme delays
_CELL_FLOOR = 1e-3        # cells below this share of the strongest are left out (-30 dB)


def footprint_cells(config, bud, share, dtau_s):
    """The mean (speckle-averaged) line of a footprint as echoes on the chirp's resolution grid:
    (delay offsets (m, J), powers (m, J)), J cells per shot (unused cells padded with power 0).

    A diffuse footprint's mean beat spectrum is sum_k w_k |T(f - kappa tau_k)|^2 (each sub-ray's
    line, weighted by its power share: the speckle phases average the cross terms away). Tones
    spaced by one resolution cell, delta = 1 / (kappa T_ov) (T_ov the equivalent rectangular
    overlap of one chirp), are orthogonal over the record, so echoes at tau_bar + j delta with
    powers W_j = sum_k w_k sinc^2((tau_k - tau_bar) / delta - j) draw that line exactly at the
    grid's frequencies, whatever their carrier or RF phases, with sum_j W_j = 1 (the sinc^2
    shifts sum to 1). tau_bar is the power-weighted mean delay: a footprint the chirp does not
    resolve is one echo there of the whole power (W_0 -> 1); a resolved one spreads over the
    cells in proportion to its power-weighted delays. ``share`` (m, k): power shares (sum 1),
    ``dtau_s`` (m, k) delay offsets.
    """
    w = np.asarray(share, float)
    d = np.asarray(dtau_s, float)
    m = w.shape[0]
    _, _, t_ov = _overlap(config, bud)
    band = bud.train.rate_hz_per_s * t_ov
    tbar = np.sum(w * d, axis=-1, keepdims=True)                       # (m, 1)
    if band <= 0 or m == 0:
        return tbar, np.ones((m, 1))
    delta = 1.0 / band
    x = np.where(w > 0, (d - tbar) / delta, 0.0)
    lo = np.floor(x.min(axis=-1)).astype(int) - _CELL_MARGIN
    hi = np.ceil(x.max(axis=-1)).astype(int) + _CELL_MARGIN
    j = lo[:, None] + np.arange(int(np.max(hi - lo)) + 1)                  # (m, J): per shot
    cells = np.einsum("mk,mkj->mj", w, np.sinc(x[..., None] - j[:, None, :]) ** 2)
    cells = np.where(cells >= _CELL_FLOOR * cells.max(axis=-1, keepdims=True), cells, 0.0)
    # Each shot's cells in use first (a footprint split between two surfaces skips the gap).
    order = np.argsort(cells <= 0, axis=-1, kind="stable")
    cells = np.take_along_axis(cells, order, axis=-1)
    j = np.take_along_axis(j, order, axis=-1)
    used = np.any(cells > 0, axis=0)
    return tbar + j[:, used] * delta, cells[:, used]


def footprint_echoes(config, bud, frac, dtau_s, fields=None, sign=-1.0):
    """A footprint's sub-rays as tier echoes: (delay_offset_s (m, J), power_weight (m, J),
    phase_rad (m, J), gain (m,)).

    The tiers sum the echoes as sum_j sqrt(u_j) exp(sign j phi_j) x (the signal delayed by the
    echo's offset), with the weights u normalised to sum 1 per shot, and scale the shot's received
    power by its power factor; ``gain`` is the factor to multiply that power factor with.
    ``frac`` (m, k): the sub-rays' received power shares w_k (unnormalised, each shot with one
    > 0); ``dtau_s`` (m, k) their delay offsets; ``bud``: the instrument at the shots' range;
    ``sign``: -1 for the baseband tier's exp(-j phi), +1 for the rf tier's exp(+j phi).

    Sub-rays sample the footprint; they are not scatterers, so their optical path differences
    (2 k0 (R_k - R_l): thousands of wavelengths) must not interfere:

    * ``fields`` (m, k) complex (speckle on, :func:`subray_speckle_fields`): each sub-ray's patch
      returns the field sqrt(w_k) z_k at its own delay. Echo weights w_k |z_k|^2, phases from
      arg z_k, gain sum_k w_k |z_k|^2 / sum_k w_k: an unresolved footprint's power is
      |sum_k sqrt(w_k) z_k|^2 (exponential of mean 1 for M = 1, circular Gaussian fields), a
      resolved one's lines carry w_k |z_k|^2; the mean spectrum is the power-weighted one.
    * no fields (speckle off): the mean return, deterministically, with one common phase: the
      resolution-cell echoes of :func:`footprint_cells` (one echo of the whole power at the
      power-weighted mean delay when the chirp does not resolve the footprint). ``gain`` =
      sum a_j^2 / :func:`footprint_coherence` (a_j = sqrt(W_j) / sum sqrt(W)) keeps the record's
      beat energy at the mean power's (about 1; it absorbs the window's taper and the truncated
      sinc^2 tails), so the footprint returns its mean power and a spread footprint broadens the
      line without interference gain or loss.
    """
    w = np.asarray(frac, float)
    tot = w.sum(axis=-1, keepdims=True)
    share = w / np.where(tot > 0, tot, 1.0)
    if fields is not None:
        z = np.asarray(fields)
        pw = share * (z.real ** 2 + z.imag ** 2)
        return np.asarray(dtau_s, float), pw, sign * np.angle(z), pw.sum(axis=-1)
    delays, cells = footprint_cells(config, bud, share, dtau_s)
    a = np.sqrt(cells)
    a = a / a.sum(axis=-1, keepdims=True)
    coh = footprint_coherence(config, bud, a, delays)
    return delays, cells, np.zeros_like(cells), np.sum(a * a, axis=-1) / np.maximum(coh, 1e-300)


def _equivalent_cn2(config, scene, geom, r_med: float) -> float:
    """The constant Cn^2 over the chunk's median slant path that gives the Fried parameter of the
    scene's Cn^2 profile along it (r0 ~ (Cn^2)^(-3/5)): the turbulence effect then sees the
    scene's atmosphere, not the instrument file's bench value."""
    from ..atmosphere import fried_parameter

    hit = np.isfinite(geom.range_true_m)
    z_g = float(np.median(geom.hit_xyz_m[..., 2][hit]))
    z_p = float(np.median(geom.platform_xyh[:, 2]))
    zen = float(np.median(geom.off_nadir_rad[hit]))
    wave = "spherical" if config.effects.coupling.target == "diffuse" else "plane"
    lam = config.laser.wavelength_m
    r0 = float(scene.fried_parameter_m(lam, z_g, z_p, zen, wave=wave))
    if not np.isfinite(r0):
        return 0.0
    return float((fried_parameter(1.0, lam, r_med, wave=wave) / r0) ** (5.0 / 3.0))


def _interp_table(x_nodes, y_nodes, table, x, y):
    """Bilinear interpolation (linear extrapolation along y beyond the nodes)."""
    ix = np.clip(np.searchsorted(x_nodes, x) - 1, 0, max(len(x_nodes) - 2, 0))
    iy = np.clip(np.searchsorted(y_nodes, y) - 1, 0, max(len(y_nodes) - 2, 0))
    if len(x_nodes) == 1:
        fx, ix1 = np.zeros_like(x), ix
    else:
        ix1 = ix + 1
        fx = np.clip((x - x_nodes[ix]) / (x_nodes[ix1] - x_nodes[ix]), 0.0, 1.0)
    if len(y_nodes) == 1:
        fy, iy1 = np.zeros_like(y), iy
    else:
        iy1 = iy + 1
        fy = (y - y_nodes[iy]) / (y_nodes[iy1] - y_nodes[iy])
    a = table[ix, iy] * (1 - fy) + table[ix, iy1] * fy
    c = table[ix1, iy] * (1 - fy) + table[ix1, iy1] * fy
    return a * (1 - fx) + c * fx


def _link_table(config, r_lo, r_hi, a_lo, a_hi, doppler: bool, lag_s: float | None = None):
    """SNR [dB] on (range, attenuation) nodes and T_ov [s] per range node, plus the SNR factor
    of a resolved Doppler split, from the link tier's closed form. ``lag_s``: every node's
    tau - tau_ref (a range window's centre); None: the configuration's reference delay."""
    lw = config.laser.linewidth_hz > 0
    base = _node_config(config, ["phase_noise"] if lw else [])

    def at_range(cfg, r):
        over = {"channel.distance_m": float(r)}
        if lag_s is not None:
            delay = 2.0 * config.channel.group_index * float(r) / SPEED_OF_LIGHT_M_S
            # (a node nearer than the lag reads the lag it can: T_ov is taken at each node)
            over["system.reference_delay_s"] = max(delay - lag_s, 0.0)
        return config_with(cfg, over)

    n_r = 1 if r_hi <= r_lo else int(min(33, np.ceil(np.log(r_hi / r_lo) / _RANGE_STEP) + 1))
    r_nodes = np.geomspace(r_lo, r_hi, n_r) if n_r > 1 else np.array([r_lo])
    a0 = np.floor(a_lo / _ATT_STEP_DB) * _ATT_STEP_DB
    a1 = max(np.ceil(min(a_hi, a_lo + _ATT_SPAN_DB) / _ATT_STEP_DB) * _ATT_STEP_DB,
             a0 + _ATT_STEP_DB)
    a_nodes = np.arange(a0, a1 + 0.5 * _ATT_STEP_DB, _ATT_STEP_DB)
    snr_db = np.empty((n_r, a_nodes.size))
    t_ov = np.empty(n_r)
    rng = np.random.default_rng(0)  # the nodes' own draws are not used (SNR is deterministic)
    for i, r in enumerate(r_nodes):  # tens of closed-form evaluations per chunk, not per shot
        cfg_r = at_range(base, r)
        for j, a in enumerate(a_nodes):
            out = simulate_link(config_with(cfg_r, {"channel.extra_attenuation_db": float(a)}),
                                rng, batch=1)
            snr_db[i, j] = out["SNR"][0]
        t_ov[i] = out["t_overlap_s"][0]
    split = 1.0
    if doppler and config.system.receiver == "coherent":
        # Appendix D: a resolved Doppler shift splits the real homodyne line; the factor is the
        # link tier's own (it depends on the carrier-phase convention), read at one node.
        # (at the first range node with a tone: a node whose chirps do not overlap has none)
        i0 = int(np.argmax(np.isfinite(snr_db[:, 0])))
        r = float(r_nodes[i0])
        f_big = 20.0 / t_ov[i0]
        dop = config_with(at_range(_node_config(config, (["phase_noise"] if lw else [])
                                                + ["doppler"]), r),
                          {"effects.doppler.radial_velocity_mps": f_big * config.laser.wavelength_m / 2,
                           "channel.extra_attenuation_db": float(a_nodes[0])})
        on = simulate_link(dop, rng, batch=1)["SNR"][0]
        split = float(db_to_ratio(on - snr_db[i0, 0])) if np.isfinite(snr_db[i0, 0]) else np.nan
    # A node without a tone (no chirp overlap at its lag, no LO) has SNR 0 (-inf dB): NaN here,
    # never a sentinel dB value; measure_link re-evaluates the shots that meet one.
    snr_db = np.where(np.isfinite(snr_db), snr_db, np.nan)
    return r_nodes, a_nodes, snr_db, t_ov, split


def received_power(config, scene, geom, seq, *, exclude_effects=("doppler",)):
    """Per shot-beam: (P_sig [W], power-weighted mean range [m], range std [m], sub-ray power
    fractions (n, b, k) after transmission and effects)."""
    return _received(config, scene, geom, seq, exclude_effects)[:4]


def _received(config, scene, geom, seq, exclude_effects=("doppler",)):
    """:func:`received_power` and the effects' (n, b) carrier phase [rad] (speckle)."""
    bud = make_budget(config)
    frac = sub_ray_power_fractions(config, scene, geom)
    power, phase = _effect_returns(config, scene, geom, seq, exclude=exclude_effects)
    scale = _transmission(config, scene, geom) * power
    mean, std, tot = weighted_range_stats(frac, geom.sub_range_m)
    return bud.ptx_w * tot * scale, mean, std, frac * scale[..., None], phase


def check_range_window(config, source: str) -> None:
    """ConfigError unless ``survey.range_window_m``'s beats fit in the processed band."""
    from ..config.loader import ConfigError
    from ..tiers.common import peak_search_max_hz

    w = config.survey.range_window_m
    if w is None:
        return
    bud = make_budget(config)
    lag_span = 2.0 * config.channel.group_index * w / SPEED_OF_LIGHT_M_S   # near to far edge
    span = bud.rate_hz_per_s * lag_span                                    # its beats [Hz]
    top = peak_search_max_hz(config, bud)
    room = top - config.processing.highpass_hz
    if lag_span >= bud.train.rise_s:
        raise ConfigError(f"{source}: survey.range_window_m = {w:g} m is longer than the chirp: "
                          f"its far edge lags the reference by {lag_span * 1e6:.3g} us, beyond "
                          f"the {bud.train.rise_s * 1e6:.3g} us ramp (no overlap, and ranges "
                          "would alias by c T / 2)")
    if span > room:
        w_max = w * room / span
        raise ConfigError(f"{source}: survey.range_window_m = {w:g} m needs beats from "
                          f"{config.processing.highpass_hz / 1e6:g} to "
                          f"{(config.processing.highpass_hz + span) / 1e6:.3g} MHz, above the "
                          f"processed band's top {top / 1e6:.3g} MHz: at most {w_max:.0f} m")


def window_reference_delay_s(config, geom, r_mean_m):
    """Per shot-beam (reference delay [s], outside-the-window mask) of ``survey.range_window_m``,
    or (None, all False) when the survey has no range window (module docstring)."""
    w = config.survey.range_window_m
    outside = np.zeros(np.shape(r_mean_m), bool)
    if w is None:
        return None, outside
    n_grp = config.channel.group_index
    near = geom.range_predicted_m - 0.5 * w
    rate = make_budget(config).rate_hz_per_s
    ref = 2.0 * n_grp * np.where(np.isfinite(near), near, 0.0) / SPEED_OF_LIGHT_M_S \
        - config.processing.highpass_hz / rate
    with np.errstate(invalid="ignore"):
        outside = ~((r_mean_m >= near) & (r_mean_m <= near + w))
    return ref, outside & np.isfinite(r_mean_m)


def gate_lags(config, bud, geom, r_mean_m):
    """Per shot-beam (tau - tau_ref reduced to a chirp period [s], reference delay [s], outside
    the range window) of the shots' power-weighted mean ranges: the range window's gate, else
    the configuration's reference delay (fixed or the ``sys.fmaxopt`` rule)."""
    ok = np.isfinite(r_mean_m)
    delay = 2.0 * config.channel.group_index * np.where(ok, r_mean_m, 1.0) / SPEED_OF_LIGHT_M_S
    ref, outside = window_reference_delay_s(config, geom, r_mean_m)
    if ref is None:
        ref = reference_delay_s(config, delay, bud.rate_hz_per_s)
    return np.mod(delay - ref, bud.train.period_s), ref, outside


def doppler_displaced(config, scene, geom, bud, lag_s) -> np.ndarray:
    """(n, b) shots whose Doppler shift the record resolves (|f_d| T_ov >= 1, T_ov the chirps'
    overlap at the shot's lag ``lag_s``, as the link tier splits the line: it moves by more than
    the range resolution) with nothing to recover it (module docstring)."""
    f_d = np.abs(doppler_hz(config, scene, geom))
    out = np.zeros(f_d.shape, bool)
    have = (f_d > 0) & np.isfinite(lag_s)
    if config.processing.doppler_recovery != "none" or not np.any(have):
        return out
    out[have] = f_d[have] * _overlap_at(config, bud, lag_s[have]) >= 1.0
    return out


def doppler_hz(config, scene, geom):
    if "doppler" not in scene.effects:
        return np.zeros_like(geom.closing_speed_mps)
    return doppler_shift_hz(geom.doppler_speed_mps, config.laser.wavelength_m)


def measure_link(config, scene, geom, seq) -> dict:
    """Link-tier measurements of every shot-beam of a chunk: arrays (n, b)."""
    if config.system.modulation != "fm_chirp":
        raise ValueError("survey runs model FM chirps (system.modulation = 'fm_chirp')")
    bud = make_budget(config)
    psig, r_mean, r_std, _, eff_phase = _received(config, scene, geom, seq)
    n_grp = config.channel.group_index
    rate = bud.rate_hz_per_s
    ok = np.isfinite(r_mean) & (psig > 0)
    snr = np.full(psig.shape, 0.0)
    f_meas = np.full(psig.shape, np.nan)
    range_meas = np.full(psig.shape, np.nan)
    width = np.full(psig.shape, np.nan)
    delay = 2.0 * n_grp * np.where(ok, r_mean, 1.0) / SPEED_OF_LIGHT_M_S
    lag, ref, outside = gate_lags(config, bud, geom, np.where(ok, r_mean, np.nan))
    f_b = rate * lag
    no_overlap, out_of_band = beat_flags(config, bud, lag, f_b)
    if np.any(ok):
        att = reference_attenuation_db(config, r_mean[ok], psig[ok] / bud.ptx_w)
        # Nodes at the mean phase power ("random") or at the optimum phase (the static phases:
        # each shot's own phase below; the node's own propagation phase would be arbitrary).
        cp = config.channel.carrier_phase
        node_cfg = config if cp == "random" else config_with(config, {
            "channel.carrier_phase": "optimal"})
        lag_c = None if config.survey.range_window_m is None else (
            config.processing.highpass_hz / rate
            + n_grp * config.survey.range_window_m / SPEED_OF_LIGHT_M_S)
        r_nodes, a_nodes, table, t_nodes, split = _link_table(
            node_cfg, float(r_mean[ok].min()), float(r_mean[ok].max()), float(att.min()),
            float(att.max()), "doppler" in scene.effects, lag_c)
        snr_ok = db_to_ratio(_interp_table(r_nodes, a_nodes, table, r_mean[ok], att))
        t_ov = np.interp(r_mean[ok], r_nodes, t_nodes)
        if lag_c is not None:
            # Nodes at the window's centre lag; each shot's own lag sets its overlap T_ov, and
            # the tone's amplitude scales with it (SNR with its square).
            t_shot = _overlap_at(config, bud, lag[ok])
            snr_ok = snr_ok * (t_shot / t_ov) ** 2
            t_ov = t_shot
        unread = ~np.isfinite(snr_ok)
        if np.any(unread):
            snr_ok, t_ov, split = _unread_nodes(
                node_cfg, config, bud, unread, snr_ok, t_ov, split, r_mean[ok], att, lag[ok],
                no_overlap[ok], "doppler" in scene.effects)
        f_d = doppler_hz(config, scene, geom)[ok]
        resolved = np.abs(f_d) >= 1.0 / t_ov
        # Carrier fading about the nodes' mean phase power, or each shot's static phase (with the
        # speckle field's phase, when that effect is on) about the optimum; a resolved Doppler
        # split replaces it.
        if cp == "random":
            fade = carrier_fading_factor(config, stream(seq, STREAM_FADING), snr_ok.size)
        else:
            fade = static_phase_factor(config, _static_phase(config, bud, delay[ok], ref[ok])
                                       + eff_phase[ok])
        snr_ok = np.where(resolved, snr_ok * split, snr_ok * fade)
        # Footprint spread: a broadened line of width ratio g (module docstring).
        sigma_f = rate * 2.0 * n_grp * r_std[ok] / SPEED_OF_LIGHT_M_S
        g = np.sqrt(1.0 + (2.355 * sigma_f * t_ov / 0.886) ** 2)
        snr_ok = snr_ok / g
        t_eff = t_ov / g
        noise = stream(seq, STREAM_NOISE).standard_normal(snr_ok.shape)
        line = doppler_line_hz(config, bud, f_b[ok], np.where(resolved, f_d, 0.0),
                               stream(seq, STREAM_SIDEBAND))
        fm = line + crb_sigma_f_hz(snr_ok, config.processing.rbw_hz, t_eff) * noise
        snr[ok] = snr_ok
        width[ok] = 0.886 / t_eff  # 3 dB width of a rectangular-envelope tone of duration t_eff
        f_meas[ok] = fm
        range_meas[ok] = SPEED_OF_LIGHT_M_S * (fm / rate + ref[ok]) / (2.0 * n_grp)
    return _finish(config, geom, psig, snr, f_meas, range_meas, width, ok, no_overlap,
                   out_of_band, outside,
                   doppler_displaced(config, scene, geom, bud, np.where(ok, lag, np.nan)),
                   ambiguous=ok & range_ambiguous(bud, delay - ref))


def _unread_nodes(node_cfg, config, bud, unread, snr_ok, t_ov, split, r_m, att_db, lag_s,
                  no_overlap, doppler: bool):
    """(SNR, T_ov, Doppler split factor) per shot, for shots whose table interpolation met a
    node without a tone (its own lag has no chirp overlap: SNR 0, or no LO), instead of a
    sentinel dB value: nodes at one lag with overlap (the median of these shots' own) and each
    shot's own overlap scaling the tone, as with a range window (SNR with the square of T_ov).
    Shots whose own chirps do not overlap have no tone: SNR 0 (written as the fill value,
    flagged ``outside_range_gate``); so has every shot when no node has a tone (no LO)."""
    snr_ok, t_ov = np.array(snr_ok, float), np.array(np.broadcast_to(t_ov, snr_ok.shape), float)
    split = np.array(np.broadcast_to(split, snr_ok.shape), float)
    t_shot = _overlap_at(config, bud, lag_s[unread])
    snr_u = np.zeros(t_shot.shape)
    split_u = np.ones(t_shot.shape)
    tone = ~no_overlap[unread]
    if config.system.receiver == "coherent" and config.balanced.lo_power_w <= 0:
        tone[:] = False   # no LO: nothing to beat with
    if np.any(tone):
        r_u, a_u = r_m[unread], att_db[unread]
        r_nodes, a_nodes, table, t_nodes, split_n = _link_table(
            node_cfg, float(r_u.min()), float(r_u.max()), float(a_u.min()), float(a_u.max()),
            doppler, float(np.median(lag_s[unread][tone])))
        s = db_to_ratio(_interp_table(r_nodes, a_nodes, table, r_u[tone], a_u[tone]))
        s = s * (t_shot[tone] / np.interp(r_u[tone], r_nodes, t_nodes)) ** 2
        snr_u[tone] = np.where(np.isfinite(s), s, 0.0)
        split_u[tone] = split_n if np.isfinite(split_n) else 1.0
    snr_ok[unread], t_ov[unread], split[unread] = snr_u, t_shot, split_u
    return snr_ok, t_ov, split


def range_ambiguous(bud, delay_minus_ref_s) -> np.ndarray:
    """Shots whose delay lies outside [tau_ref, tau_ref + T) (T the chirp period): the beat is
    that of a delay whole periods away and the range read from it is off by a multiple of
    c T / (2 n) (``tiers.common.range_ambiguous``; ``detected = 5``)."""
    return np.asarray(_range_ambiguous(bud, delay_minus_ref_s), bool)


def _overlap_at(config, bud, lag_s) -> np.ndarray:
    """The link tier's chirp overlap T_ov [s] at each lag, interpolated from 129 lags spanning
    them (T_ov is piecewise linear in the lag)."""
    lo, hi = float(np.min(lag_s)), float(np.max(lag_s))
    grid = np.linspace(lo, hi, 129) if hi > lo else np.array([lo])
    t_grid = overlap_duration_s(config, bud, grid)
    return np.interp(lag_s, grid, t_grid) if grid.size > 1 else np.full(np.shape(lag_s), t_grid[0])


def _static_phase(config, bud, delay_s, ref_delay_s) -> np.ndarray:
    """Per-shot static carrier phase [rad] of ``channel.carrier_phase`` = "optimal" (the
    receiver's optimum) or "propagation" (-2 pi nu (tau - tau_ref) of each shot's own mean delay:
    a moving platform's range changes by many wavelengths from shot to shot)."""
    delay_s = np.asarray(delay_s, float)
    if config.channel.carrier_phase == "propagation":
        return -2 * np.pi * np.mod(bud.nu_hz * (delay_s - ref_delay_s), 1.0)
    mode = config.system.coherent_mode if config.system.receiver == "coherent" else "direct"
    return np.full(delay_s.shape, optimal_phase(mode))


def _finish(config, geom, psig, snr, f_meas, range_meas, width, ok, no_overlap,
            out_of_band, outside_window, displaced, ambiguous=None) -> dict:
    """The survey's per-shot fields; ``detected`` says why a return does not count: 2 no
    surface; 3 outside the range gate (``survey.range_window_m``, or without one the ranges
    whose beat lies in the processed band with the chirps overlapping); 5 range ambiguous (the
    delay lies outside [tau_ref, tau_ref + T): the range read is off by a multiple of
    c T / 2n), whatever its SNR; 4 Doppler-displaced; 0 below the detection threshold. An SNR
    of zero (no tone) is written as NaN (the fill value), never as a sentinel dB value."""
    thr = float(db_to_ratio(config.survey.detection_threshold_db))
    hit = np.isfinite(geom.range_true_m)
    outside = outside_window | (ok & (no_overlap | out_of_band))
    seen = np.where(ok & (snr >= thr), 1, 0)
    detected = np.where(displaced & (seen == 1), 4, seen)
    if ambiguous is not None:
        detected = np.where(ok & ambiguous, 5, detected)
    detected = np.where(~hit, 2, np.where(outside, 3, detected))
    det = detected == 1
    with np.errstate(divide="ignore"):
        snr_db = np.where(ok & (snr > 0), 10.0 * np.log10(np.where(snr > 0, snr, 1.0)), np.nan)
    return {
        "received_power": np.where(hit, psig, np.nan),
        "snr_db": np.where(hit, snr_db, np.nan),
        "beat_frequency": np.where(det, f_meas, np.nan),
        "beat_width": np.where(det, width, np.nan),
        "range_measured": np.where(det, range_meas, np.nan),
        "detected": detected.astype(np.int8),
    }


def _footprint_returns(config, scene, geom, seq):
    """What the time-domain tiers (rf, baseband) start from: received power (n, b) and mean range
    without the Doppler and speckle effects (their own draws replace speckle), the sub-rays'
    power shares, their speckle fields (or None) and the shots with a return."""
    psig, r_mean, _, frac = received_power(config, scene, geom, seq,
                                           exclude_effects=("doppler", "speckle"))
    fields = subray_speckle_fields(config, scene, geom, seq)
    return psig, r_mean, frac, fields, np.isfinite(r_mean) & (psig > 0)


def shot_base_config(config, scene):
    """The instrument a survey's per-shot tier calls start from: :func:`_node_config` (the ideal
    reference target; the shot's own losses go into ``channel.extra_attenuation_db``) with laser
    phase noise when the laser has a linewidth and Doppler when the scene enables it."""
    lw = config.laser.linewidth_hz > 0
    enabled = (["phase_noise"] if lw else []) + (["doppler"] if "doppler" in scene.effects else [])
    return _node_config(config, enabled)


def rf_shot_stream(seq, flat: int) -> np.random.Generator:
    """The rf tier's random stream of shot-beam ``flat`` (= shot index x beams + beam) of the
    chunk whose SeedSequence is ``seq``."""
    return stream(seq, STREAM_RF + int(flat))


def rf_shot_setup(config, base, ptx_w: float, geom, returns, i: int, j: int,
                  window_ref=None):
    """The rf tier's input for shot ``i``, beam ``j`` of a chunk: (configuration, footprint
    :class:`~chirplidar.tiers.echoes.Echoes`).

    ``base``: :func:`shot_base_config`; ``ptx_w``: the transmitted power of ``config``'s budget;
    ``returns``: :func:`_footprint_returns` of the chunk (P_sig, mean range, sub-ray power shares,
    speckle fields or None, ...). The configuration aims the instrument at the footprint's
    power-weighted mean range R0 (``channel.distance_m``), with the shot's closing speed as the
    Doppler radial velocity when Doppler is on, and the attenuation that turns the reference
    target's power into the shot's: extra_attenuation_db = 10 log10(f_ref(R0) P_tx / (P_sig g)),
    f_ref = :func:`reference_power_fraction`, g the echoes' gain (:func:`footprint_echoes`: the
    tier scales the received power by it). The echoes are the footprint's sub-rays at their delay
    offsets 2 n (R_k - R0) / c (n: ``channel.group_index``). With ``survey.range_window_m`` the
    reference delay is the shot's range gate (``window_ref``: the chunk's, as
    :func:`window_reference_delay_s` gives them; computed when not passed).
    """
    from ..tiers.echoes import Echoes

    psig, r_mean, frac, fields = returns[:4]
    n_grp = config.channel.group_index
    r0 = float(r_mean[i, j])
    over = {"channel.distance_m": r0}
    # The range window's reference delays of the chunk (computed here when not passed).
    ref = window_ref if window_ref is not None else window_reference_delay_s(config, geom,
                                                                               r_mean)[0]
    if ref is not None:
        over["system.reference_delay_s"] = float(ref[i, j])
    if "doppler" in base.effects.enabled:
        over["effects.doppler.radial_velocity_mps"] = float(geom.doppler_speed_mps[i, j])
    cfg0 = config_with(base, over)
    w = frac[i, j]
    keep = w > 0
    dtau = 2.0 * n_grp * (geom.sub_range_m[i, j][keep] - r0) / SPEED_OF_LIGHT_M_S
    offs, pw, phase, gain = footprint_echoes(
        cfg0, make_budget(cfg0), w[keep][None], dtau[None],
        None if fields is None else fields[i, j][keep][None], sign=1.0)
    att = float(10 * np.log10(reference_power_fraction(config, r0) * ptx_w
                              / (psig[i, j] * gain[0])))
    cfg = config_with(cfg0, {"channel.extra_attenuation_db": att})
    return cfg, Echoes(offs[0], pw[0], phase[0])


def measure_rf(config, scene, geom, seq, progress=None) -> dict:
    """rf-tier measurements: each shot-beam is simulated at full rate, its footprint's sub-rays
    summed as delayed echoes (``tiers.rf`` ``echoes``, see :func:`footprint_echoes`): a sloped or
    rough footprint broadens the beat peak. With ``speckle`` enabled each sub-ray carries its own
    speckle field (:func:`subray_speckle_fields`: their sum is the footprint's speckle, so the
    speckle effect's per-shot draw is not applied); otherwise the footprint returns its mean power
    with one common carrier phase (no interference between the sub-ray samples). Each shot's
    input is :func:`rf_shot_setup`'s (also used by ``chirplidar shot`` on a survey mission)."""
    from ..tiers.rf import simulate_rf

    bud = make_budget(config)
    returns = _footprint_returns(config, scene, geom, seq)
    psig, ok = returns[0], returns[4]
    n, b = psig.shape
    base = shot_base_config(config, scene)
    snr = np.zeros((n, b))
    f_meas = np.full((n, b), np.nan)
    range_meas = np.full((n, b), np.nan)
    width = np.full((n, b), np.nan)
    no_overlap = np.zeros((n, b), bool)
    out_of_band = np.zeros((n, b), bool)
    n_grp = config.channel.group_index
    lags, window_ref, outside = gate_lags(config, bud, geom, returns[1])
    gate_ref = window_ref
    if config.survey.range_window_m is None:
        window_ref = None
    for flat in np.flatnonzero(ok.ravel()):  # the rf tier is the reference: one shot at a time
        i, j = divmod(int(flat), b)
        cfg, echoes = rf_shot_setup(config, base, bud.ptx_w, geom, returns, i, j, window_ref)
        out = simulate_rf(cfg, rf_shot_stream(seq, flat), batch=1, echoes=echoes)
        snr[i, j] = float(db_to_ratio(out["SNR"][0]))
        f_meas[i, j] = out["f_beat_hz"][0]
        range_meas[i, j] = out["d_rx"][0]
        width[i, j] = out["d_3dB"][0] * 2.0 * n_grp * bud.rate_hz_per_s / SPEED_OF_LIGHT_M_S
        no_overlap[i, j] = "no_overlap" in out["flags"]
        out_of_band[i, j] = "beat_out_of_band" in out["flags"]
        if progress is not None:
            progress(1)
    delay = 2.0 * n_grp * np.where(ok, returns[1], 1.0) / SPEED_OF_LIGHT_M_S
    return _finish(config, geom, psig, snr, f_meas, range_meas, width, ok, no_overlap,
                   out_of_band, outside,
                   doppler_displaced(config, scene, geom, bud, np.where(ok, lags, np.nan)),
                   ambiguous=ok & range_ambiguous(bud, delay - gate_ref))


def measure_baseband(config, scene, geom, seq, progress=None) -> dict:
    """Baseband-tier measurements of a chunk, in batches of shots: each shot's footprint sub-rays
    become echoes (:func:`footprint_echoes`, as in :func:`measure_rf`), its received power,
    carrier phase and Doppler per-shot returns.

    Shots are sorted by range and batched; a batch shares one instrument configuration aimed at
    its median range, so the ``sys.fmaxopt`` range gate (when ``system.reference_delay_s`` is
    unset) is set per batch of at most BASEBAND_BATCH neighbouring ranges, not per shot; each
    shot's own delay enters exactly as its echoes' offsets from that range, and with
    ``channel.carrier_phase = "propagation"`` each shot takes the propagation phase of its own
    power-weighted mean delay (the batch's phase would be shared by all its shots).
    """
    from ..channel.effects import ShotReturns
    from ..tiers.baseband import (
        band_top_hz_or_nyquist,
        baseband_grid,
        simulate_baseband,
    )
    from ..tiers.echoes import Echoes

    bud = make_budget(config)
    band_top = band_top_hz_or_nyquist(config, bud, baseband_grid(config, bud)[0])
    psig, r_mean, frac, fields, ok = _footprint_returns(config, scene, geom, seq)
    n, b = psig.shape
    lw = config.laser.linewidth_hz > 0
    base = _node_config(config, ["phase_noise"] if lw else [])
    snr = np.zeros((n, b))
    f_meas, range_meas, width = (np.full((n, b), np.nan) for _ in range(3))
    no_overlap = np.zeros((n, b), bool)
    out_of_band = np.zeros((n, b), bool)
    n_grp = config.channel.group_index
    propagation = config.channel.carrier_phase == "propagation"
    f_d_all = doppler_hz(config, scene, geom)
    window_ref, outside = window_reference_delay_s(config, geom, r_mean)
    lags = np.full((n, b), np.nan)
    ambiguous = np.zeros((n, b), bool)
    flat = np.flatnonzero(ok.ravel())
    order_by = r_mean if window_ref is None else window_ref
    flat = flat[np.argsort(order_by.ravel()[flat], kind="stable")]
    for batch_index, start in enumerate(range(0, flat.size, BASEBAND_BATCH)):
        idx = flat[start:start + BASEBAND_BATCH]
        ii, jj = np.divmod(idx, b)
        r0 = float(np.median(r_mean[ii, jj]))
        over = {"channel.distance_m": r0, "channel.extra_attenuation_db": 0.0}
        if window_ref is not None:   # one range gate per batch of neighbouring gates
            over["system.reference_delay_s"] = float(np.median(window_ref[ii, jj]))
        cfg = config_with(base, over)
        bud_batch = make_budget(cfg)
        rng = stream(seq, STREAM_BASEBAND + batch_index)
        w = frac[ii, jj]                                                  # (m, k)
        dtau = 2.0 * n_grp * (np.where(w > 0, geom.sub_range_m[ii, jj], r0) - r0) / SPEED_OF_LIGHT_M_S
        offs, pw, phase, gain = footprint_echoes(cfg, bud_batch, w, dtau,
                                                 None if fields is None else fields[ii, jj])
        delay = 2.0 * n_grp * r_mean[ii, jj] / SPEED_OF_LIGHT_M_S
        shot_phase = np.zeros(idx.size)
        if propagation:
            # The tier applies the batch's propagation phase; each shot's is its own delay's.
            shot_phase = (_static_phase(config, bud_batch, delay, bud_batch.ref_delay_s)
                          - _static_phase(config, bud_batch, bud_batch.delay_s,
                                          bud_batch.ref_delay_s))
        per_shot = ShotReturns(power_factor=psig[ii, jj] / bud_batch.psig_w * gain,
                               phase_rad=shot_phase, doppler_hz=f_d_all[ii, jj])
        out = simulate_baseband(cfg, rng, batch=idx.size, echoes=Echoes(offs, pw, phase),
                                shot_returns=per_shot)
        snr[ii, jj] = db_to_ratio(out["SNR"])
        f_meas[ii, jj] = out["f_beat_hz"]
        range_meas[ii, jj] = out["d_rx"]
        width[ii, jj] = out["d_3dB"] * 2.0 * n_grp * bud.rate_hz_per_s / SPEED_OF_LIGHT_M_S
        # Per-shot flags from each shot's own lag (the tier's flags describe the batch's centre).
        lag = np.mod(delay - bud_batch.ref_delay_s, bud.train.period_s)
        lags[ii, jj] = lag
        ambiguous[ii, jj] = range_ambiguous(bud, delay - bud_batch.ref_delay_s)
        f_b = bud.rate_hz_per_s * lag
        no_overlap[ii, jj], out_of_band[ii, jj] = beat_flags(cfg, bud, lag, f_b)
        out_of_band[ii, jj] |= f_b > band_top
        if progress is not None:
            progress(idx.size)
    return _finish(config, geom, psig, snr, f_meas, range_meas, width, ok, no_overlap,
                   out_of_band, outside, doppler_displaced(config, scene, geom, bud, lags),
                   ambiguous=ambiguous)

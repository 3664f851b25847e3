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
The measured range centres on the power-weighted mean range. (The rf tier sums the sub-ray echoes
coherently instead: see ``measure_rf``.)

Carrier fading (``channel.carrier_phase = "random"``, the field instrument's setting): the nodes
hold the mean over a uniform carrier phase; each shot's SNR takes its own fading factor
(``tiers.link.carrier_fading_factor``: 2 sin^2 psi for one homodyne record, averaged over the
record's K chirps in power), drawn on its own stream, as the rf and baseband tiers draw the phase
per chirp. Without it a K = 1 survey would detect shots near threshold by the mean SNR while the
other tiers fade (speckle x fading is chi-square of one degree of freedom, not exponential).

Doppler (``doppler`` in the scene's effects): f_d = 2 v / lambda from each shot's closing speed
(platform velocity along the beam; the terrain is fixed in ECEF, so for satellites the ECEF
velocity already holds the Earth's rotation). A shift the record resolves (|f_d| >= 1 / T_ov)
splits the homodyne line (thesis Appendix D): the SNR takes the link tier's split factor and the
beat reads f_R + f_d, so the range carries f_d / kappa of error, as a real up-chirp does.
"""

from __future__ import annotations

import numpy as np

from ..channel.effects import channel_returns
from ..config.loader import config_with
from ..doppler import doppler_shift_hz
from ..geometry.raycast import weighted_range_stats
from ..target import (cox_munk_mss, lambertian_power_fraction, receiver_cone_half_angle_rad,
                      specular_return_fraction)
from ..tiers.budget import make_budget, reference_delay_s
from ..tiers.common import beat_flags
from ..tiers.link import carrier_fading_factor, crb_sigma_f_hz, simulate_link
from ..units import SPEED_OF_LIGHT_M_S, db_to_ratio
from .survey import stream

STREAM_EFFECTS = 100      # + beam index: each beam's effect draws
STREAM_NOISE = 200        # measurement noise of the link tier
STREAM_RF = 1_000_000     # + flat shot index: each rf shot's own stream
STREAM_BASEBAND = 300     # + batch index: each baseband batch's stream
STREAM_FADING = 900_000   # carrier-phase fading of the link tier (below STREAM_RF, above the
                          # baseband batches of any practical chunk)
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
    """(n, b) round-trip atmospheric x optical x attenuator power transmission."""
    z_ground = geom.hit_xyz_m[..., 2]
    z_plat = np.broadcast_to(geom.platform_xyh[:, 2:3], z_ground.shape)
    ok = np.isfinite(z_ground)
    zen = geom.off_nadir_rad
    t1 = np.ones(z_ground.shape)
    if np.any(ok):
        t1[ok] = scene.one_way_power_transmission(z_ground[ok], z_plat[ok], zen[ok])
    ch = config.channel
    return t1 ** 2 * ch.optical_transmission ** 2 * float(db_to_ratio(-ch.extra_attenuation_db))


def _effects(config, scene, geom, seq, exclude=("doppler",)):
    """(n, b) power factor of the enabled channel effects, each beam on its own streams."""
    names = [e for e in scene.effects if e not in exclude and e != "phase_noise"]
    n, b = geom.range_true_m.shape
    if not names or n == 0:
        return np.ones((n, b))
    hit = np.isfinite(geom.range_true_m)
    r_med = float(np.median(geom.range_true_m[hit])) if np.any(hit) else 1.0
    over = {"effects.enabled": list(names), "channel.distance_m": r_med,
            "channel.free_space": True}
    if "turbulence" in names:
        over["channel.cn2_m_minus_2_3"] = _equivalent_cn2(config, scene, geom, r_med)
    cfg = config_with(config, over)
    out = np.empty((n, b))
    for j in range(b):  # a handful of beams; the shots are vectorised
        out[:, j] = channel_returns(cfg, n, stream(seq, STREAM_EFFECTS + j)).power_factor
    return out


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


def _link_table(config, r_lo, r_hi, a_lo, a_hi, doppler: bool):
    """SNR [dB] on (range, attenuation) nodes and T_ov [s] per range node, plus the SNR factor
    of a resolved Doppler split, from the link tier's closed form."""
    lw = config.laser.linewidth_hz > 0
    base = _node_config(config, ["phase_noise"] if lw else [])
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
        cfg_r = config_with(base, {"channel.distance_m": float(r)})
        for j, a in enumerate(a_nodes):
            out = simulate_link(config_with(cfg_r, {"channel.extra_attenuation_db": float(a)}),
                                rng, batch=1)
            snr_db[i, j] = out["SNR"][0]
        t_ov[i] = out["t_overlap_s"][0]
    split = 1.0
    if doppler and config.system.receiver == "coherent":
        # Appendix D: a resolved Doppler shift splits the real homodyne line; the factor is the
        # link tier's own (it depends on the carrier-phase convention), read at one node.
        r = float(r_nodes[0])
        f_big = 20.0 / t_ov[0]
        dop = config_with(_node_config(config, (["phase_noise"] if lw else []) + ["doppler"]),
                          {"channel.distance_m": r,
                           "effects.doppler.radial_velocity_mps": f_big * config.laser.wavelength_m / 2,
                           "channel.extra_attenuation_db": float(a_nodes[0])})
        on = simulate_link(dop, rng, batch=1)["SNR"][0]
        split = float(db_to_ratio(on - snr_db[0, 0]))
    snr_db = np.where(np.isfinite(snr_db), snr_db, -300.0)
    return r_nodes, a_nodes, snr_db, t_ov, split


def received_power(config, scene, geom, seq, *, exclude_effects=("doppler",)):
    """Per shot-beam: (P_sig [W], power-weighted mean range [m], range std [m], sub-ray power
    fractions (n, b, k) after transmission and effects)."""
    bud = make_budget(config)
    frac = sub_ray_power_fractions(config, scene, geom)
    scale = _transmission(config, scene, geom) * _effects(config, scene, geom, seq,
                                                          exclude=exclude_effects)
    mean, std, tot = weighted_range_stats(frac, geom.sub_range_m)
    return bud.ptx_w * tot * scale, mean, std, frac * scale[..., None]


def doppler_hz(config, scene, geom):
    if "doppler" not in scene.effects:
        return np.zeros_like(geom.closing_speed_mps)
    return doppler_shift_hz(geom.closing_speed_mps, config.laser.wavelength_m)


def measure_link(config, scene, geom, seq) -> dict:
    """Link-tier measurements of every shot-beam of a chunk: arrays (n, b)."""
    if config.system.modulation != "fm_chirp":
        raise ValueError("survey runs model FM chirps (system.modulation = 'fm_chirp')")
    bud = make_budget(config)
    psig, r_mean, r_std, _ = received_power(config, scene, geom, seq)
    n_grp = config.channel.group_index
    rate = bud.rate_hz_per_s
    ok = np.isfinite(r_mean) & (psig > 0)
    snr = np.full(psig.shape, 0.0)
    f_meas = np.full(psig.shape, np.nan)
    range_meas = np.full(psig.shape, np.nan)
    width = np.full(psig.shape, np.nan)
    delay = 2.0 * n_grp * np.where(ok, r_mean, 1.0) / SPEED_OF_LIGHT_M_S
    ref = reference_delay_s(config, delay, rate)
    lag = np.mod(delay - ref, bud.train.period_s)
    f_b = rate * lag
    no_overlap, out_of_band = beat_flags(config, bud, lag, f_b)
    if np.any(ok):
        h = psig[ok] / bud.ptx_w
        att = 10.0 * np.log10(reference_power_fraction(config, r_mean[ok]) / h)
        r_nodes, a_nodes, table, t_nodes, split = _link_table(
            config, float(r_mean[ok].min()), float(r_mean[ok].max()), float(att.min()),
            float(att.max()), "doppler" in scene.effects)
        snr_ok = db_to_ratio(_interp_table(r_nodes, a_nodes, table, r_mean[ok], att))
        t_ov = np.interp(r_mean[ok], r_nodes, t_nodes)
        f_d = doppler_hz(config, scene, geom)[ok]
        resolved = np.abs(f_d) >= 1.0 / t_ov
        # Carrier fading about the nodes' mean phase power; a resolved Doppler split replaces it.
        fade = carrier_fading_factor(config, stream(seq, STREAM_FADING), snr_ok.size)
        snr_ok = np.where(resolved, snr_ok * split, snr_ok * fade)
        # Footprint spread: a broadened line of width ratio g (module docstring).
        sigma_f = rate * 2.0 * n_grp * r_std[ok] / SPEED_OF_LIGHT_M_S
        g = np.sqrt(1.0 + (2.355 * sigma_f * t_ov / 0.886) ** 2)
        snr_ok = snr_ok / g
        t_eff = t_ov / g
        noise = stream(seq, STREAM_NOISE).standard_normal(snr_ok.shape)
        fm = (f_b[ok] + np.where(resolved, f_d, 0.0)
              + crb_sigma_f_hz(snr_ok, config.processing.rbw_hz, t_eff) * noise)
        snr[ok] = snr_ok
        width[ok] = 0.886 / t_eff  # 3 dB width of a rectangular-envelope tone of duration t_eff
        f_meas[ok] = fm
        range_meas[ok] = SPEED_OF_LIGHT_M_S * (fm / rate + ref[ok]) / (2.0 * n_grp)
    return _finish(config, geom, psig, snr, f_meas, range_meas, width, ok, no_overlap,
                   out_of_band)


def _finish(config, geom, psig, snr, f_meas, range_meas, width, ok, no_overlap,
            out_of_band) -> dict:
    thr = float(db_to_ratio(config.survey.detection_threshold_db))
    hit = np.isfinite(geom.range_true_m)
    detected = np.where(hit, np.where(ok & (snr >= thr) & ~no_overlap & ~out_of_band, 1, 0), 2)
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


def measure_rf(config, scene, geom, seq, progress=None) -> dict:
    """rf-tier measurements: each shot-beam is simulated at full rate, its footprint's sub-rays
    summed coherently as delayed echoes (``tiers.rf`` ``echoes``): a sloped or rough footprint
    broadens the beat peak. With ``speckle`` enabled the echoes carry independent uniform phases
    (each sub-ray's patch is an independent scatterer: their sum is the speckle, so the speckle
    effect's own gamma draw is not applied); otherwise the propagation phase -2 pi nu dtau."""
    from ..tiers.echoes import Echoes
    from ..tiers.rf import simulate_rf

    bud = make_budget(config)
    psig, r_mean, _, frac = received_power(config, scene, geom, seq,
                                           exclude_effects=("doppler", "speckle"))
    n, b = psig.shape
    ok = np.isfinite(r_mean) & (psig > 0)
    lw = config.laser.linewidth_hz > 0
    enabled = (["phase_noise"] if lw else []) + (["doppler"] if "doppler" in scene.effects else [])
    base = _node_config(config, enabled)
    snr = np.zeros((n, b))
    f_meas = np.full((n, b), np.nan)
    range_meas = np.full((n, b), np.nan)
    width = np.full((n, b), np.nan)
    no_overlap = np.zeros((n, b), bool)
    out_of_band = np.zeros((n, b), bool)
    nu = SPEED_OF_LIGHT_M_S / config.laser.wavelength_m
    n_grp = config.channel.group_index
    speckle = "speckle" in scene.effects
    for flat in np.flatnonzero(ok.ravel()):  # the rf tier is the reference: one shot at a time
        i, j = divmod(int(flat), b)
        r0 = float(r_mean[i, j])
        att = float(10 * np.log10(reference_power_fraction(config, r0) * bud.ptx_w / psig[i, j]))
        over = {"channel.distance_m": r0, "channel.extra_attenuation_db": att}
        if "doppler" in enabled:
            over["effects.doppler.radial_velocity_mps"] = float(geom.closing_speed_mps[i, j])
        cfg = config_with(base, over)
        rng = stream(seq, STREAM_RF + int(flat))
        w = frac[i, j]
        keep = w > 0
        dtau = 2.0 * n_grp * (geom.sub_range_m[i, j][keep] - r0) / SPEED_OF_LIGHT_M_S
        phase = (rng.uniform(0.0, 2 * np.pi, dtau.size) if speckle
                 else -2 * np.pi * np.mod(nu * dtau, 1.0))
        out = simulate_rf(cfg, rng, batch=1, echoes=Echoes(dtau, w[keep], phase))
        snr[i, j] = float(db_to_ratio(out["SNR"][0]))
        f_meas[i, j] = out["f_beat_hz"][0]
        range_meas[i, j] = out["d_rx"][0]
        width[i, j] = out["d_3dB"][0] * 2.0 * n_grp * bud.rate_hz_per_s / SPEED_OF_LIGHT_M_S
        no_overlap[i, j] = "no_overlap" in out["flags"]
        out_of_band[i, j] = "beat_out_of_band" in out["flags"]
        if progress is not None:
            progress(1)
    return _finish(config, geom, psig, snr, f_meas, range_meas, width, ok, no_overlap,
                   out_of_band)


def measure_baseband(config, scene, geom, seq, progress=None) -> dict:
    """Baseband-tier measurements of a chunk, in batches of shots: each shot's footprint sub-rays
    become echoes (as in :func:`measure_rf`), its received power and Doppler per-shot returns.

    Shots are sorted by range and batched; a batch shares one instrument configuration aimed at
    its median range, so the ``sys.fmaxopt`` range gate (when ``system.reference_delay_s`` is
    unset) is set per batch of at most BASEBAND_BATCH neighbouring ranges, not per shot; each
    shot's own delay enters exactly as its echoes' offsets from that range.
    """
    from ..channel.effects import ShotReturns
    from ..tiers.baseband import band_top_hz_or_nyquist, baseband_grid, simulate_baseband
    from ..tiers.echoes import Echoes

    bud = make_budget(config)
    band_top = band_top_hz_or_nyquist(config, bud, baseband_grid(config, bud)[0])
    psig, r_mean, _, frac = received_power(config, scene, geom, seq,
                                           exclude_effects=("doppler", "speckle"))
    n, b = psig.shape
    ok = np.isfinite(r_mean) & (psig > 0)
    lw = config.laser.linewidth_hz > 0
    base = _node_config(config, ["phase_noise"] if lw else [])
    snr = np.zeros((n, b))
    f_meas, range_meas, width = (np.full((n, b), np.nan) for _ in range(3))
    no_overlap = np.zeros((n, b), bool)
    out_of_band = np.zeros((n, b), bool)
    nu = SPEED_OF_LIGHT_M_S / config.laser.wavelength_m
    n_grp = config.channel.group_index
    speckle = "speckle" in scene.effects
    f_d_all = doppler_hz(config, scene, geom)
    flat = np.flatnonzero(ok.ravel())
    flat = flat[np.argsort(r_mean.ravel()[flat], kind="stable")]
    for batch_index, start in enumerate(range(0, flat.size, BASEBAND_BATCH)):
        idx = flat[start:start + BASEBAND_BATCH]
        ii, jj = np.divmod(idx, b)
        r0 = float(np.median(r_mean[ii, jj]))
        cfg = config_with(base, {"channel.distance_m": r0, "channel.extra_attenuation_db": 0.0})
        bud_batch = make_budget(cfg)
        rng = stream(seq, STREAM_BASEBAND + batch_index)
        w = frac[ii, jj]                                                  # (m, k)
        dtau = 2.0 * n_grp * (np.where(w > 0, geom.sub_range_m[ii, jj], r0) - r0) / SPEED_OF_LIGHT_M_S
        phase = (rng.uniform(0.0, 2 * np.pi, dtau.shape) if speckle
                 else -2 * np.pi * np.mod(nu * dtau, 1.0))
        per_shot = ShotReturns(power_factor=psig[ii, jj] / bud_batch.psig_w, phase_rad=np.zeros(idx.size),
                               doppler_hz=f_d_all[ii, jj])
        out = simulate_baseband(cfg, rng, batch=idx.size, echoes=Echoes(dtau, w, phase),
                                shot_returns=per_shot)
        snr[ii, jj] = db_to_ratio(out["SNR"])
        f_meas[ii, jj] = out["f_beat_hz"]
        range_meas[ii, jj] = out["d_rx"]
        width[ii, jj] = out["d_3dB"] * 2.0 * n_grp * bud.rate_hz_per_s / SPEED_OF_LIGHT_M_S
        # Per-shot flags from each shot's own lag (the tier's flags describe the batch's centre).
        delay = 2.0 * n_grp * r_mean[ii, jj] / SPEED_OF_LIGHT_M_S
        lag = np.mod(delay - bud_batch.ref_delay_s, bud.train.period_s)
        f_b = bud.rate_hz_per_s * lag
        no_overlap[ii, jj], out_of_band[ii, jj] = beat_flags(cfg, bud, lag, f_b)
        out_of_band[ii, jj] |= f_b > band_top
        if progress is not None:
            progress(idx.size)
    return _finish(config, geom, psig, snr, f_meas, range_meas, width, ok, no_overlap,
                   out_of_band)

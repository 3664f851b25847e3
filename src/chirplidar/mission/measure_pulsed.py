"""Pulsed-tier measurements of a survey chunk: a short-pulse altimeter over the footprints.

Each shot-beam's footprint (``chirplidar.channel.footprint``) returns a fraction of the pulse's
energy from each sub-ray; the pulsed tier (``chirplidar.tiers.pulsed``) sums the sub-rays' pulses
at their own delays (direct detection adds powers: slope and roughness spread the waveform),
counts photoelectrons against the background and reads the range off the digitized waveform.

Range window: the digitizer records ``digitizer.record_samples`` samples. As an altimeter's
tracker, the window is centred on the return: the shots of a batch (sorted by range, spanning
at most a quarter of the window) share a window centred on their median range. A return the
window does not hold is not detected.

Background (``[background]``): ``"sun"`` takes the sun's elevation at the scene centre at each
shot's time (``chirplidar.geometry.sun``; the sun moves by far less than a degree across a
scene), the surface's reflectance at the wavelength (the sub-rays' material), the sunlight's
path down through the scene's atmosphere at the sun's zenith angle (from
:data:`SUN_PATH_TOP_M`) and up along the beam to the platform; ``"radiance"`` a fixed spectral
radiance; ``"none"`` is dark. A pulsed survey without ``[background]`` is refused (preflight).
"""

from __future__ import annotations

import numpy as np

from ..channel.footprint import footprint_transmission
from ..channel.lab import collected_background_w
from ..config.instrument import instrument_from_config
from ..processing.ranging import two_way_delay_s
from ..streams import stream
from ..tiers.echoes import Echoes
from ..tiers.model import Returns
from ..tiers.registry import TIERS
from ..units import SPEED_OF_LIGHT_M_S
from ..waveform.pulse import peak_power_per_joule

#: The top of the sunlight's path through the scene's atmosphere (m): an exponential
#: atmosphere's extinction has ended well below it.
SUN_PATH_TOP_M = 100e3
#: Shots per pulsed-tier batch, and the largest spread of their ranges as a share of the
#: digitizer's window (the batch shares one window centred on its median range).
PULSED_BATCH = 256
WINDOW_SHARE = 0.25


def sun_elevation_rad(config, scene, t_s) -> np.ndarray:
    """(n,) the sun's elevation at the scene centre at the shot times ``t_s`` (s after
    ``survey.epoch_utc``)."""
    from ..geometry.earth_orientation import mjd_utc
    from ..geometry.sun import sun_elevation_deg

    lat, lon = scene.center_lat_lon_deg
    mjd = mjd_utc(config.survey.epoch_utc) + np.asarray(t_s, float) / 86400.0
    return np.radians(sun_elevation_deg(lat, lon, mjd))


def background_power_per_shot_w(config, scene, geom) -> np.ndarray:
    """(n, b) background light the receiver collects at each shot-beam (W); see the module
    docstring."""
    from ..receiver.background import surface_solar_radiance_w_m2_sr_m

    bg = config.background
    shape = geom.range_true_m.shape
    if bg.source == "none":
        return np.zeros(shape)
    if bg.source == "radiance":
        radiance = np.full(shape, bg.radiance_w_m2_sr_m)
    else:
        hit = np.isfinite(geom.range_true_m)
        z_g = np.where(hit, geom.hit_xyz_m[..., 2], 0.0)
        z_p = np.broadcast_to(geom.platform_xyh[:, 2:3], shape)
        elev = np.broadcast_to(sun_elevation_rad(config, scene, geom.t_s)[:, None], shape)
        sun_zen = np.clip(np.pi / 2 - elev, 0.0, np.radians(89.0))
        down = scene.one_way_power_transmission(z_g, SUN_PATH_TOP_M, sun_zen)
        up = scene.one_way_power_transmission(z_g, z_p, np.where(hit, geom.off_nadir_rad, 0.0))
        rho = scene.material_reflectivity(config.wavelength_m)[np.where(hit, geom.material, 0)]
        radiance = np.where(hit, surface_solar_radiance_w_m2_sr_m(
            bg.solar_irradiance_w_m2_m, elev, rho, down * up), 0.0)
    return collected_background_w(config, radiance)


def range_batches(range_m: np.ndarray, flat: np.ndarray, window_m: float):
    """Flat shot-beam indices ``flat`` in batches of neighbouring ranges: sorted by range, at
    most :data:`PULSED_BATCH` shots spanning at most ``WINDOW_SHARE`` of the window."""
    order = flat[np.argsort(range_m.ravel()[flat], kind="stable")]
    r = range_m.ravel()[order]
    start = 0
    while start < order.size:
        stop = min(start + PULSED_BATCH, order.size)
        stop = start + max(1, int(np.searchsorted(r[start:stop], r[start] + WINDOW_SHARE
                                                  * window_m, side="right")))
        yield order[start:stop]
        start = stop


def pulsed_batch_returns(config, geom, transmission, range_m, frac, background_w,
                         idx) -> Returns:
    """The returns of the shot-beams ``idx`` (flat): one window centred on the median of their
    power-weighted mean ranges ``range_m``, each shot's sub-rays as echoes at their delays from
    it, its energy transmission as its power factor."""
    b = transmission.shape[1]
    ii, jj = np.divmod(idx, b)
    n_grp = config.channel.group_index
    sub = geom.sub_range_m[ii, jj]                                   # (m, k)
    w = np.where(np.isfinite(sub), frac[ii, jj], 0.0)
    r0 = float(np.median(range_m[ii, jj]))
    dtau = 2.0 * n_grp * (np.where(w > 0, sub, r0) - r0) / SPEED_OF_LIGHT_M_S
    t_mean = float(np.mean(transmission[ii, jj]))
    return Returns(transmission=t_mean, delay_s=float(two_way_delay_s(r0, n_grp)), range_m=r0,
                   group_index=n_grp, power_factor=transmission[ii, jj] / t_mean,
                   phase_rad=0.0, doppler_hz=0.0, carrier_phase="optimal",
                   echoes=Echoes(dtau, w, np.zeros_like(w)),
                   background_power_w=background_w[ii, jj], batch=idx.size)


def measure_pulsed(config, scene, geom, seq, progress=None) -> dict:
    """Pulsed-tier measurements of every shot-beam of a chunk: the survey's fields (n, b) with
    ``pulse_width`` (the received waveform's RMS width, s) for ``beat_width``'s place and
    ``range_sigma`` (the range's Cramer-Rao bound, m) for ``h_li_sigma``."""
    instrument = instrument_from_config(config)
    transmission, r_mean, _, frac, _ = footprint_transmission(config, scene, geom, seq)
    n, b = transmission.shape
    ok = np.isfinite(r_mean) & (transmission > 0)
    background_w = background_power_per_shot_w(config, scene, geom)
    dig = config.digitizer
    window_m = SPEED_OF_LIGHT_M_S * dig.record_samples / dig.sample_rate_hz \
        / (2.0 * config.channel.group_index)
    cols = {name: np.full((n, b), np.nan) for name in ("snr_db", "range", "width", "sigma")}
    seen = np.zeros((n, b), bool)
    flat = np.flatnonzero(ok.ravel())
    for batch_index, idx in enumerate(range_batches(r_mean, flat, window_m)):
        returns = pulsed_batch_returns(config, geom, transmission, r_mean, frac, background_w,
                                       idx)
        out = TIERS["pulsed"].simulate(instrument, returns, stream(seq, "pulsed_batch",
                                                                   batch_index))
        rows = np.divmod(idx, b)
        cols["snr_db"][rows] = out["SNR"]
        cols["range"][rows] = out["d_rx"]
        cols["width"][rows] = out["pulse_width_s"]
        cols["sigma"][rows] = out["d_sigma"]
        seen[rows] = np.asarray(out["detected"], bool)
        if progress is not None:
            progress(idx.size)
    hit = np.isfinite(geom.range_true_m)
    detected = np.where(~hit, 2, np.where(ok & seen, 1, 0)).astype(np.int8)
    det = detected == 1
    p = instrument.pulse
    energy_w = p.energy_j * peak_power_per_joule(p.shape, p.duration_s)   # the pulse's peak
    return {
        "received_power": np.where(hit, energy_w * transmission, np.nan),
        "snr_db": np.where(hit & ok, cols["snr_db"], np.nan),
        "beat_frequency": np.full((n, b), np.nan),
        "beat_width": np.full((n, b), np.nan),
        "pulse_width": np.where(det, cols["width"], np.nan),
        "range_measured": np.where(det, cols["range"], np.nan),
        "range_sigma": np.where(det, cols["sigma"], np.nan),
        "detected": detected,
    }

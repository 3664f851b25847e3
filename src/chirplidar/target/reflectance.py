"""Received / transmitted power for diffuse (Lambertian) and specular (water, smooth ice) targets.

All functions are vectorised: array arguments broadcast against each other (a leading shot axis is
the usual use); 0-d results come back as Python floats. Angles in radians, lengths in metres.

Lambertian target, monostatic (thesis eq. 2.2.3 in power form, with the incidence angle)
---------------------------------------------------------------------------------------
A beam of power P fully intercepted by a surface tilted by theta (angle between the beam and the
surface normal) lights a footprint of area A_s = A_beam / cos(theta), so the irradiance on the
surface is E = P cos(theta) / A_beam. A Lambertian reflector of reflectance rho has radiance
L = rho E / pi. The receiver, looking back along the beam, sees the footprint foreshortened to
A_s cos(theta) = A_beam, so the reflected intensity towards it is I = L A_beam = rho P cos(theta)/pi
and the received power is I A_r / R^2:

    P_r / P_t = (rho / pi) cos(theta) A_r / R^2.

cos(theta) enters **once**: the 1/cos from the stretched footprint cancels the cos of the
foreshortened view, leaving the cos of the reduced irradiance. At theta = 0 this is eq. 2.2.3
(E_s = rho P_T A_r tau / (pi R^2)). The far-field form assumes R^2 >> A_r and a footprint small
against R; atmospheric and optical transmissions (thesis atm.T_atm, atm.T_opt) multiply separately.
"""

from __future__ import annotations

import numpy as np
from scipy import special

from .._checks import (
    non_negative_array,
    out,
    positive_array,
    real_array,
    unit_interval_array,
)

_HALF_PI = 0.5 * np.pi

#: Cox & Munk (1954) clean-surface fit: mean-square slope = 0.003 + 5.12e-3 U (U at 12.5 m, m/s),
#: measured for U up to about 14 m/s.
COX_MUNK_MSS_OFFSET = 3.0e-3
COX_MUNK_MSS_PER_MPS = 5.12e-3
COX_MUNK_MAX_WIND_MPS = 14.0

# Small-angle model limit for the receiver cone and the beam divergence (rad).
_MAX_SMALL_ANGLE_RAD = 0.1

# Gauss-Legendre nodes on phi in (0, pi) for the cone integral (see specular_return_fraction).
_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(64)
_PHI = 0.5 * np.pi * (_NODES + 1.0)
_PHI_W = 0.5 * np.pi * _WEIGHTS


def _incidence(incidence_rad) -> np.ndarray:
    theta = real_array("incidence_rad", incidence_rad)
    if np.any(theta < 0.0):
        raise ValueError(
            "incidence_rad must be >= 0 (the angle between the beam and the surface "
            "normal, 0 = normal incidence)"
        )
    return theta


def facing_away(incidence_rad):
    """True where the surface is seen edge-on or from behind (incidence >= 90 deg): no return.

    incidence_rad: array, rad, >= 0. Returns a bool array (or bool) of the same shape.
    """
    theta = _incidence(incidence_rad)
    flag = theta >= _HALF_PI
    return bool(flag) if flag.ndim == 0 else flag


def lambertian_power_fraction(reflectivity, aperture_area_m2, range_m, incidence_rad):
    """Received / transmitted power for a Lambertian target, (rho/pi) cos(theta) A_r / R^2.

    reflectivity: directional-hemispherical reflectance rho in [0, 1] (thesis atm.R_trg);
    aperture_area_m2: receiving area A_r (m^2, > 0); range_m: one-way range R (m, > 0);
    incidence_rad: angle between the beam and the surface normal (rad, >= 0).
    All broadcast; returns float64 W/W (float for scalar inputs).

    cos(theta) enters once (module docstring). For theta >= pi/2 the surface faces away and the
    fraction is exactly 0, never negative; ``facing_away`` gives the flag. theta just below pi/2
    (89.9 deg) gives a tiny positive value (cos = 1.7e-3), not zero. rho = 0 gives exactly 0.
    """
    rho = unit_interval_array("reflectivity", reflectivity)
    area = positive_array("aperture_area_m2", aperture_area_m2)
    rng_m = positive_array("range_m", range_m)
    theta = _incidence(incidence_rad)
    cos_t = np.where(theta < _HALF_PI, np.cos(np.minimum(theta, _HALF_PI)), 0.0)
    return out(rho / np.pi * cos_t * area / rng_m**2)


def fresnel_reflectance(refractive_index, incidence_rad):
    """Unpolarised Fresnel power reflectance of a smooth interface from air, (R_s + R_p) / 2.

    refractive_index: real relative index n2/n1 (> 0); incidence_rad: rad in [0, pi/2].
    At normal incidence this is ((n - 1)/(n + 1))^2 (Born & Wolf, Principles of Optics, Sec. 1.5).
    n < 1 beyond the critical angle gives total internal reflection (1.0).
    """
    n = positive_array("refractive_index", refractive_index)
    theta = _incidence(incidence_rad)
    if np.any(theta > _HALF_PI):
        raise ValueError("incidence_rad must be <= pi/2 for a Fresnel reflectance")
    n, theta = np.broadcast_arrays(n, theta)
    ci = np.cos(theta)
    st2 = (np.sin(theta) / n) ** 2
    tir = st2 >= 1.0
    ct = np.sqrt(np.where(tir, 0.0, 1.0 - st2))
    den_s = ci + n * ct
    den_p = ct + n * ci
    ok = ~tir & (den_s > 0) & (den_p > 0)
    safe_s = np.where(ok, den_s, 1.0)
    safe_p = np.where(ok, den_p, 1.0)
    rs = ((ci - n * ct) / safe_s) ** 2
    rp = ((ct - n * ci) / safe_p) ** 2
    # Grazing incidence (ci = 0) with n > 1 reflects everything as well.
    r = np.where(ok, 0.5 * (rs + rp), 1.0)
    return out(r)


def cox_munk_mss(wind_speed_mps):
    """Total mean-square sea-surface slope for a clean surface: 0.003 + 5.12e-3 U.

    wind_speed_mps: wind speed U at 12.5 m above the sea (m/s), in [0, 14] — the range of the
    measurements (Cox & Munk 1954, J. Opt. Soc. Am. 44, 838-850, clean-surface fit; their
    +-0.004 scatter). Beyond 14 m/s whitecaps and foam dominate and the fit is not a model:
    ValueError; pass a mean-square slope to ``specular_return_fraction`` directly instead.
    U = 0 gives 0.003 (residual roughness), not a mirror: a mirror-flat surface is mss = 0.
    """
    u = non_negative_array("wind_speed_mps", wind_speed_mps)
    if np.any(u > COX_MUNK_MAX_WIND_MPS):
        raise ValueError(
            f"wind_speed_mps must be <= {COX_MUNK_MAX_WIND_MPS} m/s (range of the "
            "Cox-Munk measurements); pass the mean-square slope directly"
        )
    return out(COX_MUNK_MSS_OFFSET + COX_MUNK_MSS_PER_MPS * u)


def receiver_cone_half_angle_rad(aperture_area_m2, range_m):
    """Half-angle (rad) the receiving aperture subtends from the target: sqrt(A_r / pi) / R."""
    area = positive_array("aperture_area_m2", aperture_area_m2)
    rng_m = positive_array("range_m", range_m)
    return out(np.sqrt(area / np.pi) / rng_m)


def specular_return_fraction(
    incidence_rad, mss, fresnel_reflectance, cone_half_angle_rad, beam_divergence_rad
):
    """Fraction of the transmitted power a facet (specular) surface sends back into the receiver.

    incidence_rad: beam angle from the mean surface normal (rad, >= 0; >= pi/2 gives 0);
    mss: total mean-square slope of an isotropic Gaussian facet-slope distribution (>= 0;
    ``cox_munk_mss`` for wind-roughened water, 0 for a mirror);
    fresnel_reflectance: facet power reflectance at normal incidence (``fresnel_reflectance(n, 0)``;
    for backscatter the contributing facets face the beam, so normal incidence is the right one);
    cone_half_angle_rad: receiver aperture half-angle seen from the target (rad, in (0, 0.1]),
    ``receiver_cone_half_angle_rad``; beam_divergence_rad: far-field 1/e^2 intensity half-angle of
    the transmitted beam (rad, in [0, 0.1]; 0 for an ideal collimated beam).
    Broadcast; returns P_r / P_t (float64, float for scalar inputs).

    Geometric optics, single reflection, no shadowing, beam fully intercepted. A facet returns a
    ray to the receiver when its normal lies within cone/2 of the beam direction (a tilt u turns the
    reflected ray by 2u). In the angle (u, v) of the facet normal from the beam direction (u in the
    plane of incidence) the Cox-Munk slope density p(z) = exp(-|z|^2/mss) / (pi mss) becomes a
    Gaussian with mean (-sin(theta) cos(theta), 0) and standard deviations
    (sqrt(mss/2) cos^2 theta, sqrt(mss/2) cos theta) (linearised at the beam direction, exact there),
    and facets of slope z intercept a share (1 + z_x tan theta) of the beam. The fraction is
    rho_F times the weighted probability of the disk |(u, v)| <= cone/2, integrated by 64-point
    Gauss-Legendre quadrature in the in-plane Gaussian's cumulative probability (accurate from a
    mirror to a rough sea), the cross-plane part in closed form (erf). A diverging beam spreads the
    ray directions by divergence/2 per axis, which adds divergence^2 / 2 to the mss.

    Limits (tested): for cone << sqrt(mss) it is the Cox-Munk backscatter
    rho_F exp(-tan^2 theta / mss) cone^2 / (4 mss cos^5 theta) (= sigma0 A_r / (4 pi R^2 cos theta)
    with sigma0 = rho_F sec^4 theta exp(-tan^2 theta/mss)/mss, Barrick 1968); for a mirror
    (mss = 0) and a collimated beam it is rho_F for theta <= cone/2 and 0 outside the specular cone;
    for a mirror and a diverging beam at normal incidence it is rho_F (1 - exp(-cone^2 / (2 div^2)))
    (the aperture's share of the Gaussian beam reflected from the image transmitter at 2R).
    """
    theta = _incidence(incidence_rad)
    s2 = non_negative_array("mss", mss)
    rho_f = unit_interval_array("fresnel_reflectance", fresnel_reflectance)
    cone = positive_array("cone_half_angle_rad", cone_half_angle_rad)
    div = non_negative_array("beam_divergence_rad", beam_divergence_rad)
    if np.any(cone > _MAX_SMALL_ANGLE_RAD):
        raise ValueError(
            f"cone_half_angle_rad must be <= {_MAX_SMALL_ANGLE_RAD} rad (small-angle model)"
        )
    if np.any(div > _MAX_SMALL_ANGLE_RAD):
        raise ValueError(
            f"beam_divergence_rad must be <= {_MAX_SMALL_ANGLE_RAD} rad (small-angle model)"
        )
    theta, s2, rho_f, cone, div = np.broadcast_arrays(theta, s2, rho_f, cone, div)
    shape = theta.shape
    theta, s2, rho_f, cone, div = (np.ravel(x) for x in (theta, s2, rho_f, cone, div))

    result = np.zeros(theta.size)
    front = theta < _HALF_PI
    a = 0.5 * cone  # disk radius in facet-normal angle
    s2_eff = s2 + 0.5 * div**2
    th = np.where(front, theta, 0.0)
    c = np.cos(th)
    s = np.sin(th)
    t = np.tan(th)

    # Mirror and collimated beam: a step at the edge of the specular cone.
    mirror = front & (s2_eff == 0.0)
    result[mirror] = np.where(th[mirror] <= a[mirror], rho_f[mirror], 0.0)

    rough = front & (s2_eff > 0.0)
    if np.any(rough):
        c_r, t_r, a_r = c[rough], t[rough], a[rough]
        sig = np.sqrt(0.5 * s2_eff[rough])
        sig_u = sig * c_r**2  # in-plane spread of the facet-normal angle
        sig_v = sig * c_r  # cross-plane spread
        mu = s[rough] * c_r  # |mean| of the in-plane angle (reflected to >= 0)
        f_lo = special.ndtr((-a_r - mu) / sig_u)
        f_hi = special.ndtr((a_r - mu) / sig_u)
        width = f_hi - f_lo
        # Nodes F = f_lo + width (1 - cos phi)/2 cluster at both ends of the disk, where the
        # cross-plane chord sqrt(a^2 - u^2) has its square-root edge.
        frac = 0.5 * (1.0 - np.cos(_PHI))
        dfrac = 0.5 * np.sin(_PHI) * _PHI_W
        big_f = f_lo[:, None] + width[:, None] * frac[None, :]
        z = mu[:, None] + sig_u[:, None] * special.ndtri(big_f)
        z = np.clip(z, -a_r[:, None], a_r[:, None])
        chord = np.sqrt(np.maximum(a_r[:, None] ** 2 - z**2, 0.0))
        p_v = special.erf(chord / (np.sqrt(2.0) * sig_v[:, None]))
        # Share of the beam on these facets, (1 + z_x tan theta) = (1 + u tan theta)/cos^2 theta
        # with u = -z (the reflection above flipped the in-plane axis).
        weight = (1.0 - z * t_r[:, None]) / c_r[:, None] ** 2
        result[rough] = rho_f[rough] * width * np.sum(p_v * weight * dfrac[None, :], axis=1)
    return out(result.reshape(shape))

"""Telescope optics and fiber coupling against closed forms and independent computations.

References: Shaklan & Roddier 1988 (Appl. Opt. 27, 2334) and Ruilier 1998 (Proc. SPIE 3350, 319)
for plane-wave coupling; Winzer & Leeb 1998 (Opt. Lett. 23, 986) for the monostatic diffuse-target
coupling; Born & Wolf, Principles of Optics, Sec. 8.5 for the Airy pattern; thesis eqs. 2.6.13-2.6.19.
"""

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.special import gamma, i0e, j1

from chirplidar.optics import (
    airy_first_null_rad,
    airy_intensity,
    annulus_mode_autocorrelation,
    beam_fraction_in_disc,
    beam_radius_m,
    coupling_beta,
    coupling_efficiency,
    coupling_mutual_coherence,
    diffraction_divergence_rad,
    fiber_mode_pupil,
    focal_plane_coupling,
    focal_spot_diameter_m,
    footprint_diameter_m,
    fraunhofer,
    fresnel_number,
    is_far_field,
    monostatic_diffuse_coupling,
    optimal_beta,
    optimal_beta_monostatic,
    pupil_field_coupling,
    pupil_grid,
    rayleigh_range_m,
)

LAMBDA_M = 1.31e-6  # thesis operating wavelength
D_M = 0.127  # 5-inch field-trial telescope (thesis Sec. 5)
F_M = D_M / 0.19  # d/f = 0.19, inside the thesis's 0.18 <= d/f <= 0.20


def kolmogorov(d_over_r0):
    """D_phi(rho) = 6.88 (rho D / r0)^(5/3), rho in units of D (Fried 1966; DESIGN.md)."""
    return lambda rho: 6.88 * (rho * d_over_r0) ** (5.0 / 3.0)


# --- Plane-wave coupling ---------------------------------------------------------------------------

def test_closed_form_equals_direct_radial_quadrature():
    # The closed form is the pupil overlap (int_annulus M 2 pi r dr)^2 / (A int |M|^2), M = exp(-r^2/W^2),
    # W = R / beta (derivation in coupling.py); check it, incl. its stable rewrite, against quad.
    for alpha in (0.0, 0.3, 0.9, 0.99):
        for beta in (0.05, 0.7, 1.1209, 2.5, 6.0):
            r, w = 0.5, 0.5 / beta
            num = quad(lambda x, w=w: 2 * np.pi * x * np.exp(-x * x / w / w), alpha * r, r,
                       epsabs=0, epsrel=1e-13)[0] ** 2
            ref = num / (np.pi * r * r * (1 - alpha**2) * np.pi * w * w / 2)
            assert coupling_efficiency(beta, alpha) == pytest.approx(ref, rel=1e-9, abs=1e-300)


def test_optimum_shaklan_roddier_1988():
    # Shaklan & Roddier 1988: optimum beta = 1.1209, eta = 0.8145 for an unobstructed pupil.
    b = optimal_beta(0.0)
    assert abs(b - 1.1209) < 1e-3
    assert abs(coupling_efficiency(b) - 0.8145) < 1e-3
    assert coupling_efficiency(b) >= coupling_efficiency(b * 1.01)
    assert coupling_efficiency(b) >= coupling_efficiency(b * 0.99)


def test_optimum_falls_with_obstruction():
    # Ruilier 1998: the central obstruction lowers the best coupling monotonically.
    best = [coupling_efficiency(optimal_beta(a), a) for a in np.linspace(0.0, 0.9, 10)]
    assert np.all(np.diff(best) < 0)
    # and at fixed beta too
    fixed = [coupling_efficiency(1.12, a) for a in np.linspace(0.0, 0.9, 10)]
    assert np.all(np.diff(fixed) < 0)


@pytest.mark.parametrize("alpha", [0.0, 0.1, 0.2, 0.3, 0.4, 0.5])
def test_numeric_matches_closed_form(alpha):
    # Numeric pupil overlap (n = 256, exact-area edge weights) vs Ruilier 1998 closed form.
    for beta in (optimal_beta(alpha), 0.6, 1.8):
        num = coupling_efficiency(beta, alpha, method="numeric", n=256)
        assert abs(num - coupling_efficiency(beta, alpha)) < 0.003


def test_numeric_converges_with_grid():
    # Error of the midpoint rule with exact-area weights falls as 1/n^2 (measured: 1.5e-4 at n = 64,
    # 1e-5 at n = 256, 2.5e-6 at n = 512 for alpha = 0).
    for alpha in (0.0, 0.3):
        b = optimal_beta(alpha)
        ref = coupling_efficiency(b, alpha)
        err = {n: abs(coupling_efficiency(b, alpha, method="numeric", n=n) - ref)
               for n in (64, 256, 512)}
        assert err[64] > 8 * err[256]
        assert err[512] < 1e-5


def test_pupil_grid_weights_are_exact_areas():
    # Annulus area pi (1 - alpha^2) / 4 (units of D^2) is represented exactly at any n.
    for n in (16, 33, 128):
        for alpha in (0.0, 0.37, 0.99):
            g = pupil_grid(n, alpha)
            assert g.area == pytest.approx(np.pi * (1 - alpha**2) / 4, rel=1e-12)
            assert g.weights.min() >= 0.0 and g.weights.max() <= 1.0
            assert np.allclose(g.x[0], (np.arange(n) + 0.5) / n - 0.5)  # the documented convention
            assert np.allclose(g.y[:, 0], (np.arange(n) + 0.5) / n - 0.5)


def test_piston_changes_nothing_tilt_lowers_coupling():
    n = 128
    g = pupil_grid(n, 0.0)
    b = optimal_beta(0.0)
    flat = coupling_efficiency(b, method="numeric", n=n)
    # A constant phase factors out of the overlap: |e^{ic} int P M|^2 = |int P M|^2 (closed form).
    piston = coupling_efficiency(b, method="numeric", pupil_phase=np.full((n, n), 2.3))
    assert piston == pytest.approx(flat, abs=1e-12)
    # A tilt of 2 pi across D moves the focal spot by lambda f / D (1 lambda/D in angle).
    tilt = 2 * np.pi * g.x
    tilted = coupling_efficiency(b, method="numeric", pupil_phase=tilt)
    assert tilted < 0.2 * flat
    # Shift theorem: same as a flat wave into a fiber displaced by lambda f / D, computed in the
    # focal plane by MFT (an independent code path).
    w0 = b * 2 * LAMBDA_M * F_M / (np.pi * D_M)
    offset = focal_plane_coupling(np.ones((n, n)), D_M / n, LAMBDA_M, F_M, w0, weights=g.weights,
                                  mode_offset_m=(LAMBDA_M * F_M / D_M, 0.0))
    assert tilted == pytest.approx(offset, rel=1e-9)
    # and a smaller tilt costs less
    assert coupling_efficiency(b, method="numeric", pupil_phase=0.5 * tilt) > tilted


def test_focal_plane_overlap_equals_pupil_overlap():
    # Parseval: the Fraunhofer transform is unitary, so the focal-plane overlap with the Gaussian
    # mode equals the pupil-plane overlap with the back-propagated mode (W = lambda f / (pi w0)).
    n = 96
    rng = np.random.default_rng(3)
    for alpha in (0.0, 0.4):
        g = pupil_grid(n, alpha)
        b = coupling_beta(D_M, F_M, 4.6e-6, LAMBDA_M)
        field = np.exp(1j * 0.8 * rng.standard_normal((2, n, n)))  # batch of aberrated fields
        pupil = pupil_field_coupling(field, b, alpha)
        focal = focal_plane_coupling(field, D_M / n, LAMBDA_M, F_M, 4.6e-6, weights=g.weights)
        assert pupil.shape == (2,)
        np.testing.assert_allclose(focal, pupil, rtol=1e-6)


def test_thesis_beta():
    # beta = (pi/2)(d/f)(w0/lambda): SMF-28 MFD 9.2 um at 1310 nm, d/f = 0.19 -> beta = 1.048.
    b = coupling_beta(D_M, F_M, 4.6e-6, LAMBDA_M)
    assert b == pytest.approx(0.5 * np.pi * 0.19 * 4.6 / 1.31, rel=1e-12)
    assert 0.80 < coupling_efficiency(b) < 0.8145


# --- Mean coupling through turbulence --------------------------------------------------------------

def test_mutual_coherence_without_turbulence_is_plane_wave():
    zero = lambda rho: np.zeros_like(rho)
    for alpha in (0.0, 0.3, 0.5):
        b = optimal_beta(alpha)
        for method in ("fft", "lattice"):
            mc = coupling_mutual_coherence(b, alpha, zero, n=128, method=method)
            assert abs(mc - coupling_efficiency(b, alpha, method="numeric", n=128)) < 1e-5
            assert abs(mc - coupling_efficiency(b, alpha)) < 0.003
        radial = coupling_mutual_coherence(b, alpha, zero, method="radial")
        assert radial == pytest.approx(coupling_efficiency(b, alpha), rel=1e-6)


def test_mutual_coherence_falls_with_d_over_r0():
    ratios = np.geomspace(0.1, 10.0, 12)
    for method in ("fft", "radial"):
        vals = [coupling_mutual_coherence(1.12, 0.0, kolmogorov(q), n=64, method=method)
                for q in ratios]
        assert np.all(np.diff(vals) < 0)
        assert 0 < vals[-1] < 0.02 and vals[0] > 0.79


def _square_law_reference(beta, alpha, rho0):
    """<eta> for D_phi = 2 (rho / rho0)^2 by direct quadrature (independent of the FFT/radial code).

    exp(-|r1 - r2|^2 / rho0^2) integrates over both azimuths to (2 pi)^2 exp(-(r1^2 + r2^2)/rho0^2)
    I0(2 r1 r2 / rho0^2) (as in Dikmelik & Davidson 2005, Appl. Opt. 44, 4946), leaving a 2-D
    integral over the two radii.
    """
    r_out, r_in, w = 0.5, 0.5 * alpha, 0.5 / beta
    edges = np.linspace(r_in, r_out, 201)
    x, wx = np.polynomial.legendre.leggauss(8)
    r = (0.5 * (edges[:-1] + edges[1:])[:, None] + 0.5 * np.diff(edges)[:, None] * x).ravel()
    wr = (0.5 * np.diff(edges)[:, None] * wx).ravel()
    r1, r2 = r[:, None], r[None, :]
    integrand = (r1 * r2 * np.exp(-(r1**2 + r2**2) / w**2 - (r1 - r2) ** 2 / rho0**2)
                 * i0e(2 * r1 * r2 / rho0**2))
    num = 4 * np.pi**2 * (wr[:, None] * wr[None, :] * integrand).sum()
    return num / (np.pi * (r_out**2 - r_in**2) * np.pi * w * w / 2)


@pytest.mark.parametrize("alpha,rho0", [(0.0, 0.3), (0.0, 0.05), (0.3, 0.1), (0.0, 0.004)])
def test_mutual_coherence_square_law_closed_reduction(alpha, rho0):
    # rho0 = 0.004 D is 4x smaller than the n = 64 grid step: the hard case r0 << pixel.
    b = 1.1
    ref = _square_law_reference(b, alpha, rho0)
    sf = lambda rho: 2 * (rho / rho0) ** 2
    assert coupling_mutual_coherence(b, alpha, sf, method="radial") == pytest.approx(ref, rel=1e-6)
    assert coupling_mutual_coherence(b, alpha, sf, n=64) == pytest.approx(ref, rel=5e-3)


def test_mutual_coherence_kolmogorov_small_r0_asymptote():
    # For r0 << D: <eta> -> C(0) int exp(-3.44 (rho/r0)^(5/3)) d^2rho / (A int M^2)
    #   = (1 - exp(-2 beta^2)) * 8 Gamma(6/5) / ((5/3) 3.44^(6/5)) * (r0 / D)^2   (alpha = 0).
    b, q = 1.12, 2000.0  # r0 = D / 2000, 30x below the n = 64 pixel pitch
    asym = -np.expm1(-2 * b * b) * 8 * gamma(1.2) / (5 / 3 * 3.44**1.2) / q**2
    for method, tol in (("radial", 2e-3), ("fft", 3e-3)):
        val = coupling_mutual_coherence(b, 0.0, kolmogorov(q), n=64, method=method)
        assert np.isfinite(val) and val == pytest.approx(asym, rel=tol)


def test_annulus_autocorrelation_geometry():
    # beta -> 0 (M = 1): C(rho) is the overlap area of two discs of radius R = 1/2 (closed form).
    rho = np.array([0.0, 0.1, 0.5, 0.9, 1.0, 1.2])
    lens = 2 * 0.25 * np.arccos(np.minimum(rho, 1)) - rho / 2 * np.sqrt(np.maximum(1 - rho**2, 0))
    np.testing.assert_allclose(annulus_mode_autocorrelation(rho, 1e-6, 0.0), lens, atol=1e-9)


# --- Monostatic diffuse target: the thesis's "approximately 42 %" ----------------------------------

def test_monostatic_diffuse_coupling_is_42_percent():
    # Winzer & Leeb 1998: "a maximum coupling efficiency of approximately 42% can be obtained for a
    # monostatic system" -- the value the thesis quotes on p. 59 (ref. 22), 3.8 dB.
    b = optimal_beta_monostatic(0.0)
    eta = monostatic_diffuse_coupling(b)
    assert abs(eta - 0.42) < 0.01 and abs(b - 1.15) < 0.01
    assert abs(-10 * np.log10(eta) - 3.8) < 0.1
    # The lattice sum converges to the grid-free value as 1/n.
    err = [monostatic_diffuse_coupling(b, method="fft", n=n) - eta for n in (32, 128)]
    assert 0 < err[1] < err[0] < 0.002


def test_monostatic_speckle_monte_carlo():
    # Speckle Monte Carlo: transmit the truncated mode, give each target sample a random phase, let
    # the speckle back to the pupil, couple. Mean coupled / mean incident power must equal the
    # van Cittert-Zernike lattice formula (same grid). 20000 draws: MC std 0.4 % (ratio estimator);
    # measured agreement 0.18 %; tolerance 5 sigma.
    n, pad, b = 16, 32, 1.15
    rng = np.random.default_rng(2024)
    g = pupil_grid(n, 0.0)
    m = fiber_mode_pupil(g, b)
    tx = np.zeros((pad, pad))
    tx[:n, :n] = g.weights * m
    amp = np.abs(np.fft.fft2(tx))
    coupled = incident = 0.0
    for _ in range(10):
        target = amp * np.exp(2j * np.pi * rng.random((2000, pad, pad)))
        rx = np.fft.ifft2(target)[:, :n, :n]
        coupled += np.sum(np.abs(np.einsum("kij,ij->k", rx, g.weights * m)) ** 2) * g.pixel_area
        incident += np.sum(np.abs(rx) ** 2 * g.weights)
    eta_mc = coupled / (incident * np.pi / (8 * b * b))
    assert eta_mc == pytest.approx(monostatic_diffuse_coupling(b, method="fft", n=n), rel=0.02)


# --- Diffraction -----------------------------------------------------------------------------------

def test_airy_first_null_eq_2_6_18():
    th = airy_first_null_rad(D_M, LAMBDA_M)
    # eq. 2.6.18: sin(theta) = 1.22 lambda / d; the exact coefficient is j_{1,1}/pi = 1.21967.
    assert np.sin(th) == pytest.approx(1.22 * LAMBDA_M / D_M, rel=5e-4)
    assert np.sin(th) == pytest.approx(3.8317059702 / np.pi * LAMBDA_M / D_M, rel=1e-10)
    assert airy_intensity(th, D_M, LAMBDA_M) < 1e-25
    assert focal_spot_diameter_m(D_M, LAMBDA_M, F_M) == pytest.approx(np.sin(th) * F_M, rel=1e-9)
    # An obstruction moves the first null inwards (Born & Wolf 8.6, annular aperture).
    th_obs = airy_first_null_rad(D_M, LAMBDA_M, 0.3)
    assert th_obs < th and airy_intensity(th_obs, D_M, LAMBDA_M, 0.3) < 1e-20


def test_airy_unobstructed_values():
    # Born & Wolf Sec. 8.5.2: I = [2 J1(x)/x]^2, x = pi D sin(theta)/lambda; first ring maximum at
    # x = 5.1356 with I = 0.0175, second null at x = 7.0156; I(1) = (2 J1(1))^2 = 0.7745781.
    to_theta = lambda x: np.arcsin(x * LAMBDA_M / (np.pi * D_M))
    assert airy_intensity(0.0, D_M, LAMBDA_M) == 1.0
    assert airy_intensity(to_theta(1.0), D_M, LAMBDA_M) == pytest.approx(0.7745781, abs=1e-6)
    assert airy_intensity(to_theta(5.1356), D_M, LAMBDA_M) == pytest.approx(0.0175, abs=5e-5)
    assert airy_intensity(to_theta(7.0156), D_M, LAMBDA_M) < 1e-8
    x = np.array([0.3, 2.0, 4.0, 9.0])
    np.testing.assert_allclose(airy_intensity(to_theta(x), D_M, LAMBDA_M), (2 * j1(x) / x) ** 2,
                               rtol=1e-12)
    # obstructed pattern is 1 on axis and has a brighter first ring (Born & Wolf 8.6)
    assert airy_intensity(0.0, D_M, LAMBDA_M, 0.5) == 1.0
    assert airy_intensity(to_theta(5.1356), D_M, LAMBDA_M, 0.5) > 0.0175


@pytest.mark.parametrize("alpha", [0.0, 0.3])
def test_fraunhofer_fft_and_mft_match_airy(alpha):
    n = 128
    g = pupil_grid(n, alpha)
    dx = D_M / n
    field_fft, u = fraunhofer(g.weights, dx, LAMBDA_M, F_M, method="fft", n_out=4 * n)
    field_mft, u2 = fraunhofer(g.weights, dx, LAMBDA_M, F_M, method="mft", n_out=4 * n)
    np.testing.assert_allclose(u, u2)
    np.testing.assert_allclose(field_fft, field_mft, atol=1e-12 * np.abs(field_mft).max())
    # Parseval: focal power = pupil power of the sampled field (periodic focal plane, one period).
    du = u[1] - u[0]
    assert np.sum(np.abs(field_fft) ** 2) * du**2 == pytest.approx(np.sum(g.weights**2) * dx**2,
                                                                  rel=1e-10)
    # MFT at fine, arbitrary sampling (0.1 lambda f / D) out to 5 lambda / D.
    k_max = 5.0
    fine, uf = fraunhofer(g.weights, dx, LAMBDA_M, F_M, method="mft", n_out=101,
                          dx_out_m=0.1 * LAMBDA_M * F_M / D_M)
    for field, uu in ((field_fft, u), (fine, uf)):
        intensity = np.abs(field) ** 2
        c = uu.size // 2
        intensity = intensity / intensity[c, c]
        rr = np.hypot(*np.meshgrid(uu, uu))
        theta = np.arcsin(rr / F_M)  # sin(theta) = u / f (eq. 2.6.17 b)
        mask = rr <= k_max * LAMBDA_M * F_M / D_M
        # Resolution-aware tolerance: a pixel of the pupil spans a kernel phase of 2 pi k_max / n at
        # k_max lambda/D; the midpoint rule's relative error is ~(that phase)^2 / 24.
        tol = (2 * np.pi * k_max / n) ** 2 / 24
        err = np.abs(intensity - airy_intensity(theta, D_M, LAMBDA_M, alpha))[mask].max()
        assert err < tol


def test_fresnel_number_eq_2_6_13():
    # F = a^2 / (L lambda): a = 6.35 cm (5-inch aperture), 370 m trial range -> F = 8.32 (near field);
    # 600 km orbit -> F = 5.1e-3 (far field).
    f_trial = fresnel_number(0.0635, 370.0, LAMBDA_M)
    assert f_trial == pytest.approx(0.0635**2 / (370.0 * LAMBDA_M), rel=1e-15)
    assert not is_far_field(0.0635, 370.0, LAMBDA_M)
    assert is_far_field(0.0635, 600e3, LAMBDA_M)
    np.testing.assert_allclose(fresnel_number(np.array([1e-3, 1e-2]), 1.0, 1e-6), [1.0, 100.0])


# --- Gaussian transmit beam ------------------------------------------------------------------------

def test_beam_radius_models():
    # thesis Table 4.6: atm.Wo = 10 mm, atm.div = 0.4 mrad, atm.dst = 1572 m
    w0, div, r = 0.010, 0.4e-3, 1572.0
    assert beam_radius_m(w0, div, r) == pytest.approx(math.hypot(w0, div * r), rel=1e-15)
    assert beam_radius_m(w0, div, r, model="linear") == pytest.approx(w0 + div * r, rel=1e-15)
    assert footprint_diameter_m(w0, div, r) == pytest.approx(2 * math.hypot(w0, div * r))
    assert beam_radius_m(w0, div, 0.0) == w0
    # Diffraction-limited Gaussian beam: W(z) = W0 sqrt(1 + (z / z_R)^2) (Siegman, Lasers, 17.1).
    lam, z = 1.31e-6, np.array([0.0, 10.0, 300.0, 3e4])
    theta = diffraction_divergence_rad(w0, lam)
    np.testing.assert_allclose(beam_radius_m(w0, theta, z),
                               w0 * np.sqrt(1 + (z / rayleigh_range_m(w0, lam)) ** 2), rtol=1e-12)
    # Power inside the 1/e^2 radius: 1 - e^-2 (closed form).
    assert beam_fraction_in_disc(0.2, 0.2) == pytest.approx(1 - np.exp(-2), rel=1e-14)


# --- Hard cases and validation ---------------------------------------------------------------------

def test_hard_cases_finite():
    for alpha in (0.0, 0.99):
        for method in ("analytic", "numeric"):
            eta = coupling_efficiency(1.0, alpha, method=method, n=64)
            assert np.isfinite(eta) and 0.0 < eta < 1.0
    tiny = coupling_efficiency(optimal_beta(0.99), 0.99)
    assert 0.0 < tiny < 0.01
    assert coupling_efficiency(optimal_beta(0.99), 0.99, method="numeric", n=256) == \
        pytest.approx(tiny, rel=1e-3)
    assert coupling_efficiency(1e-200) == 0.0 and coupling_efficiency(1e200) == 0.0
    assert coupling_efficiency(1e200, method="numeric", n=16) == 0.0
    assert 0.0 < coupling_mutual_coherence(1.0, 0.99, kolmogorov(3.0), n=64) < 0.01
    assert 0.0 < monostatic_diffuse_coupling(1.0, 0.99) < 0.01


BAD_INPUTS = [
    (lambda: coupling_efficiency(0.0), "beta"),
    (lambda: coupling_efficiency(-1.0), "beta"),
    (lambda: coupling_efficiency(float("nan")), "beta"),
    (lambda: coupling_efficiency(1.0, 1.0), "obstruction"),
    (lambda: coupling_efficiency(1.0, -0.1), "obstruction"),
    (lambda: coupling_efficiency(1.0, method="numeric", n=8), "n"),
    (lambda: coupling_efficiency(1.0, method="numeric", n=64.5), "n"),
    (lambda: coupling_efficiency(1.0, method="exact"), "method"),
    (lambda: coupling_efficiency(1.0, pupil_phase=np.zeros((32, 32))), "pupil_phase"),
    (lambda: coupling_efficiency(1.0, method="numeric", pupil_phase=np.zeros((32, 16))),
     "pupil_phase"),
    (lambda: coupling_efficiency(1.0, method="numeric", pupil_phase=np.full((32, 32), np.nan)),
     "pupil_phase"),
    (lambda: coupling_efficiency(1.0, method="numeric", pupil_phase=np.zeros((32, 32)), n=64), "n"),
    (lambda: pupil_grid(8), "n"),
    (lambda: pupil_field_coupling(np.zeros((32, 32)), 1.0), "pupil_field"),
    (lambda: optimal_beta(1.5), "obstruction"),
    (lambda: coupling_mutual_coherence(1.0, 0.0, 3.0), "structure_function"),
    (lambda: coupling_mutual_coherence(1.0, 0.0, lambda r: -r), "structure_function"),
    (lambda: coupling_mutual_coherence(1.0, 0.0, lambda r: 1.0), "structure_function"),
    (lambda: coupling_mutual_coherence(1.0, 0.0, lambda r: r + 1.0), "structure_function"),
    (lambda: coupling_mutual_coherence(1.0, 0.0, kolmogorov(1.0), method="mc"), "method"),
    (lambda: coupling_mutual_coherence(1.0, 0.0, lambda r: 6.88 * (r * 1e12) ** (5 / 3),
                                       method="radial"), "structure_function"),
    (lambda: monostatic_diffuse_coupling(1.0, method="lattice"), "method"),
    (lambda: coupling_beta(0.1, 0.0, 4.6e-6, 1.31e-6), "focal_length_m"),
    (lambda: airy_intensity(0.0, 0.0, 1.31e-6), "diameter_m"),
    (lambda: airy_intensity(np.nan, 0.1, 1.31e-6), "theta_rad"),
    (lambda: airy_first_null_rad(1e-6, 1.31e-6), "diameter_m"),
    (lambda: fresnel_number(-0.1, 10.0, 1e-6), "radius_m"),
    (lambda: fresnel_number(0.1, 0.0, 1e-6), "distance_m"),
    (lambda: is_far_field(0.1, 10.0, 1e-6, threshold=0.0), "threshold"),
    (lambda: fraunhofer(np.ones((32, 32)), 1e-3, 1e-6, 1.0, dx_out_m=1e-6), "dx_out_m"),
    (lambda: fraunhofer(np.ones((32, 32)), 1e-3, 1e-6, 1.0, n_out=16), "n_out"),
    (lambda: fraunhofer(np.ones((32, 32)), 1e-3, 1e-6, 1.0, method="dft"), "method"),
    (lambda: fraunhofer(np.ones(32), 1e-3, 1e-6, 1.0), "pupil_field"),
    (lambda: focal_plane_coupling(np.ones((8, 8)), 1e-3, 1e-6, 1.0, 0.0), "mode_radius_m"),
    (lambda: focal_plane_coupling(np.ones((8, 8)), 1e-3, 1e-6, 1.0, 1e-6, weights=np.ones((4, 4))),
     "weights"),
    (lambda: beam_radius_m(0.01, 1e-4, -1.0), "range_m"),
    (lambda: beam_radius_m(0.0, 1e-4, 1.0), "w0_m"),
    (lambda: beam_radius_m(0.01, -1e-4, 1.0), "divergence_half_angle_rad"),
    (lambda: beam_radius_m(0.01, 1e-4, 1.0, model="conic"), "model"),
]


@pytest.mark.parametrize("call,name", BAD_INPUTS)
def test_invalid_inputs_raise_value_error_naming_argument(call, name):
    with pytest.raises(ValueError, match=name):
        call()

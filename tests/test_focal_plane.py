"""The focal-plane field and the fiber / large-detector receivers against closed forms.

References: Shaklan & Roddier 1988 (Appl. Opt. 27, 2334) and Ruilier 1998 (Proc. SPIE 3350, 319)
for plane-wave fiber coupling (0.8145 at beta = 1.1209); Winzer & Leeb 1998 (Opt. Lett. 23, 986)
for the monostatic speckle mean (0.4248 at beta = 1.149, ``monostatic_diffuse_coupling``, grid-free);
Goodman 2007 ("Speckle Phenomena in Optics", Sec. 5.6, van Cittert-Zernike) for the speckle's
degree of coherence; Siegman 1966 (Appl. Opt. 5, 1588, the antenna theorem) for the mean mixing
efficiency of a large detector. Monte Carlo means are compared within 3 standard errors (the
ratio of means by the delta method: SE^2 = var(X - R Y) / (N <Y>^2)).
"""

import numpy as np
import pytest

from chirplidar.atmosphere.screens import phase_screens
from chirplidar.optics import (
    coupling_efficiency,
    focal_plane_coupling,
    fraunhofer,
    monostatic_diffuse_coupling,
    optimal_beta,
    pupil_field_coupling,
    pupil_grid,
)
from chirplidar.optics.focal_plane import (
    detector_mixing_efficiency,
    fiber_coupling,
    fiber_mode_lo,
    flat_top_lo,
    focal_fields,
    gaussian_lo,
    mean_mixing_efficiency_closed_form,
    mean_mixing_efficiency_focal,
    monostatic_speckle_pupil_fields,
    pupil_power,
    speckle_coherence_radius_m,
    speckle_pupil_fields,
)

LAMBDA_M = 1.55e-6
FOCAL_M = 0.5
APERTURE_M = 0.05


def _w0(beta: float) -> float:
    """Mode radius for beta = (pi / 2)(D / f)(w0 / lambda) (``coupling.coupling_beta``)."""
    return 2.0 * beta * LAMBDA_M * FOCAL_M / (np.pi * APERTURE_M)


def _mode_window(w0: float):
    du = w0 / 4.0  # the focal field is band-limited (period 2 lambda f / D): 0.18 lambda f / D
    return 2 * int(np.ceil(5.0 * w0 / du)) + 1, du


def _ratio_of_means(x, y):
    """R = <x> / <y> and its delta-method standard error."""
    r = x.mean() / y.mean()
    return r, np.std(x - r * y) / np.sqrt(x.size) / y.mean()


def test_plane_wave_fiber_coupling_through_the_focal_plane():
    # Ruilier 1998 / Shaklan & Roddier 1988: 0.8145 at the optimum beta (closed form); the
    # independent focal-plane overlap of diffraction.focal_plane_coupling gives the same number.
    n = 64
    grid = pupil_grid(n)
    dx = APERTURE_M / n
    beta = optimal_beta()
    w0 = _w0(beta)
    n_out, du = _mode_window(w0)
    field = np.ones((n, n))
    ef, u = focal_fields(grid.weights * field, dx, LAMBDA_M, FOCAL_M, n_out, du)
    eta = fiber_coupling(ef, u, w0, pupil_power(field, grid, APERTURE_M))
    assert eta == pytest.approx(coupling_efficiency(beta), rel=5e-3)
    assert eta == pytest.approx(0.8145, rel=5e-3)
    ref = focal_plane_coupling(field, dx, LAMBDA_M, FOCAL_M, w0, weights=grid.weights)
    assert eta == pytest.approx(ref, rel=1e-10)


def test_focal_fields_are_the_fraunhofer_mft():
    # the batched products reproduce diffraction.fraunhofer (method "mft") sample by sample
    e = speckle_pupil_fields(pupil_grid(16), APERTURE_M, 1e-3, np.random.default_rng(8), 3)
    dx, du = APERTURE_M / 16, 3e-6
    ef, u = focal_fields(e.reshape(3, 1, 16, 16), dx, LAMBDA_M, FOCAL_M, 21, du)
    ref, u_ref = fraunhofer(e, dx, LAMBDA_M, FOCAL_M, method="mft", n_out=21, dx_out_m=du)
    np.testing.assert_allclose(u, u_ref, rtol=1e-15)
    np.testing.assert_allclose(ef[:, 0], ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


def test_turbulent_plane_wave_focal_coupling_equals_the_pupil_overlap():
    # The MFT is unitary, so the focal-plane overlap equals the pupil-plane overlap
    # (coupling.pupil_field_coupling) realisation by realisation, here with von Karman screens.
    n, batch = 32, 6
    grid = pupil_grid(n, 0.2)
    dx = APERTURE_M / n
    rng = np.random.default_rng(11)
    phi = phase_screens(batch, n, dx, APERTURE_M / 4.0, outer_scale_m=1.0, rng=rng)
    beta = optimal_beta(0.2)
    w0 = _w0(beta)
    n_out, du = _mode_window(w0)
    field = np.exp(1j * phi)
    ef, u = focal_fields(grid.weights * field, dx, LAMBDA_M, FOCAL_M, n_out, du)
    eta = fiber_coupling(ef, u, w0, pupil_power(field, grid, APERTURE_M))
    np.testing.assert_allclose(eta, pupil_field_coupling(field, beta, 0.2), rtol=1e-9)
    # the speckle generator multiplies the same screen in
    a = speckle_pupil_fields(grid, APERTURE_M, dx, np.random.default_rng(1), batch)
    b = speckle_pupil_fields(
        grid, APERTURE_M, dx, np.random.default_rng(1), batch, phase_screen_rad=phi
    )
    np.testing.assert_allclose(b, a * np.exp(1j * phi), rtol=1e-12, atol=1e-15)


def test_monostatic_speckle_mean_coupling_is_winzer_and_leeb():
    # Winzer & Leeb 1998: mean coupled power / mean aperture power = 0.4248 at beta = 1.149
    # (grid-free ``monostatic_diffuse_coupling``). The generator's expectation on the n = 32 grid
    # is the lattice value (method="fft", 0.4260: +1.2e-3, well inside 3 SE = 0.0055 at N = 8000).
    n, beta, chunks, per = 32, 1.149, 4, 2000
    grid = pupil_grid(n)
    dx = APERTURE_M / n
    w0 = _w0(beta)
    n_out, du = _mode_window(w0)
    rng = np.random.default_rng(2026)
    coupled, power = [], []
    for _ in range(chunks):
        e = monostatic_speckle_pupil_fields(grid, beta, rng, per, aperture=False)
        ef, u = focal_fields(grid.weights * e, dx, LAMBDA_M, FOCAL_M, n_out, du)
        p = pupil_power(e, grid, APERTURE_M)
        coupled.append(fiber_coupling(ef, u, w0, p) * p)
        power.append(p)
    r, se = _ratio_of_means(np.concatenate(coupled), np.concatenate(power))
    assert se < 0.003
    assert abs(r - monostatic_diffuse_coupling(beta)) < 3.0 * se


def test_gaussian_speckle_moments_and_coherence():
    # Goodman 2007 Sec. 5.6: a Gaussian footprint (1/e^2 radius w) gives mu(d) = exp(-d^2/(2 rho^2)),
    # rho = lambda R / (pi w); E|E|^2 = 1. One pixel pair per realisation (independent samples).
    n, batch = 32, 4000
    grid = pupil_grid(n)
    dx = APERTURE_M / n
    rho = 4.0 * dx
    assert speckle_coherence_radius_m(1.0e-6, 1000.0, 1.0e-6 * 1000.0 / (np.pi * rho)) == (
        pytest.approx(rho, rel=1e-12)
    )
    e = speckle_pupil_fields(grid, APERTURE_M, rho, np.random.default_rng(3), batch, aperture=False)
    i0, j0 = 12, 6
    inten = np.abs(e[:, i0, j0]) ** 2
    assert abs(inten.mean() - 1.0) < 3.0 * inten.std() / np.sqrt(batch)
    for lag in (2, 4, 8, 12):
        prod = e[:, i0, j0] * e[:, i0, j0 + lag].conj()
        ref = np.exp(-((lag * dx) ** 2) / (2.0 * rho**2))
        se = np.sqrt(prod.real.var() / batch)
        assert abs(prod.real.mean() - ref) < 3.0 * se
        assert abs(prod.imag.mean()) < 3.0 * np.sqrt(prod.imag.var() / batch)


def test_large_detector_in_gaussian_speckle_follows_the_antenna_theorem():
    # Siegman 1966 / Goodman 2007: <eta> = (1/A_d^2) int int mu over the detector, closed form
    # g(L / (sqrt 2 rho))^2; detectors from L = rho / 4 to 7 rho on the speckle itself (the
    # detector in the plane of the generated speckle, uniform LO), within 10 % (issue 18).
    n, batch = 64, 1500
    grid = pupil_grid(n)
    dx = APERTURE_M / n
    rho = 8.0 * dx
    e = speckle_pupil_fields(grid, APERTURE_M, rho, np.random.default_rng(4), batch, aperture=False)
    x = grid.x[0] * APERTURE_M
    lo = np.ones((n, n))
    for pixels in (2, 4, 8, 16, 32, 56):  # edges on pixel edges: the exact midpoint rule
        side = pixels * dx
        # total power 1: ``frac`` is then the signal power on the detector
        eta, sig = detector_mixing_efficiency(e, lo, x, 0.5 * side, total_power_w=1.0)
        r, se = _ratio_of_means(eta * sig, sig)
        ref = mean_mixing_efficiency_closed_form(side, rho)
        assert abs(r - ref) < max(0.1 * ref, 3.0 * se), (side / rho, r, ref, se)
    # the two limits of the closed form: 1 and A_c / A_d = 2 pi rho^2 / L^2
    assert mean_mixing_efficiency_closed_form(1e-4 * rho, rho) == pytest.approx(1.0, abs=1e-8)
    big = 1e3 * rho
    assert mean_mixing_efficiency_closed_form(big, rho) == pytest.approx(
        2.0 * np.pi * rho**2 / big**2, rel=3e-3
    )


def test_large_focal_plane_detector_follows_the_antenna_theorem():
    # Speckle unresolved across the aperture (rho = dx / 4: independent pupil samples); the focal
    # plane's mu is the aperture's amplitude spread function and the mean mixing efficiency is the
    # back-propagated LO's overlap with the aperture (Siegman 1966), within 10 %. The large-L limit
    # is (lambda f)^2 / (A_P A_d) (A Omega = lambda^2).
    n, batch = 64, 1500
    grid = pupil_grid(n)
    dx = APERTURE_M / n
    res = LAMBDA_M * FOCAL_M / APERTURE_M
    du = res / 16.0
    n_out = 2 * int(np.ceil(2.6 * res / du)) + 1
    e = speckle_pupil_fields(grid, APERTURE_M, 0.25 * dx, np.random.default_rng(5), batch)
    ef, u = focal_fields(e, dx, LAMBDA_M, FOCAL_M, n_out, du)
    power = pupil_power(e, grid, APERTURE_M)
    lo = flat_top_lo(u, 4.0 * res)
    for cells in (5, 17, 33, 49, 81):  # detector edges on sample-cell edges
        side = cells * du
        eta, frac = detector_mixing_efficiency(ef, lo, u, 0.5 * side, total_power_w=power)
        r, se = _ratio_of_means(eta * frac * power, frac * power)
        ref = mean_mixing_efficiency_focal(side, APERTURE_M, LAMBDA_M, FOCAL_M)
        assert abs(r - ref) < max(0.1 * ref, 3.0 * se), (side / res, r, ref, se)
    big = 300.0 * res  # edge terms O(lambda f / (L D)) ~ 1e-3
    a_p = 0.25 * np.pi * APERTURE_M**2
    assert mean_mixing_efficiency_focal(big, APERTURE_M, LAMBDA_M, FOCAL_M) == pytest.approx(
        (LAMBDA_M * FOCAL_M) ** 2 / (a_p * big**2), rel=1e-2
    )


def test_mixing_efficiency_is_one_for_a_matched_lo_and_phase_cancels():
    # Cauchy-Schwarz: eta_mix = 1 iff E_s is proportional to E_LO on the detector; a tilt of one
    # wave across the detector cancels the area integral of a uniform beat (sinc(1)^2 = 0).
    u = np.linspace(-1e-4, 1e-4, 101)
    lo = gaussian_lo(u, 4e-5)
    eta, frac = detector_mixing_efficiency(2j * lo, lo, u, 5e-5)
    assert float(eta) == pytest.approx(1.0, rel=1e-12)
    assert 0.0 < float(frac) < 1.0
    du = u[1] - u[0]
    a = 50.5 * du  # 101 whole cells
    tilt = np.exp(2j * np.pi * u[None, :] / (2 * a)) * np.ones((101, 1))
    eta_t, _ = detector_mixing_efficiency(tilt, np.ones((101, 101)), u, a)
    assert float(eta_t) < 1e-6
    assert fiber_mode_lo(u, 4e-5) == pytest.approx(lo)


def test_parseval_between_pupil_and_focal_plane():
    # Unitary Fraunhofer transform (diffraction module docstring): a full-period MFT window
    # (n_out = 2n, du = lambda f / (2 n dx)) holds all of the sampled field's power.
    n = 32
    grid = pupil_grid(n, 0.3)
    dx = APERTURE_M / n
    e = speckle_pupil_fields(grid, APERTURE_M, 2.0 * dx, np.random.default_rng(6), 3)
    du = LAMBDA_M * FOCAL_M / (2 * n * dx)
    ef, _ = focal_fields(e, dx, LAMBDA_M, FOCAL_M, 2 * n, du)
    pupil = np.sum(np.abs(e) ** 2, axis=(-2, -1)) * dx * dx
    focal = np.sum(np.abs(ef) ** 2, axis=(-2, -1)) * du * du
    np.testing.assert_allclose(focal, pupil, rtol=1e-10)


def test_same_seed_same_fields():
    grid = pupil_grid(16)
    a = speckle_pupil_fields(grid, 0.1, 0.01, np.random.default_rng(9), 5)
    b = speckle_pupil_fields(grid, 0.1, 0.01, np.random.default_rng(9), 5)
    np.testing.assert_array_equal(a, b)
    c = monostatic_speckle_pupil_fields(grid, 1.1, np.random.default_rng(9), 2)
    np.testing.assert_array_equal(
        c, monostatic_speckle_pupil_fields(grid, 1.1, np.random.default_rng(9), 2)
    )


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda g, r, u: speckle_pupil_fields(g, 0.0, 0.01, r, 2), "aperture_m"),
        (lambda g, r, u: speckle_pupil_fields(g, 0.1, -1.0, r, 2), "coherence_radius_m"),
        (lambda g, r, u: speckle_pupil_fields(g, 0.1, 0.01, r, 0), "batch"),
        (lambda g, r, u: speckle_pupil_fields(g, 0.1, 0.01, 1, 2), "rng"),
        (lambda g, r, u: speckle_pupil_fields("g", 0.1, 0.01, r, 2), "grid"),
        (
            lambda g, r, u: speckle_pupil_fields(g, 0.1, 0.01, r, 2, phase_screen_rad=np.ones(3)),
            "phase_screen_rad",
        ),
        (lambda g, r, u: monostatic_speckle_pupil_fields(g, 0.0, r, 2), "beta"),
        (lambda g, r, u: speckle_coherence_radius_m(1e-6, -1.0, 1.0), "range_m"),
        (lambda g, r, u: focal_fields(np.ones((16, 16)), 1e-3, 1e-6, 0.5, 1, 1e-6), "n_out"),
        (lambda g, r, u: focal_fields(np.ones((16, 16)), 1e-3, 1e-6, 0.5, 8, 0.0), "dx_out_m"),
        (lambda g, r, u: fiber_mode_lo(u, 0.0), "w0_m"),
        (lambda g, r, u: flat_top_lo(u, -1.0), "half_width_m"),
        (lambda g, r, u: gaussian_lo(u[::-1], 1.0), "u must be an increasing"),
        (lambda g, r, u: fiber_coupling(np.ones((9, 9)), u, 0.5, 1.0), "cover the fiber mode"),
        (lambda g, r, u: fiber_coupling(np.ones((9, 9)), u, 0.1, 0.0), "power_w"),
        (lambda g, r, u: fiber_coupling(np.ones((8, 8)), u, 0.1, 1.0), "ef must be"),
        (
            lambda g, r, u: detector_mixing_efficiency(np.ones((9, 9)), np.ones((9, 9)), u, 2.0),
            "exceeds the focal window",
        ),
        (
            lambda g, r, u: detector_mixing_efficiency(np.ones((9, 9)), np.ones((9, 9)), u, 0.0),
            "detector_half_width_m",
        ),
        (lambda g, r, u: mean_mixing_efficiency_closed_form(0.0, 1.0), "detector_side_m"),
        (lambda g, r, u: mean_mixing_efficiency_closed_form(1.0, 0.0), "coherence_radius_m"),
        (lambda g, r, u: mean_mixing_efficiency_focal(1.0, 1.0, 1.0, 1.0, 1.0), "obstruction"),
        (lambda g, r, u: pupil_power(np.ones((8, 8)), g, 0.1), "fields must be"),
    ],
)
def test_bad_input(call, match):
    grid = pupil_grid(16)
    u = np.linspace(-1.0, 1.0, 9)
    with pytest.raises(ValueError, match=match):
        call(grid, np.random.default_rng(0), u)

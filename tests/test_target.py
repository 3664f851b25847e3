"""Target kernels: Lambertian and specular returns, materials, speckle (docs/targets.md)."""

import numpy as np
import pytest
from scipy import stats

from chirplidar.target import (
    MATERIALS,
    Material,
    correlated_speckle,
    correlated_speckle_field,
    cox_munk_mss,
    facing_away,
    fresnel_reflectance,
    get_material,
    ice_refractive_index,
    lambertian_power_fraction,
    receiver_cone_half_angle_rad,
    snow_albedo_art,
    speckle_cells,
    speckle_contrast_finite,
    speckle_decorrelation,
    speckle_phase,
    speckle_power,
    specular_return_fraction,
    surface_scatterer_count,
    water_refractive_index,
)

# Thesis Table 4.6 (simulation parameters, transmission channel).
THESIS_R_TRG = 0.46
THESIS_D_TEL_M = 0.2032
THESIS_DST_M = 1572.0
THESIS_LC_M = 4.0e-3
THESIS_WR_M = 150.0e-3


# --------------------------------------------------------------------------------------------
# Speckle statistics (Goodman, "Speckle Phenomena in Optics", 2007: exponential for one cell,
# gamma of order M with contrast 1/sqrt(M) for M integrated cells)
# --------------------------------------------------------------------------------------------

def test_single_cell_speckle_is_exponential_ks():
    x = speckle_power(10_000, 1, np.random.default_rng(20240611))
    assert stats.kstest(x, "expon").pvalue > 0.01


@pytest.mark.parametrize("cells", [1, 4, 16])
def test_speckle_contrast_and_mean(cells):
    n = 10_000
    x = speckle_power(n, cells, np.random.default_rng(cells))
    assert abs(x.std() / x.mean() - 1 / np.sqrt(cells)) < 3 / np.sqrt(n)
    # Mean 1 within 4 standard errors (std of the mean = 1/sqrt(M N)).
    assert abs(x.mean() - 1.0) < 4 / np.sqrt(cells * n)
    # Gamma(M, 1/M) against the whole distribution.
    assert stats.kstest(x, stats.gamma(a=cells, scale=1 / cells).cdf).pvalue > 0.01


def test_speckle_power_draws_nothing_for_zero_shots_and_validates():
    rng = np.random.default_rng(3)
    state = rng.bit_generator.state
    assert speckle_power(0, 1, rng).shape == (0,)
    assert rng.bit_generator.state == state
    with pytest.raises(ValueError, match="cells"):
        speckle_power(10, 0.5, rng)
    with pytest.raises(ValueError, match="rng"):
        speckle_power(10, 1, np.random)
    with pytest.raises(ValueError, match="n must be"):
        speckle_power(2.5, 1, rng)
    with pytest.raises(ValueError, match="cells"):
        speckle_power(10, float("nan"), rng)


def test_speckle_phase_uniform():
    ph = speckle_phase(10_000, np.random.default_rng(5))
    assert ph.min() >= 0.0 and ph.max() < 2 * np.pi
    assert stats.kstest(ph, stats.uniform(0, 2 * np.pi).cdf).pvalue > 0.01


def test_speckle_cells_coherent_and_direct():
    # A single-mode (coherent) receiver integrates one spatial mode.
    assert speckle_cells("coherent") == 1.0
    assert speckle_cells("coherent", range_m=np.array([1e3, 2e3])).shape == (2,)
    lam, rng_m, foot = 1.31e-6, 1000.0, np.pi * 0.5**2
    coherence_area = (lam * rng_m) ** 2 / foot          # van Cittert-Zernike, (lambda R)^2 / A
    assert speckle_cells("direct", wavelength_m=lam, range_m=rng_m, footprint_area_m2=foot,
                         receiver_area_m2=1e-3 * coherence_area) == pytest.approx(1.001)
    big = speckle_cells("direct", wavelength_m=lam, range_m=rng_m, footprint_area_m2=foot,
                        receiver_area_m2=np.pi * 0.1**2)
    assert big == pytest.approx(1 + np.pi * 0.1**2 / coherence_area)
    assert big > 1e3
    with pytest.raises(ValueError, match="receiver_area_m2"):
        speckle_cells("direct", wavelength_m=lam, range_m=rng_m, footprint_area_m2=foot)
    with pytest.raises(ValueError, match="detection"):
        speckle_cells("heterodyne")


def test_thesis_surface_gives_fully_developed_speckle():
    # atm.lc = 4 mm against a 150 mm target radius: thousands of scatterers.
    n = surface_scatterer_count(np.pi * THESIS_WR_M**2, THESIS_LC_M)
    assert n == pytest.approx(np.pi * (150 / 4) ** 2)
    assert speckle_contrast_finite(n) > 0.9998


def test_finite_scatterer_contrast_matches_random_phasor_sum():
    # Sum of N unit phasors with uniform phases: <I^2>/<I>^2 = 2 - 1/N (Goodman 2007, Ch. 2).
    rng = np.random.default_rng(11)
    for n in (2, 3, 10):
        s = np.exp(1j * rng.uniform(0, 2 * np.pi, (200_000, n))).sum(axis=1)
        i = np.abs(s) ** 2
        assert i.std() / i.mean() == pytest.approx(speckle_contrast_finite(n), abs=0.01)
    with pytest.raises(ValueError, match="n_scatterers"):
        speckle_contrast_finite(0.5)


# --------------------------------------------------------------------------------------------
# Shot-to-shot decorrelation
# --------------------------------------------------------------------------------------------

def test_decorrelation_limits():
    assert speckle_decorrelation(0.0, 0.5, 1.31e-6, 1e3) == 1.0
    assert speckle_decorrelation(10.0, 0.5, 1.31e-6, np.inf) < 1e-100
    # Flat wavefront: only the overlap of the two illuminated patches, exp(-2 s^2 / W^2).
    assert speckle_decorrelation(0.1, 0.2, 1.31e-6, np.inf) == pytest.approx(np.exp(-0.5))
    with pytest.raises(ValueError, match="wavefront_radius_m"):
        speckle_decorrelation(0.1, 0.2, 1.31e-6, 0.0)


def test_decorrelation_of_a_gaussian_beam_depends_on_the_waist_only():
    # Gaussian beam (Siegman, "Lasers", Ch. 17): W(z) = w0 sqrt(1 + (z/zR)^2),
    # R(z) = z (1 + (zR/z)^2), zR = pi w0^2 / lambda. The bracket 1/W^2 + (pi W/(lambda R))^2
    # equals 1/w0^2 at every z, so rho_I = exp(-2 s^2 / w0^2).
    lam, w0 = 1.31e-6, 0.01
    z_r = np.pi * w0**2 / lam
    z = np.array([0.3, 1.0, 10.0, 1e3]) * z_r
    w = w0 * np.sqrt(1 + (z / z_r) ** 2)
    r_c = z * (1 + (z_r / z) ** 2)
    s = 0.004
    np.testing.assert_allclose(speckle_decorrelation(s, w, lam, r_c), np.exp(-2 * s**2 / w0**2),
                               rtol=1e-12)


@pytest.mark.parametrize("curved", [False, True])
def test_decorrelation_matches_a_simulated_rough_surface(curved):
    # Independent check: a delta-correlated complex surface a(x) on a grid, received field
    # U = sum a(x) E(x)^2 (monostatic, matched mode), beam shifted by s between shots; the
    # intensity correlation of many surfaces against the closed form. 1-D suffices: the
    # cross-track factor is the same for both shots.
    rng = np.random.default_rng(17 + curved)
    lam, w, s = 1.0e-6, 0.05, 0.02
    r_c = 1.0e4 if curved else np.inf      # curvature term comparable with the overlap term
    k = 2 * np.pi / lam
    x = np.linspace(-0.3, 0.3, 1201)
    def mode(x0):
        phase = 0.0 if not curved else k * (x - x0) ** 2 / r_c
        return np.exp(-2 * (x - x0) ** 2 / w**2 + 1j * phase)
    a = (rng.standard_normal((6000, x.size)) + 1j * rng.standard_normal((6000, x.size)))
    i1 = np.abs(a @ mode(0.0)) ** 2
    i2 = np.abs(a @ mode(s)) ** 2
    measured = np.corrcoef(i1, i2)[0, 1]
    expected = speckle_decorrelation(s, w, lam, r_c)
    assert 0.05 < expected < 0.95
    assert measured == pytest.approx(expected, abs=0.04)   # ~3 sigma at 6000 realisations


@pytest.mark.parametrize("cells", [1, 4])
@pytest.mark.parametrize("rho", [0.3, 0.8])
def test_correlated_speckle_reproduces_the_requested_correlation(cells, rho):
    n = 40_000
    p = correlated_speckle(n, rho, cells, np.random.default_rng(int(10 * rho) + cells))
    lag1 = np.corrcoef(p[:-1], p[1:])[0, 1]
    assert lag1 == pytest.approx(rho, abs=0.03)
    # Marginals stay gamma(M): mean 1, contrast 1/sqrt(M).
    assert p.mean() == pytest.approx(1.0, abs=0.05)
    assert p.std() / p.mean() == pytest.approx(1 / np.sqrt(cells), abs=0.05)


def test_correlated_speckle_zero_and_large_shift():
    lam, w, r_c = 1.31e-6, 0.5, np.inf
    same = correlated_speckle(1000, speckle_decorrelation(0.0, w, lam, r_c), 1,
                              np.random.default_rng(1))
    assert np.all(same == same[0])                 # zero shift: identical speckle every shot
    far = correlated_speckle(40_000, speckle_decorrelation(5.0, w, lam, r_c), 1,
                             np.random.default_rng(2))
    assert abs(np.corrcoef(far[:-1], far[1:])[0, 1]) < 4 / np.sqrt(40_000)


def test_correlated_speckle_field_shape_and_validation():
    z = correlated_speckle_field(5, 0.5, 3, np.random.default_rng(0))
    assert z.shape == (5, 3) and z.dtype == np.complex128
    assert correlated_speckle(0, 0.5, 2, np.random.default_rng(0)).shape == (0,)
    with pytest.raises(ValueError, match="integer"):
        correlated_speckle(5, 0.5, 2.5, np.random.default_rng(0))
    with pytest.raises(ValueError, match="rho_between_shots"):
        correlated_speckle(5, 1.2, 1, np.random.default_rng(0))


# --------------------------------------------------------------------------------------------
# Lambertian return (thesis eq. 2.2.3 with the incidence angle)
# --------------------------------------------------------------------------------------------

def test_lambertian_closed_form_at_normal_incidence():
    # Thesis eq. 2.2.3 (power form): rho A_r / (pi R^2), Table 4.6 numbers.
    area = np.pi * (THESIS_D_TEL_M / 2) ** 2
    got = lambertian_power_fraction(THESIS_R_TRG, area, THESIS_DST_M, 0.0)
    assert got == pytest.approx(THESIS_R_TRG * area / (np.pi * THESIS_DST_M**2), rel=1e-15)
    assert isinstance(got, float)


def test_lambertian_cos_dependence_and_grazing():
    theta = np.deg2rad(np.array([0.0, 10.0, 30.0, 60.0, 80.0]))
    f = lambertian_power_fraction(0.5, 0.01, 100.0, theta)
    np.testing.assert_allclose(f / f[0], np.cos(theta), rtol=1e-14)
    tiny = lambertian_power_fraction(0.5, 0.01, 100.0, np.deg2rad(89.9))
    assert 0.0 < tiny == pytest.approx(np.cos(np.deg2rad(89.9)) * f[0], rel=1e-9)
    beyond = lambertian_power_fraction(0.5, 0.01, 100.0, np.deg2rad([90.0, 91.0, 180.0]))
    assert np.all(beyond == 0.0)
    assert facing_away(np.deg2rad(90.0)) and not facing_away(np.deg2rad(89.9))
    np.testing.assert_array_equal(facing_away(np.deg2rad([0.0, 90.0, 120.0])),
                                  [False, True, True])
    sweep = lambertian_power_fraction(0.5, 0.01, 100.0, np.linspace(0, np.pi, 1001))
    assert np.all(sweep >= 0.0)


def test_lambertian_zero_reflectivity_and_validation():
    assert lambertian_power_fraction(0.0, 0.01, 100.0, 0.3) == 0.0
    with pytest.raises(ValueError, match="reflectivity"):
        lambertian_power_fraction(1.2, 0.01, 100.0, 0.0)
    with pytest.raises(ValueError, match="range_m"):
        lambertian_power_fraction(0.5, 0.01, 0.0, 0.0)
    with pytest.raises(ValueError, match="incidence_rad"):
        lambertian_power_fraction(0.5, 0.01, 100.0, -0.1)
    with pytest.raises(ValueError, match="incidence_rad"):
        lambertian_power_fraction(0.5, 0.01, 100.0, np.nan)


# --------------------------------------------------------------------------------------------
# Fresnel, Cox-Munk and the specular return
# --------------------------------------------------------------------------------------------

def test_fresnel_normal_incidence_and_brewster():
    # Normal incidence ((n-1)/(n+1))^2 (Born & Wolf 1.5): ~2 % for water at 1.3 um (n = 1.32).
    r0 = fresnel_reflectance(1.32, 0.0)
    assert r0 == pytest.approx((0.32 / 2.32) ** 2, rel=1e-14)
    assert 0.018 < r0 < 0.02
    # At Brewster's angle R_p = 0 and R_s = sin^2(theta_i - theta_t) (Born & Wolf 1.5.3).
    n = 1.32
    tb = np.arctan(n)
    tt = np.arcsin(np.sin(tb) / n)
    assert fresnel_reflectance(n, tb) == pytest.approx(0.5 * np.sin(tb - tt) ** 2, rel=1e-12)
    assert fresnel_reflectance(n, np.pi / 2) == pytest.approx(1.0)


def test_cox_munk_mean_square_slope():
    # Cox & Munk (1954), clean surface: 0.003 + 5.12e-3 U.
    assert cox_munk_mss(0.0) == pytest.approx(0.003)
    assert cox_munk_mss(10.0) == pytest.approx(0.0542)
    with pytest.raises(ValueError, match="wind_speed_mps"):
        cox_munk_mss(20.0)


def test_specular_flat_surface_returns_fresnel_at_normal_incidence():
    n = 1.32
    rho_f = ((n - 1) / (n + 1)) ** 2
    cone = receiver_cone_half_angle_rad(np.pi * 0.1**2, 1000.0)
    assert cone == pytest.approx(1e-4)
    assert specular_return_fraction(0.0, 0.0, rho_f, cone, 0.0) == pytest.approx(rho_f)
    # Only within the specular cone: a mirror tilted by more than cone/2 returns nothing.
    assert specular_return_fraction(0.4 * cone, 0.0, rho_f, cone, 0.0) == pytest.approx(rho_f)
    assert specular_return_fraction(0.6 * cone, 0.0, rho_f, cone, 0.0) == 0.0


def test_specular_mirror_with_a_diverging_beam():
    # Gaussian beam reflected by a mirror: from the image transmitter at 2R the aperture of
    # radius r = cone R catches 1 - exp(-2 r^2 / W(2R)^2) with W(2R) = 2 R div.
    rho_f, cone = 0.02, 1e-4
    for div in (3e-5, 1e-4, 1e-3):
        got = specular_return_fraction(0.0, 0.0, rho_f, cone, div)
        assert got == pytest.approx(rho_f * (1 - np.exp(-cone**2 / (2 * div**2))), rel=1e-9)
    # Tilted mirror: the reflected beam misses by 2 theta R, exp(-2 (2 theta R)^2 / W(2R)^2)
    # (small aperture against the beam, so the aperture samples the beam's centre value).
    div, th, cone = 1e-3, 1e-3, 1e-5
    got = specular_return_fraction(th, 0.0, rho_f, cone, div)
    assert got == pytest.approx(rho_f * cone**2 / (2 * div**2) * np.exp(-2 * th**2 / div**2),
                                rel=1e-3)


def test_specular_rough_limit_is_cox_munk_backscatter():
    # cone << rms slope: rho_F exp(-tan^2/mss) cone^2 / (4 mss cos^5) (Barrick 1968 sigma0 with
    # the footprint stretched by 1/cos theta; Cox & Munk 1954 slope density).
    mss = cox_munk_mss(7.0)
    theta = np.deg2rad(np.array([0.0, 3.0, 10.0, 20.0, 30.0]))
    rho_f, cone = 0.0192, 5e-5
    got = specular_return_fraction(theta, mss, rho_f, cone, 0.0)
    closed = rho_f * np.exp(-np.tan(theta) ** 2 / mss) * cone**2 / (4 * mss * np.cos(theta) ** 5)
    np.testing.assert_allclose(got, closed, rtol=1e-4)


def test_specular_fraction_falls_with_incidence():
    mss = cox_munk_mss(5.0)
    theta = np.deg2rad(np.linspace(0.0, 60.0, 61))
    f = specular_return_fraction(theta, mss, 0.02, 1e-4, 1e-4)
    assert np.all(np.diff(f) < 0)
    assert f[-1] < 1e-20 * f[0]
    assert np.all(specular_return_fraction(np.deg2rad([90.0, 100.0]), mss, 0.02, 1e-4, 1e-4) == 0)
    assert specular_return_fraction(np.deg2rad(89.99), 1e-6, 0.02, 1e-4, 1e-2) == 0.0


@pytest.mark.parametrize("theta,mss,cone", [(0.0, 2e-4, 0.01), (0.01, 2e-4, 0.01),
                                            (0.3, 0.02, 0.05)])
def test_specular_matches_ray_tracing(theta, mss, cone):
    # Independent method: draw facet slopes, reflect the beam direction exactly, count the rays
    # within the cone, weight facets by their share (1 + z_x tan theta) of the beam.
    rng = np.random.default_rng(23)
    n = 1_000_000
    z = rng.standard_normal((n, 2)) * np.sqrt(mss / 2)
    normal = np.column_stack([-z[:, 0], -z[:, 1], np.ones(n)])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    d = np.array([np.sin(theta), 0.0, -np.cos(theta)])
    refl = d[None, :] - 2 * (normal @ d)[:, None] * normal
    inside = np.arccos(np.clip(refl @ -d, -1, 1)) <= cone
    hits = np.maximum(1 + z[:, 0] * np.tan(theta), 0) * inside
    mc, err = hits.mean(), hits.std() / np.sqrt(n)
    got = specular_return_fraction(theta, mss, 1.0, cone, 0.0)
    assert abs(got - mc) < 4 * err + 1e-3 * mc


def test_specular_validation():
    with pytest.raises(ValueError, match="cone_half_angle_rad"):
        specular_return_fraction(0.0, 0.01, 0.02, 0.2, 0.0)
    with pytest.raises(ValueError, match="mss"):
        specular_return_fraction(0.0, -0.01, 0.02, 1e-4, 0.0)
    with pytest.raises(ValueError, match="fresnel_reflectance"):
        specular_return_fraction(0.0, 0.01, 1.5, 1e-4, 0.0)


# --------------------------------------------------------------------------------------------
# Materials and optical constants
# --------------------------------------------------------------------------------------------

def test_water_index_iapws_against_daimon_masumura():
    # Daimon & Masumura (2007, Appl. Opt. 46, 3811), Sellmeier fit at 21.5 degC (valid to
    # 1.129 um), coefficients as published on refractiveindex.info; density 997.86 kg/m^3.
    b = (5.689093832e-1, 1.719708856e-1, 2.062501582e-2, 1.123965424e-1)
    c = (5.110301794e-3, 1.825180155e-2, 2.624158904e-2, 1.067505178e1)
    for lam_um in (0.5893, 0.8, 1.064):
        n_dm = np.sqrt(1 + sum(bi * lam_um**2 / (lam_um**2 - ci) for bi, ci in zip(b, c)))
        n = water_refractive_index(lam_um * 1e-6, 294.65, 997.86)
        assert n == pytest.approx(n_dm, abs=1e-4)
    with pytest.raises(ValueError, match="wavelength_m"):
        water_refractive_index(2.5e-6, 273.15, 999.84)


def test_ice_index_is_the_warren_brandt_table():
    # Warren & Brandt (2008) table row 1.31 um: n = 1.2959, k = 1.31e-5.
    m = ice_refractive_index(1.31e-6)
    assert m.real == pytest.approx(1.2959) and m.imag == pytest.approx(1.31e-5)
    with pytest.raises(ValueError, match="wavelength_m"):
        ice_refractive_index(0.5e-6)


def test_snow_albedo_art_trends_and_validity():
    wl = np.array([1064e-9, 1310e-9])
    fine = snow_albedo_art(wl, 60.0, 0.0)
    coarse = snow_albedo_art(wl, 8.0, 0.0)
    assert np.all(coarse < fine) and np.all(np.diff(fine) < 0)
    # Direct-beam albedo rises with the incidence angle (ART: exponent 3(1 + 2 mu0)/7).
    assert snow_albedo_art(1310e-9, 25.0, 1.0) > snow_albedo_art(1310e-9, 25.0, 0.0)
    # The thesis' target reflectivity at 1310 nm (Table 4.6, 0.46) lies in the snow range.
    assert snow_albedo_art(1310e-9, 25.0, 0.0) < THESIS_R_TRG < snow_albedo_art(1310e-9, 60.0, 0.0)
    # At 1550 nm ice absorbs too strongly for the weak-absorption theory: refused.
    with pytest.raises(ValueError, match="co-albedo"):
        snow_albedo_art(1550e-9, 60.0, 0.0)


def test_material_table():
    for m in MATERIALS.values():
        assert m.source.strip()
        assert all(0.0 <= r <= 1.0 for r in m.reflectivity)
        for wl, r in zip(m.wavelengths_m, m.reflectivity):
            assert m.reflectivity_at(wl) == r
    water = get_material("open_water")
    assert water.scattering == "specular"
    assert water.reflectivity_at(1310e-9) == pytest.approx(0.019, abs=0.001)   # ~2 % Fresnel
    snow, firn = get_material("snow"), get_material("firn")
    for wl in (1064e-9, 1310e-9, 1550e-9):
        assert firn.reflectivity_at(wl) < snow.reflectivity_at(wl)
    assert snow.reflectivity_at(1550e-9) < snow.reflectivity_at(1310e-9) \
        < snow.reflectivity_at(1064e-9)
    mid = snow.reflectivity_at(1187e-9)
    assert snow.reflectivity_at(1310e-9) < mid < snow.reflectivity_at(1064e-9)
    assert get_material("thesis_target").reflectivity_at(1310.5e-9) == 0.46   # within 1 nm
    with pytest.raises(ValueError, match="outside"):
        snow.reflectivity_at(532e-9)
    with pytest.raises(ValueError, match="unknown material"):
        get_material("lava")
    with pytest.raises(ValueError, match="scattering"):
        Material("x", "glossy", (1e-6,), (0.1,), "test")
    with pytest.raises(ValueError, match="reflectivity"):
        Material("x", "lambertian", (1e-6,), (1.1,), "test")

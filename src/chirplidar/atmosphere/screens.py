"""Kolmogorov / von Karman phase screens (FFT method with Lane et al. subharmonics).

Spectrum (spatial frequency f in cycles/m; Schmidt 2010, *Numerical Simulation of Optical Wave
Propagation*, SPIE, Ch. 9):

    Phi(f) = c r0^(-5/3) (f^2 + 1/L0^2)^(-11/6)  rad^2 m^2,   c = 0.023 (exactly 0.022896...)

c is taken exactly as Gamma(11/6)^2 / (2 pi^(11/3)) (24/5 Gamma(6/5))^(5/6), the value for which the
Kolmogorov (L0 = inf) structure function is D(r) = 6.8839 (r/r0)^(5/3) (Fried 1965).

Structure function of any isotropic phase spectrum (Wiener-Khinchin, D(r) = 2 int (1 - cos 2 pi f.r)
Phi d^2f, angular integral done):

    D(r) = 4 pi int_0^inf Phi(f) [1 - J0(2 pi f r)] f df.

For von Karman it has a closed form through the covariance
B(r) = (6 pi c / 5)(L0/r0)^(5/3) 2^(1/6)/Gamma(5/6) x^(5/6) K_{5/6}(x), x = 2 pi r / L0, D = 2 (B(0) - B(r)).

Screen synthesis (reimplemented after Schmidt's listings ft_phase_screen / ft_sh_phase_screen):

* high frequencies: circular complex Gaussian amplitudes c with E|c|^2 = 2 var(f) on the FFT grid
  f = k / (N dx) (DC set to 0), one 2-D FFT; the real and the imaginary part are two independent
  screens (their cross-covariance vanishes on the grid because Phi is even), so one FFT gives two.
* low frequencies (Lane, Glindemann & Dainty 1992, Waves Random Media 2, 209): level p = 1..P adds the
  3 x 3 grid f = (-1, 0, 1) df / 3^p (centre excluded) with the same normalisation; each level tiles
  the cell the previous level (or the FFT's DC) left out, so the spectrum is partitioned, not
  double-counted. The grid mean of the subharmonic part is removed (piston). All levels are summed
  in one matrix product of separable factors (rank 3 per level). Default P = 12
  (``DEFAULT_SUBHARMONIC_LEVELS``): Kolmogorov D(N dx / 4) 2.2 % low, where 3 levels leave 23 %.
* mode variances: var = Phi(f_c) df^2 at the cell centre f_c (Schmidt's midpoint rule) for most FFT
  cells. Near the origin the spectrum is too steep for the midpoint rule: it leaves a 7-13 %
  deficit of D(N dx / 4) that no number of subharmonic levels removes. There -- all subharmonic
  cells and the FFT cells with max(|kx|, |ky|) <= 4 -- each mode gets the cell's exact phase-gradient
  power, var = int_cell |f|^2 Phi d^2f / |f_c|^2 ("tilt-matched" weights, Gauss-Legendre per cell).
  This departs from plain Lane/Schmidt on purpose; see
  docs/explanation/validation/atmosphere.md for the measured gain.

Screens are periodic only in their high-frequency part; subharmonics are not periodic.

Hard case r0 < dx: a screen whose neighbouring pixels differ by more than 2.6 rad rms (D(dx) > 6.88
rad^2) cannot represent a field: the phase between samples is aliased. ``phase_screen`` refuses it
with a ValueError naming r0_m and dx_m; callers that can refine their grid (``turbulent_coupling``)
do so and warn.
"""

from __future__ import annotations

import itertools
from functools import lru_cache

import numpy as np
from scipy import special
from scipy.integrate import quad

from ._checks import generator, integer, outer_scale, positive

#: c in Phi(f) = c r0^(-5/3) f^(-11/3) (Kolmogorov phase PSD in cycles/m), ~ 0.023.
PSD_COEFF = float(
    special.gamma(11 / 6) ** 2
    / (2.0 * np.pi ** (11 / 3))
    * (24 / 5 * special.gamma(6 / 5)) ** (5 / 6)
)
#: 6.8839 in D(r) = 6.88 (r/r0)^(5/3) (Fried 1965).
KOLMOGOROV_SF_COEFF = float(2.0 * (24 / 5 * special.gamma(6 / 5)) ** (5 / 6))

_CHUNK_ELEMENTS = 1 << 22  # complex elements per FFT batch (64 MiB)


class ResolutionWarning(UserWarning):
    """A grid was refined automatically because r0 was below what it can sample."""


# --- spectra and structure functions -------------------------------------------------------------


def von_karman_psd(f_per_m, r0_m: float, outer_scale_m: float = np.inf):
    """Phase power spectral density Phi(f) in rad^2 m^2 (f in cycles/m), see the module docstring.

    ``f_per_m`` float or array >= 0. Kolmogorov (outer_scale_m = inf) is infinite at f = 0; that
    value is returned as ``inf`` without a warning.
    """
    r0 = positive("r0_m", r0_m)
    l0 = outer_scale("outer_scale_m", outer_scale_m)
    f = np.asarray(f_per_m, dtype=float)
    if np.any(f < 0.0) or not np.all(np.isfinite(f)):
        raise ValueError("f_per_m must be finite and >= 0")
    q = f * f + (0.0 if np.isinf(l0) else 1.0 / (l0 * l0))
    with np.errstate(divide="ignore"):
        out = PSD_COEFF * r0 ** (-5.0 / 3.0) * np.where(q > 0.0, q, 0.0) ** (-11.0 / 6.0)
    return float(out) if out.ndim == 0 else out


def kolmogorov_structure_function(r_m, r0_m: float):
    """D(r) = 6.8839 (r/r0)^(5/3) in rad^2 (Fried 1965). Float or array like ``r_m``."""
    r0 = positive("r0_m", r0_m)
    r = np.asarray(r_m, dtype=float)
    if np.any(r < 0.0):
        raise ValueError("r_m must be >= 0")
    out = KOLMOGOROV_SF_COEFF * (r / r0) ** (5.0 / 3.0)
    return float(out) if out.ndim == 0 else out


def von_karman_phase_variance(r0_m: float, outer_scale_m: float) -> float:
    """Total phase variance B(0) = (6 pi c / 5)(L0/r0)^(5/3) ~ 0.0863 (L0/r0)^(5/3) rad^2 (finite L0)."""
    r0 = positive("r0_m", r0_m)
    l0 = positive("outer_scale_m", outer_scale_m)
    return 1.2 * np.pi * PSD_COEFF * (l0 / r0) ** (5.0 / 3.0)


def _one_minus_g(x):
    """1 - 2^(1/6)/Gamma(5/6) x^(5/6) K_{5/6}(x) for x >= 0, without cancellation at small x."""
    nu = 5.0 / 6.0
    x = np.asarray(x, dtype=float)
    out = np.empty_like(x)
    small = x < 0.05
    xs = x[small] / 2.0
    # Series from K_nu = pi (I_-nu - I_nu) / (2 sin nu pi):
    # 1 - g = G(1-nu) t^(2nu) sum_k t^(2k) / (k! G(k+1+nu)) - G(1-nu) sum_{k>=1} t^(2k) / (k! G(k+1-nu))
    acc = np.zeros_like(xs)
    for k in range(5):
        acc += (
            special.gamma(1 - nu)
            * xs ** (2 * nu + 2 * k)
            / (special.factorial(k) * special.gamma(k + 1 + nu))
        )
        if k >= 1:
            acc -= (
                special.gamma(1 - nu)
                * xs ** (2 * k)
                / (special.factorial(k) * special.gamma(k + 1 - nu))
            )
    out[small] = acc
    xl = x[~small]
    out[~small] = 1.0 - 2.0 ** (1.0 / 6.0) / special.gamma(nu) * xl**nu * special.kv(nu, xl)
    return out


def von_karman_structure_function(r_m, r0_m: float, outer_scale_m: float = np.inf):
    """Phase structure function (rad^2) of the von Karman spectrum ``von_karman_psd``.

    Closed form D(r) = 2 B(0) [1 - 2^(1/6)/Gamma(5/6) x^(5/6) K_{5/6}(x)], x = 2 pi r / L0
    (small-x series where the difference cancels); L0 = inf gives 6.8839 (r/r0)^(5/3).
    ``r_m`` float or array >= 0; returns the same shape.
    """
    r0 = positive("r0_m", r0_m)
    l0 = outer_scale("outer_scale_m", outer_scale_m)
    r = np.asarray(r_m, dtype=float)
    if np.any(r < 0.0) or not np.all(np.isfinite(r)):
        raise ValueError("r_m must be finite and >= 0")
    if np.isinf(l0):
        return kolmogorov_structure_function(r, r0)
    out = 2.0 * von_karman_phase_variance(r0, l0) * _one_minus_g(2.0 * np.pi * r / l0)
    return float(out) if out.ndim == 0 else out


def von_karman_covariance(r_m, r0_m: float, outer_scale_m: float):
    """Phase covariance B(r) = B(0) - D(r)/2 (rad^2) of the von Karman spectrum, finite L0 only."""
    b0 = von_karman_phase_variance(r0_m, outer_scale_m)
    return b0 - 0.5 * np.asarray(von_karman_structure_function(r_m, r0_m, outer_scale_m))


def _one_minus_j0(u: float) -> float:
    """1 - J0(u) without cancellation (power series below u = 0.1, error < 1e-16 relative)."""
    if u < 0.1:
        q = 0.25 * u * u
        return q * (1.0 - q / 4.0 * (1.0 - q / 9.0 * (1.0 - q / 16.0)))
    return 1.0 - float(special.j0(u))


def structure_function_from_psd(r_m, psd) -> np.ndarray:
    """D(r) = 4 pi int_0^inf Phi(f) [1 - J0(2 pi f r)] f df (rad^2) by numerical quadrature.

    ``psd`` is a callable f_per_m -> Phi (rad^2 m^2), isotropic. Substituting u = 2 pi f r, the
    oscillatory part is integrated on [0, 200] (scipy quad on geometric panels below 1
    and panels of 5 above) and the tail
    u > 200 with J0 dropped (its oscillating remainder is below 1e-7 relative for Phi ~ f^(-11/3)).
    Returns float64 array of the shape of ``r_m`` (0 at r = 0).
    """
    r = np.atleast_1d(np.asarray(r_m, dtype=float))
    if np.any(r < 0.0) or not np.all(np.isfinite(r)):
        raise ValueError("r_m must be finite and >= 0")
    out = np.zeros_like(r)
    u_split = 200.0
    for i, ri in enumerate(r.ravel()):
        if ri == 0.0:
            continue
        scale = 2.0 * np.pi * ri

        def body(u, scale=scale):
            return float(psd(u / scale)) * _one_minus_j0(u) * u

        def tail(u, scale=scale):
            return float(psd(u / scale)) * u

        # panels: geometric below u = 1 (where an outer scale bends Phi), unit-ish above.
        edges = np.concatenate(
            [np.geomspace(1e-8, 1.0, 17), np.arange(5.0, u_split, 5.0), [u_split]]
        )
        a = quad(body, 0.0, edges[0], epsabs=0.0, epsrel=1e-9, limit=100)[0]
        for lo, hi in itertools.pairwise(edges):
            a += quad(body, lo, hi, epsabs=0.0, epsrel=1e-9, limit=100)[0]
        b = quad(tail, u_split, np.inf, epsabs=0.0, epsrel=1e-9, limit=200)[0]
        out.flat[i] = 4.0 * np.pi * (a + b) / scale**2
    return out.reshape(np.shape(r_m)) if np.ndim(r_m) else out


# --- screen synthesis ----------------------------------------------------------------------------


def _check_screen_args(n, dx_m, r0_m, outer_scale_m, subharmonic_levels):
    n = integer("n", n, 2)
    dx = positive("dx_m", dx_m)
    r0 = positive("r0_m", r0_m)
    l0 = outer_scale("outer_scale_m", outer_scale_m)
    levels = integer("subharmonic_levels", subharmonic_levels, 0)
    if r0 < dx:
        raise ValueError(
            f"r0_m = {r0:.3g} m is below the grid step dx_m = {dx:.3g} m: neighbouring samples "
            f"would differ by {np.sqrt(kolmogorov_structure_function(dx, r0)):.2g} rad rms and the "
            f"field is aliased; use dx_m <= r0_m (e.g. dx_m = r0_m / 2)"
        )
    return n, dx, r0, l0, levels


#: Default Lane subharmonic levels of ``phase_screens`` and of its exact expectations. Each level
#: removes ~3^(-1/3) of the missing tilt power: for Kolmogorov, 3 levels leave D(N dx / 4) 23 %
#: low, 12 levels 2.2 % (D within 5 % of 6.88 (r/r0)^(5/3) from 2 dx to 0.46 N dx; 5.4 % low at
#: N dx / 2; 8 % low at 1 dx, the power beyond Nyquist), for about 1.1-1.3x the cost of 3 levels
#: per batched screen (all levels in one product).
DEFAULT_SUBHARMONIC_LEVELS = 12

#: FFT cells with max(|kx|, |ky|) <= this many grid steps get tilt-matched weights.
LOW_CELLS = 4
_GL_X, _GL_W = np.polynomial.legendre.leggauss(12)
_SUBCELLS = 2


def _tilt_matched_power(fx, fy, h: float, l0: float) -> np.ndarray:
    """int_cell |f|^2 Phi d^2f / |f_c|^2 for square cells of side h centred at (fx, fy), r0 = 1.

    Gauss-Legendre, 2 x 2 sub-cells of 12 x 12 points (converged to < 1e-6 relative for cells
    whose centre is at least one cell from the origin, as here).
    """
    fx, fy = np.asarray(fx, dtype=float)[:, None], np.asarray(fy, dtype=float)[:, None]
    sub = (np.arange(_SUBCELLS) + 0.5) / _SUBCELLS - 0.5
    u = (sub[:, None] + 0.5 * _GL_X[None, :] / _SUBCELLS).ravel()  # offsets / h
    w = np.tile(_GL_W, _SUBCELLS) * (0.5 / _SUBCELLS)  # weights / h
    ux, uy = np.meshgrid(u, u)
    ww = np.outer(w, w).ravel()
    px = fx + h * ux.ravel()[None, :]
    py = fy + h * uy.ravel()[None, :]
    f2 = px * px + py * py
    integrand = f2 * von_karman_psd(np.sqrt(f2), 1.0, l0)
    return (integrand @ ww) * h * h / (fx[:, 0] ** 2 + fy[:, 0] ** 2)


def _fft_amplitudes(n: int, dx: float, r0: float, l0: float) -> np.ndarray:
    """Mode amplitudes sqrt(var) on the FFT grid (fft order), DC = 0: (n, n) float64 in rad.

    var = Phi(f_c) df^2 (midpoint) except for the cells with max(|kx|, |ky|) <= LOW_CELLS around the
    origin, where the spectrum is steep: there var = int_cell |f|^2 Phi d^2f / |f_c|^2, which gives
    each mode the exact phase-gradient (tilt) power of its cell.
    """
    df = 1.0 / (n * dx)
    f = np.fft.fftfreq(n, dx)
    f2 = f[:, None] ** 2 + f[None, :] ** 2
    f2[0, 0] = 1.0  # placeholder, zeroed below
    var = von_karman_psd(np.sqrt(f2), 1.0, l0) * df * df
    k = np.fft.fftfreq(n, 1.0 / n).astype(int)
    low = np.flatnonzero(np.abs(k) <= LOW_CELLS)
    gy, gx = np.meshgrid(low, low, indexing="ij")
    iy, ix = gy.ravel(), gx.ravel()
    keep = (iy != 0) | (ix != 0)
    iy, ix = iy[keep], ix[keep]
    var[iy, ix] = _tilt_matched_power(f[ix], f[iy], df, l0)
    var[0, 0] = 0.0
    return np.sqrt(var) * r0 ** (-5.0 / 6.0)


def _subharmonic_modes(n: int, dx: float, r0: float, l0: float, levels: int):
    """Per level p = 1..levels: (frequencies (3,), amplitudes (3, 3) in rad, centre 0).

    Lane et al. (1992) 3 x 3 grids of spacing df / 3^p, with tilt-matched cell weights.
    """
    scale = r0 ** (-5.0 / 6.0)
    return [(fr, a * scale) for fr, a in _subharmonic_modes_r0_1(n, dx, l0, levels)]


@lru_cache(maxsize=64)
def _subharmonic_modes_r0_1(n: int, dx: float, l0: float, levels: int):
    """:func:`_subharmonic_modes` at r0 = 1 m (read-only arrays), cached: the cell integrals cost
    more than drawing a small screen, and r0 only scales the amplitudes."""
    out = []
    for p in range(1, levels + 1):
        dfp = 1.0 / (3**p * n * dx)
        fr = np.array([-1.0, 0.0, 1.0]) * dfp
        fy, fx = np.meshgrid(fr, fr, indexing="ij")
        var = np.zeros((3, 3))
        mask = np.ones((3, 3), dtype=bool)
        mask[1, 1] = False
        var[mask] = _tilt_matched_power(fx[mask], fy[mask], dfp, l0)
        a = np.sqrt(var)
        fr.setflags(write=False)
        a.setflags(write=False)
        out.append((fr, a))
    return tuple(out)


def _complex_screens(
    k: int, n: int, amp: np.ndarray, sub, x: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """k complex screens (k, n, n); real and imaginary parts are independent phase screens."""
    c = rng.standard_normal((k, n, n)) + 1j * rng.standard_normal((k, n, n))
    c *= amp
    z = np.fft.fft2(c)
    if sub:
        # All levels in one product: low[k, i, j] = sum_ab cs[k, a, b] e[a, i] e[b, j] with cs
        # block-diagonal (one 3 x 3 block per level; a: y frequency, b: x frequency), drawn level
        # by level in the same order as one level at a time.
        m = 3 * len(sub)
        e = np.exp(2j * np.pi * np.outer(np.concatenate([fr for fr, _ in sub]), x))  # (m, n)
        cs = np.zeros((k, m, m), dtype=complex)
        for p, (_, a) in enumerate(sub):
            cs[:, 3 * p : 3 * p + 3, 3 * p : 3 * p + 3] = (
                rng.standard_normal((k, 3, 3)) + 1j * rng.standard_normal((k, 3, 3))
            ) * a
        low = np.matmul(e.T, cs @ e)
        low -= low.mean(axis=(1, 2), keepdims=True)
        z += low
    return z


def phase_screens(
    count: int,
    n: int,
    dx_m: float,
    r0_m: float,
    *,
    outer_scale_m: float = np.inf,
    subharmonics: bool = True,
    subharmonic_levels: int = DEFAULT_SUBHARMONIC_LEVELS,
    rng: np.random.Generator,
) -> np.ndarray:
    """``count`` independent phase screens, (count, n, n) float64 in radians.

    Parameters
    ----------
    count : number of screens (>= 1). n : samples per side (>= 2). dx_m : grid step in m.
    r0_m : Fried parameter in m (>= dx_m, see the module docstring).
    outer_scale_m : von Karman outer scale L0 in m (numpy.inf: Kolmogorov).
    subharmonics : add Lane et al. (1992) subharmonics; ``subharmonic_levels`` levels (>= 0).
    rng : numpy.random.Generator, the only source of randomness.

    Returns
    -------
    (count, n, n) float64, axis 1 = y (rows), axis 2 = x (columns), pitch dx_m. Screens come in pairs
    (real and imaginary part of one complex FFT screen), so the draws consumed depend on
    ceil(count / 2); the same generator state gives the same screens.
    """
    count = integer("count", count, 1)
    n, dx, r0, l0, levels = _check_screen_args(n, dx_m, r0_m, outer_scale_m, subharmonic_levels)
    rng = generator("rng", rng)
    amp = _fft_amplitudes(n, dx, r0, l0)
    sub = _subharmonic_modes(n, dx, r0, l0, levels) if subharmonics else []
    x = np.arange(n) * dx
    out = np.empty((count, n, n))
    pairs = (count + 1) // 2
    per_chunk = max(1, _CHUNK_ELEMENTS // (n * n))
    done = 0
    for start in range(0, pairs, per_chunk):
        k = min(per_chunk, pairs - start)
        z = _complex_screens(k, n, amp, sub, x, rng)
        both = np.stack([z.real, z.imag], axis=1).reshape(2 * k, n, n)
        take = min(2 * k, count - done)
        out[done : done + take] = both[:take]
        done += take
    return out


def phase_screen(
    n: int,
    dx_m: float,
    r0_m: float,
    *,
    outer_scale_m: float = np.inf,
    subharmonics: bool = True,
    subharmonic_levels: int = DEFAULT_SUBHARMONIC_LEVELS,
    rng: np.random.Generator,
) -> np.ndarray:
    """One n x n phase screen in radians (float64, pitch dx_m); see ``phase_screens``.

    Raises ValueError when r0_m < dx_m (the hard case "r0 far below the grid step").
    """
    return phase_screens(
        1,
        n,
        dx_m,
        r0_m,
        outer_scale_m=outer_scale_m,
        subharmonics=subharmonics,
        subharmonic_levels=subharmonic_levels,
        rng=rng,
    )[0]


def expected_screen_structure_function(
    r_m,
    n: int,
    dx_m: float,
    r0_m: float,
    *,
    outer_scale_m: float = np.inf,
    subharmonics: bool = True,
    subharmonic_levels: int = DEFAULT_SUBHARMONIC_LEVELS,
) -> np.ndarray:
    """Exact ensemble structure function (rad^2) of ``phase_screens`` along a grid axis.

    E[(phi(x + r) - phi(x))^2] = sum over the synthesised modes of 2 Phi(f) df^2 (1 - cos 2 pi f_x r):
    the deterministic expectation of the generator, used to price the low-frequency deficit of a
    screen size and subharmonic level without Monte Carlo noise. ``r_m`` float or array (m).
    """
    n, dx, r0, l0, levels = _check_screen_args(n, dx_m, r0_m, outer_scale_m, subharmonic_levels)
    r = np.asarray(r_m, dtype=float)
    amp2 = _fft_amplitudes(n, dx, r0, l0) ** 2
    fx = np.fft.fftfreq(n, dx)
    # sum over f_y of the variance per f_x column, then the cosine in f_x only.
    col = amp2.sum(axis=0)
    out = 2.0 * np.sum(col * (1.0 - np.cos(2.0 * np.pi * np.multiply.outer(r, fx))), axis=-1)
    if subharmonics:
        for fr, a in _subharmonic_modes(n, dx, r0, l0, levels):
            col = (a**2).sum(axis=0)
            out = out + 2.0 * np.sum(
                col * (1.0 - np.cos(2.0 * np.pi * np.multiply.outer(r, fr))), axis=-1
            )
    return out


def screen_structure_function_lattice(
    max_lag: int,
    n: int,
    dx_m: float,
    r0_m: float,
    *,
    outer_scale_m: float = np.inf,
    subharmonics: bool = True,
    subharmonic_levels: int = DEFAULT_SUBHARMONIC_LEVELS,
) -> np.ndarray:
    """Exact ensemble structure function (rad^2) of ``phase_screens`` on the 2-D lag lattice.

    Returns a (2 m + 1, 2 m + 1) float64 array, m = ``max_lag`` (< n), entry [m + dy, m + dx] the
    expectation of (phi(y + dy, x + dx) - phi(y, x))^2 for integer pixel lags: FFT modes through one
    FFT of the mode variances (the screens' periodic part), subharmonic modes summed directly.
    """
    n, dx, r0, l0, levels = _check_screen_args(n, dx_m, r0_m, outer_scale_m, subharmonic_levels)
    m = integer("max_lag", max_lag, 0)
    if m >= n:
        raise ValueError(f"max_lag must be < n = {n}, got {m}")
    var = _fft_amplitudes(n, dx, r0, l0) ** 2
    cov = np.fft.fft2(var).real  # sum_k var_k cos(2 pi k . lag / n), lag in fft order
    lags = np.arange(-m, m + 1)
    d = 2.0 * (var.sum() - cov[np.ix_(lags % n, lags % n)])
    if subharmonics:
        for fr, a in _subharmonic_modes(n, dx, r0, l0, levels):
            v = a**2  # [y frequency, x frequency]
            for iy in range(3):
                for ix in range(3):
                    if v[iy, ix] == 0.0:
                        continue
                    ph = 2.0 * np.pi * dx * (fr[iy] * lags[:, None] + fr[ix] * lags[None, :])
                    d += 2.0 * v[iy, ix] * (1.0 - np.cos(ph))
    return d


def structure_function_estimate(screens, dx_m: float, max_lag: int):
    """Sample structure function of screens along both grid axes (no wrap-around pairs).

    Parameters
    ----------
    screens : (..., n, n) float array (rad). dx_m : pitch (m). max_lag : largest lag in pixels (< n).

    Returns
    -------
    r_m : (max_lag,) lags 1..max_lag times dx_m.
    d : (..., max_lag) rad^2, per screen: mean of (phi(x + r) - phi(x))^2 over all pairs along x
        and along y. Average over the leading axes for the ensemble estimate; their spread gives the
        standard error.
    """
    s = np.asarray(screens, dtype=float)
    if s.ndim < 2 or s.shape[-1] != s.shape[-2]:
        raise ValueError(f"screens must be (..., n, n), got shape {s.shape}")
    dx = positive("dx_m", dx_m)
    n = s.shape[-1]
    max_lag = integer("max_lag", max_lag, 1)
    if max_lag >= n:
        raise ValueError(f"max_lag must be < n = {n}, got {max_lag}")
    d = np.empty(s.shape[:-2] + (max_lag,))
    for lag in range(1, max_lag + 1):
        dxs = s[..., :, lag:] - s[..., :, :-lag]
        dys = s[..., lag:, :] - s[..., :-lag, :]
        d[..., lag - 1] = 0.5 * ((dxs**2).mean(axis=(-1, -2)) + (dys**2).mean(axis=(-1, -2)))
    return np.arange(1, max_lag + 1) * dx, d

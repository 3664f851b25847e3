"""Single-mode-fiber coupling through phase-only turbulence in the receiver pupil.

Two paths, both in units of the aperture diameter D (only D / r0 matters):

* Monte Carlo (``turbulent_coupling_samples`` / ``turbulent_coupling``): Kolmogorov (or von Karman)
  phase screens on a grid ``screen_factor`` (default 2) times larger than the aperture, with 12
  levels of subharmonics, so that tilt and the other low orders are present; each screen's
  non-overlapping n x n tiles (pitch D / n, the grid of ``chirplidar.optics.pupil_grid``) are
  coupled with ``chirplidar.optics.pupil_field_coupling`` (the batched form of
  ``coupling_efficiency(..., method="numeric", pupil_phase=...)``). The per-sample efficiencies
  are the fading distribution. ``turbulent_coupling_screen_expectation`` is the estimator's exact
  expectation (its bias without the noise).
* Deterministic mean (``turbulent_coupling_mean``): <eta> = int int P M P M exp(-D_phi/2) / norms via
  ``chirplidar.optics.coupling_mutual_coherence`` (Gaussian phase statistics give
  <exp(i (phi1 - phi2))> = exp(-D_phi / 2)), tabulated once per (beta, obstruction, L0 / D) on
  log-spaced D / r0 and interpolated (PCHIP in log-log, monotone).

Missing low-order turbulence (screens no larger than the aperture, no subharmonics) removes most of
the tilt, which dominates the phase variance over the aperture (Noll 1976: 0.896 of 1.03 (D/r0)^(5/3)),
and biases the coupling high for D / r0 >= 3.

Hard case r0 below the pupil sampling: the Monte Carlo needs at least ``min_pixels_per_r0`` samples
per r0 (default 4: the pixel-sampled field biases the mean coupling by +8 % at 2 samples per r0,
+4 % at 3, +2.7 % at 4, +1.6 % at 6, whatever D/r0); when n is too small for that it is raised to
an even number that satisfies it, with a ``ResolutionWarning``. The deterministic mean resolves r0
far below a pixel.
"""

from __future__ import annotations

import warnings
from functools import lru_cache

import numpy as np
from scipy.interpolate import PchipInterpolator

from ._checks import generator, integer, outer_scale, positive, real_scalar
from .screens import (
    ResolutionWarning,
    phase_screens,
    screen_structure_function_lattice,
    von_karman_structure_function,
)

#: Subharmonic levels used for coupling: with 3 levels on a 2D screen ~30 % of the Kolmogorov
#: structure function at r = D is missing and the mean coupling is 13-22 % high at D/r0 = 1-10;
#: 12 levels leave 5 % (bias <= 1.6 % at n = 64) for ~1.6x the screen cost.
COUPLING_SUBHARMONIC_LEVELS = 12
#: D / r0 nodes of the cached mean-coupling table (log-spaced, 12 per decade).
TABLE_D_OVER_R0 = np.logspace(-2.0, 3.0, 61)
MEAN_N = 128
_SCREEN_BYTES = 1 << 25  # screens generated per batch: about 32 MiB


def _optics():
    from chirplidar import optics  # imported lazily: the atmosphere package stands alone

    return optics


def _d_over_r0(value) -> float:
    v = real_scalar("d_over_r0", value)
    if not (np.isfinite(v) and v > 0.0):
        raise ValueError(f"d_over_r0 must be finite and > 0 (D / r0, dimensionless), got {v!r}")
    return v


def _beta_obstruction(beta, obstruction):
    optics = _optics()
    alpha = real_scalar("obstruction", obstruction)
    if not 0.0 <= alpha < 1.0:
        raise ValueError(f"obstruction must be in [0, 1) (diameter ratio), got {alpha}")
    b = optics.optimal_beta(alpha) if beta is None else positive("beta", beta)
    return b, alpha


def _structure_function(d_over_r0: float, l0_over_d: float):
    """Phase structure function of separation rho (units of D), rad^2."""
    if np.isinf(l0_over_d):
        return lambda rho: von_karman_structure_function(np.asarray(rho, float), 1.0 / d_over_r0)
    return lambda rho: von_karman_structure_function(
        np.asarray(rho, float), 1.0 / d_over_r0, l0_over_d
    )


def turbulent_coupling_samples(
    d_over_r0: float,
    beta: float | None = None,
    obstruction: float = 0.0,
    *,
    samples: int = 200,
    rng: np.random.Generator,
    n: int = 64,
    subharmonics: bool = True,
    subharmonic_levels: int = COUPLING_SUBHARMONIC_LEVELS,
    screen_factor: int = 2,
    outer_scale_over_d: float = np.inf,
    min_pixels_per_r0: float = 4.0,
) -> np.ndarray:
    """Per-sample fiber coupling efficiencies through random phase screens (the fading distribution).

    Parameters
    ----------
    d_over_r0 : aperture diameter over Fried parameter, > 0.
    beta : (pi/2)(D/f)(w0/lambda) of the fiber-coupling optics; None = ``optics.optimal_beta``.
    obstruction : central obstruction ratio in [0, 1).
    samples : number of independent screens (>= 1).
    rng : numpy.random.Generator (the only randomness).
    n : pupil samples across D (>= 16; raised with a ResolutionWarning if r0 < min_pixels_per_r0
        pixels, default 4).
    subharmonics, subharmonic_levels : Lane et al. low-frequency compensation (see screens).
    screen_factor : screen side over aperture diameter (integer >= 1). Each screen is cut into its
        screen_factor^2 non-overlapping n x n tiles, each one aperture sample; tiles of one screen
        share its low orders (coupling correlation 0.1-0.4 between neighbours, measured), which
        leaves the mean and the marginal distribution unbiased.
    outer_scale_over_d : von Karman L0 / D (numpy.inf: Kolmogorov).

    Returns
    -------
    (samples,) float64 in [0, 1]; sample i comes from screen i // screen_factor**2 (group by screen
    for an honest standard error: ``grouped_standard_error(eta, screen_factor**2)``).
    """
    x = _d_over_r0(d_over_r0)
    b, alpha = _beta_obstruction(beta, obstruction)
    samples = integer("samples", samples, 1)
    rng = generator("rng", rng)
    n = integer("n", n, 16)
    factor = integer("screen_factor", screen_factor, 1)
    l0 = outer_scale("outer_scale_over_d", outer_scale_over_d)
    px = positive("min_pixels_per_r0", min_pixels_per_r0)
    if px < 1.0:
        raise ValueError(f"min_pixels_per_r0 must be >= 1 (r0 >= one pixel), got {px}")
    need = int(2 * np.ceil(0.5 * px * x))
    if n < need:
        warnings.warn(
            f"D/r0 = {x:g} needs n >= {need} pupil samples for {px:g} per r0; "
            f"n raised from {n} to {need}",
            ResolutionWarning,
            stacklevel=2,
        )
        n = need
    optics = _optics()
    big = factor * n
    tiles = factor * factor
    screens_needed = -(-samples // tiles)
    per_batch = max(
        2, min(screens_needed + screens_needed % 2, 2 * (_SCREEN_BYTES // (16 * big * big)))
    )
    out = np.empty(screens_needed * tiles)
    done = 0
    while done < screens_needed:
        k = min(per_batch, screens_needed - done)
        screens = phase_screens(
            k,
            big,
            1.0 / n,
            1.0 / x,
            outer_scale_m=l0,
            subharmonics=subharmonics,
            subharmonic_levels=subharmonic_levels,
            rng=rng,
        )
        # (k, factor, n, factor, n) -> (k, factor, factor, n, n): the non-overlapping tiles.
        cut = screens.reshape(k, factor, n, factor, n).transpose(0, 1, 3, 2, 4)
        cut = cut.reshape(k * tiles, n, n)
        # Batched form of optics.coupling_efficiency(b, alpha, method="numeric", pupil_phase=cut[i]).
        out[done * tiles : (done + k) * tiles] = optics.pupil_field_coupling(
            np.exp(1j * cut), b, alpha
        )
        done += k
    return out[:samples]


def turbulent_coupling(
    d_over_r0: float,
    beta: float | None = None,
    obstruction: float = 0.0,
    *,
    samples: int = 200,
    rng: np.random.Generator,
    n: int = 64,
    subharmonics: bool = True,
    **kwargs,
) -> float:
    """Monte Carlo mean fiber coupling efficiency through phase-only turbulence (float in [0, 1]).

    The mean of ``turbulent_coupling_samples`` (same arguments; extra keywords are passed on).
    For D/r0 >~ 3 the efficiency is roughly exponentially distributed (coefficient of variation
    1.1-1.3), so the relative standard error is about 1.2 / sqrt(samples) (a little more because
    tiles of one screen are correlated; see ``grouped_standard_error``).
    """
    return float(
        np.mean(
            turbulent_coupling_samples(
                d_over_r0,
                beta,
                obstruction,
                samples=samples,
                rng=rng,
                n=n,
                subharmonics=subharmonics,
                **kwargs,
            )
        )
    )


def grouped_standard_error(values, group: int) -> float:
    """Standard error of the mean of ``values`` whose consecutive groups of ``group`` are correlated.

    The group means are treated as the independent draws (an incomplete last group is dropped).
    """
    v = np.asarray(values, dtype=float).ravel()
    g = integer("group", group, 1)
    m = v[: (v.size // g) * g].reshape(-1, g).mean(axis=1)
    if m.size < 2:
        raise ValueError(f"need at least two complete groups of {g} values, got {v.size} values")
    return float(m.std(ddof=1) / np.sqrt(m.size))


def turbulent_coupling_screen_expectation(
    d_over_r0: float,
    beta: float | None = None,
    obstruction: float = 0.0,
    *,
    n: int = 64,
    subharmonics: bool = True,
    subharmonic_levels: int = COUPLING_SUBHARMONIC_LEVELS,
    screen_factor: int = 2,
    outer_scale_over_d: float = np.inf,
) -> float:
    """Exact expectation of the Monte Carlo estimator ``turbulent_coupling`` (no sampling noise).

    The screens are Gaussian, so <exp(i (phi_a - phi_b))> = exp(-D_gen / 2) with D_gen the
    generator's own lattice structure function (``screen_structure_function_lattice``: the FFT grid's
    mode variances, its periodicity and the subharmonics as synthesised). Hence

        E[eta] = eta_grid(plane wave) * sum_d A(d) exp(-D_gen(d) / 2) / sum_d A(d),

    A the lattice autocorrelation of (pupil weights x fiber mode) on the n x n grid, eta_grid the
    grid's plane-wave coupling (``optics.pupil_field_coupling`` of a uniform field). The difference
    to ``turbulent_coupling_exact`` (continuous Kolmogorov / von Karman) is the systematic error of
    the screens (missing low orders, pixel sampling) for these settings. Float in [0, 1].
    """
    x = _d_over_r0(d_over_r0)
    b, alpha = _beta_obstruction(beta, obstruction)
    n = integer("n", n, 16)
    factor = integer("screen_factor", screen_factor, 1)
    l0 = outer_scale("outer_scale_over_d", outer_scale_over_d)
    optics = _optics()
    grid = optics.pupil_grid(n, alpha)
    f = grid.weights * optics.fiber_mode_pupil(grid, b)
    spec = np.fft.rfft2(f, s=(2 * n, 2 * n))
    acorr = np.fft.irfft2((spec * spec.conj()).real, s=(2 * n, 2 * n))
    lags = np.arange(-(n - 1), n)
    a = acorr[np.ix_(lags % (2 * n), lags % (2 * n))]
    d = screen_structure_function_lattice(
        n - 1,
        factor * n,
        1.0 / n,
        1.0 / x,
        outer_scale_m=l0,
        subharmonics=subharmonics,
        subharmonic_levels=subharmonic_levels,
    )
    eta_plane = float(optics.pupil_field_coupling(np.ones((n, n)), b, alpha))
    return float(eta_plane * np.sum(a * np.exp(-0.5 * d)) / np.sum(a))


def turbulent_coupling_exact(
    d_over_r0: float,
    beta: float | None = None,
    obstruction: float = 0.0,
    *,
    outer_scale_over_d: float = np.inf,
    n: int = MEAN_N,
) -> float:
    """Deterministic mean coupling <eta> (mutual-coherence integral, no table), float in [0, 1]."""
    x = _d_over_r0(d_over_r0)
    b, alpha = _beta_obstruction(beta, obstruction)
    l0 = outer_scale("outer_scale_over_d", outer_scale_over_d)
    n = integer("n", n, 16)
    return float(_optics().coupling_mutual_coherence(b, alpha, _structure_function(x, l0), n=n))


@lru_cache(maxsize=32)
def _mean_table(beta: float, alpha: float, l0: float, n: int):
    optics = _optics()
    eta0 = float(optics.coupling_mutual_coherence(beta, alpha, lambda rho: 0.0 * rho, n=n))
    eta = np.array(
        [
            optics.coupling_mutual_coherence(beta, alpha, _structure_function(x, l0), n=n)
            for x in TABLE_D_OVER_R0
        ]
    )
    if np.any(eta <= 0.0):
        raise ValueError("mean coupling table underflowed (D/r0 too large for float64)")
    spline = PchipInterpolator(np.log(TABLE_D_OVER_R0), np.log(eta), extrapolate=False)
    return eta0, eta, spline


def turbulent_coupling_mean(
    d_over_r0,
    beta: float | None = None,
    obstruction: float = 0.0,
    *,
    outer_scale_over_d: float = np.inf,
):
    """Mean fiber coupling through phase-only turbulence from a cached table (fast path for missions).

    Parameters
    ----------
    d_over_r0 : float or array of D / r0 (> 0, finite).
    beta, obstruction : as ``turbulent_coupling`` (beta None = optimal for the obstruction).
    outer_scale_over_d : von Karman L0 / D (numpy.inf: Kolmogorov).

    Returns
    -------
    <eta> in [0, 1], float for scalar input else float64 array of the input's shape.

    Method: ``turbulent_coupling_exact`` at 61 log-spaced D/r0 in [0.01, 1000] (n = 128, ~1 s once
    per (beta, obstruction, L0/D), then cached), PCHIP interpolation of log <eta> against
    log(D/r0) (monotone; interpolation error < 1e-3 relative, tested). Outside the table:
    D/r0 < 0.01 uses 1 - <eta>/eta0 proportional to (D/r0)^(5/3) (phase variance), D/r0 > 1000 uses
    the strong-turbulence law <eta> proportional to (r0/D)^2 (coherence area over aperture area).
    """
    x = np.asarray(d_over_r0, dtype=float)
    if not np.all(np.isfinite(x)) or np.any(x <= 0.0):
        raise ValueError("d_over_r0 must be finite and > 0 everywhere")
    b, alpha = _beta_obstruction(beta, obstruction)
    l0 = outer_scale("outer_scale_over_d", outer_scale_over_d)
    eta0, eta, spline = _mean_table(float(b), float(alpha), float(l0), MEAN_N)
    x_lo, x_hi = TABLE_D_OVER_R0[0], TABLE_D_OVER_R0[-1]
    xc = np.clip(x, x_lo, x_hi)
    out = np.exp(spline(np.log(xc)))
    small = x < x_lo
    out = np.where(
        small, eta0 - (eta0 - eta[0]) * (np.where(small, x, x_lo) / x_lo) ** (5 / 3), out
    )
    out = np.where(x > x_hi, eta[-1] * (x_hi / np.where(x > x_hi, x, x_hi)) ** 2, out)
    return float(out) if out.ndim == 0 else out

"""Coupling of a received field into the fundamental mode of a single-mode fiber.

Model (Shaklan & Roddier 1988, Appl. Opt. 27, 2334; Ruilier 1998, Proc. SPIE 3350, 319): the
fiber mode is a Gaussian E_f(u) = exp(-u^2 / w0^2) in the focal plane of a lens of focal length f
(w0 = mode-field radius, 1/e field = 1/e^2 intensity radius, MFD / 2). Back-propagated to the pupil
through the Fraunhofer transform (eq. 2.6.16) it is again a Gaussian,

    M(r) = exp(-r^2 / W^2),    W = lambda f / (pi w0).

The coupling efficiency of a pupil field E over the annulus P (aperture diameter D, central
obstruction ratio alpha) is the normalised overlap

    eta = |int P E M* d^2r|^2 / (int P |E|^2 d^2r  *  int |M|^2 d^2r),

the mode norm taken over the whole plane. The overlap is the same in the pupil and in the focal
plane: the Fraunhofer transform is unitary (Parseval), so inner products and norms are preserved.
With beta = R / W = (pi / 2)(D / f)(w0 / lambda) and a uniform plane wave E = 1 the integrals are
elementary (int_{aR}^{R} exp(-r^2/W^2) 2 pi r dr = pi W^2 [exp(-a^2 b^2) - exp(-b^2)]):

    eta(beta, alpha) = 2 [exp(-alpha^2 beta^2) - exp(-beta^2)]^2 / (beta^2 (1 - alpha^2)),

which peaks at beta = 1.1209, eta = 0.8145 for alpha = 0 (Shaklan & Roddier 1988).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import map_coordinates
from scipy.optimize import minimize_scalar

from ._checks import finite_array, grid_size, obstruction_ratio, positive, square_field
from .pupil import PupilGrid, pupil_grid

DEFAULT_N = 256
MUTUAL_COHERENCE_DEFAULT_N = 128


def coupling_beta(
    aperture_diameter_m: float,
    focal_length_m: float,
    mode_field_radius_m: float,
    wavelength_m: float,
) -> float:
    """beta = (pi / 2) (D / f) (w0 / lambda), dimensionless (w0 = MFD / 2, 1/e^2 intensity radius)."""
    d = positive("aperture_diameter_m", aperture_diameter_m)
    f = positive("focal_length_m", focal_length_m)
    w0 = positive("mode_field_radius_m", mode_field_radius_m)
    lam = positive("wavelength_m", wavelength_m)
    return 0.5 * np.pi * (d / f) * (w0 / lam)


def _beta(beta) -> float:
    return positive("beta", beta)


def _analytic(beta: float, alpha: float) -> float:
    """Closed form, written as 2 x exp(-2 a^2 b^2) [(1 - exp(-x)) / x]^2 with x = (1 - a^2) b^2.

    This is the same expression without the cancellation of exp(-a^2 b^2) - exp(-b^2) for
    alpha -> 1 and without 0/0 for beta -> 0 or inf/inf for beta -> inf.
    """
    b2 = beta * beta
    x = (1.0 - alpha * alpha) * b2
    if x == 0.0 or not np.isfinite(x):
        return 0.0
    ratio = -np.expm1(-x) / x
    return float(2.0 * x * np.exp(-2.0 * alpha * alpha * b2) * ratio * ratio)


def fiber_mode_pupil(grid: PupilGrid, beta: float) -> np.ndarray:
    """Back-propagated fiber mode M(r) = exp(-(2 beta r / D)^2) on ``grid``: (n, n) float64, peak 1.

    (W = D / (2 beta) is the mode's 1/e field radius in the pupil.)
    """
    b = _beta(beta)
    with np.errstate(over="ignore"):  # beta r beyond 1e154: the mode is 0 there, exactly
        return np.exp(-np.square(2.0 * b * grid.r))


def _mode_norm(beta: float) -> float:
    """int |M|^2 d^2r over the whole plane, in units of D^2: pi W^2 / 2 with W = 1 / (2 beta)."""
    return np.pi / (8.0 * beta * beta)


def pupil_field_coupling(pupil_field, beta: float, obstruction: float = 0.0):
    """Coupling efficiency of sampled pupil fields into the fiber mode (pupil-plane overlap).

    Parameters
    ----------
    pupil_field : complex array (..., n, n), field across the aperture diameter on the grid of
        ``pupil_grid(n, obstruction)`` (pitch D / n, index [row = y, column = x]). Its values
        outside the annulus are ignored (weight 0); any amplitude and phase are allowed.
    beta : (pi / 2)(D / f)(w0 / lambda) > 0.
    obstruction : central obstruction ratio alpha in [0, 1).

    Returns
    -------
    float for a single (n, n) field, else float64 array of shape (...): eta in [0, 1].
    """
    b = _beta(beta)
    field = square_field("pupil_field", pupil_field)
    grid = pupil_grid(grid_size(field.shape[-1], "pupil_field size n"), obstruction)
    w = grid.weights
    m = fiber_mode_pupil(grid, b)
    da = grid.pixel_area
    overlap = np.einsum("...ij,ij->...", field, w * m) * da
    power = np.einsum("...ij,ij->...", (field * field.conj()).real, w) * da
    if np.any(power <= 0.0):
        raise ValueError("pupil_field carries no power inside the aperture")
    overlap_sq = (overlap * overlap.conj()).real
    # 1 / int|M|^2 = 8 beta^2 / pi; for beta beyond ~1e154 the mode (and the overlap) is exactly 0.
    with np.errstate(over="ignore"):
        inv_norm = 8.0 * b * b / np.pi
    ratio = overlap_sq / power
    eta = np.multiply(ratio, inv_norm, out=np.zeros_like(ratio), where=ratio > 0.0)
    return float(eta) if eta.ndim == 0 else eta


def coupling_efficiency(
    beta: float,
    obstruction: float = 0.0,
    *,
    method: str = "analytic",
    pupil_phase=None,
    n: int | None = None,
) -> float:
    """Fiber coupling efficiency of a (possibly aberrated) plane wave through an annular aperture.

    Parameters
    ----------
    beta : (pi / 2)(D / f)(w0 / lambda) > 0 (D aperture diameter, f focal length, w0 mode-field
        radius = MFD / 2, lambda wavelength); see ``coupling_beta``.
    obstruction : central obstruction ratio alpha = d_obstruction / D in [0, 1).
    method : "analytic" (closed form, Ruilier 1998) or "numeric" (overlap integral on an n x n
        pupil grid with exact-area edge weights; see ``pupil_grid``).
    pupil_phase : optional (n, n) float array of phase in radians (numeric only), sampled on the grid
        of ``pupil_grid(n, obstruction)``: the array spans the full aperture diameter D, pixel pitch
        D / n, pixel (i, j) centred at (x, y) = ((j + 1/2)/n - 1/2, (i + 1/2)/n - 1/2) D. Values
        outside the annulus are ignored. For a stack of screens (..., n, n) use
        ``pupil_field_coupling(np.exp(1j * screens), beta, obstruction)`` (same grid, batched).
    n : samples across D for "numeric"; default: the size of ``pupil_phase``, else 256. Must be
        >= 16 and equal ``pupil_phase``'s size when both are given.

    Returns
    -------
    eta : float in [0, 1].
    """
    b = _beta(beta)
    alpha = obstruction_ratio(obstruction)
    if method == "analytic":
        if pupil_phase is not None:
            raise ValueError(
                "pupil_phase requires method='numeric' (the closed form is for a plane wave)"
            )
        if n is not None:
            grid_size(n)
        return _analytic(b, alpha)
    if method != "numeric":
        raise ValueError(f"method must be 'analytic' or 'numeric', got {method!r}")
    if pupil_phase is None:
        size = DEFAULT_N if n is None else grid_size(n)
        field = np.ones((size, size))
    else:
        phase = finite_array("pupil_phase", pupil_phase, float)
        if phase.ndim != 2 or phase.shape[0] != phase.shape[1]:
            raise ValueError(f"pupil_phase must be a square (n, n) array, got shape {phase.shape}")
        if n is not None and grid_size(n) != phase.shape[0]:
            raise ValueError(f"n = {n} does not match pupil_phase of shape {phase.shape}")
        grid_size(phase.shape[0], "pupil_phase size n")
        field = np.exp(1j * phase)
    return float(pupil_field_coupling(field, b, alpha))


def optimal_beta(obstruction: float = 0.0) -> float:
    """beta maximising the closed-form plane-wave coupling for the obstruction ratio alpha.

    alpha = 0 gives 1.1209 (eta = 0.8145, Shaklan & Roddier 1988). Bounded Brent search
    (scipy.optimize.minimize_scalar) around the best point of a coarse log-spaced scan.
    """
    alpha = obstruction_ratio(obstruction)
    return _maximise(lambda b: _analytic(b, alpha))


def _maximise(fn, lo: float = 0.02, hi: float = 6.0, points: int = 121) -> float:
    scan = np.geomspace(lo, hi, points)
    vals = np.array([fn(b) for b in scan])
    k = int(np.argmax(vals))
    a, c = scan[max(k - 1, 0)], scan[min(k + 1, points - 1)]
    res = minimize_scalar(
        lambda b: -fn(b), bounds=(a, c), method="bounded", options={"xatol": 1e-9}
    )
    return float(res.x)


# --- Mean coupling of partially coherent fields -------------------------------------------------
#
# Both functions below are integrals over the separation d = r2 - r1 of the autocorrelation
#     C(d) = int P M(r) P M(r + d) d^2r
# of the aperture-weighted mode against a degree of coherence mu(|d|):
#     <eta> = int C(d) mu(|d|) d^2d / (int P d^2r * int M^2 d^2r).
# C comes either from the pupil grid (lattice autocorrelation of weights * M by zero-padded FFT:
# methods "fft" and "lattice") or grid-free ("radial": C(rho) of the annulus times the Gaussian as
# a 2-D integral in polar coordinates, ~1e-8 relative for this circular pupil).

_RHO_FLOOR = 1e-9  # smallest resolved separation, units of D
_GL6 = np.polynomial.legendre.leggauss(6)
_GL16 = np.polynomial.legendre.leggauss(16)
_METHODS = ("fft", "lattice", "radial")


def _weighted_mode(beta: float, alpha: float, n: int):
    grid = pupil_grid(n, alpha)
    return grid, grid.weights * fiber_mode_pupil(grid, beta)


def _autocorrelation(f: np.ndarray) -> np.ndarray:
    """Lattice autocorrelation sum_r f(r) f(r + d) of a real (n, n) array, zero-padded (no wrap).

    Returns a (2n, 2n) array with zero lag at index [n, n].
    """
    n = f.shape[-1]
    spec = np.fft.rfft2(f, s=(2 * n, 2 * n))
    c = np.fft.irfft2((spec * spec.conj()).real, s=(2 * n, 2 * n))
    return np.fft.fftshift(c)


def _gl_nodes(a, b, rule, cosine_map: bool):
    """Gauss-Legendre nodes and weights on [a, b] (broadcast over leading axes).

    With ``cosine_map`` the rule is applied in theta, r = (a + b)/2 - (b - a)/2 cos(theta), which
    removes square-root end-point singularities (the chord lengths of circles).
    """
    x, w = rule
    a = np.asarray(a, dtype=float)[..., None]
    b = np.asarray(b, dtype=float)[..., None]
    if not cosine_map:
        return 0.5 * (a + b) + 0.5 * (b - a) * x, 0.5 * (b - a) * w
    th = 0.5 * np.pi * (x + 1.0)
    return 0.5 * (a + b) - 0.5 * (b - a) * np.cos(th), 0.25 * np.pi * (b - a) * np.sin(th) * w


def _radial_nodes(pitch: float | None, breakpoints=(), geometric: bool = True):
    """Radial rule on [0, rho_max] (units of D); ``geometric`` panels resolve kernels to 1e-9 D."""
    rho_max = 1.0 if pitch is None else 1.0 + 2.0 * pitch
    parts = [np.array([0.0, rho_max]), np.asarray(breakpoints, dtype=float)]
    if geometric:
        parts.append(np.geomspace(_RHO_FLOOR, rho_max, 91))
    if pitch is not None:
        parts.append(np.arange(0.0, rho_max, 0.5 * pitch))
    else:
        parts.append(np.linspace(0.0, rho_max, 21))
    edges = np.unique(np.clip(np.concatenate(parts), 0.0, rho_max))
    rho, wts = _gl_nodes(edges[:-1], edges[1:], _GL6, cosine_map=pitch is None)
    return rho.ravel(), wts.ravel()


def _lattice_radial_mean(
    lag_field: np.ndarray, pitch: float, rho: np.ndarray, n_angles: int
) -> np.ndarray:
    """Angular mean of the bilinear interpolant of a lag lattice (zero lag at [n, n]) at radii rho.

    Uses the lattice's 8-fold symmetry (angles in [0, pi/4]).
    """
    n = lag_field.shape[-1] // 2
    theta = (np.arange(n_angles) + 0.5) * (0.25 * np.pi / n_angles)
    rows = n + np.outer(rho, np.sin(theta)) / pitch
    cols = n + np.outer(rho, np.cos(theta)) / pitch
    return (
        map_coordinates(lag_field, [rows.ravel(), cols.ravel()], order=1, mode="constant", cval=0.0)
        .reshape(rho.size, n_angles)
        .mean(axis=1)
    )


def annulus_mode_autocorrelation(rho, beta: float, obstruction: float = 0.0) -> np.ndarray | float:
    """C(rho) = int P M(r) P M(r + rho) d^2r for the annulus P and mode M = exp(-(2 beta r / D)^2).

    rho : separations / D (array, >= 0). Returns float64 of rho's shape (a float for a scalar
    rho), units of D^2. Computed in
    polar coordinates about the first point: for each radius r the angles where |r + rho| lies in
    the annulus are explicit (law of cosines); Gauss-Legendre in r (cosine-mapped between the
    breakpoints where those limits change) and in angle.
    """
    b = _beta(beta)
    alpha = obstruction_ratio(obstruction)
    p = np.atleast_1d(np.asarray(rho, dtype=float))
    if not np.all(np.isfinite(p)) or np.any(p < 0.0):
        raise ValueError("rho must be finite and >= 0")
    big_r, small_r = 0.5, 0.5 * alpha
    inv_w2 = 4.0 * b * b  # 1 / W^2 in units of D^-2
    out = np.zeros(p.shape)
    flat = p.ravel()
    res = out.ravel()
    for start in range(0, flat.size, 256):
        q = flat[start : start + 256][:, None]  # (m, 1)
        bps = np.sort(
            np.clip(
                np.concatenate(
                    [
                        np.full_like(q, small_r),
                        np.full_like(q, big_r),
                        big_r - q,
                        q - big_r,
                        small_r - q,
                        q - small_r,
                        q + small_r,
                    ],
                    axis=1,
                ),
                small_r,
                big_r,
            ),
            axis=1,
        )
        r, wr = _gl_nodes(bps[:, :-1], bps[:, 1:], _GL16, cosine_map=True)  # (m, 6, 16)
        qq = q[:, :, None]
        two_rq = np.maximum(2.0 * r * qq, 1e-300)
        cmax = np.clip((big_r**2 - r * r - qq * qq) / two_rq, -1.0, 1.0)
        cmin = np.clip((small_r**2 - r * r - qq * qq) / two_rq, -1.0, 1.0)
        phi_lo, phi_hi = np.arccos(cmax), np.arccos(cmin)  # allowed phi in [phi_lo, phi_hi]
        phi, wphi = _gl_nodes(phi_lo, phi_hi, _GL16, cosine_map=False)  # (m, 6, 16, 16)
        expo = (
            -(
                2.0 * r[..., None] ** 2
                + qq[..., None] ** 2
                + 2.0 * r[..., None] * qq[..., None] * np.cos(phi)
            )
            * inv_w2
        )
        inner = 2.0 * np.sum(wphi * np.exp(expo), axis=-1)  # both half planes
        res[start : start + 256] = np.sum(wr * r * inner, axis=(1, 2))
    return out.reshape(np.shape(rho)) if np.ndim(rho) else float(out[0])


def _zero_lag(beta: float, alpha: float) -> float:
    """C(0) = int P M^2 d^2r = (pi W^2 / 2)[exp(-2 a^2 b^2) - exp(-2 b^2)], units of D^2."""
    b2 = beta * beta
    return float(
        np.pi
        / (8.0 * b2)
        * np.exp(-2.0 * alpha * alpha * b2)
        * -np.expm1(-2.0 * (1.0 - alpha * alpha) * b2)
    )


def _annulus_breakpoints(alpha: float):
    return [0.5 * (1.0 - alpha), alpha, 0.5 * (1.0 + alpha)]


def _structure_kernel(structure_function):
    if not callable(structure_function):
        raise ValueError(
            "structure_function must be a callable of separation / D returning the "
            "phase structure function in rad^2"
        )

    def kernel(rho):
        try:
            d = np.asarray(structure_function(rho), dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"structure_function failed on a float64 array of separations: {exc}"
            ) from None
        if d.shape != rho.shape:
            raise ValueError(
                f"structure_function must return an array of the input's shape "
                f"{rho.shape}, got {d.shape}"
            )
        if not np.all(np.isfinite(d)) or np.any(d < 0.0):
            raise ValueError("structure_function must return finite values >= 0 (rad^2)")
        k = int(np.argmin(rho))
        if d.flat[k] > 0.02:
            raise ValueError(
                f"structure_function is {d.flat[k]:.3g} rad^2 already at a separation "
                f"of {rho.flat[k]:.1e} D: the phase coherence length is below what "
                f"can be resolved (about 1e-9 D), or D_phi(0) != 0"
            )
        return np.exp(-0.5 * d)

    return kernel


def _method(method: str) -> str:
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    return method


def coupling_mutual_coherence(
    beta: float,
    obstruction: float,
    structure_function,
    *,
    n: int = MUTUAL_COHERENCE_DEFAULT_N,
    method: str = "fft",
    n_angles: int = 64,
) -> float:
    """Mean coupling efficiency of a plane wave through phase-only (Gaussian-statistics) turbulence.

    Deterministic:  <eta> = int int P M(r1) P M(r2) exp(-D_phi(|r1 - r2|) / 2) d^2r1 d^2r2
                            / (int P d^2r * int M^2 d^2r),
    using <exp(i(phi1 - phi2))> = exp(-D_phi / 2); equivalently int C(d) exp(-D_phi(|d|)/2) d^2d
    with C the autocorrelation of P M. The separation integral is radial, on panels that resolve
    exp(-D_phi / 2) down to 1e-9 D, so coherence lengths far below the pixel pitch are handled.

    Parameters
    ----------
    beta : (pi / 2)(D / f)(w0 / lambda) > 0.
    obstruction : central obstruction ratio alpha in [0, 1).
    structure_function : callable(rho) -> D_phi in rad^2, rho = separation / aperture diameter
        (float64 array), e.g. ``lambda rho: 6.88 * (rho * D / r0) ** (5 / 3)`` (Kolmogorov). Must be
        vectorised, finite and >= 0.
    n : pupil samples across D for method "fft" (>= 16).
    method :
        "fft" (default): C from the zero-padded FFT autocorrelation of weights * M on the n x n grid
        of ``pupil_grid`` (zero lag set to its quadrature sum(weights M^2) dA), angular mean of its
        bilinear interpolant over ``n_angles`` angles in [0, pi/4], kernel integrated radially.
        Relative error vs "radial" (alpha = 0.3): <= 5e-4 at n = 128 for D/r0 <= 10, <= 2e-3
        beyond, including r0 far below the pixel pitch.
        "lattice": sum over the grid's lags of C(d) exp(-D_phi(|d|)/2) dA. This is exactly the
        expectation of a Monte Carlo run on the same n x n grid with a statistically perfect phase
        screen (weights as quadrature weights); it departs from the continuum once r0 nears the
        pixel pitch D / n, so use it to separate screen errors from grid errors.
        "radial": grid-free C of the annulus (``annulus_mode_autocorrelation``), ~1e-8 relative
        for any D/r0; n is ignored. About 0.03 s.

    Returns
    -------
    <eta> : float in [0, 1]. With D_phi = 0 it is the plane-wave coupling of ``coupling_efficiency``
        (numeric on the same grid for "fft" and "lattice", the closed form for "radial").
    """
    b = _beta(beta)
    alpha = obstruction_ratio(obstruction)
    method = _method(method)
    n = grid_size(n)
    n_angles = grid_size(n_angles, "n_angles", minimum=4)
    kernel = _structure_kernel(structure_function)
    if method in ("fft", "lattice"):
        grid, f = _weighted_mode(b, alpha, n)
        lag = _autocorrelation(f) * grid.pixel_area  # int f(r) f(r + d) d^2r, units D^2
        if method == "lattice":
            k = np.arange(2 * n) - n
            rho = grid.pitch * np.hypot(k[:, None], k[None, :])
            total = float(np.sum(lag * kernel(rho))) * grid.pixel_area
            return float(max(total, 0.0) / (grid.area * _mode_norm(b)))
        # The lattice's zero lag sum(w^2 M^2) understates int P M^2 at partial edge pixels; use the
        # quadrature sum(w M^2) (matters when exp(-D_phi/2) is narrower than a pixel).
        lag[n, n] = float(np.sum(f * fiber_mode_pupil(grid, b))) * grid.pixel_area
        rho, wts = _radial_nodes(grid.pitch)
        c: np.ndarray | float = _lattice_radial_mean(lag, grid.pitch, rho, n_angles)
        area = grid.area
    else:
        rho, wts = _radial_nodes(None, _annulus_breakpoints(alpha))
        c = annulus_mode_autocorrelation(rho, b, alpha)
        area = 0.25 * np.pi * (1.0 - alpha * alpha)
    total = float(np.sum(wts * kernel(rho) * c * 2.0 * np.pi * rho))
    return float(max(total, 0.0) / (area * _mode_norm(b)))


def monostatic_diffuse_coupling(
    beta: float,
    obstruction: float = 0.0,
    *,
    method: str = "radial",
    n: int = MUTUAL_COHERENCE_DEFAULT_N,
) -> float:
    """Mean coupling of speckle from a diffuse target lit by the same fiber and telescope.

    Monostatic lidar (Winzer & Leeb 1998, Opt. Lett. 23, 986): the transmit field in the pupil is
    the truncated mode P M; the target in the far field (or at the focus) is lit with |FT(P M)|^2;
    by van Cittert-Zernike the returned speckle has uniform mean intensity over the pupil and
    degree of coherence mu(d) = C(d) / C(0), with C the autocorrelation of P M. Hence

        <eta> = int C(d)^2 d^2d / (C(0) * int P d^2r * int M^2 d^2r)

    (mean coupled power / mean power on the aperture). Peaks at 0.4248 for beta = 1.149, alpha = 0:
    the "approximately 42 %" of the thesis (p. 59, ref. 22).

    method : "radial" (grid-free, default) or "fft" (lattice sum on the zero-padded n x n grid, the
        expectation of a speckle Monte Carlo on that grid; its error falls only as 1/n because
        products of partial edge weights misstate the aperture's overlap with itself at small
        lags: +4e-4 at n = 128).
    Returns <eta> : float in [0, 1].
    """
    b = _beta(beta)
    alpha = obstruction_ratio(obstruction)
    if method not in ("fft", "radial"):
        raise ValueError(f"method must be 'fft' or 'radial', got {method!r}")
    n = grid_size(n)
    if method == "fft":
        grid, f = _weighted_mode(b, alpha, n)
        lag = _autocorrelation(f)
        c0 = float(np.sum(f * f))
        total = float(np.sum(lag * lag)) / c0 * grid.pixel_area**2  # int C^2 / C(0), D^4
        return float(total / (grid.area * _mode_norm(b)))
    rho, wts = _radial_nodes(None, _annulus_breakpoints(alpha), geometric=False)
    c = annulus_mode_autocorrelation(rho, b, alpha)
    total = float(np.sum(wts * c * c * 2.0 * np.pi * rho)) / _zero_lag(b, alpha)
    return float(total / (0.25 * np.pi * (1.0 - alpha * alpha) * _mode_norm(b)))


def optimal_beta_monostatic(obstruction: float = 0.0) -> float:
    """beta maximising ``monostatic_diffuse_coupling`` (1.149 for alpha = 0)."""
    alpha = obstruction_ratio(obstruction)
    return _maximise(lambda b: monostatic_diffuse_coupling(b, alpha), lo=0.2, hi=4.0, points=31)

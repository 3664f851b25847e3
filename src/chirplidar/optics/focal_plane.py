"""The received field in the pupil and the focal plane, and the receivers that mix it with an LO.

Speckle across the pupil (Goodman 2007, "Speckle Phenomena in Optics", Ch. 4 and 5): a rough
target lit over a footprint of intensity I_t(xi) at range R returns, in the Fraunhofer
approximation (the quadratic phases dropped: the receiver is focused on the target),

    E(x) = sum_k a_k z_k exp(-i 2 pi x . s_k),    s_k = xi_k / (lambda R)  (cycles / m),

with |a_k|^2 proportional to I_t at the scatterer xi_k and z_k independent circular complex
Gaussian (E|z|^2 = 1). E is then circular complex Gaussian with E|E|^2 = sum |a_k|^2 = 1 and
(van Cittert-Zernike, Goodman 2007 Sec. 5.6) degree of coherence

    mu(d) = sum_k |a_k|^2 exp(-i 2 pi d . s_k)  ~  FT{I_t}(d / (lambda R)) / FT{I_t}(0).

* Gaussian footprint, 1/e^2 intensity radius w: I_t = exp(-2 |xi|^2 / w^2) gives
  mu(d) = exp(-(pi w d / (lambda R))^2 / 2) = exp(-d^2 / (2 rho^2)), |mu|^2 = exp(-d^2 / rho^2),
  rho = lambda R / (pi w)  (``speckle_coherence_radius_m``).
* Monostatic (Winzer & Leeb 1998, Opt. Lett. 23, 986): the footprint is the far field of the
  truncated transmit mode P M, so |a(s)|^2 = |FT{P M}(s)|^2 and mu(d) = C(d) / C(0), C the
  autocorrelation of P M.

The sums are evaluated by FFT on a target grid of pitch 1 / (N dx) (N >= 2 n), so the pupil
samples are exactly the Fraunhofer sum and the correlation is free of wrap-around across the
grid. Focal fields use ``diffraction.fraunhofer`` (MFT, unitary).
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft
from scipy.special import erf, sici

from .._checks import generator, integer
from ._checks import finite_array, grid_size, obstruction_ratio, positive, square_field
from .coupling import fiber_mode_pupil
from .diffraction import focal_spot_diameter_m
from .pupil import PupilGrid

_ALIAS_RADII = 10.0  # wrap-around of a Gaussian correlation at >= 10 rho: exp(-50), negligible
_MAX_ELEMENTS = 2**21  # complex target-plane samples generated at once (32 MiB)


def _grid(value) -> PupilGrid:
    if not isinstance(value, PupilGrid):
        raise ValueError(
            f"grid must be a PupilGrid (optics.pupil_grid), got {type(value).__name__}"
        )
    return value


def speckle_coherence_radius_m(wavelength_m: float, range_m: float, footprint_radius_m: float):
    """rho = lambda R / (pi w) (m): |mu(d)|^2 = exp(-d^2 / rho^2) for a Gaussian footprint of 1/e^2
    intensity radius w at range R (van Cittert-Zernike, Goodman 2007 Sec. 5.6)."""
    lam = positive("wavelength_m", wavelength_m)
    r = positive("range_m", range_m)
    w = positive("footprint_radius_m", footprint_radius_m)
    return lam * r / (np.pi * w)


def return_spot_radius_m(
    focal_length_m: float,
    wavelength_m: float,
    aperture_m: float,
    footprint_radius_m: float,
    range_m: float,
) -> float:
    """Radius of the return's spot in the focal plane (m): the footprint's image f w / R and the
    aperture's Airy radius 1.22 lambda f / D (``diffraction.focal_spot_diameter_m``, thesis eq.
    2.6.19) added in quadrature: the speckle grains' envelope, the footprint's image blurred by
    the aperture."""
    f = positive("focal_length_m", focal_length_m)
    w = positive("footprint_radius_m", footprint_radius_m)
    r = positive("range_m", range_m)
    airy = focal_spot_diameter_m(aperture_m, wavelength_m, f)
    return float(np.hypot(f * w / r, airy))


def _fields_from_amplitude(amp, n: int, batch: int, rng, phase_screen_rad, weights):
    """Fraunhofer sums E = FFT(a z) cropped to n x n, optionally times exp(i phi) and weights."""
    size = amp.shape[-1]
    out = np.empty((batch, n, n), dtype=complex)
    step = max(1, _MAX_ELEMENTS // (size * size))
    for start in range(0, batch, step):
        k = min(step, batch - start)
        z = rng.standard_normal((k, size, size, 2)).view(complex)[..., 0] * np.sqrt(0.5)
        # the 2-D FFT row by row, keeping only the n x n pupil samples
        half = sfft.fft(amp * z, axis=-1)[..., :n]
        out[start : start + k] = sfft.fft(half, axis=-2)[:, :n, :]
    if phase_screen_rad is not None:
        phi = finite_array("phase_screen_rad", phase_screen_rad, float)
        if phi.shape not in ((n, n), (batch, n, n)):
            raise ValueError(
                f"phase_screen_rad must have shape {(n, n)} or {(batch, n, n)}, got {phi.shape}"
            )
        out *= np.exp(1j * phi)
    if weights is not None:
        out *= weights
    return out


def speckle_pupil_fields(
    grid: PupilGrid,
    aperture_m: float,
    coherence_radius_m: float,
    rng: np.random.Generator,
    batch: int,
    *,
    phase_screen_rad=None,
    aperture: bool = True,
) -> np.ndarray:
    """Fully developed speckle from a Gaussian footprint across the pupil: complex (batch, n, n).

    Circular complex Gaussian, E|E|^2 = 1 at every sample, mu(d) = exp(-d^2 / (2 rho^2))
    (|mu|^2 = exp(-d^2 / rho^2); module docstring), rho = ``coherence_radius_m`` (see
    ``speckle_coherence_radius_m``). Generated as the Fraunhofer field of circular-Gaussian
    scatterers on a target grid of pitch 1 / (N dx), N >= sqrt(2) n + 10 rho / dx, so that the
    whole square grid is free of wrap-around. The footprint is cut at the band edge 1 / (2 dx):
    for rho < 3 dx the field is whiter than mu, and rho << dx gives independent samples
    (speckle unresolved by the grid: the limit of many cells across the aperture).

    grid : ``pupil_grid(n, obstruction)``; aperture_m : D (m), pupil pitch dx = D / n.
    rng : the only randomness. batch : realisations (>= 1).
    phase_screen_rad : optional (n, n) or (batch, n, n) turbulence phase (rad) on the same grid
        (e.g. ``atmosphere.phase_screens(batch, n, D / n, r0, rng=...)``), multiplied in.
    aperture : multiply by ``grid.weights`` (the obstructed aperture); False gives the field on
        the whole square grid.
    """
    grid = _grid(grid)
    d = positive("aperture_m", aperture_m)
    rho = positive("coherence_radius_m", coherence_radius_m)
    rng, batch = generator("rng", rng), integer("batch", batch, 1)
    n = grid.n
    dx = d / n
    size = sfft.next_fast_len(max(2 * n, int(np.ceil(np.sqrt(2.0) * n + _ALIAS_RADII * rho / dx))))
    s = np.fft.fftfreq(size, d=dx)
    s2 = s[:, None] ** 2 + s[None, :] ** 2
    intensity = np.exp(-2.0 * (np.pi * rho) ** 2 * s2)  # exp(-2 s^2 / sigma^2), sigma = 1/(pi rho)
    amp = np.sqrt(intensity / intensity.sum())
    weights = grid.weights if aperture else None
    return _fields_from_amplitude(amp, n, batch, rng, phase_screen_rad, weights)


def monostatic_speckle_pupil_fields(
    grid: PupilGrid,
    beta: float,
    rng: np.random.Generator,
    batch: int,
    *,
    phase_screen_rad=None,
    aperture: bool = True,
) -> np.ndarray:
    """Speckle returned to a monostatic fiber telescope: complex (batch, n, n), E|E|^2 = 1.

    The footprint is the far field of the transmit field P M (grid weights times
    ``fiber_mode_pupil(grid, beta)``), so the scatterer amplitudes are |a(s)| = |FFT(P M)| on the
    2n x 2n zero-padded grid and mu(d) = C(d) / C(0) with C the lattice autocorrelation of P M
    (Winzer & Leeb 1998): the expectation of any second-order statistic is the one of
    ``coupling.monostatic_diffuse_coupling(method="fft")`` on this grid. The footprint scales
    with R, and mu does not depend on R or lambda. Other arguments as ``speckle_pupil_fields``.
    """
    grid = _grid(grid)
    rng, batch = generator("rng", rng), integer("batch", batch, 1)
    n = grid.n
    tx = grid.weights * fiber_mode_pupil(grid, beta)
    intensity = np.abs(np.fft.fft2(tx, s=(2 * n, 2 * n))) ** 2
    amp = np.sqrt(intensity / intensity.sum())
    weights = grid.weights if aperture else None
    return _fields_from_amplitude(amp, n, batch, rng, phase_screen_rad, weights)


def pupil_power(fields, grid: PupilGrid, aperture_m: float):
    """P = sum(weights |E|^2) dx^2 (W for E in sqrt(W) / m): power of unweighted fields through the
    annulus, the quadrature of ``focal_plane_coupling``. Float or float64 (...)."""
    grid = _grid(grid)
    e = square_field("fields", fields)
    if e.shape[-1] != grid.n:
        raise ValueError(f"fields must be (..., {grid.n}, {grid.n}) on grid, got {e.shape}")
    dx = positive("aperture_m", aperture_m) / grid.n
    p = np.einsum("...ij,ij->...", (e * e.conj()).real, grid.weights) * dx * dx
    return float(p) if p.ndim == 0 else p


def focal_fields(
    pupil_fields,
    dx_m: float,
    wavelength_m: float,
    focal_length_m: float,
    n_out: int,
    dx_out_m: float,
):
    """Focal-plane fields of a batch of pupil fields: ``fraunhofer(..., method="mft")``.

    E_f(u) = -i / (lambda f) int E(x) exp(-i 2 pi x . u / (lambda f)) d^2x (unitary; eq. 2.6.17),
    the same sums and grids as ``diffraction.fraunhofer`` (pupil samples at (j - (n - 1)/2) dx,
    u_k = (k - n_out // 2) dx_out), evaluated as two flat matrix products so that a large batch
    runs as single BLAS calls. pupil_fields : complex (..., n, n) (pass them aperture-weighted).
    Returns (fields complex (..., n_out, n_out), u_m float64 (n_out,)).
    """
    field = square_field("pupil_fields", pupil_fields)
    dx = positive("dx_m", dx_m)
    lf = positive("wavelength_m", wavelength_m) * positive("focal_length_m", focal_length_m)
    n_out = grid_size(n_out, "n_out", minimum=2)
    du = positive("dx_out_m", dx_out_m)
    n = field.shape[-1]
    lead = field.shape[:-2]
    x = (np.arange(n) - 0.5 * (n - 1)) * dx
    u = (np.arange(n_out) - n_out // 2) * du
    kern_t = np.exp(-2j * np.pi * np.outer(x, u) / lf)  # (n, n_out)
    flat = field.reshape(-1, n, n)
    b = flat.shape[0]
    rows = (flat.reshape(b * n, n) @ kern_t).reshape(b, n, n_out)  # sum over x (columns)
    both = (np.swapaxes(rows, 1, 2).reshape(b * n_out, n) @ kern_t).reshape(b, n_out, n_out)
    out = (-1j * dx * dx / lf) * np.swapaxes(both, 1, 2)
    return out.reshape(lead + (n_out, n_out)), u


def _coords(u) -> np.ndarray:
    c = finite_array("u", u, float)
    if c.ndim != 1 or c.size < 2 or not np.all(np.diff(c) > 0.0):
        raise ValueError("u must be an increasing 1-D array of focal-plane coordinates (m)")
    return c


def _r2(u) -> np.ndarray:
    c = _coords(u)
    return c[None, :] ** 2 + c[:, None] ** 2


def fiber_mode_lo(u, w0_m: float) -> np.ndarray:
    """Fiber mode in the focal plane, M(u, v) = exp(-(u^2 + v^2) / w0^2) on the grid u x u
    (w0 = MFD / 2). (n, n) float64, peak 1, int |M|^2 = pi w0^2 / 2."""
    w0 = positive("w0_m", w0_m)
    return np.exp(-_r2(u) / (w0 * w0))


def gaussian_lo(u, w_m: float) -> np.ndarray:
    """Gaussian LO beam focused on the detector, exp(-(u^2 + v^2) / w^2) (w: 1/e^2 intensity
    radius, m) on the grid u x u. (n, n) float64, peak 1."""
    w = positive("w_m", w_m)
    return np.exp(-_r2(u) / (w * w))


def flat_top_lo(u, half_width_m: float) -> np.ndarray:
    """Flat-top LO: 1 inside the disc u^2 + v^2 <= half_width^2 (m), 0 outside, on the grid u x u.

    Use a half-width beyond the detector's half diagonal for a uniform LO on a square detector.
    """
    h = positive("half_width_m", half_width_m)
    return (_r2(u) <= h * h).astype(float)


def _field_batch(name: str, value, size: int) -> np.ndarray:
    e = square_field(name, value)
    if e.shape[-1] != size:
        raise ValueError(f"{name} must be (..., {size}, {size}) to match u, got {e.shape}")
    return e


def fiber_coupling(ef, u, w0_m: float, power_w):
    """Fiber coupling of focal fields: eta = |int E_f M* du dv|^2 / (P int |M|^2 du dv).

    M = ``fiber_mode_lo(u, w0)``, int |M|^2 = pi w0^2 / 2 (whole plane); the overlap is the
    rectangle rule on the window u x u (it must cover the mode, +-5 w0). P : power of each field
    in the pupil (``pupil_power``; W, scalar or shape (...)), equal by Parseval to its power
    over the whole focal plane. Equals ``diffraction.focal_plane_coupling`` for the same fields.
    Returns float or float64 (...).
    """
    c = _coords(u)
    e = _field_batch("ef", ef, c.size)
    m = fiber_mode_lo(c, w0_m)
    if c[0] > -4.0 * w0_m or c[-1] < 4.0 * w0_m:
        raise ValueError("u must cover the fiber mode to at least +-4 w0_m")
    du = float(np.mean(np.diff(c)))
    p = finite_array("power_w", power_w, float)
    if np.any(p <= 0.0):
        raise ValueError("power_w must be > 0 (the field's power in the pupil)")
    overlap = np.einsum("...ij,ij->...", e, m) * du * du
    eta = (overlap * overlap.conj()).real / (p * 0.5 * np.pi * w0_m * w0_m)
    return float(eta) if eta.ndim == 0 else eta


def detector_weights(u, detector_half_width_m: float) -> np.ndarray:
    """Exact area fraction of each focal-plane sample cell (pitch du) inside the square detector
    |u|, |v| <= a (m): (n, n) float64 in [0, 1], separable. The window must cover the detector.

    With edges on cell edges this is the midpoint rule (second order); a partial cell stands for
    the field at its centre, outside the detector, so keep du << a (a detector 1.5 cells wide
    reads a mean mixing efficiency 2 % low in speckle).
    """
    c = _coords(u)
    a = positive("detector_half_width_m", detector_half_width_m)
    du = float(np.mean(np.diff(c)))
    if a > min(-c[0], c[-1]) + 0.5 * du:
        raise ValueError(
            f"detector_half_width_m = {a:.3g} m exceeds the focal window "
            f"[{c[0]:.3g}, {c[-1]:.3g}] m"
        )
    lo = np.maximum(c - 0.5 * du, -a)
    hi = np.minimum(c + 0.5 * du, a)
    w1 = np.clip(hi - lo, 0.0, du) / du
    return w1[:, None] * w1[None, :]


def detector_mixing_efficiency(ef, lo, u, detector_half_width_m: float, *, total_power_w=None):
    """Heterodyne (mixing) efficiency of one square detector of side 2a in the focal plane.

        eta_mix = |int_det E_s E_LO* dA|^2 / (int_det |E_s|^2 dA  int_det |E_LO|^2 dA),

    (Siegman 1966, Appl. Opt. 5, 1588; Cohen 1975, Appl. Opt. 14, 1953). The detector current is
    the area integral of the beat E_s E_LO*, so where the signal's phase varies across the
    detector relative to the LO's the contributions cancel in the integral: eta_mix = 1 only if
    E_s is proportional to E_LO over the detector (Cauchy-Schwarz), and a speckled signal with M
    grains on the detector gives about 1 / M (``mean_mixing_efficiency_closed_form``).

    ef : complex (..., n, n) focal fields on u x u; lo : (n, n) LO field on the same grid
    (``flat_top_lo``, ``gaussian_lo``, ...); detector_half_width_m : a (m), exact-area edge
    weights (``detector_weights``). total_power_w : power of each signal field (W, scalar or
    (...), e.g. ``pupil_power``); default: its power in the window u x u.

    Returns (eta_mix, fraction): float64 (...) each; fraction = int_det |E_s|^2 / total power.
    eta_mix is 0 where no signal or no LO falls on the detector.
    """
    c = _coords(u)
    e = _field_batch("ef", ef, c.size)
    lo_f = _field_batch("lo", lo, c.size)
    if lo_f.ndim != 2:
        raise ValueError(f"lo must be one (n, n) field, got shape {lo_f.shape}")
    w = detector_weights(c, detector_half_width_m)
    du2 = float(np.mean(np.diff(c))) ** 2
    beat = np.einsum("...ij,ij->...", e, w * lo_f.conj()) * du2
    sig = np.einsum("...ij,ij->...", (e * e.conj()).real, w) * du2
    lo_p = float(np.sum(w * (lo_f * lo_f.conj()).real)) * du2
    num = (beat * beat.conj()).real
    den = sig * lo_p
    eta = np.divide(num, den, out=np.zeros_like(num), where=den > 0.0)
    if total_power_w is None:
        total = np.sum((e * e.conj()).real, axis=(-2, -1)) * du2
    else:
        total = finite_array("total_power_w", total_power_w, float)
    if np.any(total <= 0.0):
        raise ValueError("total_power_w must be > 0")
    return eta, sig / total


def _square_gauss_factor(a) -> np.ndarray:
    """(1/L^2) int_0^L int_0^L exp(-(x1 - x2)^2 / (2 rho^2)) with a = L / (sqrt(2) rho):
    g(a) = sqrt(pi) erf(a) / a - (1 - exp(-a^2)) / a^2 (-> 1 - a^2 / 6 for small a)."""
    a = np.asarray(a, dtype=float)
    small = a < 1e-3
    s = np.where(small, 1.0, a)
    g = np.sqrt(np.pi) * erf(s) / s + np.expm1(-s * s) / (s * s)
    return np.where(small, 1.0 - a * a / 6.0, g)


def mean_mixing_efficiency_closed_form(detector_side_m, coherence_radius_m):
    """Mean mixing efficiency of a square detector (side L) with a uniform LO in Gaussian speckle.

    Ratio of means (Siegman 1966; Goodman 2007 Sec. 4.6 for the area integral):

        <eta> = E|int_det E_s|^2 / (A_d E int_det |E_s|^2) = (1/A_d^2) int int_det mu(r1 - r2),

    with the FIELD degree of coherence mu(d) = exp(-d^2 / (2 rho^2)) of ``speckle_pupil_fields``
    (|mu|^2 = exp(-d^2 / rho^2)). It separates over x and y: <eta> = g(L / (sqrt(2) rho))^2, g of
    ``_square_gauss_factor``. Limits: 1 - L^2 / (6 rho^2) for L << rho; A_c / A_d for L >> rho
    with A_c = int mu d^2d = 2 pi rho^2 (the antenna theorem: one coherence area contributes).
    Note: Goodman's 1/M (contrast^2 of the integrated intensity) is the same integral over
    |mu|^2; the mixing efficiency integrates mu itself. Float or float64 array (broadcast).
    """
    lside = np.asarray(detector_side_m, dtype=float)
    if not np.all(np.isfinite(lside)) or np.any(lside <= 0.0):
        raise ValueError("detector_side_m must be finite and > 0 (m)")
    rho = positive("coherence_radius_m", coherence_radius_m)
    g = _square_gauss_factor(lside / (np.sqrt(2.0) * rho))
    eta = g * g
    return float(eta) if eta.ndim == 0 else eta


def _sinc2_chord(k, y):
    """int_{-y}^{y} sinc^2(k t) dt (numpy sinc), closed form via Si: (2/(pi k))(Si(2T) - sin^2 T/T),
    T = pi k y."""
    t = np.pi * k * y
    small = t < 1e-6
    ts = np.where(small, 1.0, t)
    si2 = sici(2.0 * ts)[0]
    val = 2.0 / (np.pi * k) * (si2 - np.sin(ts) ** 2 / ts)
    return np.where(small, 2.0 * y, val)


def mean_mixing_efficiency_focal(
    detector_side_m,
    aperture_m: float,
    wavelength_m: float,
    focal_length_m: float,
    obstruction: float = 0.0,
    *,
    nodes: int | None = None,
):
    """Mean mixing efficiency of a square focal-plane detector (side L, uniform LO) in speckle
    with many grains across the (annular) aperture P (pupil coherence << D).

    The focal-plane speckle then has mu_f(d) = FT{P}(d / (lambda f)) / A_P (the aperture's
    amplitude spread function, Airy for alpha = 0; van Cittert-Zernike with the pupil as the
    incoherent source), and by Parseval (1/A_d^2) int int_det mu_f equals the overlap of the
    LO back-propagated to the pupil with the aperture (the antenna theorem, Siegman 1966):

        <eta> = (1/A_P) int_P sinc^2(L x / (lambda f)) sinc^2(L y / (lambda f)) dx dy,

    -> 1 for L << lambda f / D and (lambda f)^2 / (A_P A_d) = lambda^2 / (A_P Omega_d) for
    L >> lambda f / D (Omega_d = A_d / f^2, the detector's field of view). The y integral is the
    Si closed form, x by Gauss-Legendre (``nodes``; default 16 per sinc lobe across D, >= 400).
    Float or float64 (broadcast over L).
    """
    lside = np.asarray(detector_side_m, dtype=float)
    if not np.all(np.isfinite(lside)) or np.any(lside <= 0.0):
        raise ValueError("detector_side_m must be finite and > 0 (m)")
    d = positive("aperture_m", aperture_m)
    lf = positive("wavelength_m", wavelength_m) * positive("focal_length_m", focal_length_m)
    alpha = obstruction_ratio(obstruction)
    k = lside[..., None] / lf  # sinc argument per metre in the pupil
    lobes = float(np.max(k)) * d
    nodes = max(400, int(16 * lobes)) if nodes is None else grid_size(nodes, "nodes", minimum=16)
    t, wt = np.polynomial.legendre.leggauss(nodes)

    def disc(radius):  # int over the disc of radius R, x = R sin(theta) maps the chord's sqrt
        th = 0.5 * np.pi * t
        x = radius * np.sin(th)
        chord = radius * np.cos(th)
        integrand = np.sinc(k * x) ** 2 * _sinc2_chord(k, chord) * radius * np.cos(th)
        return np.sum(integrand * wt, axis=-1) * 0.5 * np.pi

    total = disc(0.5 * d) - (disc(0.5 * alpha * d) if alpha > 0.0 else 0.0)
    eta = total / (0.25 * np.pi * d * d * (1.0 - alpha * alpha))
    return float(eta) if eta.ndim == 0 else eta

"""Diffraction: Fresnel number (eq. 2.6.13), Fraunhofer focal fields (eqs. 2.6.16-2.6.17) by FFT
or matrix Fourier transform, the (obstructed) Airy pattern and its first null (eqs. 2.6.18-2.6.19).

Fraunhofer convention used throughout (paraxial focal plane of a lens of focal length f, the
quadratic phase across the focal plane dropped):

    E_f(u, v) = -i / (lambda f) * int int E(x, y) exp(-i 2 pi (x u + y v) / (lambda f)) dx dy,

which is unitary: int |E_f|^2 du dv = int |E|^2 dx dy (Parseval), so overlaps (coupling) computed
in the focal plane equal those computed in the pupil. Direction cosine sin(theta) = u / f
(eq. 2.6.17 b).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq
from scipy.special import j1

from ._checks import (
    grid_size,
    non_negative_array,
    obstruction_ratio,
    positive,
    positive_array,
    square_field,
)

J1_FIRST_ZERO = 3.8317059702075125  # first zero of J1; 1.21967 = J1_FIRST_ZERO / pi


def fresnel_number(radius_m, distance_m, wavelength_m):
    """F = a^2 / (L lambda) (eq. 2.6.13); a aperture radius, L distance. Broadcasts; float or array."""
    a = positive_array("radius_m", radius_m)
    d = positive_array("distance_m", distance_m)
    lam = positive_array("wavelength_m", wavelength_m)
    f = a * a / (d * lam)
    return float(f) if f.ndim == 0 else f


def is_far_field(radius_m, distance_m, wavelength_m, *, threshold: float = 0.1):
    """True where F = a^2 / (L lambda) < threshold (Fraunhofer regime, F << 1; eq. 2.6.13).

    ``threshold`` (dimensionless, default 0.1) states how small "<< 1" is taken to be.
    """
    t = positive("threshold", threshold)
    f = np.asarray(fresnel_number(radius_m, distance_m, wavelength_m))
    out = f < t
    return bool(out) if out.ndim == 0 else out


def _airy_amplitude(x, alpha):
    """Normalised field (1 on axis) of an annular pupil at x = pi D sin(theta) / lambda."""
    x = np.asarray(x, dtype=float)
    small = np.abs(x) < 1e-6
    xs = np.where(small, 1.0, x)

    def jinc(z):  # 2 J1(z) / z -> 1 - z^2 / 8
        return 2.0 * j1(z) / z

    full = np.where(small, 1.0 - x * x / 8.0, jinc(xs))
    if alpha == 0.0:
        return full
    ax = alpha * xs
    inner_small = np.abs(alpha * x) < 1e-6
    inner = np.where(
        inner_small, 1.0 - (alpha * x) ** 2 / 8.0, jinc(np.where(inner_small, 1.0, ax))
    )
    return (full - alpha * alpha * inner) / (1.0 - alpha * alpha)


def airy_intensity(theta_rad, diameter_m: float, wavelength_m: float, obstruction: float = 0.0):
    """Far-field intensity of a uniformly lit annular aperture, normalised to 1 on axis.

    I(theta) = [(2 J1(x)/x - alpha^2 2 J1(alpha x)/(alpha x)) / (1 - alpha^2)]^2,
    x = pi D sin(theta) / lambda (Born & Wolf 8.5; alpha = 0 is the Airy pattern [2 J1(x)/x]^2).

    theta_rad : array-like angle from the axis (rad), any shape; returns float64 of that shape.
    """
    th = np.asarray(theta_rad, dtype=float)
    if not np.all(np.isfinite(th)):
        raise ValueError("theta_rad must be finite")
    d = positive("diameter_m", diameter_m)
    lam = positive("wavelength_m", wavelength_m)
    alpha = obstruction_ratio(obstruction)
    x = np.pi * d * np.sin(th) / lam
    amp = _airy_amplitude(x, alpha)
    out = amp * amp
    return float(out) if out.ndim == 0 else out


def airy_first_null_rad(diameter_m: float, wavelength_m: float, obstruction: float = 0.0) -> float:
    """Angle of the first dark ring: sin(theta) = 1.22 lambda / D for alpha = 0 (eq. 2.6.18).

    The coefficient is j_{1,1} / pi = 1.21967; with a central obstruction the null moves inwards and
    is found numerically (first zero of the annular amplitude). Raises ValueError if the null does
    not exist (lambda / D too large).
    """
    d = positive("diameter_m", diameter_m)
    lam = positive("wavelength_m", wavelength_m)
    alpha = obstruction_ratio(obstruction)
    if alpha == 0.0:
        x0 = J1_FIRST_ZERO
    else:
        xs = np.linspace(1e-3, J1_FIRST_ZERO, 2000)
        amp = _airy_amplitude(xs, alpha)
        k = int(np.argmax(amp <= 0.0))
        x0 = (
            J1_FIRST_ZERO
            if amp[k] > 0.0
            else brentq(lambda z: float(_airy_amplitude(z, alpha)), xs[k - 1], xs[k], xtol=1e-14)
        )
    s = x0 * lam / (np.pi * d)
    if s >= 1.0:
        raise ValueError(
            f"no first null: {x0 / np.pi:.4f} * wavelength_m / diameter_m = {s:.3g} >= 1"
        )
    return float(np.arcsin(s))


def focal_spot_diameter_m(diameter_m: float, wavelength_m: float, focal_length_m: float) -> float:
    """Thesis eq. 2.6.19: D_spot = 1.22 lambda f / d (small angle).

    Note: 1.22 lambda f / d is the *radius* of the first dark ring; the thesis calls it the smallest
    spot diameter. Returned as written in eq. 2.6.19 (coefficient j_{1,1} / pi = 1.21967).
    """
    d = positive("diameter_m", diameter_m)
    lam = positive("wavelength_m", wavelength_m)
    f = positive("focal_length_m", focal_length_m)
    return J1_FIRST_ZERO / np.pi * lam * f / d


def _centred(n: int) -> np.ndarray:
    """Pixel-centre offsets (in pitch units) of the pupil grid: i - (n - 1) / 2."""
    return np.arange(n) - 0.5 * (n - 1)


def _out_coords(n_out: int) -> np.ndarray:
    """Output sample offsets (in output pitch units): k - n_out // 2 (exact zero at n_out // 2)."""
    return np.arange(n_out) - n_out // 2


def fraunhofer(
    pupil_field,
    dx_m: float,
    wavelength_m: float,
    focal_length_m: float,
    *,
    method: str = "fft",
    n_out: int | None = None,
    dx_out_m: float | None = None,
):
    """Focal-plane field of a pupil field (eq. 2.6.17: the Fraunhofer integral as a Fourier transform).

    Parameters
    ----------
    pupil_field : complex (..., n, n), sampled with pitch ``dx_m`` at pixel centres
        x_j = (j - (n - 1)/2) dx (the ``pupil_grid`` convention, scaled by D = n dx). For an
        anti-aliased aperture pass ``grid.weights * field``.
    dx_m, wavelength_m, focal_length_m : pupil pitch, wavelength, focal length (m).
    method : "fft" (zero-padded FFT; output pitch fixed to lambda f / (n_out dx)) or "mft" (matrix
        Fourier transform, Soummer et al. 2007, Opt. Express 15, 15935: any output pitch and size,
        cost O(n n_out (n + n_out))).
    n_out : output samples per axis; default 2 n. For "fft" it is the padded size (>= n).
    dx_out_m : output pitch (m), "mft" only; default lambda f / (n_out dx) (same as "fft").

    Returns
    -------
    (field, u_m) : complex128 (..., n_out, n_out) field E_f(u, v) in the normalisation above
        (units of the pupil field; int |E_f|^2 du dv = int |E|^2 dx dy), and float64 (n_out,)
        focal-plane coordinates u_k = (k - n_out // 2) dx_out (m), the same for both axes.
    """
    field = square_field("pupil_field", pupil_field)
    n = field.shape[-1]
    dx = positive("dx_m", dx_m)
    lam = positive("wavelength_m", wavelength_m)
    f = positive("focal_length_m", focal_length_m)
    n_out = 2 * n if n_out is None else grid_size(n_out, "n_out", minimum=2)
    lf = lam * f
    prefactor = -1j * dx * dx / lf
    if method == "fft":
        if dx_out_m is not None:
            raise ValueError(
                "dx_out_m applies to method='mft' only (the FFT output pitch is "
                "wavelength_m * focal_length_m / (n_out * dx_m))"
            )
        if n_out < n:
            raise ValueError(f"n_out must be >= the pupil size {n} for method='fft', got {n_out}")
        du = lf / (n_out * dx)
        off = (n_out - n) // 2
        padded = np.zeros(field.shape[:-2] + (n_out, n_out), dtype=complex)
        padded[..., off : off + n, off : off + n] = field
        spec = np.fft.fftshift(np.fft.fft2(np.fft.ifftshift(padded, axes=(-2, -1))), axes=(-2, -1))
        u = _out_coords(n_out) * du
        # The FFT places pupil sample j at (j + off - n_out // 2) dx; the grid puts it at
        # (j - (n - 1)/2) dx. The constant offset s is a linear phase in the focal plane.
        s = (n_out // 2 - off - 0.5 * (n - 1)) * dx
        ramp = np.exp(-2j * np.pi * s * u / lf)
        out = prefactor * spec * ramp[:, None] * ramp[None, :]
        return out, u
    if method == "mft":
        du = lf / (n_out * dx) if dx_out_m is None else positive("dx_out_m", dx_out_m)
        x = _centred(n) * dx
        u = _out_coords(n_out) * du
        kern = np.exp(-2j * np.pi * np.outer(u, x) / lf)  # (n_out, n)
        out = prefactor * (kern @ field @ kern.T)
        return out, u
    raise ValueError(f"method must be 'fft' or 'mft', got {method!r}")


def focal_plane_coupling(
    pupil_field,
    dx_m: float,
    wavelength_m: float,
    focal_length_m: float,
    mode_radius_m: float,
    *,
    weights=None,
    mode_offset_m=(0.0, 0.0),
    n_out: int | None = None,
    dx_out_m: float | None = None,
):
    """Fiber coupling computed in the focal plane: MFT focal field overlapped with the fiber mode.

    eta = |int E_f M_f* du dv|^2 / (P * int |M_f|^2 du dv), M_f = exp(-|u - u0|^2 / w0^2),
    E_f = fraunhofer(weights * pupil_field) and P = sum(weights |pupil_field|^2) dx^2 the power in
    the pupil (equal to the full focal-plane power by Parseval; the focal window need only cover
    the mode). Equals the pupil-plane overlap of ``pupil_field_coupling`` with
    beta = (pi/2)(D/f)(w0/lambda), which makes it an independent check; ``mode_offset_m`` (x, y)
    models a laterally displaced fiber.

    pupil_field : complex (..., n, n); weights : (n, n) amplitude/quadrature weights (default 1);
    mode_radius_m : w0 = MFD / 2 (m); n_out, dx_out_m : focal window (default: +-5 w0 around the
    mode at w0 / 8 pitch). Returns float, or float64 array of shape (...).
    """
    field = square_field("pupil_field", pupil_field)
    n = field.shape[-1]
    dx = positive("dx_m", dx_m)
    w0 = positive("mode_radius_m", mode_radius_m)
    w = np.ones((n, n)) if weights is None else non_negative_array("weights", weights)
    if w.shape != (n, n):
        raise ValueError(f"weights must have shape {(n, n)}, got {w.shape}")
    off = np.asarray(mode_offset_m, dtype=float)
    if off.shape != (2,) or not np.all(np.isfinite(off)):
        raise ValueError("mode_offset_m must be a finite (x, y) pair in metres")
    du = w0 / 8.0 if dx_out_m is None else positive("dx_out_m", dx_out_m)
    if n_out is None:
        n_out = 2 * int(np.ceil((5.0 * w0 + np.max(np.abs(off))) / du)) + 1
    ef, u = fraunhofer(
        w * field, dx, wavelength_m, focal_length_m, method="mft", n_out=n_out, dx_out_m=du
    )
    mx = np.exp(-(((u - off[0]) / w0) ** 2))
    my = np.exp(-(((u - off[1]) / w0) ** 2))
    overlap = np.einsum("...ij,i,j->...", ef, my, mx) * du * du
    power = np.einsum("...ij,ij->...", (field * field.conj()).real, w) * dx * dx
    if np.any(power <= 0.0):
        raise ValueError("pupil_field carries no power")
    mode_norm = 0.5 * np.pi * w0 * w0
    eta = (overlap * overlap.conj()).real / (power * mode_norm)
    return float(eta) if eta.ndim == 0 else eta

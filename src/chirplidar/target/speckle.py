"""Target speckle: per-shot power and phase of the return from a rough surface (Goodman).

A surface rough on the scale of the wavelength, with many independent scatterers in the footprint,
returns a circular complex Gaussian field: its intensity in one speckle cell is exponential, and a
receiver integrating M independent cells sees a gamma distribution of order M (mean 1, contrast
std/mean = 1/sqrt(M)) (J. W. Goodman, "Speckle Phenomena in Optics", Roberts & Co., 2007: Ch. 3 for the single
cell, Ch. 4 for integrated speckle and correlations).

When the statistics are "fully developed" (thesis atm.lc)
---------------------------------------------------------
With surface correlation length l_c (thesis Table 4.6 atm.lc = 4 mm) the footprint holds about
N = A_footprint / l_c^2 independent scatterers (thesis: Wr = 150 mm, N ~ 4400). The sum of N
unit phasors with random phases has <I^2>/<I>^2 = 2 - 1/N (Goodman 2007, Ch. 2, random phasor
sums with a finite number of terms), so the speckle
contrast is sqrt(1 - 1/N): l_c much smaller than the footprint (N >> 1) gives fully developed
speckle and the gamma/exponential model holds; l_c comparable with the footprint does not, and
``speckle_contrast_finite`` tells how far off it is. (Fully developed also needs surface height
variations larger than the wavelength — true of snow and ice at 1-1.6 um.)

Shot-to-shot correlation
------------------------
For a monostatic transceiver whose receive mode is its transmit mode (single-mode fiber; the
antenna theorem), the received field is U = int a(x) E(x)^2 dx, with a(x) the delta-correlated
surface reflection and E the transmitted field at the surface: a Gaussian beam with 1/e^2
intensity radius W and wavefront radius R_c,
E(x)^2 = exp(-2|x|^2/W^2 + i k |x|^2 / R_c). Moving the beam by s along the surface, the field
correlation is the overlap mu(s) = int E^2(x) E*^2(x - s) dx / int |E|^4 dx, whose modulus is
|mu(s)| = exp(-s^2/W^2) exp(-k^2 W^2 s^2 / (4 R_c^2)), and for circular Gaussian fields the
intensity correlation coefficient is |mu|^2 (complex Gaussian moment theorem; Goodman 2007 Ch. 4):

    rho_I(s) = exp(-2 s^2 [1/W^2 + (pi W / (lambda R_c))^2]).

For a Gaussian beam the bracket equals 1/w0^2 at every range (w0 the waist radius), so
rho_I(s) = exp(-2 s^2 / w0^2): speckle decorrelates after the platform moves about a transmit-beam
radius, independently of the footprint size. The first factor alone (R_c = inf) is the overlap of
the two illuminated patches; the second is the wavefront curvature that sweeps the speckle across
the receive mode.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from .._checks import count, generator, out, positive_array, real_array


def _cells(value) -> float:
    arr = real_array("cells", value)
    if arr.ndim != 0:
        raise ValueError(f"cells must be a scalar, got an array of shape {arr.shape}")
    m = float(arr)
    if m < 1.0:
        raise ValueError(f"cells (speckle cells integrated, M) must be >= 1, got {m!r}")
    return m


def speckle_power(n, cells, rng):
    """n speckle power factors, mean 1: gamma of order M = cells (shape M, scale 1/M).

    n: number of shots (int >= 0); cells: M >= 1 (float; 1 gives the exponential distribution of a
    single speckle cell; Goodman 2007 Ch. 3-4); rng: numpy Generator. Returns float64
    array of shape (n,). Contrast std/mean = 1/sqrt(M). Draws exactly one gamma variate per shot.
    """
    n = count("n", n)
    m = _cells(cells)
    rng = generator("rng", rng)
    return rng.gamma(shape=m, scale=1.0 / m, size=n)


def speckle_phase(n, rng):
    """n speckle phases (rad), uniform on [0, 2 pi): the phase of a circular Gaussian field.

    n: int >= 0; rng: numpy Generator. Returns float64 array of shape (n,).
    """
    n = count("n", n)
    rng = generator("rng", rng)
    return rng.uniform(0.0, 2.0 * np.pi, n)


def speckle_cells(
    detection, *, wavelength_m=None, range_m=None, footprint_area_m2=None, receiver_area_m2=None
):
    """Number M of independent speckle cells the receiver integrates (spatial diversity only).

    detection: "coherent" — mixing with a single LO mode or coupling into a single-mode fiber
    selects one spatial mode of the return, M = 1 (the thesis' self-chirped homodyne receiver);
    "direct" — a detector of area A_r collecting the speckle pattern,
    M = 1 + A_r / A_c with the coherence area A_c = lambda^2 R^2 / A_footprint (van Cittert-Zernike;
    Goodman 2007 Ch. 4: the interpolation between M = 1 for A_r << A_c and M = A_r / A_c for
    A_r >> A_c). Needs wavelength_m, range_m, footprint_area_m2, receiver_area_m2 (all > 0,
    broadcast). For "coherent" they are optional and only set the output shape.
    Temporal diversity (a chirp resolving the footprint's range spread) is not counted here.
    Returns float64 (float for scalars).
    """
    given = {
        k: v
        for k, v in {
            "wavelength_m": wavelength_m,
            "range_m": range_m,
            "footprint_area_m2": footprint_area_m2,
            "receiver_area_m2": receiver_area_m2,
        }.items()
        if v is not None
    }
    arrays = {k: positive_array(k, v) for k, v in given.items()}
    if detection == "coherent":
        shape = np.broadcast_shapes(*(a.shape for a in arrays.values())) if arrays else ()
        return out(np.ones(shape))
    if detection == "direct":
        missing = [
            k
            for k in ("wavelength_m", "range_m", "footprint_area_m2", "receiver_area_m2")
            if k not in arrays
        ]
        if missing:
            raise ValueError(f"detection='direct' needs {', '.join(missing)}")
        coherence_area = (arrays["wavelength_m"] * arrays["range_m"]) ** 2 / arrays[
            "footprint_area_m2"
        ]
        return out(1.0 + arrays["receiver_area_m2"] / coherence_area)
    raise ValueError(f"detection must be 'coherent' or 'direct', got {detection!r}")


def surface_scatterer_count(footprint_area_m2, correlation_length_m):
    """Independent scatterers in the footprint, N = A_footprint / l_c^2 (thesis atm.lc = l_c).

    footprint_area_m2, correlation_length_m: > 0, broadcast. Returns float64.
    """
    area = positive_array("footprint_area_m2", footprint_area_m2)
    lc = positive_array("correlation_length_m", correlation_length_m)
    return out(area / lc**2)


def speckle_contrast_finite(n_scatterers):
    """Speckle contrast std(I)/<I> of a sum of N unit phasors with uniform random phases.

    sqrt(1 - 1/N) (Goodman 2007 Ch. 2: <I^2> = (2 - 1/N) <I>^2); 1 when fully developed.
    n_scatterers: >= 1, float or array.
    """
    n = real_array("n_scatterers", n_scatterers)
    if np.any(n < 1.0):
        raise ValueError("n_scatterers must be >= 1")
    return out(np.sqrt(1.0 - 1.0 / n))


def speckle_decorrelation(shift_m, footprint_radius_m, wavelength_m, wavefront_radius_m):
    """Shot-to-shot speckle intensity correlation coefficient after the beam moves by shift_m.

    rho_I = exp(-2 s^2 [1/W^2 + (pi W / (lambda R_c))^2]) for a monostatic single-mode (coherent)
    transceiver over a surface with l_c << W (module docstring: derivation; for a Gaussian beam
    the bracket is 1/w0^2 with w0 the waist radius).
    shift_m: displacement of the footprint centre along the surface between the shots (m);
    footprint_radius_m: 1/e^2 intensity radius W of the beam at the surface (m, > 0);
    wavelength_m: > 0; wavefront_radius_m: radius of curvature R_c of the beam at the surface (m;
    ~range in the far field; +-inf for a beam focused on the surface; nonzero). Broadcast.
    Returns float64 in [0, 1]: 1 at zero shift (identical speckle), -> 0 for large shifts.
    """
    s = real_array("shift_m", shift_m)
    w = positive_array("footprint_radius_m", footprint_radius_m)
    lam = positive_array("wavelength_m", wavelength_m)
    rc = np.asarray(wavefront_radius_m, dtype=float)
    if np.any(np.isnan(rc)) or np.any(rc == 0.0):
        raise ValueError(
            "wavefront_radius_m must be nonzero and not NaN (inf for a flat wavefront)"
        )
    curvature = np.pi * w / (lam * np.abs(rc))  # 0 for an infinite radius
    return out(np.exp(-2.0 * s**2 * (1.0 / w**2 + curvature**2)))


def _rho(value) -> float:
    arr = real_array("rho_between_shots", value)
    if arr.ndim != 0:
        raise ValueError("rho_between_shots must be a scalar (one correlation for the sequence)")
    r = float(arr)
    if not 0.0 <= r <= 1.0:
        raise ValueError(f"rho_between_shots must lie in [0, 1], got {r!r}")
    return r


def correlated_speckle_field(n_shots, rho_between_shots, cells, rng):
    """Complex speckle fields of a shot sequence with a given shot-to-shot intensity correlation.

    n_shots: int >= 0; rho_between_shots: intensity correlation coefficient between consecutive
    shots in [0, 1] (``speckle_decorrelation``); cells: integer M >= 1; rng: numpy Generator.
    Returns complex128 array (n_shots, M): each cell a stationary AR(1) circular complex Gaussian
    field, z_k = a z_{k-1} + sqrt(1 - a^2) w_k with a = sqrt(rho), E|z|^2 = 1/M, so that the power
    sum_cells |z|^2 has mean 1, gamma(M) marginals and lag-1 intensity correlation rho (|a|^2 for
    circular Gaussian fields). Lag k has rho^k — the physical Gaussian overlap gives rho^(k^2),
    so beyond lag 1 this sequence stays correlated somewhat longer. rho = 1: every shot identical;
    rho = 0: independent shots. Draws 2 n_shots M normals.
    """
    n = count("n_shots", n_shots)
    rho = _rho(rho_between_shots)
    m = _cells(cells)
    if m != int(m):
        raise ValueError(f"cells must be an integer for a correlated sequence, got {m!r}")
    m = int(m)
    rng = generator("rng", rng)
    w = rng.standard_normal((n, m, 2)) @ np.array([1.0, 1.0j]) * np.sqrt(0.5 / m)
    if n == 0:
        return w
    a = np.sqrt(rho)
    x = np.sqrt(1.0 - rho) * w
    x[0] = w[0]  # start in the stationary distribution
    return signal.lfilter([1.0], [1.0, -a], x, axis=0)


def correlated_speckle(n_shots, rho_between_shots, cells, rng):
    """Speckle power factors (mean 1, gamma of order M) with lag-1 intensity correlation rho.

    Sum over cells of |correlated_speckle_field|^2: float64 array (n_shots,). Arguments as
    ``correlated_speckle_field``.
    """
    z = correlated_speckle_field(n_shots, rho_between_shots, cells, rng)
    return np.sum(z.real**2 + z.imag**2, axis=1)


__all__ = [
    "correlated_speckle",
    "correlated_speckle_field",
    "speckle_cells",
    "speckle_contrast_finite",
    "speckle_decorrelation",
    "speckle_phase",
    "speckle_power",
    "surface_scatterer_count",
]

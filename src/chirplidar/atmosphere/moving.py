"""Frozen-flow phase screen that moves with the platform: an "infinite" screen extruded row by row.

Method: Assemat, Wilson & Gendron (2006), Opt. Express 14, 988, "Method for simulating infinitely
long and non stationary phase screens with optimized memory storage". The screen is a strip n
samples wide (pitch dx) that grows along the flight direction. Each new row X (n values) is drawn
from its Gaussian conditional distribution given a *stencil* Z of already generated values:

    X = A Z + B w,   A = C_XZ C_ZZ^-1,   B B^T = C_XX - A C_ZX,   w ~ N(0, I_n),

with C the von Karman phase covariance B(r) = B(0) - D(r)/2 of ``screens.von_karman_covariance``.
Nothing is periodic, so there is no wrap-around however far the platform flies; the memory is the
stencil depth (4 n rows by default).

Stencil (after the paper's): every column of the three newest rows; rows 5, 9, 17, ... back
(2^k + 1 < 2n) with columns 2^(k-1) apart (always including both edges); and the centre and edge
columns n, 2n, ..., ``depth_factor`` n rows back, which carry the large-scale (tilt) memory. While the strip is shorter than the stencil (start-up), rows are conditioned on the
part of the stencil that exists, starting from an exact draw of the first row: no FFT initial
screen, no burn-in.

Limits (documented and tested):

* Finite outer scale only (the covariance of Kolmogorov turbulence does not exist). For
  Kolmogorov-like statistics use an outer scale much larger than the aperture; the conditioning
  is checked and a ValueError raised if the covariance matrices are numerically singular.
* Statistics along the flight direction are exact for lags covered by the stencil rows with full
  or dense columns and approximate beyond (the truncated stencil is the approximation). Tests
  check D(s) against von Karman for shifts up to the aperture width and the loss of correlation at
  separations far beyond L0.
* Shifts are quantised to the grid step: the aperture is cut at round(position / dx) rows; the
  fractional part is carried, so the position never drifts. Only forward motion (shift >= 0) along
  the rows; a cross-track wind component is not modelled.
* Cost: O(n * stencil size) ~ 2 n^2 multiply-adds per new row plus one n x n matrix product per
  batch of rows; set-up is about ten dense solves of size <= ~4n, cached per (n, dx, r0, L0,
  depth_factor) across instances.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy import linalg

from ._checks import generator, integer, non_negative, positive, real_scalar
from .screens import kolmogorov_structure_function, von_karman_covariance


def _stencil(n: int, depth_factor: int):
    """(lag, column) pairs of the stencil; lag >= 1 rows back from the new row.

    Rows 1, 2, 3 back: every column (a contiguous block -- leaving a gap here, e.g. rows 1 and 3
    without row 2, conditions on values whose joint law the recursion does not reproduce, and the
    large B(0) / D(dx) ratio amplifies that into a 15 % deficit of D(dx)); rows 2^k + 1 back
    (5, 9, 17, ... < 2n) with columns 2^(k-1) apart plus the last column; and columns 0, n/2, n-1 at
    m n rows back (m = 1..depth_factor) beyond those.
    """
    pts = [(lag, j) for lag in (1, 2, 3) for j in range(n)]
    k = 2
    last = 3
    while 2**k + 1 < 2 * n:
        lag = 2**k + 1
        cols = np.unique(np.append(np.arange(0, n, 2 ** (k - 1)), n - 1))
        pts += [(lag, int(j)) for j in cols]
        last = lag
        k += 1
    for m in range(1, depth_factor + 1):
        if m * n > last:
            pts += [(m * n, j) for j in sorted({0, n // 2, n - 1})]
    return np.array(pts, dtype=int)


def _cov(pa: np.ndarray, pb: np.ndarray, dx: float, r0: float, l0: float) -> np.ndarray:
    """Covariance between points pa (k, 2) and pb (m, 2) given as (row, col) in pixels."""
    d = np.hypot(pa[:, None, 0] - pb[None, :, 0], pa[:, None, 1] - pb[None, :, 1])
    return von_karman_covariance(d * dx, r0, l0)


@lru_cache(maxsize=64)
def _ar_matrices(n: int, dx: float, r0: float, l0: float, depth_factor: int, count: int):
    """AR matrices for the first ``count`` stencil points (those available), cached per parameters.

    Returns read-only A (n, count), B (n, n) and the (count, 2) stencil (lag, column) array.
    """
    sel = _stencil(n, depth_factor)
    sel = sel[np.argsort(sel[:, 0], kind="stable")][:count]
    new = np.stack([np.zeros(n), np.arange(n)], axis=1)
    old = np.stack([-sel[:, 0].astype(float), sel[:, 1].astype(float)], axis=1)
    czz = _cov(old, old, dx, r0, l0)
    cxz = _cov(new, old, dx, r0, l0)
    cxx = _cov(new, new, dx, r0, l0)
    hint = (
        f"for outer_scale_m = {l0:g} m, r0_m = {r0:g} m, dx_m = {dx:g} m (outer scale too large "
        f"for the grid); reduce outer_scale_m or increase dx_m"
    )
    try:
        factor = linalg.cho_factor(czz, lower=True, check_finite=True)
    except linalg.LinAlgError:
        raise ValueError(f"the stencil covariance is numerically singular {hint}") from None
    a = linalg.cho_solve(factor, cxz.T).T
    cond = cxx - a @ cxz.T
    cond = 0.5 * (cond + cond.T)
    w, v = np.linalg.eigh(cond)
    if w.min() < -1e-8 * max(w.max(), 0.0) - 1e-12 * abs(cxx[0, 0]):
        raise ValueError(f"the conditional covariance is not positive {hint}")
    b = v * np.sqrt(np.clip(w, 0.0, None))
    for arr in (a, b, sel):
        arr.setflags(write=False)
    return a, b, sel


class MovingScreen:
    """A von Karman phase screen carried past an n x n aperture by the platform's motion.

    Parameters
    ----------
    n : aperture samples per side (>= 4); the aperture is the newest n rows of the strip.
    dx_m : grid step in m (pitch of the aperture samples).
    r0_m : Fried parameter in m (>= dx_m; the hard case r0 < dx raises like ``phase_screen``).
    outer_scale_m : von Karman outer scale L0 in m, finite (see the module docstring).
    rng : numpy.random.Generator, the only source of randomness.
    depth_factor : stencil depth in units of n rows (>= 1, default 4).

    Usage
    -----
    ``first = screen.aperture`` then ``screen.next_aperture(v * dt)`` per shot, or
    ``screen.next_apertures(shifts_m)`` for a batch. Apertures are (n, n) float64 radians, axis 0
    along the flight direction (row 0 the oldest), axis 1 across track.
    """

    def __init__(
        self,
        n: int,
        dx_m: float,
        r0_m: float,
        outer_scale_m: float,
        *,
        rng: np.random.Generator,
        depth_factor: int = 4,
    ):
        self.n = integer("n", n, 4)
        self.dx_m = positive("dx_m", dx_m)
        self.r0_m = positive("r0_m", r0_m)
        l0 = real_scalar("outer_scale_m", outer_scale_m, allow_inf=True)
        if not np.isfinite(l0) or l0 <= 0.0:
            raise ValueError(
                f"outer_scale_m must be finite and > 0 m for a MovingScreen (the "
                f"Kolmogorov covariance does not exist; use an outer scale much "
                f"larger than the aperture), got {outer_scale_m!r}"
            )
        self.outer_scale_m = l0
        if self.r0_m < self.dx_m:
            raise ValueError(
                f"r0_m = {self.r0_m:.3g} m is below the grid step dx_m = {self.dx_m:.3g} m: "
                f"neighbouring samples would differ by "
                f"{np.sqrt(kolmogorov_structure_function(self.dx_m, self.r0_m)):.2g} rad rms; "
                f"use dx_m <= r0_m"
            )
        self.depth_factor = integer("depth_factor", depth_factor, 1)
        self._rng = generator("rng", rng)
        self._stencil = _stencil(self.n, self.depth_factor)
        self._stencil = self._stencil[np.argsort(self._stencil[:, 0], kind="stable")]
        self._depth = max(int(self._stencil[:, 0].max()), self.n)
        # Ring buffer of rows; _count rows generated so far; newest at (_count - 1) % depth.
        self._buf = np.zeros((self._depth, self.n))
        self._count = 0
        self._row_index = 0  # strip row index of the aperture's last row + 1 (= rows in the past)
        self._position_m = 0.0
        self._first_row()
        self._extrude(self.n - 1)
        self._row_index = self._count

    # --- covariance algebra ---------------------------------------------------------------------

    def _cov(self, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
        return _cov(pa, pb, self.dx_m, self.r0_m, self.outer_scale_m)

    def _matrices(self, available_lag: int):
        """A (n, m), B (n, n) and stencil rows for the stencil points with lag <= available_lag."""
        count = int(np.sum(self._stencil[:, 0] <= available_lag))
        return _ar_matrices(
            self.n, self.dx_m, self.r0_m, self.outer_scale_m, self.depth_factor, count
        )

    def _first_row(self):
        pts = np.stack([np.zeros(self.n), np.arange(self.n)], axis=1)
        c = self._cov(pts, pts)
        w, v = np.linalg.eigh(0.5 * (c + c.T))
        row = (v * np.sqrt(np.clip(w, 0.0, None))) @ self._rng.standard_normal(self.n)
        self._buf[0] = row
        self._count = 1

    def _extrude(self, rows: int):
        """Append ``rows`` new rows to the strip."""
        if rows <= 0:
            return
        noise = self._rng.standard_normal((rows, self.n))
        depth = self._depth
        i = 0
        while i < rows:
            a, b, sel = self._matrices(self._count)
            full = len(sel) == len(self._stencil)
            # rows that can use this stencil: all remaining if the stencil is complete, else until
            # the next stencil row becomes available.
            if full:
                chunk = rows - i
            else:
                nxt = self._stencil[self._stencil[:, 0] > self._count, 0].min()
                chunk = min(rows - i, int(nxt) - self._count)
            bw = noise[i : i + chunk] @ b.T
            lags, cols = sel[:, 0], sel[:, 1]
            for t in range(chunk):
                new_pos = self._count % depth
                z = self._buf[(new_pos - lags) % depth, cols]
                self._buf[new_pos] = a @ z + bw[t]
                self._count += 1
            i += chunk

    # --- public API ----------------------------------------------------------------------------

    @property
    def position_m(self) -> float:
        """Distance travelled since construction (m), before quantisation to the grid."""
        return self._position_m

    @property
    def rows_generated(self) -> int:
        """Rows of the strip generated so far (including the first aperture's n rows)."""
        return self._count

    @property
    def aperture(self) -> np.ndarray:
        """The current (n, n) aperture cut, float64 radians (a copy)."""
        idx = (np.arange(self._row_index - self.n, self._row_index)) % self._depth
        return self._buf[idx].copy()

    def next_aperture(self, shift_m: float) -> np.ndarray:
        """Move the platform forward by ``shift_m`` (m, >= 0) and return the new (n, n) aperture.

        The aperture advances by round(position / dx) - round(previous position / dx) rows.
        """
        s = non_negative("shift_m", shift_m)
        before = int(np.rint(self._position_m / self.dx_m))
        self._position_m += s
        after = int(np.rint(self._position_m / self.dx_m))
        self._extrude(after - before)
        self._row_index = self._count
        return self.aperture

    def next_apertures(self, shifts_m) -> np.ndarray:
        """Apply successive shifts (1-D array, m, >= 0); returns (len(shifts_m), n, n) apertures."""
        shifts = np.asarray(shifts_m, dtype=float)
        if shifts.ndim != 1 or not np.all(np.isfinite(shifts)) or np.any(shifts < 0.0):
            raise ValueError("shifts_m must be a 1-D array of finite shifts >= 0 m")
        out = np.empty((shifts.size, self.n, self.n))
        for k, s in enumerate(shifts):
            out[k] = self.next_aperture(float(s))
        return out

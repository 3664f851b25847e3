"""The sampled pupil: an n x n grid across the aperture diameter with exact-area annulus weights.

Grid convention (shared with the atmosphere code and kept stable):

* The grid spans exactly the aperture diameter D: n x n pixels of pitch D / n, the aperture circle
  is inscribed in the square [-D/2, D/2]^2.
* Pixel (i, j) (row i, column j) has its centre at y = ((i + 1/2)/n - 1/2) D, x = ((j + 1/2)/n - 1/2) D,
  so an (n, n) phase screen cut with pitch D / n maps onto the grid index for index.
* Coordinates are returned in units of D (multiply by the diameter in metres for SI).
* ``weights[i, j]`` is the exact fraction of the pixel's area inside the annulus
  alpha D / 2 <= r <= D / 2 (closed-form area of a square cut by a circle), so sums
  ``sum(weights * g) * pixel_area`` are quadratures of the integral of g over the annulus whose error
  falls as n grows (the domain is represented exactly; only g is sampled at pixel centres).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ._checks import grid_size, obstruction_ratio


@dataclass(frozen=True)
class PupilGrid:
    """An n x n pupil sampling (read-only arrays, all lengths in units of the aperture diameter D).

    Attributes
    ----------
    n : samples across the diameter.
    obstruction : central obstruction ratio alpha (diameter ratio), in [0, 1).
    x, y : (n, n) float64 pixel-centre coordinates / D; ``x`` varies along columns (axis -1),
        ``y`` along rows (axis -2).
    r : (n, n) float64 radius / D (the aperture edge is r = 0.5).
    weights : (n, n) float64 in [0, 1], fraction of each pixel's area inside the annulus.
    pixel_area : float, (1 / n)^2, pixel area / D^2.
    """

    n: int
    obstruction: float
    x: np.ndarray
    y: np.ndarray
    r: np.ndarray
    weights: np.ndarray
    pixel_area: float

    @property
    def pitch(self) -> float:
        """Pixel pitch / D (= 1 / n)."""
        return 1.0 / self.n

    @property
    def area(self) -> float:
        """Annulus area / D^2 as represented by the weights (exact: pi (1 - alpha^2) / 4)."""
        return float(self.weights.sum() * self.pixel_area)


def _quadrant_disc_area(x, y, radius):
    """Area of {0 <= X <= x, 0 <= Y <= y, X^2 + Y^2 <= radius^2} for x, y >= 0 (closed form)."""
    x = np.minimum(x, radius)
    y = np.minimum(y, radius)
    inside = x * x + y * y <= radius * radius
    # Where the corner (x, y) is outside the circle: the rectangle up to xc = sqrt(R^2 - y^2) plus the
    # area under the arc from xc to x, F(t) = (t sqrt(R^2 - t^2) + R^2 asin(t / R)) / 2.
    xc = np.sqrt(np.maximum(radius * radius - y * y, 0.0))
    xc = np.minimum(xc, x)

    def prim(t):
        s = np.clip(t / radius, -1.0, 1.0)
        return 0.5 * (
            t * np.sqrt(np.maximum(radius * radius - t * t, 0.0)) + radius * radius * np.arcsin(s)
        )

    outside = xc * y + prim(x) - prim(xc)
    return np.where(inside, x * y, outside)


def _signed_area(x, y, radius):
    """Signed extension of the quadrant area: odd in x and in y (inclusion-exclusion over quadrants)."""
    return np.sign(x) * np.sign(y) * _quadrant_disc_area(np.abs(x), np.abs(y), radius)


def disc_pixel_area(x0, x1, y0, y1, radius) -> np.ndarray:
    """Exact area of the rectangle [x0, x1] x [y0, y1] inside the disc |r| <= radius centred at 0."""
    if radius <= 0.0:
        return np.zeros(np.broadcast(x0, x1, y0, y1).shape)
    a = (
        _signed_area(x1, y1, radius)
        - _signed_area(x0, y1, radius)
        - _signed_area(x1, y0, radius)
        + _signed_area(x0, y0, radius)
    )
    return np.maximum(a, 0.0)


@lru_cache(maxsize=16)
def _cached_grid(n: int, obstruction: float) -> PupilGrid:
    h = 1.0 / n
    c = (np.arange(n) + 0.5) * h - 0.5
    x, y = np.meshgrid(c, c)
    x0, x1, y0, y1 = x - h / 2, x + h / 2, y - h / 2, y + h / 2
    area = disc_pixel_area(x0, x1, y0, y1, 0.5)
    if obstruction > 0.0:
        area = area - disc_pixel_area(x0, x1, y0, y1, 0.5 * obstruction)
    w = np.clip(area / (h * h), 0.0, 1.0)
    r = np.hypot(x, y)
    for a in (x, y, r, w):
        a.setflags(write=False)
    return PupilGrid(n=n, obstruction=obstruction, x=x, y=y, r=r, weights=w, pixel_area=h * h)


def pupil_grid(n: int, obstruction: float = 0.0) -> PupilGrid:
    """n x n sampling of an annular aperture of diameter D (coordinates in units of D).

    Parameters
    ----------
    n : int >= 16, pixels across the diameter (pitch D / n).
    obstruction : central obstruction ratio alpha = d_obstruction / D in [0, 1).

    Returns
    -------
    PupilGrid with read-only (n, n) float64 arrays ``x``, ``y``, ``r`` (units of D) and ``weights``
    (exact area fraction of each pixel inside the annulus), and ``pixel_area`` = 1 / n^2 (units of
    D^2). Results are cached per (n, obstruction).
    """
    return _cached_grid(grid_size(n), obstruction_ratio(obstruction))

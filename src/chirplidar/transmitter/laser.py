"""Laser phase noise: a Wiener process whose increments have variance 2 pi dnu |dt|.

For a Lorentzian line of FWHM ``dnu`` the phase difference over a delay tau has variance
2 pi dnu |tau| (self-homodyne coherence). The path is sampled exactly at every requested time —
the union of the LO times t - tau_ref and the signal times t - tau, however far apart — so the
delayed phase is exact, not interpolated.
"""

from __future__ import annotations

import numpy as np


def wiener_phase(
    times_s: list[np.ndarray], linewidth_hz: float, rng: np.random.Generator, batch: int = 1
) -> list[np.ndarray]:
    """Laser phase (rad) at each array of ``times_s``, jointly exact; shape (batch, len(times)).

    ``linewidth_hz == 0`` returns zeros and draws nothing.
    """
    if linewidth_hz <= 0:
        return [np.zeros((batch, np.size(t))) for t in times_s]
    sizes = [np.size(t) for t in times_s]
    allt = np.concatenate([np.ravel(t) for t in times_s])
    order = np.argsort(allt, kind="stable")
    ts = allt[order]
    dt = np.diff(ts, prepend=ts[0])
    steps = rng.standard_normal((batch, ts.size)) * np.sqrt(2.0 * np.pi * linewidth_hz * dt)
    path = np.cumsum(steps, axis=1)
    out = np.empty_like(path)
    out[:, order] = path
    return list(np.split(out, np.cumsum(sizes)[:-1], axis=1))

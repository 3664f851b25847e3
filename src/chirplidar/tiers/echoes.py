"""Sub-returns of a beam footprint for the rf tier (sloped or rough terrain).

A beam on real terrain spans a range of distances: the mission runner casts sub-rays over the
beam's divergence and hands the rf and baseband tiers, per shot, echoes built from them (extra
round-trip delay, power share and carrier phase of each). The tiers then sum the delayed echoes
coherently, so the beat peak spreads over kappa x (the footprint's delay spread).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_FIELDS = ("delay_offset_s", "power_weight", "phase_rad")


@dataclass(frozen=True)
class Echoes:
    """Sub-returns of each shot's footprint.

    delay_offset_s: (batch, k) or (k,) extra round-trip delay of each echo relative to the budget's
        delay (s, may be negative)
    power_weight:   (batch, k) or (k,) share of the received power in each echo (>= 0; normalised
        to sum 1 per shot by the rf tier)
    phase_rad:      (batch, k) or (k,) carrier phase of each echo (rad), added to the shot's own
        carrier phase (channel.carrier_phase, speckle, Doppler, laser phase noise).

    The tiers sum the echoes coherently, with amplitudes sqrt(w_k) (w normalised) and their phases:
    echoes are fields, not powers. Footprint samples are not scatterers, so a caller must not
    give them their optical propagation phases 2 pi nu dtau_k (the samples would interfere:
    anything from 0 to (sum_k sqrt(w_k))^2 times the power). The survey runs
    (``mission.measure.footprint_echoes``) pass each sub-ray's speckle field for a diffuse
    surface (weight w_k |z_k|^2, phase arg z_k), and otherwise the mean line's resolution-cell
    echoes with one common phase; both keep the footprint's mean power.

    A (k,) array is shared by every shot of the batch. A single echo of offset 0, weight 1 and
    phase 0 is the echo-free shot. Arrays are stored as read-only float64.
    """

    delay_offset_s: np.ndarray
    power_weight: np.ndarray
    phase_rad: np.ndarray

    def __post_init__(self):
        ks, rows = set(), set()
        for name in _FIELDS:
            raw = getattr(self, name)
            try:
                arr = np.array(raw, dtype=np.float64)  # a copy: the caller may reuse its array
            except (TypeError, ValueError):
                raise ValueError(f"echoes.{name} must be a real array of shape (batch, k) or (k,)"
                                 ) from None
            if arr.ndim not in (1, 2) or arr.shape[-1] == 0:
                raise ValueError(f"echoes.{name} must have shape (batch, k) or (k,) with k >= 1; "
                                 f"got shape {arr.shape}")
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"echoes.{name} must be finite (got NaN or inf)")
            ks.add(arr.shape[-1])
            if arr.ndim == 2:
                rows.add(arr.shape[0])
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        shapes = ", ".join(f"{n} {getattr(self, n).shape}" for n in _FIELDS)
        if len(ks) > 1:
            raise ValueError(f"echoes fields must share the number of echoes k (last axis); got {shapes}")
        if len(rows) > 1:
            raise ValueError(f"echoes fields of shape (batch, k) must share batch; got {shapes}")
        w = self.power_weight
        if np.any(w < 0):
            raise ValueError("echoes.power_weight must be >= 0")
        if np.any(np.sum(w, axis=-1) <= 0):
            raise ValueError("echoes.power_weight must have a positive sum for every shot")

    @property
    def k(self) -> int:
        """Number of echoes per shot."""
        return int(self.power_weight.shape[-1])

    def for_batch(self, batch: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(delay_offset_s, normalised power weight, phase_rad), each of shape (batch, k).

        Raises ValueError when a (batch, k) field does not have ``batch`` rows.
        """
        out = []
        for name in _FIELDS:
            arr = getattr(self, name)
            if arr.ndim == 2 and arr.shape[0] != batch:
                raise ValueError(f"echoes.{name} must have shape (batch, k) = ({batch}, {self.k}) "
                                 f"or ({self.k},); got {arr.shape}")
            out.append(np.broadcast_to(arr, (batch, self.k)))
        offsets, w, phases = out
        return offsets, w / np.sum(w, axis=-1, keepdims=True), phases

"""Channel effects of a mission (``[effects]``): the list of effect names and each effect's section.

:data:`EFFECT_NAMES` is the one list of effects: ``effects.enabled`` (missions) and ``effects``
(scenes) accept these names, and :data:`chirplidar.channel.effects.EFFECTS` implements them in
this order (it checks so at import).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from .base import StrictModel

#: The effects, in the order the channel applies them.
EFFECT_NAMES = ("phase_noise", "speckle", "doppler", "coupling", "turbulence")
#: One effect's name.
EffectName = Literal[EFFECT_NAMES]  # type: ignore[valid-type]


class DopplerEffect(StrictModel):
    """Target motion along the beam (thesis eq. 2.2.5, Appendix D)."""

    radial_velocity_mps: float = Field(description="closing speed along the line of sight "
                                       "(positive: range decreasing)")


class SpeckleEffect(StrictModel):
    """Speckle of a rough target (Goodman): gamma-distributed power of order M, random phase."""

    cells: float = Field(ge=1, description="speckle cells the receiver integrates, M (1 for a "
                         "single-mode-fiber coherent receiver)")
    shift_per_shot_m: float | None = Field(
        None, ge=0, description="footprint displacement between successive shots; unset: "
        "independent speckle per shot; set: a correlated sequence (whole cells only)")

    @model_validator(mode="after")
    def _whole_cells(self):
        if self.shift_per_shot_m is not None and self.cells != int(self.cells):
            raise ValueError("effects.speckle.shift_per_shot_m needs a whole number of cells")
        return self


class CouplingEffect(StrictModel):
    """Telescope-to-fiber coupling with a central obstruction (free space only).

    diffuse targets: the monostatic mean of Winzer & Leeb (1998), 42 % at best unobstructed;
    specular targets (a plane wave back): the closed form of Ruilier (1998), 81 % at best.
    """

    obstruction_ratio: float = Field(ge=0, lt=1, description="secondary / primary diameter")
    focal_length_m: float = Field(gt=0, description="telescope focal length")
    mode_field_radius_m: float = Field(gt=0, description="fiber mode-field radius (MFD / 2)")
    fiber_numerical_aperture: float = Field(gt=0, lt=1, description="fiber NA: the focal cone "
                                            "D / (2 f) beyond it is flagged (thesis: about +-6 deg)")
    target: Literal["diffuse", "specular"] = Field(description="diffuse (Lambertian speckle) or "
                                                   "specular (plane wave) return")


class TurbulenceEffect(StrictModel):
    """Phase-only turbulence in the receive pupil, Cn^2 = atm.Cn2 over atm.dst (needs 'coupling').

    'mean': the mutual-coherence mean coupling (deterministic, draws nothing). 'frozen_flow':
    successive shots of a batch see one screen moving past the aperture by speed x interval, so
    the fading of coupled power is correlated from shot to shot.
    """

    fading: Literal["mean", "frozen_flow"]
    outer_scale_m: float = Field(gt=0, allow_inf_nan=True, description="von Karman outer scale "
                                 "(inf: Kolmogorov; finite for "
                                 "frozen flow; the phase covariance needs it)")
    transverse_speed_mps: float | None = Field(None, ge=0, description="screen speed across the "
                                               "beam (frozen_flow)")
    shot_interval_s: float | None = Field(None, gt=0, description="time between shots (frozen_flow)")
    screen_pixels: int | None = Field(
        None, ge=16, description="frozen_flow: phase-screen samples across the aperture (a "
        "fidelity knob: >= 16, the pupil-coupling grid's minimum, and the pixel D / screen_pixels "
        "must not exceed r0); unset = max(64, ceil(4 D / r0)), at least 4 pixels per r0")

    @model_validator(mode="after")
    def _frozen(self):
        if self.fading == "frozen_flow":
            if self.transverse_speed_mps is None or self.shot_interval_s is None:
                raise ValueError("turbulence fading = 'frozen_flow' needs transverse_speed_mps "
                                 "and shot_interval_s")
            if not np.isfinite(self.outer_scale_m):
                raise ValueError("turbulence fading = 'frozen_flow' needs a finite outer_scale_m")
        return self


class Effects(StrictModel):
    """Channel effects by name (docs/architecture.md): only the enabled ones are computed or draw numbers."""

    enabled: tuple[EffectName, ...] = Field(
        (), description="effects to simulate; the rest cost nothing and draw no random numbers")
    doppler: DopplerEffect | None = None
    speckle: SpeckleEffect | None = None
    coupling: CouplingEffect | None = None
    turbulence: TurbulenceEffect | None = None

    # Each effect that takes parameters has a section of its name (phase_noise takes lsr.Lw).

    @model_validator(mode="after")
    def _sections(self):
        if len(set(self.enabled)) != len(self.enabled):
            raise ValueError(f"effects.enabled lists an effect twice: {list(self.enabled)}")
        for name in self.enabled:
            if name in type(self).model_fields and getattr(self, name) is None:
                raise ValueError(f"effects.enabled includes '{name}' but [effects.{name}] is missing")
        return self

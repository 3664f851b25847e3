"""The coherent receiver's architecture (``[receiver]``, thesis Ch. 6): fiber, large detector or
focal-plane array, each mixing the focal-plane field of the return with a local oscillator.

Without a ``[receiver]`` section a chirped instrument keeps today's receiver: the beat of a
single-mode fiber, with the closed-form mean coupling of the ``coupling`` effect. With one, the
channel draws each shot's field across the telescope pupil (speckle of the footprint when the
``speckle`` effect is on, a plane wave otherwise, times a turbulence phase screen when
``turbulence`` is on), focuses it, and mixes it with the architecture's LO
(``chirplidar.channel.receiver``).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from .base import StrictModel

#: The receiver architectures.
ARCHITECTURES = ("fiber", "large_detector", "fpa")
#: How a focal-plane array's pixels are combined by the DSP.
COMBINING = ("incoherent", "mrc", "mrc_estimated", "selection")

_KEYS = {
    "fiber": ("mode_field_radius_m", "fiber_numerical_aperture"),
    "large_detector": ("lo_profile", "lo_radius_m", "detector_side_m"),
    "fpa": ("lo_profile", "lo_radius_m", "pixels", "pixel_pitch_m", "fill_factor",
            "pixel_noise_a_per_rthz", "pixel_dark_current_a", "combining"),
}


class Receiver(StrictModel):
    """The receiver behind the telescope: a single-mode fiber (``fiber``), one large balanced
    detector with a free-space LO (``large_detector``), or an N x N focal-plane array whose
    pixels the DSP combines (``fpa``). Lengths in the focal plane are in metres."""

    architecture: Literal[ARCHITECTURES] = Field(  # type: ignore[valid-type]
        description="fiber | large_detector | fpa")
    focal_length_m: float = Field(gt=0, description="telescope focal length")
    obstruction_ratio: float = Field(ge=0, lt=1, description="secondary / primary diameter")
    pupil_samples: int | None = Field(
        None, ge=16, le=1024, description="samples across the pupil (a fidelity knob); unset: "
        "max(32, ceil(3 D / rho)), three per speckle coherence radius rho = lambda R / (pi w)")
    focal_sampling: float = Field(
        2.0, ge=1, le=16, description="focal-plane samples per lambda f / D (a fidelity knob)")
    mode_field_radius_m: float | None = Field(None, gt=0, description="fiber: MFD / 2")
    fiber_numerical_aperture: float | None = Field(
        None, gt=0, lt=1, description="fiber: its NA (a focal cone D / 2f beyond it is flagged)")
    lo_profile: Literal["gaussian", "flat_top"] | None = Field(
        None, description="large_detector, fpa: the LO beam in the focal plane")
    lo_radius_m: float | None = Field(
        None, gt=0, description="large_detector, fpa: the LO's 1/e^2 intensity radius "
        "(gaussian) or half width (flat_top) in the focal plane")
    detector_side_m: float | None = Field(None, gt=0, description="large_detector: its side")
    pixels: int | None = Field(None, description="fpa: N, for N x N pixels")
    pixel_pitch_m: float | None = Field(None, gt=0, description="fpa: centre-to-centre pitch")
    fill_factor: float | None = Field(
        None, description="fpa: active area / pitch^2, in (0, 1]")
    pixel_noise_a_per_rthz: float | None = Field(
        None, ge=0, description="fpa: each pixel's own circuit noise current density (thermal "
        "and amplifier, A/sqrt(Hz)); the pixels share the LO's shot noise")
    pixel_dark_current_a: float | None = Field(None, ge=0, description="fpa: dark current of "
                                               "each pixel's balanced pair")
    combining: Literal[COMBINING] | None = Field(  # type: ignore[valid-type]
        None, description="fpa: incoherent (sum of power spectra) | mrc (maximal ratio, known "
        "gains) | mrc_estimated (gains estimated from each pixel's beat) | selection (best pixel)")

    @model_validator(mode="after")
    def _architecture_keys(self):
        arch = self.architecture
        missing = [k for k in _KEYS[arch] if getattr(self, k) is None]
        if missing:
            raise ValueError(f"receiver.architecture = {arch!r} needs receiver."
                             + ", receiver.".join(missing))
        others = {k for a, keys in _KEYS.items() if a != arch for k in keys} - set(_KEYS[arch])
        stray = sorted(k for k in others if getattr(self, k) is not None)
        if stray:
            raise ValueError(f"receiver.{', receiver.'.join(stray)} do(es) not apply to "
                             f"receiver.architecture = {arch!r}")
        if arch == "fpa":
            if self.pixels < 1:
                raise ValueError(f"receiver.pixels = {self.pixels}: an FPA needs at least one "
                                 "pixel (N x N pixels, N >= 1)")
            if not 0.0 < self.fill_factor <= 1.0:
                raise ValueError(f"receiver.fill_factor = {self.fill_factor:g} is outside "
                                 "(0, 1]: it is the pixel's active area over pitch^2")
        return self

    @property
    def pixel_count(self) -> int:
        """Detectors the beat is read from: N^2 for an FPA, else 1."""
        return int(self.pixels) ** 2 if self.architecture == "fpa" else 1

"""The coherent receiver's architecture (``[receiver]``, thesis Ch. 6): a single-mode fiber, one
large detector or a focal-plane array, each mixing the focal-plane field of the return with a
local oscillator.

Without a ``[receiver]`` section a chirped instrument keeps the closed-form fiber receiver of
the ``coupling`` effect. With one, the channel draws each shot's field across the telescope pupil
(speckle of the footprint when the ``speckle`` effect is on, a plane wave otherwise, times a
turbulence phase screen when ``turbulence`` is on), focuses it, and mixes it with the chosen
architecture's LO (``chirplidar.channel.receiver``). Each architecture has its own subsection;
``architecture`` picks one, so a file may hold all three and a study may vary
``receiver.architecture`` (as ``effects.enabled`` picks among the effects' sections).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from .base import StrictModel

#: The receiver architectures, each the name of its subsection.
ARCHITECTURES = ("fiber", "large_detector", "fpa")
#: How a focal-plane array's pixels are combined by the DSP.
COMBINING = ("incoherent", "mrc", "mrc_estimated", "selection")
#: The LO beam of the free-space (beam-splitter) receivers.
LoProfile = Literal["gaussian", "flat_top"]


class FiberReceiver(StrictModel):
    """A single-mode fiber in the focal plane (thesis Sec. 2.6; the field trial's receiver)."""

    mode_field_radius_m: float = Field(gt=0, description="MFD / 2")
    numerical_aperture: float = Field(gt=0, lt=1, description="the fiber's NA (a focal cone "
                                      "D / 2f beyond it is flagged)")


class LargeDetector(StrictModel):
    """One square balanced detector in the focal plane with a free-space LO (thesis Fig. 6.2)."""

    side_m: float = Field(gt=0, description="the detector's side")
    lo_profile: LoProfile = Field(description="the LO beam in the focal plane")
    lo_radius_m: float = Field(gt=0, description="the LO's 1/e^2 intensity radius (gaussian) "
                               "or half width (flat_top)")


class FocalPlaneArray(StrictModel):
    """N x N pixels, each an I/Q balanced pair with its own circuit noise, combined by DSP
    (thesis Ch. 6)."""

    pixels: int = Field(description="N, for N x N pixels (>= 1)")
    pitch_m: float = Field(gt=0, description="centre-to-centre pitch")
    fill_factor: float = Field(description="active area / pitch^2, in (0, 1]")
    noise_a_per_rthz: float = Field(ge=0, description="each pixel's own circuit noise current "
                                    "density (thermal and amplifier, A/sqrt(Hz)); the pixels "
                                    "share the LO's shot noise")
    dark_current_a: float = Field(ge=0, description="each pixel's dark current")
    combining: Literal[COMBINING] = Field(  # type: ignore[valid-type]
        description="incoherent (sum of power spectra) | mrc (maximal ratio, known gains) | "
        "mrc_estimated (gains estimated from each pixel's beat) | selection (best pixel)")
    lo_profile: LoProfile = Field(description="the LO beam across the array")
    lo_radius_m: float = Field(gt=0, description="the LO's 1/e^2 intensity radius (gaussian) "
                               "or half width (flat_top)")

    @model_validator(mode="after")
    def _layout(self):
        if self.pixels < 1:
            raise ValueError(f"receiver.fpa.pixels = {self.pixels}: an FPA needs at least one "
                             "pixel (N x N pixels, N >= 1)")
        if not 0.0 < self.fill_factor <= 1.0:
            raise ValueError(f"receiver.fpa.fill_factor = {self.fill_factor:g} is outside "
                             "(0, 1]: it is the pixel's active area over pitch^2")
        return self


class Receiver(StrictModel):
    """The receiver behind the telescope and the footprint it sees. Focal-plane lengths in m."""

    architecture: Literal[ARCHITECTURES] = Field(  # type: ignore[valid-type]
        description="fiber | large_detector | fpa: the subsection that receives")
    focal_length_m: float = Field(gt=0, description="telescope focal length")
    obstruction_ratio: float = Field(ge=0, lt=1, description="secondary / primary diameter")
    footprint: Literal["monostatic", "beam"] = Field(
        description="monostatic: the transmit fiber's mode through this telescope lights the "
        "footprint (its far field; Winzer & Leeb 1998; the field trial, thesis Sec. 5); beam: "
        "the channel's Gaussian beam (channel.beam_radius_m, divergence_half_angle_rad)")
    transmit_mode_radius_m: float | None = Field(
        None, gt=0, description="monostatic: the transmit fiber's MFD / 2")
    pupil_samples: int | None = Field(
        None, ge=16, le=1024, description="samples across the pupil (a fidelity knob); unset: "
        "enough for 3 per speckle coherence radius, 2 per r0 and the focal window")
    focal_sampling: float = Field(
        2.0, ge=1, le=16, description="focal-plane samples per lambda f / D (a fidelity knob)")
    fiber: FiberReceiver | None = None
    large_detector: LargeDetector | None = None
    fpa: FocalPlaneArray | None = None

    @model_validator(mode="after")
    def _chosen(self):
        if getattr(self, self.architecture) is None:
            raise ValueError(f"receiver.architecture = {self.architecture!r} needs "
                             f"[receiver.{self.architecture}]")
        if self.footprint == "monostatic" and self.transmit_mode_radius_m is None:
            raise ValueError("receiver.footprint = 'monostatic' needs "
                             "receiver.transmit_mode_radius_m (the transmit fiber's MFD / 2)")
        if self.footprint == "beam" and self.transmit_mode_radius_m is not None:
            raise ValueError("receiver.transmit_mode_radius_m is for footprint = 'monostatic'; "
                             "footprint = 'beam' takes the channel's beam")
        return self

    @property
    def chosen(self):
        """The chosen architecture's subsection."""
        return getattr(self, self.architecture)

    @property
    def pixel_count(self) -> int:
        """Detectors the beat is read from: N^2 for an FPA, else 1."""
        return int(self.fpa.pixels) ** 2 if self.architecture == "fpa" else 1

    @property
    def combining(self) -> str | None:
        """The FPA's combining rule (None for one detector)."""
        return self.fpa.combining if self.architecture == "fpa" else None

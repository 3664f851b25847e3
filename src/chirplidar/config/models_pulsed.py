"""Sections of a pulsed (short-pulse, direct-detection) altimeter: thesis Ch. 2, Tables 2.1-2.2.

A pulsed instrument has a ``[pulse]`` section and none of the chirped transceiver's sections
(``[waveform]``, ``[system]``, ``[laser]``, ...): :class:`~chirplidar.config.models.MissionConfig`
refuses a file that mixes them. It shares ``[channel]`` (telescope, beam, optics) and, for an
analog detector, ``[apd]`` (thesis Table 4.7: gain, excess noise, transimpedance noise) with the
chirped receivers. Physical quantities have no defaults.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from .base import StrictModel


class Pulse(StrictModel):
    """The transmitted pulse (thesis Table 2.1: GLAS 1064 nm, 75 mJ, 5 ns, 40 Hz)."""

    wavelength_m: float = Field(gt=0, description="laser wavelength")
    energy_j: float = Field(gt=0, description="energy of one transmitted pulse")
    duration_s: float = Field(gt=0, description="full width at half maximum of the pulse's "
                              "power (the tau of eq. 2.1.1)")
    shape: Literal["gaussian", "rectangular"] = Field(
        description="the pulse's power envelope: 'gaussian' (a Q-switched pulse) or "
        "'rectangular' (on-off, as eq. 2.1.1 pictures it)")
    prf_hz: float = Field(gt=0, description="pulse repetition frequency")


class PulseReceiver(StrictModel):
    """The pulsed receiver's detector choice and the optics that set its background."""

    detector: Literal["apd", "photon_counting"] = Field(
        description="'apd': analog linear-mode APD with the [apd] section's gain, excess noise "
        "and amplifier noise (thesis Table 4.7); 'photon_counting': a Geiger-mode or "
        "single-photon detector with the [photon_counting] section")
    bandwidth_hz: float = Field(gt=0, description="electrical bandwidth of the detector and its "
                                "amplifier (-3 dB of a Gaussian impulse response)")
    field_of_view_rad: float = Field(gt=0, description="full angle of the receiver's field stop: "
                                     "the solid angle pi (fov/2)^2 collects background light")
    filter_bandwidth_m: float = Field(gt=0, description="optical band-pass filter width "
                                      "(FWHM, taken as rectangular)")


class PhotonCounting(StrictModel):
    """A single-photon detector (``pulse_receiver.detector = "photon_counting"``)."""

    detection_efficiency: float = Field(gt=0, le=1, description="probability that a photon "
                                        "reaching the detector is counted")
    dead_time_s: float = Field(ge=0, description="non-paralyzable dead time after a count")
    dark_count_rate_hz: float = Field(ge=0, description="counts per second without light")


class Digitizer(StrictModel):
    """The waveform digitizer (GLAS: 1 GHz, 8 bits, 544 samples over land)."""

    sample_rate_hz: float = Field(gt=0, description="samples per second")
    bits: int = Field(ge=1, le=24, description="resolution; 2^bits levels from 0 to full scale")
    record_samples: int = Field(ge=8, description="samples per shot: the range window is "
                                "record_samples / sample_rate_hz long")
    gain_control: Literal["agc", "fixed"] = Field(
        description="'agc': full scale follows each shot's expected peak (an ideal automatic "
        "gain control); 'fixed': full_scale_photoelectrons")
    full_scale_photoelectrons: float | None = Field(
        None, gt=0, description="gain_control = 'fixed': the signal, in primary photoelectrons "
        "per sample, that reaches full scale (above it the sample saturates)")

    @model_validator(mode="after")
    def _fixed(self):
        if self.gain_control == "fixed" and self.full_scale_photoelectrons is None:
            raise ValueError("digitizer.gain_control = 'fixed' needs "
                             "digitizer.full_scale_photoelectrons")
        return self


class PulseRanging(StrictModel):
    """How a pulsed altimeter reads its range off the digitized waveform."""

    estimator: Literal["threshold", "centroid", "gaussian_fit"] = Field(
        description="'threshold': the leading edge's crossing of the detection threshold, "
        "referred to the pulse's half-maximum point; 'centroid': the first moment of the "
        "background-subtracted return; 'gaussian_fit': a weighted least-squares fit of a "
        "Gaussian plus background (GLAS's ice-sheet algorithm)")
    threshold_sigma: float = Field(gt=0, description="detection threshold above the mean "
                                   "background, in standard deviations of the noise per "
                                   "sample: sets the detection probability and false-alarm rate")


class Background(StrictModel):
    """Background light in the receiver's field of view (direct detection counts it).

    ``source = "sun"``: the surface reflects the sun, L = rho E_sun sin(elevation) / pi with the
    sun's elevation at each shot (``chirplidar.geometry.sun``) and the surface's reflectance at
    the wavelength; ``"radiance"``: a fixed spectral radiance at the receiver (a night pass, a
    lab bench); ``"none"``: dark.
    """

    source: Literal["sun", "radiance", "none"] = Field(
        description="'sun' (survey runs), 'radiance' (a fixed value) or 'none'")
    solar_irradiance_w_m2_m: float | None = Field(
        None, gt=0, description="source = 'sun': the sun's spectral irradiance at the top of "
        "the atmosphere at the wavelength (W m^-2 per metre of wavelength; ASTM E-490: "
        "6.4e8 at 1064 nm)")
    radiance_w_m2_sr_m: float | None = Field(
        None, ge=0, description="source = 'radiance': spectral radiance reaching the receiver "
        "(W m^-2 sr^-1 per metre of wavelength)")

    @model_validator(mode="after")
    def _source(self):
        if self.source == "sun" and self.solar_irradiance_w_m2_m is None:
            raise ValueError("background.source = 'sun' needs "
                             "background.solar_irradiance_w_m2_m")
        if self.source == "radiance" and self.radiance_w_m2_sr_m is None:
            raise ValueError("background.source = 'radiance' needs "
                             "background.radiance_w_m2_sr_m")
        return self

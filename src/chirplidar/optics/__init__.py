"""Telescope and fiber optics: pupil sampling, fiber coupling, diffraction, Gaussian transmit beam.

Public API (stable):

* coupling: ``coupling_efficiency``, ``optimal_beta``, ``coupling_beta``,
  ``pupil_field_coupling``, ``fiber_mode_pupil``, ``coupling_mutual_coherence``,
  ``annulus_mode_autocorrelation``, ``monostatic_diffuse_coupling``, ``optimal_beta_monostatic``
* pupil grid: ``pupil_grid``, ``PupilGrid`` (n x n across the aperture diameter, pitch D / n)
* diffraction: ``fraunhofer``, ``focal_plane_coupling``, ``airy_intensity``,
  ``airy_first_null_rad``, ``focal_spot_diameter_m``, ``fresnel_number``, ``is_far_field``
* beam: ``beam_radius_m``, ``footprint_diameter_m``, ``diffraction_divergence_rad``,
  ``rayleigh_range_m``, ``beam_fraction_in_disc``

See docs/explanation/validation/optics.md.
"""

from ..lazy import lazy_exports

# Imported on first use (PEP 562): the submodules pull in scipy.
__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "beam": (
            "beam_fraction_in_disc",
            "beam_radius_m",
            "diffraction_divergence_rad",
            "footprint_diameter_m",
            "rayleigh_range_m",
        ),
        "coupling": (
            "annulus_mode_autocorrelation",
            "coupling_beta",
            "coupling_efficiency",
            "coupling_mutual_coherence",
            "fiber_mode_pupil",
            "monostatic_diffuse_coupling",
            "optimal_beta",
            "optimal_beta_monostatic",
            "pupil_field_coupling",
        ),
        "diffraction": (
            "airy_first_null_rad",
            "airy_intensity",
            "focal_plane_coupling",
            "focal_spot_diameter_m",
            "fraunhofer",
            "fresnel_number",
            "is_far_field",
        ),
        "pupil": ("PupilGrid", "pupil_grid"),
    },
)

__all__ = [
    "PupilGrid",
    "airy_first_null_rad",
    "airy_intensity",
    "annulus_mode_autocorrelation",
    "beam_fraction_in_disc",
    "beam_radius_m",
    "coupling_beta",
    "coupling_efficiency",
    "coupling_mutual_coherence",
    "diffraction_divergence_rad",
    "fiber_mode_pupil",
    "focal_plane_coupling",
    "focal_spot_diameter_m",
    "footprint_diameter_m",
    "fraunhofer",
    "fresnel_number",
    "is_far_field",
    "monostatic_diffuse_coupling",
    "optimal_beta",
    "optimal_beta_monostatic",
    "pupil_field_coupling",
    "pupil_grid",
    "rayleigh_range_m",
]
